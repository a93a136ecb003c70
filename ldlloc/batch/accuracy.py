"""A query's result record (:class:`QueryResult`) and the accuracy of a set of them: pose errors, the
paper's thresholds, top-K candidate ranks, summaries, CSV rows and terminal tables.

Top-K candidates against the truth (to judge ambiguity: is the right pose among the search's
K, and how far down?): a candidate is *good* when within :data:`GOOD_T_M` = 0.5 m and
:data:`GOOD_R_DEG` = 10 deg of the truth; ``first_good_rank`` is the 1-based rank of the first
good one (1: the search's top-1 is good; None: none of the K is). The *best candidate*
(:func:`best_candidate`) is the one with the smallest translation error among the candidates
within 10 deg rotation error, or, when none is, the one with the smallest rotation error; its
errors are ``best_candidate_t_error_m`` and ``best_candidate_r_error_deg``.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np


from ldlmap.core.geometry import rotation_error_deg, translation_error

# (name, metres, degrees): the paper's thresholds; the second is the headline accuracy.
THRESHOLDS: tuple[tuple[str, float, float], ...] = (
    ("0.05m_5deg", 0.05, 5.0),
    ("0.1m_5deg", 0.1, 5.0),
    ("0.2m_10deg", 0.2, 10.0),
)
STAGES = ("lines2d", "rotation", "search", "refine", "confidence", "total")  # image runs on several maps add "choose"
CONFIDENT_T_M, CONFIDENT_R_DEG = 0.25, 5.0  # a confident pose is meant to be within 0.25 m / 5 deg (issue 20)
GOOD_T_M = 0.5  # a top-K candidate is "good" within 0.5 m and 10 degrees of the truth
GOOD_R_DEG = 10.0


def pose_errors(rot_est: np.ndarray, center_est: np.ndarray, rot_true: np.ndarray, center_true: np.ndarray) -> dict:
    """``t_error_m``, ``r_error_deg`` of an estimated pose against the truth, and ``localized``:
    both under the headline threshold (``THRESHOLDS[1]``: 0.1 m and 5 degrees)."""
    t_err = translation_error(center_est, center_true)
    r_err = rotation_error_deg(rot_est, rot_true)
    _, t_max, r_max = THRESHOLDS[1]
    return {"t_error_m": t_err, "r_error_deg": r_err, "localized": bool(t_err < t_max and r_err < r_max)}


@dataclass
class QueryResult:
    """The outcome of localizing one panorama."""

    image: str
    scene: str
    split: str
    name: str
    R: list | None = None  # estimated rotation, world -> camera (3x3 nested list)
    t: list | None = None  # estimated camera centre (3,)
    t_error_m: float | None = None
    r_error_deg: float | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    num_rotations: int = 0
    num_matches: int = 0
    num_inliers: int = 0
    refined: bool = False
    status: str = "ok"  # ok | coarse (refinement failed or skipped) | failed
    message: str = ""
    refine_method: str = "none"  # what produced the final pose: features | geometric | none
    refine_residual_deg: float | None = None  # geometric refinement: median angle of matched line points
    rotation_prior: str = "free"  # "free" (paper) or "upright<=Xdeg" (--max-tilt, upright queries)
    candidates: list = field(default_factory=list)  # top-K search poses, best first: {R, t, loss}
    best_candidate_t_error_m: float | None = None  # errors of the best of the K (best_candidate)
    best_candidate_r_error_deg: float | None = None
    first_good_rank: int | None = None  # 1-based rank of the first candidate within 0.5 m / 10 deg
    input_frame: dict | None = None  # maps built from another frame (SfM): the pose {R, t} in that frame
    picture_error: str | None = None  # --save-vis: why this query's picture was not written (its result stands)
    map: str | None = None  # image runs: path of the map the pose is in (the chosen one)
    map_runner_up: dict | None = None  # image runs on several maps: the next best {"map": path, "score": loss}
    map_scores: list | None = None  # image runs on several maps: [{"map", "search_loss", "loss"}], best search first
    confidence: float | None = None  # how far to trust the pose, in [0, 1] (ldlloc.confidence; None: older runs)
    verdict: str | None = None  # confident | ambiguous | failed (None: older runs)
    competitors: list = field(default_factory=list)  # distinct poses of nearly the same loss: {R, t, loss, why}
    confidence_signals: dict | None = None  # what the confidence was computed from (ldlloc.confidence)
    walk: dict | None = None  # a frame of a walk (ldlloc.walk.run.walk_fields): {name, frame, time, walk_decided,
    # single_verdict, single_confidence, margin, tracked}; None: a single image

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "QueryResult":
        known = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        return cls(**known)


def best_candidate(t_errors, r_errors, max_r_deg: float = GOOD_R_DEG) -> int | None:
    """Index of the best candidate: the smallest translation error among those within
    ``max_r_deg`` rotation error, else the smallest rotation error (None when there are none)."""
    t = np.asarray(t_errors, dtype=np.float64)
    r = np.asarray(r_errors, dtype=np.float64)
    if len(t) == 0:
        return None
    close = np.flatnonzero(r < max_r_deg)
    return int(close[np.argmin(t[close])]) if len(close) else int(np.argmin(r))


def first_good_rank(t_errors, r_errors, max_t_m: float = GOOD_T_M, max_r_deg: float = GOOD_R_DEG) -> int | None:
    """1-based rank of the first candidate within ``max_t_m`` and ``max_r_deg`` (None: none is)."""
    good = np.flatnonzero((np.asarray(t_errors, float) < max_t_m) & (np.asarray(r_errors, float) < max_r_deg))
    return int(good[0]) + 1 if len(good) else None


def _median(values: Iterable[float]) -> float | None:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else None


def summarize(results: list[QueryResult], device: str | None = None) -> dict[str, Any]:
    """Counts, median errors, accuracy at each threshold and median per-stage seconds.

    Failed queries count as not localized (infinite error) in the accuracies and medians. Runs
    without ground truth (:func:`has_ground_truth`: image runs) have no errors, accuracies or
    search ranks (None) but per-map counts (``maps``: map -> {count, ok, coarse, failed}).
    """
    n = len(results)
    if not has_ground_truth(results):
        return _summarize_without_truth(results, device)
    terr = np.array([r.t_error_m if r.t_error_m is not None else np.inf for r in results], float)
    rerr = np.array([r.r_error_deg if r.r_error_deg is not None else np.inf for r in results], float)
    acc = {name: (float(np.mean((terr < m) & (rerr < d))) if n else None) for name, m, d in THRESHOLDS}
    stages = sorted({s for r in results for s in r.seconds})
    out: dict[str, Any] = {
        "count": n,
        "failed": int(sum(r.status == "failed" for r in results)),
        "coarse_only": int(sum(r.status == "coarse" for r in results)),
        "median_t_error_m": float(np.median(terr)) if n else None,
        "median_r_error_deg": float(np.median(rerr)) if n else None,
        "accuracy": acc,
        "median_seconds": {s: _median(r.seconds.get(s) for r in results) for s in stages},
        "median_num_rotations": _median(r.num_rotations for r in results if r.status != "failed"),
    }
    with_cands = [r for r in results if r.candidates]
    if with_cands:  # pose search alone: top-1 and best of the top K within 0.5 m / 10 deg
        ranks = [r.first_good_rank for r in results]
        key = f"{GOOD_T_M:g}m_{GOOD_R_DEG:g}deg"
        out["search"] = {f"top1_{key}": float(np.mean([k == 1 for k in ranks])),
                         f"topk_{key}": float(np.mean([k is not None for k in ranks]))}
    verdicts = verdict_summary(results)
    if verdicts:
        out["verdicts"] = verdicts
    if device is not None:
        out["device"] = device
    return out


def has_ground_truth(results: list[QueryResult]) -> bool:
    """Whether errors can be known: records of a dataset run (image runs, ``split="images"``, have none)."""
    return not results or any(r.split != "images" for r in results)


def outcome(r: QueryResult) -> str:
    """How a run without ground truth counts query ``r``: its status, except that a pose whose own
    verdict is ``failed`` counts as failed (never as ok or coarse)."""
    return "failed" if r.verdict == "failed" else r.status


def _summarize_without_truth(results: list[QueryResult], device: str | None) -> dict[str, Any]:
    """:func:`summarize` of an image run: counts by :func:`outcome` and by map, median stage seconds."""
    stages = sorted({s for r in results for s in r.seconds})
    per_map: dict[str, dict[str, int]] = {}
    outcomes = [outcome(r) for r in results]
    for r, o in zip(results, outcomes):
        c = per_map.setdefault(r.map or r.scene, {"count": 0, "ok": 0, "coarse": 0, "failed": 0})
        c["count"] += 1
        c[o] += 1
    out: dict[str, Any] = {
        "count": len(results),
        "localized": outcomes.count("ok"),
        "failed": outcomes.count("failed"),
        "coarse_only": outcomes.count("coarse"),
        "median_t_error_m": None, "median_r_error_deg": None,
        "accuracy": {name: None for name, _, _ in THRESHOLDS},
        "median_seconds": {s: _median(r.seconds.get(s) for r in results if r.status != "failed") for s in stages},
        "median_num_rotations": _median(r.num_rotations for r in results if r.status != "failed"),
        "maps": dict(sorted(per_map.items())),
    }
    if device is not None:
        out["device"] = device
    return out


def verdict_summary(results: list[QueryResult]) -> dict[str, Any] | None:
    """How many queries are confident, ambiguous, failed (None when no result has a verdict: older
    runs) and, when errors exist, the share of the confident ones within 0.25 m / 5 deg
    (``confident_within_0.25m_5deg``) and 0.1 m / 5 deg."""
    if not any(r.verdict is not None for r in results):
        return None
    out: dict[str, Any] = {v: sum(r.verdict == v for r in results) for v in ("confident", "ambiguous", "failed")}
    conf = [r for r in results if r.verdict == "confident" and r.t_error_m is not None and r.r_error_deg is not None]
    if conf:
        for t_max, r_max in ((CONFIDENT_T_M, CONFIDENT_R_DEG), THRESHOLDS[1][1:]):
            out[f"confident_within_{t_max:g}m_{r_max:g}deg"] = float(np.mean(
                [r.t_error_m < t_max and r.r_error_deg < r_max for r in conf]))
    return out


def verdict_line(results: list[QueryResult]) -> str | None:
    """One line: the verdict counts and, with ground truth, the accuracy of the confident poses."""
    v = verdict_summary(results)
    if v is None:
        return None
    n = len(results)
    line = f"verdicts: {v['confident']} confident, {v['ambiguous']} ambiguous, {v['failed']} failed (of {n})"
    key = f"confident_within_{CONFIDENT_T_M:g}m_{CONFIDENT_R_DEG:g}deg"
    if key in v:
        k = round(v[key] * v["confident"])
        line += (f"; confident poses within {CONFIDENT_T_M:g} m / {CONFIDENT_R_DEG:g} deg: {v[key]:.3f} "
                 f"({k} / {v['confident']})")
    return line


def group_by(results: list[QueryResult], key: str) -> dict[str, list[QueryResult]]:
    """Results grouped by an attribute (``scene`` or ``split``), keys sorted."""
    groups: dict[str, list[QueryResult]] = {}
    for r in results:
        groups.setdefault(getattr(r, key), []).append(r)
    return dict(sorted(groups.items()))


def results_csv(results: list[QueryResult]) -> str:
    """One row per query: identifiers, errors, estimate, counts, rotation prior, the best of the
    top-K candidates (errors, first good rank) and stage seconds (the candidates themselves are in
    the JSON only)."""
    stages = sorted({s for r in results for s in r.seconds}, key=lambda s: (s not in STAGES, STAGES.index(s) if s in STAGES else 0, s))
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["name", "scene", "split", "image", "status", "t_error_m", "r_error_deg", "tx", "ty", "tz",
                "num_rotations", "num_matches", "num_inliers", "refined", "refine_method", "rotation_prior",
                "best_candidate_t_error_m", "best_candidate_r_error_deg", "first_good_rank", "map", "confidence",
                "verdict"]
               + [f"sec_{s}" for s in stages])
    for r in results:
        t = r.t if r.t is not None else [None] * 3
        w.writerow([r.name, r.scene, r.split, r.image, r.status, r.t_error_m, r.r_error_deg, *t,
                    r.num_rotations, r.num_matches, r.num_inliers, int(r.refined), r.refine_method, r.rotation_prior,
                    r.best_candidate_t_error_m, r.best_candidate_r_error_deg, r.first_good_rank, r.map, r.confidence,
                    r.verdict]
                   + [r.seconds.get(s) for s in stages])
    return buf.getvalue()


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def summary_table(results: list[QueryResult], by: str, title: str):
    """A Rich table of errors and accuracies, one row per group (scene or split) and a total row."""
    from rich.table import Table

    groups = group_by(results, by)
    if not has_ground_truth(results):
        return _counts_table(groups, by, title)
    table = Table(title=title, caption="accuracy: fraction of queries within (t, R) error; errors are medians")
    table.add_column(by, no_wrap=True, min_width=max([len(k) for k in groups] + [3]))
    for col in ("n", "fail", "t m", "R °", "5cm,5°", "10cm,5°", "20cm,10°", "s"):
        table.add_column(col, justify="right", no_wrap=True)
    rows = list(groups.items()) + ([("all", results)] if len(groups) > 1 else [])
    for name, rs in rows:
        s = summarize(rs)
        table.add_row(
            name, str(s["count"]), str(s["failed"]), _fmt(s["median_t_error_m"], ".3f"),
            _fmt(s["median_r_error_deg"], ".2f"), *[_fmt(s["accuracy"][k], ".2f") for k, _, _ in THRESHOLDS],
            _fmt(s["median_seconds"].get("total"), ".2f"), style="bold" if name == "all" else None,
        )
    return table


def _counts_table(groups: dict[str, list[QueryResult]], by: str, title: str):
    """:func:`summary_table` without ground truth: per group, queries localized (refined), coarse
    (the search's pose kept) and failed, and the median seconds."""
    from rich.table import Table

    table = Table(title=title, caption="no ground truth: ok = refined pose, coarse = the search's pose, fail = "
                  "none, or a pose whose verdict is failed")
    table.add_column(by, no_wrap=True, min_width=max([len(k) for k in groups] + [3]))
    for col in ("n", "ok", "coarse", "fail", "s"):
        table.add_column(col, justify="right", no_wrap=True)
    rows = list(groups.items()) + ([("all", [r for rs in groups.values() for r in rs])] if len(groups) > 1 else [])
    for name, rs in rows:
        s = summarize(rs)
        table.add_row(name, str(s["count"]), str(s["localized"]), str(s["coarse_only"]), str(s["failed"]),
                      _fmt(s["median_seconds"].get("total"), ".2f"), style="bold" if name == "all" else None)
    return table


def timing_table(results: list[QueryResult], title: str = "median seconds per stage"):
    """A Rich table of the median seconds of each stage (successful queries)."""
    from rich.table import Table

    ok = [r for r in results if r.status != "failed"]
    s = summarize(ok)["median_seconds"] if ok else {}
    stages = [*STAGES[:-1], *sorted(set(s) - set(STAGES)), STAGES[-1]]  # e.g. image runs' "choose"
    table = Table(title=title)
    for st in stages:
        table.add_column(st, justify="right")
    table.add_row(*[_fmt(s.get(st), ".3f") for st in stages])
    return table
