"""Localization results: per-query records, summaries at the paper's thresholds, JSON/CSV, tables.

Results file (DESIGN.md section 4)::

    {"queries": [ {image, scene, split, name, R (3x3), t (3,), t_error_m, r_error_deg,
                   seconds: {stage: s}, num_rotations, num_matches, num_inliers, refined,
                   status, message, refine_method, refine_residual_deg, rotation_prior,
                   candidates: [{R, t, loss}, ...] (the search's top K, best first),
                   best_candidate_t_error_m, best_candidate_r_error_deg, first_good_rank}, ... ],
     "summary": {count, failed, median_t_error_m, median_r_error_deg,
                 accuracy: {"0.05m_5deg": a, "0.1m_5deg": a, "0.2m_10deg": a},
                 median_seconds: {stage: s}, device,
                 search: {"top1_0.5m_10deg": a, "topk_0.5m_10deg": a} (when candidates were kept),
                 ...}}

Top-K candidates against the truth (to judge ambiguity: is the right pose among the search's
K, and how far down?): a candidate is *good* when within :data:`GOOD_T_M` = 0.5 m and
:data:`GOOD_R_DEG` = 10 deg of the truth; ``first_good_rank`` is the 1-based rank of the first
good one (1: the search's top-1 is good; None: none of the K is). The *best candidate*
(:func:`best_candidate`) is the one with the smallest translation error among the candidates
within 10 deg rotation error, or, when none is, the one with the smallest rotation error; its
errors are ``best_candidate_t_error_m`` and ``best_candidate_r_error_deg``. The candidates are
in the JSON only (not in the CSV). Files written before these fields existed still load (the
fields get their defaults: no candidates, rotation prior "free").

``ResultsWriter`` rewrites the JSON and then the CSV beside it, each atomically, after every
query, so an interrupted run loses nothing and ``--resume`` skips the queries already there (and
retries the failed ones). It holds a lock (``r.json.lock``) while it writes: a second run on the
same file is refused. Files carry ``"format_version": 1`` (absent in older files, read as 1);
:func:`validate_results` checks every record when a file is read (``report``, ``--resume``).
"""

from __future__ import annotations

import csv
import fcntl
import io
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from ldlmap.errors import FormatVersionError, InputError, LdlError, atomic_file, remove_stale_temporaries, require_file
from ldlmap.geometry import rotation_error_deg, translation_error

