"""The results record of one localized panorama (:class:`QueryResult`), defined once.

Each field of :class:`QueryResult` is declared once, with its type, its default, the check a
results file's value must pass (:data:`FIELD_CHECKS`, read by
:func:`ldlloc.batch.results.validate_results`), what that check wants (the error says it), its
one-line meaning and where its value comes from (:data:`SOURCES`). From that declaration come:

- the writer: :func:`record_of` (a :class:`~ldlloc.pipeline.Localization` to a record: the fields
  that come from the localization, from the ground truth and from the map choice), used by dataset
  runs, image runs, Ray and walks; :func:`failed_record`; :func:`record_json` (one line of JSON);
- the reader: :meth:`QueryResult.from_dict` after the checks;
- what ``ldlloc localize --json`` prints (:func:`printed_record`: the same fields, rounded);
- the field table of ``docs/formats.md`` (:func:`fields_table`; ``python -m ldlloc.record`` prints
  it, and ``tests/test_record.py`` checks that the docs hold it).

A new field is one more declaration in :class:`QueryResult`.
"""

from __future__ import annotations

import json
import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any, Callable

import numpy as np

from ldlloc.pipeline import Localization
from ldlmap.core.geometry import rotation_error_deg, translation_error

STATUSES = ("ok", "coarse", "failed")
VERDICTS = ("confident", "ambiguous", "failed")
GOOD_T_M = 0.5  # a top-K candidate is "good" within 0.5 m and 10 degrees of the truth
GOOD_R_DEG = 10.0
PRINTED_T_DIGITS = 6  # `localize --json` rounds positions to 6 decimals and rotations to 8
SOURCES = {  # where a field's value comes from, for the docs
    "query": "the query", "loc": "the localization", "truth": "the ground truth (dataset runs)",
    "maps": "the map choice (several maps)", "run": "the run",
}


def is_number(x: Any) -> bool:
    """Whether ``x`` is a finite number (not a bool); math, not numpy: called per matrix entry."""
    if isinstance(x, float):
        return math.isfinite(x)
    return isinstance(x, int) and not isinstance(x, bool)


def is_count(x: Any, lo: int = 0) -> bool:
    """Whether ``x`` is an integer (not a bool) of at least ``lo``."""
    return isinstance(x, int) and not isinstance(x, bool) and x >= lo


def is_matrix(x: Any, rows: int, cols: int | None = None) -> bool:
    """Whether ``x`` is a (rows,) list, or (rows, cols) nested lists, of finite numbers."""
    if not isinstance(x, list) or len(x) != rows:
        return False
    if cols is None:
        return all(is_number(v) for v in x)
    return all(is_matrix(row, cols) for row in x)


def _is_pose(x: Any) -> bool:
    return isinstance(x, dict) and is_matrix(x.get("R"), 3, 3) and is_matrix(x.get("t"), 3)


def _is_str(x: Any) -> bool:
    return isinstance(x, str)


def _is_name(x: Any) -> bool:
    return isinstance(x, str) and x != ""


