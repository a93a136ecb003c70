"""The accuracy of a set of results records (:class:`ldlloc.record.QueryResult`): pose errors, the
paper's thresholds, summaries, CSV rows and terminal tables.

Top-K candidates against the truth (to judge ambiguity: is the right pose among the search's
K, and how far down?): a candidate is *good* when within :data:`~ldlloc.record.GOOD_T_M` = 0.5 m
and :data:`~ldlloc.record.GOOD_R_DEG` = 10 deg of the truth; ``first_good_rank`` is the 1-based
rank of the first good one (1: the search's top-1 is good; None: none of the K is). The *best
candidate* (:func:`ldlloc.record.best_candidate`) is the one with the smallest translation error
among the candidates within 10 deg rotation error, or, when none is, the one with the smallest
rotation error; its errors are ``best_candidate_t_error_m`` and ``best_candidate_r_error_deg``.
"""

from __future__ import annotations

import csv
import io
from typing import Any, Iterable

import numpy as np
from rich.table import Table

from ldlloc.record import GOOD_R_DEG, GOOD_T_M, QueryResult

# (name, metres, degrees): the paper's thresholds; the second is the headline accuracy.
THRESHOLDS: tuple[tuple[str, float, float], ...] = (
    ("0.05m_5deg", 0.05, 5.0),
    ("0.1m_5deg", 0.1, 5.0),
    ("0.2m_10deg", 0.2, 10.0),
)
STAGES = ("lines2d", "rotation", "search", "refine", "confidence", "total")  # image runs on several maps add "choose"
CONFIDENT_T_M, CONFIDENT_R_DEG = 0.25, 5.0  # what a confident pose is meant to be within (verdict_summary checks it)


def within_threshold(t_error_m: float, r_error_deg: float) -> bool:
    """Whether pose errors are within the headline threshold (``THRESHOLDS[1]``: 0.1 m and 5 degrees)."""
    _, t_max, r_max = THRESHOLDS[1]
    return bool(t_error_m < t_max and r_error_deg < r_max)


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
    ok = [r for r in results if r.status != "failed"]
    s = summarize(ok)["median_seconds"] if ok else {}
    stages = [*STAGES[:-1], *sorted(set(s) - set(STAGES)), STAGES[-1]]  # e.g. image runs' "choose"
    table = Table(title=title)
    for st in stages:
        table.add_column(st, justify="right")
    table.add_row(*[_fmt(s.get(st), ".3f") for st in stages])
    return table