# (name, metres, degrees): the paper's thresholds; the second is the headline accuracy.
THRESHOLDS: tuple[tuple[str, float, float], ...] = (
    ("0.05m_5deg", 0.05, 5.0),
    ("0.1m_5deg", 0.1, 5.0),
    ("0.2m_10deg", 0.2, 10.0),
)
STAGES = ("lines2d", "rotation", "search", "refine", "total")
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

    Failed queries count as not localized (infinite error) in the accuracies and medians.
    """
    n = len(results)
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
    if device is not None:
        out["device"] = device
    return out


def group_by(results: list[QueryResult], key: str) -> dict[str, list[QueryResult]]:
    """Results grouped by an attribute (``scene`` or ``split``), keys sorted."""
    groups: dict[str, list[QueryResult]] = {}
    for r in results:
        groups.setdefault(getattr(r, key), []).append(r)
    return dict(sorted(groups.items()))


RESULTS_FORMAT_VERSION = 1  # top-level "format_version" of a results file (absent: written before it, read as 1)
STATUSES = ("ok", "coarse", "failed")
OPTION_KEYS = ("dataset", "root", "splits", "map_level", "device", "params", "max_tilt_deg")  # meta compared by --resume
MAX_RESULTS_BYTES = 2 << 30  # a results file larger than this is not one of ours (2 GiB: ~1 million queries)


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and bool(np.isfinite(x))


def _is_count(x: Any, lo: int = 0) -> bool:
    """Whether ``x`` is an integer (not a bool) of at least ``lo``."""
    return isinstance(x, int) and not isinstance(x, bool) and x >= lo


def _is_matrix(x: Any, rows: int, cols: int | None = None) -> bool:
    """Whether ``x`` is a (rows,) list, or (rows, cols) nested lists, of finite numbers."""
    if not isinstance(x, list) or len(x) != rows:
        return False
    if cols is None:
        return all(_is_number(v) for v in x)
    return all(_is_matrix(row, cols) for row in x)


# Field of a query record -> (check, what it must be). Absent fields get their defaults (older files).
_FIELD_CHECKS: dict[str, tuple[Any, str]] = {
    "image": (lambda x: isinstance(x, str), "a string"),
    "scene": (lambda x: isinstance(x, str) and x != "", "a non-empty string"),
    "split": (lambda x: isinstance(x, str), "a string"),
    "name": (lambda x: isinstance(x, str) and x != "", "a non-empty string"),
    "R": (lambda x: x is None or _is_matrix(x, 3, 3), "a 3x3 matrix of finite numbers or null"),
    "t": (lambda x: x is None or _is_matrix(x, 3), "3 finite numbers or null"),
    "t_error_m": (lambda x: x is None or (_is_number(x) and x >= 0), "a finite number >= 0 or null"),
    "r_error_deg": (lambda x: x is None or (_is_number(x) and x >= 0), "a finite number >= 0 or null"),
    "seconds": (lambda x: isinstance(x, dict) and all(isinstance(k, str) and _is_number(v) for k, v in x.items()),
                "an object of finite seconds"),
    "num_rotations": (_is_count, "an integer >= 0"),
    "num_matches": (_is_count, "an integer >= 0"),
    "num_inliers": (_is_count, "an integer >= 0"),
    "refined": (lambda x: isinstance(x, bool), "true or false"),
    "status": (lambda x: x in STATUSES, " | ".join(STATUSES)),
    "message": (lambda x: isinstance(x, str), "a string"),
    "refine_method": (lambda x: isinstance(x, str), "a string"),
    "refine_residual_deg": (lambda x: x is None or _is_number(x), "a finite number or null"),
    "rotation_prior": (lambda x: isinstance(x, str), "a string"),
    "candidates": (lambda x: isinstance(x, list) and all(
        isinstance(c, dict) and _is_matrix(c.get("R"), 3, 3) and _is_matrix(c.get("t"), 3)
        and (c.get("loss") is None or isinstance(c.get("loss"), (int, float))) for c in x),
        "a list of {R: 3x3, t: 3, loss} of finite numbers"),
    "best_candidate_t_error_m": (lambda x: x is None or _is_number(x), "a finite number or null"),
    "best_candidate_r_error_deg": (lambda x: x is None or _is_number(x), "a finite number or null"),
    "first_good_rank": (lambda x: x is None or _is_count(x, 1),
                        "an integer >= 1 or null"),
    "input_frame": (lambda x: x is None or (isinstance(x, dict) and _is_matrix(x.get("R"), 3, 3)
                                            and _is_matrix(x.get("t"), 3)), "{R: 3x3, t: 3} or null"),
    "picture_error": (lambda x: x is None or isinstance(x, str), "a string or null"),
}
_REQUIRED_FIELDS = ("image", "scene", "split", "name")


def validate_results(data: Any, source: str | Path = "results") -> tuple[list[QueryResult], dict[str, Any]]:
    """The records and ``meta`` of a parsed results file, checked field by field.

    Raises :class:`InputError` (one line naming the first bad field) for a wrong top-level type,
    missing or mistyped fields, NaN or infinite numbers, an unknown status or a query twice, and
    :class:`FormatVersionError` for a ``format_version`` this code does not read. The ``summary``
    is not read (it is recomputed from the records)."""
    bad = f"not a results file of `ldlloc run`: {source}"
    if not isinstance(data, dict):
        raise InputError(f"{bad} (the top level is a JSON {type(data).__name__}, not an object)")
    version = data.get("format_version", RESULTS_FORMAT_VERSION)
    if isinstance(version, bool) or not isinstance(version, int):
        raise InputError(f"{bad} (format_version must be an integer, got {version!r:.40})")
    if version != RESULTS_FORMAT_VERSION:
        raise FormatVersionError(f"results file {source} has format_version {version}; this ldlloc reads "
                                 f"{RESULTS_FORMAT_VERSION} (use the ldlloc that wrote it, or run again)")
    queries, meta = data.get("queries"), data.get("meta", {})
    if not isinstance(queries, list):
        raise InputError(f"{bad} (\"queries\" must be a list, got {type(queries).__name__})")
    if not isinstance(meta, dict):
        raise InputError(f"{bad} (\"meta\" must be an object, got {type(meta).__name__})")
    seen: set[str] = set()
    for i, q in enumerate(queries):
        if not isinstance(q, dict):
            raise InputError(f"{bad} (queries[{i}] is a {type(q).__name__}, not an object)")
        missing = [k for k in _REQUIRED_FIELDS if k not in q]
        if missing:
            raise InputError(f"{bad} (queries[{i}] lacks {', '.join(missing)})")
        for key, (ok, what) in _FIELD_CHECKS.items():
            if key in q and not ok(q[key]):
                raise InputError(f"{bad} (queries[{i}].{key} must be {what}, got {json.dumps(q[key])[:40]})")
        if q["name"] in seen:
            raise InputError(f"{bad} (query {q['name']} appears twice)")
        seen.add(q["name"])
    return [QueryResult.from_dict(q) for q in queries], meta


def load_results(path: str | Path) -> tuple[list[QueryResult], dict[str, Any]]:
    """Read and validate (:func:`validate_results`) a results JSON written by :class:`ResultsWriter`."""
    path = require_file(path, "results file")
    if path.stat().st_size > MAX_RESULTS_BYTES:
        raise InputError(f"not a results file of `ldlloc run`: {path} ({path.stat().st_size} bytes)")
    try:
        data = json.loads(path.read_bytes())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        reason = "nested too deeply" if isinstance(exc, RecursionError) else f"not JSON: {exc}"
        raise InputError(f"not a results file of `ldlloc run`: {path} ({reason})") from None
    return validate_results(data, path)


def check_results_path(path: str | Path) -> Path:
    """``path`` as a results JSON path: a ``.json`` name that is not a folder (its CSV goes beside it,
    same name, ``.csv``)."""
    p = Path(path)
    if p.suffix.lower() != ".json":
        raise InputError(f"--output must name a .json file (the CSV is written beside it with the same name), "
                         f"got {p}")
    if p.is_dir():
        raise InputError(f"--output is a folder: {p} (name a .json file)")
    return p


def results_outputs(path: str | Path) -> list[Path]:
    """Every file a run on results file ``path`` writes: the JSON, its CSV and the lock file."""
    p = Path(path)
    return [p, p.with_suffix(".csv"), lock_path(p)]


def lock_path(path: str | Path) -> Path:
    """The lock file of results file ``path`` (``r.json`` -> ``r.json.lock``), held while a run writes it."""
    p = Path(path)
    return p.with_name(p.name + ".lock")


def option_differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """The :data:`OPTION_KEYS` whose values differ between two results ``meta`` (a key absent from
    either, as in files written before it existed, is no difference)."""
    norm = lambda v: json.loads(json.dumps(v, default=str))  # noqa: E731 - tuples vs lists, as in the file
    diffs: list[str] = []
    for key in OPTION_KEYS:
        if key in old and key in new and norm(old[key]) != norm(new[key]):
            if isinstance(old[key], dict) and isinstance(new[key], dict):
                diffs += [f"{key}.{k}" for k in _dict_differences(norm(old[key]), norm(new[key]))]
            else:
                diffs.append(key)
    return diffs


def _dict_differences(a: dict, b: dict, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested dicts."""
    out: list[str] = []
    for k in sorted(set(a) | set(b)):
        x, y = a.get(k), b.get(k)
        if isinstance(x, dict) and isinstance(y, dict):
            out += _dict_differences(x, y, f"{prefix}{k}.")
        elif x != y:
            out.append(f"{prefix}{k}")
    return out