def _or_none(check: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda x: x is None or check(x)


def _is_error(x: Any) -> bool:
    return is_number(x) and x >= 0


def _is_seconds(x: Any) -> bool:
    return isinstance(x, dict) and all(isinstance(k, str) and is_number(v) for k, v in x.items())


def _is_candidates(x: Any) -> bool:
    return isinstance(x, list) and all(
        _is_pose(c) and (c.get("loss") is None or isinstance(c.get("loss"), (int, float))) for c in x)


def _is_competitors(x: Any) -> bool:
    return isinstance(x, list) and all(_is_pose(c) and isinstance(c.get("why", ""), str) for c in x)


def _is_runner_up(x: Any) -> bool:
    return isinstance(x, dict) and isinstance(x.get("map"), str) and is_number(x.get("score"))


def _input_frame(loc: Localization) -> dict | None:
    """The final pose in the map's input frame (maps built from another frame), as lists."""
    pose = loc.input_frame_pose()
    return None if pose is None else {"R": pose[0].tolist(), "t": pose[1].tolist()}


def _spec(meaning: str, what: str, check: Callable[[Any], bool], source: str, default: Any = MISSING, *,
          factory: Any = MISSING, required: bool = False, of_loc: Callable[[Localization], Any] | None = None):
    """A record field: its ``meaning`` (docs), the ``check`` a file's value passes and ``what`` it
    wants (errors), its ``source`` (:data:`SOURCES`), whether every record must have it
    (``required``), and ``of_loc``: its value taken from a localization (:func:`record_of`)."""
    meta = {"meaning": meaning, "what": what, "check": check, "source": source, "required": required,
            "of_loc": of_loc}
    return field(default=default, default_factory=factory, metadata=meta)


_FINITE_OR_NULL = "a finite number or null"


@dataclass
class QueryResult:
    """The outcome of localizing one panorama: one record of a results file (module docstring)."""

    image: str = _spec("path of the panorama (relative ones start at `meta.base_dir`)", "a string", _is_str,
                       "query", required=True)
    scene: str = _spec("the query's scene; image runs: the chosen map's name, `(none)` before one was chosen",
                       "a non-empty string", _is_name, "query", required=True)
    split: str = _spec("the dataset split; `images` for a run of your own panoramas", "a string", _is_str, "query",
                       required=True)
    name: str = _spec("the query's name, unique in the file", "a non-empty string", _is_name, "query",
                      required=True)
    R: list | None = _spec("estimated rotation, world to camera (3x3)", "a 3x3 matrix of finite numbers or null",
                           _or_none(lambda x: is_matrix(x, 3, 3)), "loc", None,
                           of_loc=lambda loc: np.asarray(loc.rot_cam_from_world).tolist())
    t: list | None = _spec("estimated camera centre in the map frame (metres)", "3 finite numbers or null",
                           _or_none(lambda x: is_matrix(x, 3)), "loc", None,
                           of_loc=lambda loc: np.asarray(loc.center).tolist())
    t_error_m: float | None = _spec("distance to the true camera centre (metres; null without ground truth)",
                                    "a finite number >= 0 or null", _or_none(_is_error), "truth", None,
                                    required=True)
    r_error_deg: float | None = _spec("angle to the true rotation (degrees; null without ground truth)",
                                      "a finite number >= 0 or null", _or_none(_is_error), "truth", None,
                                      required=True)
    seconds: dict[str, float] = _spec("seconds per stage (lines2d, rotation, search, refine, confidence, total)",
                                      "an object of finite seconds", _is_seconds, "loc", factory=dict,
                                      of_loc=lambda loc: {k: float(v) for k, v in loc.seconds.items()})
    num_rotations: int = _spec("candidate rotations searched", "an integer >= 0", is_count, "loc", 0,
                               of_loc=lambda loc: int(loc.num_rotations))
    num_matches: int = _spec("feature matches of the refinement", "an integer >= 0", is_count, "loc", 0,
                             of_loc=lambda loc: int(loc.num_matches))
    num_inliers: int = _spec("inliers of the refinement", "an integer >= 0", is_count, "loc", 0,
                             of_loc=lambda loc: int(loc.num_inliers))
    refined: bool = _spec("whether the refinement made the final pose", "true or false",
                          lambda x: isinstance(x, bool), "loc", False, of_loc=lambda loc: bool(loc.refined))
    status: str = _spec("ok | coarse (the search's pose: refinement failed or skipped) | failed", " | ".join(STATUSES),
                        lambda x: x in STATUSES, "loc", "ok", required=True, of_loc=lambda loc: loc.status)
    message: str = _spec("why a query failed or was not refined", "a string", _is_str, "loc", "",
                         of_loc=lambda loc: loc.message)
    refine_method: str = _spec("what made the final pose: features | geometric | features+geometric | none",
                               "a string", _is_str, "loc", "none", of_loc=lambda loc: loc.refine_method)
    refine_residual_deg: float | None = _spec("geometric refinement: median angle of the matched line points",
                                              _FINITE_OR_NULL, _or_none(is_number), "loc", None,
                                              of_loc=lambda loc: loc.refine_residual_deg)
    rotation_prior: str = _spec("`free` (the paper's) or `upright<=Xdeg` (--max-tilt, upright queries)", "a string",
                                _is_str, "loc", "free", of_loc=lambda loc: loc.rotation_prior)
    candidates: list = _spec("the search's top-K poses, best first: `{R, t, loss}`",
                             "a list of {R: 3x3, t: 3, loss} of finite numbers", _is_candidates, "loc", factory=list,
                             of_loc=lambda loc: loc.candidate_dicts())
    best_candidate_t_error_m: float | None = _spec("translation error of the best of the K (`best_candidate`)",
                                                   _FINITE_OR_NULL, _or_none(is_number), "truth", None)
    best_candidate_r_error_deg: float | None = _spec("rotation error of the best of the K", _FINITE_OR_NULL,
                                                     _or_none(is_number), "truth", None)
    first_good_rank: int | None = _spec("1-based rank of the first candidate within 0.5 m / 10 deg",
                                        "an integer >= 1 or null", _or_none(lambda x: is_count(x, 1)), "truth", None)
    input_frame: dict | None = _spec("maps built from another frame (SfM): the pose `{R, t}` in that frame",
                                     "{R: 3x3, t: 3} or null", _or_none(_is_pose), "loc", None, of_loc=_input_frame)
    picture_error: str | None = _spec("--save-vis: why this query's picture was not written (its result stands)",
                                      "a string or null", _or_none(_is_str), "run", None)
    map: str | None = _spec("image runs: path of the map the pose is in (the chosen one)", "a string or null",
                            _or_none(_is_str), "maps", None)
    map_runner_up: dict | None = _spec("several maps: the next best `{map, score, confidence}`",
                                       "{map: string, score: number} or null", _or_none(_is_runner_up), "maps", None)
    map_scores: list | None = _spec("several maps: `[{map, search_loss, loss}]`, best search first",
                                    "a list of objects or null",
                                    _or_none(lambda x: isinstance(x, list) and all(isinstance(v, dict) for v in x)),
                                    "maps", None)
    confidence: float | None = _spec("how far to trust the pose, in [0, 1] (null: older runs)",
                                     "a number in [0, 1] or null", _or_none(lambda x: is_number(x) and 0 <= x <= 1),
                                     "loc", None, of_loc=lambda loc: loc.confidence)
    verdict: str | None = _spec("confident | ambiguous | failed (null: older runs)",
                                "confident | ambiguous | failed or null", _or_none(lambda x: x in VERDICTS), "loc",
                                None, of_loc=lambda loc: loc.verdict)
    competitors: list = _spec("distinct poses of nearly the same loss: `{R, t, loss, why}`",
                              "a list of {R: 3x3, t: 3, loss, why}", _is_competitors, "loc", factory=list,
                              of_loc=lambda loc: list(loc.competitors))
    confidence_signals: dict | None = _spec("what the confidence was computed from", "an object of finite numbers "
                                            "or null", _or_none(_is_seconds), "loc", None,
                                            of_loc=lambda loc: dict(loc.confidence_signals) or None)
    walk: dict | None = _spec("a frame of a walk: `{name, frame, time, walk_decided, single_verdict, "
                              "single_confidence, margin, tracked, lost, checked, basis, single_pose, single_map, "
                              "ref_loss, relative}`; null: a single image",
                              "an object or null", _or_none(lambda x: isinstance(x, dict)), "run", None)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "QueryResult":
        """The record of a parsed (and checked: :data:`FIELD_CHECKS`) JSON object; absent fields get
        their defaults (files written before they existed)."""
        known = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        return cls(**known)


FIELD_CHECKS: dict[str, tuple[Callable[[Any], bool], str]] = {
    f.name: (f.metadata["check"], f.metadata["what"]) for f in fields(QueryResult)}  # name -> (check, what it must be)
# Fields every record has had since the first results file: a record without one is not ours.
REQUIRED_FIELDS = tuple(f.name for f in fields(QueryResult) if f.metadata["required"])


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


def truth_fields(loc: Localization, rot_true: np.ndarray, center_true: np.ndarray) -> dict[str, Any]:
    """The fields of source ``truth``: errors of the pose and of the top-K candidates against a
    ground truth in the dataset's frame, the map's input frame (moved into the map frame, where
    errors are in metres, on maps built with another frame)."""
    gt_rot, gt_center = loc.truth_in_map_frame(rot_true, center_true)
    cand_t = [translation_error(c, gt_center) for c in np.asarray(loc.candidates_center)]
    cand_r = [rotation_error_deg(R, gt_rot) for R in np.asarray(loc.candidates_rot)]
    best = best_candidate(cand_t, cand_r)
    return {"t_error_m": translation_error(loc.center, gt_center),
            "r_error_deg": rotation_error_deg(loc.rot_cam_from_world, gt_rot),
            "best_candidate_t_error_m": None if best is None else float(cand_t[best]),
            "best_candidate_r_error_deg": None if best is None else float(cand_r[best]),
            "first_good_rank": first_good_rank(cand_t, cand_r)}


def record_of(loc: Localization, image: str, scene: str, split: str, name: str,
              truth: tuple[np.ndarray, np.ndarray] | None = None, **more: Any) -> QueryResult:
    """The record of query ``name`` (``image``, ``scene``, ``split``) localized as ``loc``: every
    field of source ``loc``, the ``truth`` fields when its pose ``(R world to camera, centre)``
    is known, and ``more`` (the map choice's fields, a walk's)."""
    values = {f.name: f.metadata["of_loc"](loc) for f in fields(QueryResult) if f.metadata["of_loc"] is not None}
    if truth is not None:
        values.update(truth_fields(loc, *truth))
    return QueryResult(image=image, scene=scene, split=split, name=name, **{**values, **more})


def failed_record(image: str, scene: str, split: str, name: str, message: str, seconds: dict[str, float],
                  rotation_prior: str, **more: Any) -> QueryResult:
    """The ``failed`` record of a query that could not be localized, with its reason (``more``:
    other fields, e.g. the map)."""
    return QueryResult(image=image, scene=scene, split=split, name=name, status="failed", message=message,
                       seconds=seconds, rotation_prior=rotation_prior, confidence=0.0, verdict="failed", **more)


def json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (strict JSON, no NaN / Infinity)."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def record_json(r: QueryResult) -> str:
    """Record ``r`` as one line of strict JSON (non-finite numbers as null), its fields in
    declaration order."""
    values = {k: getattr(r, k) for k in r.__dataclass_fields__}  # values are plain lists and dicts already
    try:
        return json.dumps(values, allow_nan=False)
    except ValueError:  # a NaN or an infinity somewhere: null
        return json.dumps(json_safe(asdict(r)), allow_nan=False)


def _rounded_pose(pose: dict) -> dict:
    """``{R, t}`` (and any other keys) with R to 8 decimals and t to 6, as `localize --json` prints."""
    return {**pose, "R": np.round(np.asarray(pose["R"], dtype=np.float64), PRINTED_T_DIGITS + 2).tolist(),
            "t": np.round(np.asarray(pose["t"], dtype=np.float64), PRINTED_T_DIGITS).tolist()}


# The record's fields that `ldlloc localize --json` prints first, in this order (then the map's line count
# and loading seconds, the errors against --gt, the candidates and the input frame's pose).
PRINTED_FIELDS = ("image", "map", "R", "t", "status", "refined", "message", "num_rotations", "num_matches",
                  "num_inliers", "rotation_prior", "refine_method", "refine_residual_deg", "confidence", "verdict",
                  "competitors", "confidence_signals", "seconds")


def printed_record(r: QueryResult, num_lines: int, load_seconds: dict[str, float],
                   errors: dict[str, Any] | None = None) -> dict[str, Any]:
    """Record ``r`` as `ldlloc localize --json` prints it: :data:`PRINTED_FIELDS` (poses rounded
    to 8 and 6 decimals, seconds to 4), ``num_lines`` after ``num_rotations``, ``load_seconds``,
    ``errors`` (against ``--gt``), the candidates (rounded) and ``input_frame`` when there is one."""
    out: dict[str, Any] = {}
    for key in PRINTED_FIELDS:
        out[key] = getattr(r, key)
        if key == "num_rotations":
            out["num_lines"] = num_lines
    out.update(_rounded_pose({"R": r.R, "t": r.t}))
    out["confidence_signals"] = r.confidence_signals or {}  # printed as an object, empty or not
    out["seconds"] = {k: round(v, 4) for k, v in r.seconds.items()}
    out["load_seconds"] = {k: round(v, 4) for k, v in load_seconds.items()}
    out.update(errors or {})
    out["candidates"] = [_rounded_pose(c) for c in r.candidates]
    if r.input_frame is not None:
        out["input_frame"] = _rounded_pose(r.input_frame)
    return out


def printed_failure(r: QueryResult) -> dict[str, Any]:
    """Failed record ``r`` as `ldlloc localize --json` prints it: the reason, the panorama and the map."""
    return {"error": r.message, "image": r.image, "map": r.map, "status": r.status, "confidence": r.confidence,
            "verdict": r.verdict}


def fields_table() -> str:
    """The record's fields as a Markdown table (name, what a value must be, source, meaning): the
    table of ``docs/formats.md``."""
    cell = lambda text: text.replace("|", "\\|")  # noqa: E731 - a bar inside a cell is escaped
    rows = ["| field | value | from | meaning |", "| --- | --- | --- | --- |"]
    for f in fields(QueryResult):
        m = f.metadata
        rows.append(f"| `{f.name}`{' (always)' if m['required'] else ''} | {cell(m['what'])} | "
                    f"{SOURCES[m['source']]} | {cell(m['meaning'])} |")
    return "\n".join(rows)


if __name__ == "__main__":  # python -m ldlloc.record: the table of docs/formats.md
    print(fields_table())