def _json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (strict JSON, no NaN / Infinity)."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


class ResultsBusy(LdlError):
    """Another run holds the lock of the results file."""


class ResultsWriter:
    """Keeps the results of a run and rewrites ``path`` (JSON) and its ``.csv`` after each query.

    While open it holds an exclusive lock on ``path``'s lock file (:func:`lock_path`): a second
    writer of the same file is refused at once (:class:`ResultsBusy`). Opening removes temporary
    files that killed runs left beside the results and rewrites a CSV that is behind its JSON.
    Each flush writes the JSON first, then the CSV (both atomically): a kill between the two leaves
    a CSV at most one flush behind, never ahead, and the next open brings it level. A CSV that
    cannot be written is a warning (``warn``, once; ``meta["csv_error"]``), never a lost result.

    ``resume``: keep the file's records; :meth:`done` (the queries not to run again) excludes
    failed ones, which a resumed run retries. Options (:data:`OPTION_KEYS`) that differ from the
    file's ``meta`` are refused unless ``any_options`` (then ``meta["mixed_options"]`` records the
    earlier options). Use it as a context manager, or call :meth:`close`, to release the lock.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None, resume: bool = False,
                 any_options: bool = False, warn: Callable[[str], None] | None = None):
        self._lock = None
        self.path = check_results_path(path)
        self.csv_path = self.path.with_suffix(".csv")
        self.meta = dict(meta or {})
        self.results: list[QueryResult] = []
        self._records: dict[str, tuple[QueryResult, dict]] = {}  # name -> (result, its JSON-safe record)
        self.warn = warn or (lambda message: None)
        self._warned: set[str] = set()
        self._lock = _acquire_lock(self.path)
        try:
            remove_stale_temporaries(self.path, ".json")
            remove_stale_temporaries(self.csv_path, ".csv")
            if resume and self.path.exists():
                self.results, old_meta = load_results(self.path)
                self.meta = _resumed_meta(self.path, old_meta, self.meta, any_options)
                self._sync_csv()
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> "ResultsWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the lock (and remove its file)."""
        if self._lock is not None:
            _release_lock(self._lock, lock_path(self.path))
            self._lock = None

    def __del__(self) -> None:
        self.close()

    def done(self) -> set[str]:
        """Names of the queries already in the file that a resumed run skips (failed ones excepted)."""
        return {r.name for r in self.results if r.status != "failed"}

    def failed(self) -> set[str]:
        """Names of the failed queries in the file (a resumed run retries them)."""
        return {r.name for r in self.results if r.status == "failed"}

    def add(self, result: QueryResult) -> None:
        self.extend([result])

    def extend(self, results: list[QueryResult]) -> None:
        """Add (or replace, by name) several results and rewrite the files once."""
        latest = {r.name: r for r in results}  # one record per query, the last one given
        self.results = [r for r in self.results if r.name not in latest] + list(latest.values())
        for r in latest.values():
            if r.picture_error:
                self.warn_once("picture", f"picture of {r.name} not written ({r.picture_error}); its result is "
                               "kept (later picture failures: picture_error in the results file)")
        self.flush()

    def warn_once(self, kind: str, message: str) -> None:
        """Say ``message`` through ``warn`` the first time a warning of ``kind`` comes."""
        if kind not in self._warned:
            self._warned.add(kind)
            self.warn(f"warning: {message}")

    def flush(self) -> None:
        """Write the JSON, then the CSV (each atomically)."""
        self._write_json()
        self._write_csv()

    def _record(self, r: QueryResult) -> dict:
        """``r``'s JSON-safe record, converted once (a flush follows every query)."""
        hit = self._records.get(r.name)
        if hit is None or hit[0] is not r:
            hit = self._records[r.name] = (r, _json_safe(asdict(r)))
        return hit[1]

    def _write_json(self) -> None:
        data = _json_safe({
            "format_version": RESULTS_FORMAT_VERSION,
            "meta": self.meta,
            "summary": summarize(self.results, self.meta.get("device")),
        })
        data["queries"] = [self._record(r) for r in self.results]
        with atomic_file(self.path) as tmp:
            tmp.write_text(json.dumps(data, indent=1, allow_nan=False))

    def _write_csv(self) -> None:
        """Write the CSV; on failure warn once and record why in the JSON's ``meta["csv_error"]``."""
        try:
            with atomic_file(self.csv_path) as tmp:
                tmp.write_text(results_csv(self.results))
        except (OSError, LdlError) as exc:
            reason = getattr(exc, "strerror", None) or str(exc)
            self.warn_once("csv", f"cannot write {self.csv_path} ({reason}); the results are in {self.path}")
            if self.meta.get("csv_error") != reason:
                self.meta["csv_error"] = reason
                self._write_json()
        else:
            self.meta.pop("csv_error", None)  # written again: the next JSON says so

    def _sync_csv(self) -> None:
        """Rewrite the CSV when it does not match the JSON (a run killed between the two writes)."""
        try:
            current = self.csv_path.read_bytes().decode()  # as written: csv rows end in \r\n
        except (OSError, UnicodeDecodeError):
            current = None
        if current != results_csv(self.results):
            self._write_csv()


def _resumed_meta(path: Path, old: dict[str, Any], new: dict[str, Any], any_options: bool) -> dict[str, Any]:
    """The meta of a resumed file: refuses other options unless ``any_options`` (then recorded)."""
    diffs = option_differences(old, new)
    if diffs and not any_options:
        shown = ", ".join(diffs[:4]) + (f" and {len(diffs) - 4} more" if len(diffs) > 4 else "")
        raise InputError(f"--resume: {path} was written with other options ({shown}); use the same options, "
                         "another --output, or --resume-any-options to mix them")
    meta = {**old, **new}
    if diffs:
        earlier = old.get("mixed_options", [])
        meta["mixed_options"] = [*earlier, {k: old[k] for k in OPTION_KEYS if k in old}]
    return meta


def _acquire_lock(path: Path):
    """An open, exclusively locked (``flock``) lock file of results file ``path``; refuses at once
    (:class:`ResultsBusy`) when another run holds it."""
    lock = lock_path(path)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LdlError(f"cannot create output folder {lock.parent}: {exc.strerror or exc}") from None
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise LdlError(f"cannot write beside {path}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise ResultsBusy(f"another `ldlloc run` is writing {path} (it holds {lock.name}); wait for it to "
                              "finish or use another --output") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino  # not removed by a run that just finished
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)


def _release_lock(fd: int, lock: Path) -> None:
    try:
        lock.unlink()  # while still holding it: a run that opened the old file retries on a new one
    except OSError:
        pass
    os.close(fd)


def results_csv(results: list[QueryResult]) -> str:
    """One row per query: identifiers, errors, estimate, counts, rotation prior, the best of the
    top-K candidates (errors, first good rank) and stage seconds (the candidates themselves are in
    the JSON only)."""
    stages = sorted({s for r in results for s in r.seconds}, key=lambda s: (s not in STAGES, STAGES.index(s) if s in STAGES else 0, s))
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["name", "scene", "split", "image", "status", "t_error_m", "r_error_deg", "tx", "ty", "tz",
                "num_rotations", "num_matches", "num_inliers", "refined", "refine_method", "rotation_prior",
                "best_candidate_t_error_m", "best_candidate_r_error_deg", "first_good_rank"]
               + [f"sec_{s}" for s in stages])
    for r in results:
        t = r.t if r.t is not None else [None] * 3
        w.writerow([r.name, r.scene, r.split, r.image, r.status, r.t_error_m, r.r_error_deg, *t,
                    r.num_rotations, r.num_matches, r.num_inliers, int(r.refined), r.refine_method, r.rotation_prior,
                    r.best_candidate_t_error_m, r.best_candidate_r_error_deg, r.first_good_rank]
                   + [r.seconds.get(s) for s in stages])
    return buf.getvalue()


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def summary_table(results: list[QueryResult], by: str, title: str):
    """A Rich table of errors and accuracies, one row per group (scene or split) and a total row."""
    from rich.table import Table

    groups = group_by(results, by)
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


def timing_table(results: list[QueryResult], title: str = "median seconds per stage"):
    """A Rich table of the median seconds of each stage (successful queries)."""
    from rich.table import Table

    ok = [r for r in results if r.status != "failed"]
    s = summarize(ok)["median_seconds"] if ok else {}
    table = Table(title=title)
    for st in STAGES:
        table.add_column(st, justify="right")
    table.add_row(*[_fmt(s.get(st), ".3f") for st in STAGES])
    return table
