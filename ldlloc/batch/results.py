"""The results file of a run: JSON (and a CSV beside it), validated on read, written after every query
(records and summaries: :mod:`.accuracy`).

Results file::

    {"format_version": 1, "meta": {the run's options}, "summary": {...}, "queries": [record, ...]}

Each record is a :class:`ldlloc.record.QueryResult`: its fields, the check each value passes on
read and their meanings are declared there once (``docs/formats.md`` lists them). The ``summary``
(:func:`ldlloc.batch.accuracy.summarize`: counts, median errors, accuracies, median seconds, the
search's own accuracy and the verdicts; image runs count by map instead) is recomputed on read.
The candidates are in the JSON only (not in the CSV). Files written before a field existed still
load (the field gets its default).

While a run goes on, ``ResultsWriter`` appends each query's record to a journal beside the JSON
(``r.json.journal``, JSON Lines: :func:`journal_path`) and rewrites the JSON (and the CSV beside it,
each atomically) only when the journal has grown as large as the JSON, and at the end: writing n
records costs O(n) in all, a few milliseconds per query whatever the run's length (``bench/bench_results_write.py``).
The JSON of an unfinished run names its journal (top-level ``"journal"``: a token the journal's
first line repeats); :func:`load_results` (``report``, ``export``, ``--resume``) reads the JSON and
then the records of its journal, so an interrupted run loses nothing and ``--resume`` skips the
queries already there (and retries the failed ones). A finished run's JSON holds every record
and has no journal. The run holds a lock (``r.json.lock``) while it writes: a second run on the
same file is refused. Files carry ``"format_version": 1`` (absent in older files, read as 1);
:func:`validate_results` checks every record when a file is read.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

from ldlloc.batch.accuracy import results_csv, summarize
from ldlloc.batch.journal import MAX_RESULTS_BYTES, is_journal, journal_header, journal_path, read_journal
from ldlloc.batch.lock import ResultsBusy, acquire_lock, lock_path, release_lock
from ldlloc.record import FIELD_CHECKS, REQUIRED_FIELDS, QueryResult, json_safe, record_json
from ldlmap.core.errors import (FormatVersionError, InputError, LdlError, WriteError, atomic_file, remove_stale_temporaries,
                                require_file)


_IN_JSON, _IN_JOURNAL = 0, 1  # where a record's line of JSON is (ResultsWriter._where)
_JOURNAL_LINE = '{"query": '  # a journal line: this, the record's JSON, "}" and a newline
RESULTS_FORMAT_VERSION = 1  # top-level "format_version" of a results file (absent: written before it, read as 1)
OPTION_KEYS = ("dataset", "root", "splits", "map_level", "device", "params", "max_tilt_deg", "maps", "top_maps",
               "scene_unknown", "images_path", "walk", "video", "fps", "every")  # meta compared by --resume


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
        missing = [k for k in REQUIRED_FIELDS if k not in q]
        if missing:
            who = f", query {q['name']}" if isinstance(q.get("name"), str) else ""
            raise InputError(f"{bad} (queries[{i}] lacks {', '.join(missing)}{who})")
        for key, (ok, what) in FIELD_CHECKS.items():
            if key in q and not ok(q[key]):
                who = f", query {q['name']}" if isinstance(q.get("name"), str) else ""
                raise InputError(f"{bad} (queries[{i}].{key} must be {what}, got {json.dumps(q[key])[:40]}{who})")
        if q["name"] in seen:
            raise InputError(f"{bad} (query {q['name']} appears twice)")
        seen.add(q["name"])
    return [QueryResult.from_dict(q) for q in queries], meta


def load_results(path: str | Path) -> tuple[list[QueryResult], dict[str, Any]]:
    """Read and validate (:func:`validate_results`) a results file written by :class:`ResultsWriter`,
    with the records of its journal when the run did not finish (:func:`read_results_data`)."""
    return validate_results(read_results_data(path), path)


def read_results_data(path: str | Path) -> dict[str, Any]:
    """The parsed results JSON ``path`` with its journal's records applied (a record replaces the
    one of the same name and moves to the end, as :class:`ResultsWriter` keeps them); not yet
    validated. One-line :class:`InputError` for a file that is not JSON, too large, or whose
    journal is broken."""
    path = require_file(path, "results file")
    data = _read_json(path)
    token = data.get("journal") if isinstance(data, dict) else None
    if isinstance(token, str) and isinstance(data.get("queries"), list):
        records = read_journal(journal_path(path), token)
        if records:
            latest: dict[str, dict] = {}
            for rec in records:
                latest.pop(rec["name"], None)
                latest[rec["name"]] = rec
            kept = [q for q in data["queries"] if not (isinstance(q, dict) and q.get("name") in latest)]
            data["queries"] = kept + list(latest.values())
    return data


def _read_json(path: Path) -> Any:
    """``path`` parsed as JSON, or a one-line error saying it is not a results file."""
    if path.stat().st_size > MAX_RESULTS_BYTES:
        raise InputError(f"not a results file of `ldlloc run`: {path} ({path.stat().st_size} bytes)")
    try:
        return json.loads(path.read_bytes())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        reason = "nested too deeply" if isinstance(exc, RecursionError) else f"not JSON: {exc}"
        raise InputError(f"not a results file of `ldlloc run`: {path} ({reason})") from None


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


def refuse_replacing_results(path: str | Path, overwrite: bool = False, resume: bool = False) -> None:
    """Before a run writes results file ``path`` (and its CSV): refuse (one line) to replace a file
    that is not a results file of `ldlloc run` (a user's own JSON or CSV), or the results of a run
    that did not finish (killed or interrupted: ``meta["finished"]`` false), unless ``overwrite``;
    ``resume`` continues such a file instead (and validates it when it opens), and is refused as a
    plain run is when the JSON is not there (it starts the file anew: a user's CSV stays). A file
    of the journal's name that is not a journal is refused either way."""
    p = Path(path)
    if resume and overwrite:
        raise InputError("--resume keeps the results file and --overwrite replaces it: give one of them")
    if overwrite:
        return
    journal = journal_path(p)
    if journal.exists() and not is_journal(journal):
        raise InputError(f"{journal} (written beside --output {p.name}) exists and is not a journal of `ldlloc run`; "
                         "use --overwrite to replace it, or another --output")
    if resume and p.exists():
        return  # continued: the writer validates it when it opens
    csv_path = p.with_suffix(".csv")
    if not p.exists():  # a run (resumed or not) that starts the file anew writes the CSV too
        if csv_path.is_file() and not _is_results_csv(csv_path):
            raise InputError(f"{csv_path} (written beside --output {p.name}) exists and is not a results CSV of "
                             "`ldlloc run`; use --overwrite to replace it, or another --output")
        return
    try:
        results, meta = load_results(p)
    except LdlError as exc:
        why = str(exc).removeprefix(f"not a results file of `ldlloc run`: {p}").strip(" ()")  # the reason alone
        why = why if len(why) <= 80 else why[:77] + "..."
        raise InputError(f"output {p} exists and is not a results file of `ldlloc run` ({why}); use "
                         "--overwrite to replace it, or another --output") from None
    if meta.get("finished") is False:  # absent: written before the flag, or by a run that finished
        release_lock(*acquire_lock(p), lock_path(p))  # a run writing it now: ResultsBusy says so
        raise InputError(f"{p} holds {len(results)} results of a run that did not finish (killed or interrupted): "
                         "continue it with --resume, or replace it with --overwrite")


def _is_results_csv(path: Path) -> bool:
    """Whether ``path`` starts with the header row of :func:`results_csv`."""
    head = results_csv([]).splitlines()[0]
    try:
        with open(path, encoding="utf-8", errors="replace", newline="") as fh:
            return fh.readline().startswith(head)  # then the stages' seconds columns
    except OSError:
        return False


def results_outputs(path: str | Path) -> list[Path]:
    """Every file a run on results file ``path`` writes: the JSON, its CSV, the journal and the lock file."""
    p = Path(path)
    return [p, p.with_suffix(".csv"), journal_path(p), lock_path(p)]


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


WALK_KEPT = ("name", "frame")  # a walk record's fields a run reads back from the records it added itself


def light_record(r: QueryResult, resumed: bool = True) -> QueryResult:
    """``r`` without what only its JSON line needs (the candidates, but an empty one standing for them:
    the summary counts the records that have candidates; the competitors, confidence signals, map
    scores and message): what :class:`ResultsWriter` keeps in memory for the summary, the CSV and a
    resumed walk (the whole records are on disk only). ``resumed`` false (a record added by the run
    itself, not read back from the file): its ``walk`` only its name and frame (a walk resumes from
    the records read when the file was opened)."""
    walk = r.walk if resumed or r.walk is None else {k: r.walk.get(k) for k in WALK_KEPT}
    return replace(r, candidates=[{}] if r.candidates else [], competitors=[], confidence_signals=None,
                   map_scores=None, message="", walk=walk)


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


class ResultsWriter:
    """Keeps the results of a run: appends each query's record to the journal (:func:`journal_path`)
    and rewrites ``path`` (JSON) and its ``.csv`` when the journal has grown as large as the JSON,
    and at :meth:`finish` (module docstring): O(1) amortized work and bytes per query.

    While open it holds an exclusive lock on ``path``'s lock file (:func:`lock_path`): a second
    writer of the same file is refused at once (:class:`ResultsBusy`). Opening removes temporary
    files that killed runs left beside the results; a resumed file is rewritten at once (its journal
    folded in, the CSV brought level). Each rewrite writes the JSON, then the CSV, then a new empty
    journal (each atomically): a kill anywhere leaves a JSON and journal that together hold every
    record written, and a CSV that matches the JSON or an earlier one. A CSV that cannot be written
    is a warning (``warn``, once; ``meta["csv_error"]``), never a lost result; a JSON or journal
    that cannot be written is an :class:`LdlError` naming the file (the records written before stay).

    ``resume``: keep the file's records; :meth:`done` (the queries not to run again) excludes
    failed ones, which a resumed run retries. Options (:data:`OPTION_KEYS`) that differ from the
    file's ``meta`` are refused unless ``any_options`` (then ``meta["mixed_options"]`` records the
    earlier options); a run of another kind (:func:`run_kind`) always. Use it as a context
    manager, or call :meth:`close`, to release the lock.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None, resume: bool = False,
                 any_options: bool = False, warn: Callable[[str], None] | None = None):
        self._lock = None
        self._journal = None  # the journal, open for appending (None: the JSON must be rewritten first)
        self.path = check_results_path(path)
        self.csv_path = self.path.with_suffix(".csv")
        self.journal_path = journal_path(self.path)
        self.meta = {**(meta or {}), "finished": False}  # true once :meth:`finish` ran (a rerun checks it)
        self._results: dict[str, QueryResult] = {}  # name -> its light record (light_record), in file order
        self._where: dict[str, tuple[int, int, int]] = {}  # name -> where its line of JSON is on disk: (_IN_JSON
        # or _IN_JOURNAL, byte offset, length); the whole records are not kept in memory
        self._pending: dict[str, str] = {}  # name -> its line of JSON, made once, until it is on disk
        self._journal_pos = 0  # the journal's bytes (where the next record's line starts)
        self._json_bytes = self._journal_bytes = 0
        self.warn = warn or (lambda message: None)
        self._warned: set[str] = set()
        self._lock = acquire_lock(self.path)
        try:
            remove_stale_temporaries(self.path, ".json")
            remove_stale_temporaries(self.csv_path, ".csv")
            remove_stale_temporaries(self.journal_path, ".journal")
            if resume and self.path.exists():
                results, old_meta = load_results(self.path)
                self._results = {r.name: light_record(r) for r in results}
                self._pending = {r.name: record_json(r) for r in results}
                del results
                self.meta = _resumed_meta(self.path, old_meta, self.meta, any_options)
                self.flush()
        except BaseException:
            self.close()
            raise

    @property
    def results(self) -> list[QueryResult]:
        """The records, in file order (whole: read back from their lines of JSON on disk)."""
        with self._texts() as text:
            return [QueryResult.from_dict(json.loads(text(name))) for name in self._results]

    @contextlib.contextmanager
    def _texts(self):
        """``text(name)``: a record's line of JSON, from memory or read back from the JSON or the journal
        (each opened once, when first needed, for the block)."""
        files: dict[int, Any] = {}
        try:
            def text(name: str) -> str:
                if name in self._pending:
                    return self._pending[name]
                source, offset, length = self._where[name]
                if source not in files:
                    files[source] = open(self.path if source == _IN_JSON else self.journal_path, "rb")
                fh = files[source]
                fh.seek(offset)
                return fh.read(length).decode()
            with _naming_errors(self.path):
                yield text
        finally:
            for fh in files.values():
                fh.close()

    @property
    def light_results(self) -> list[QueryResult]:
        """The records, in file order, as the writer keeps them in memory (:func:`light_record`)."""
        return list(self._results.values())

    def __enter__(self) -> "ResultsWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the journal and release the lock (removing its file when this run made it)."""
        if self._journal is not None:
            self._journal.close()
            self._journal = None
        if self._lock is not None:
            release_lock(*self._lock, lock_path(self.path))
            self._lock = None

    def __del__(self) -> None:
        self.close()

    def finish(self) -> None:
        """Record that the run ended with every query done (``meta["finished"]``) and write the
        whole JSON (no journal left): a later run without ``--resume`` may replace the file
        (:func:`refuse_replacing_results`)."""
        if self.meta.get("finished") is not True:
            self.meta["finished"] = True
            self.flush()

    def done(self) -> set[str]:
        """Names of the queries already in the file that a resumed run skips (failed ones excepted)."""
        return {r.name for r in self._results.values() if r.status != "failed"}

    def failed(self) -> set[str]:
        """Names of the failed queries in the file (a resumed run retries them)."""
        return {r.name for r in self._results.values() if r.status == "failed"}

    def reorder(self, key: Callable[[QueryResult], Any]) -> None:
        """Put the records in the order of ``key`` (written at the next rewrite, e.g. :meth:`finish`)."""
        self._results = {r.name: r for r in sorted(self._results.values(), key=key)}

    def add(self, result: QueryResult) -> None:
        self.extend([result])

    def extend(self, results: list[QueryResult]) -> None:
        """Add (or replace, by name: the record moves to the end) several results and write them."""
        latest = {r.name: r for r in results}  # one record per query, the last one given
        for r in latest.values():
            self._results.pop(r.name, None)
            self._where.pop(r.name, None)
            self._results[r.name] = light_record(r, resumed=False)
            self._pending[r.name] = record_json(r)
            if r.picture_error:
                self.warn_once("picture", f"picture of {r.name} not written ({r.picture_error}); its result is "
                               "kept (later picture failures: picture_error in the results file)")
        if self._journal is None or self._journal_bytes >= self._json_bytes:
            self.flush()  # the journal as large as the JSON: rewriting now keeps the total linear
        else:
            self._append(list(latest.values()))

    def warn_once(self, kind: str, message: str) -> None:
        """Say ``message`` through ``warn`` the first time a warning of ``kind`` comes."""
        if kind not in self._warned:
            self._warned.add(kind)
            self.warn(f"warning: {message}")

    def flush(self) -> None:
        """Rewrite the JSON (every record), then the CSV, then start an empty journal (none once
        finished), each atomically."""
        finished = self.meta.get("finished") is True
        token = None if finished else os.urandom(8).hex()
        if self._journal is not None:
            self._journal.close()
            self._journal = None
        self._write_json(token)
        self._write_csv(token)
        self._journal_bytes = 0
        if finished:
            _remove_journal(self.journal_path)
            return
        header = journal_header(token)
        with _naming_errors(self.journal_path):
            with atomic_file(self.journal_path) as tmp:
                tmp.write_bytes(header)
            self._journal = open(self.journal_path, "ab")
        self._journal_pos = len(header)

    def _append(self, results: list[QueryResult]) -> None:
        """Append the records of ``results`` to the journal, one line each, in one write."""
        lines, where, pos = [], {}, self._journal_pos
        for r in results:
            text = self._pending[r.name]
            where[r.name] = (_IN_JOURNAL, pos + len(_JOURNAL_LINE), len(text))
            lines.append(f"{_JOURNAL_LINE}{text}}}\n")
            pos += len(_JOURNAL_LINE) + len(text) + 2
        lines = "".join(lines).encode()
        with _naming_errors(self.journal_path):
            try:
                self._journal.write(lines)
                self._journal.flush()
            except OSError:  # part of a line may be there: never append after it (the next write rewrites)
                journal, self._journal = self._journal, None
                with contextlib.suppress(OSError):
                    journal.close()
                raise
        self._journal_bytes += len(lines)
        self._journal_pos += len(lines)
        self._where.update(where)
        for name in where:
            del self._pending[name]

    def _write_json(self, token: str | None) -> None:
        """The JSON: its head indented, then ``"queries"`` with one record per line (each serialized
        once, when it was added)."""
        head = json_safe({
            "format_version": RESULTS_FORMAT_VERSION,
            "meta": self.meta,
            "summary": summarize(self.light_results, self.meta.get("device")),
            **({"journal": token} if token is not None else {}),  # the journal of this JSON (read_results_data)
        })
        start = json.dumps(head, indent=1, allow_nan=False)[:-2]  # without the closing "\n}"
        start += ',\n "queries": [\n' if self._results else ',\n "queries": []\n}'
        where, pos = {}, len(start)
        with _naming_errors(self.path), self._texts() as text:
            with atomic_file(self.path) as tmp, tmp.open("w", encoding="ascii") as fh:
                fh.write(start)
                for k, name in enumerate(self._results):
                    line = text(name) + (",\n" if k + 1 < len(self._results) else "\n ]\n}")
                    fh.write(line)
                    where[name] = (_IN_JSON, pos, len(line) - (2 if k + 1 < len(self._results) else 4))
                    pos += len(line)
        self._where, self._pending = where, {}
        self._json_bytes = pos

    def _write_csv(self, token: str | None) -> None:
        """Write the CSV; on failure warn once and record why in the JSON's ``meta["csv_error"]``."""
        try:
            with atomic_file(self.csv_path) as tmp:
                tmp.write_text(results_csv(self.light_results), errors="surrogateescape")  # names as their bytes
        except (OSError, LdlError) as exc:
            reason = getattr(exc, "strerror", None) or str(exc)
            self.warn_once("csv", f"cannot write {self.csv_path} ({reason}); the results are in {self.path}")
            if self.meta.get("csv_error") != reason:
                self.meta["csv_error"] = reason
                self._write_json(token)
        else:
            if self.meta.pop("csv_error", None) is not None:  # written again: the JSON says so
                self._write_json(token)


@contextlib.contextmanager
def _naming_errors(path: Path):
    """Turn an OSError (a full disk, a folder made read-only) into a one-line error naming ``path``
    and how to go on (``--resume``)."""
    kept = "(the results written before are kept: continue with --resume)"
    try:
        yield
    except WriteError as exc:  # already names the file it could not write
        raise LdlError(f"{exc} {kept}") from None
    except OSError as exc:
        raise LdlError(f"cannot write {path}: {exc.strerror or exc} {kept}") from None


def _remove_journal(path: Path) -> None:
    """Remove a finished run's journal (only one of ours)."""
    if is_journal(path):
        try:
            path.unlink()
        except OSError:
            pass


def run_kind(meta: dict[str, Any]) -> str:
    """The kind of run a results ``meta`` is of: ``images`` (``--images``), ``dataset`` or ``video``,
    ``images`` and ``dataset`` with `` walk`` for a ``--walk`` run (meta ``walk``): runs of two kinds
    never share a results file."""
    if meta.get("dataset") == "video":
        return "video"
    kind = "images" if meta.get("dataset") == "images" else "dataset"
    return f"{kind} walk" if meta.get("walk") else kind


RUN_KINDS = {"images": "an --images run", "images walk": "an --images --walk run", "dataset": "a dataset run",
             "dataset walk": "a dataset --walk run", "video": "a --video run"}  # :func:`run_kind` in words


def unfinished_note(records: list, meta: dict) -> str | None:
    """What to say of a results file whose run did not finish (``meta["finished"]`` false: killed
    or interrupted), None for a finished run (or one written before the flag existed)."""
    if meta.get("finished") is not False:
        return None
    return (f"this run did not finish (killed or interrupted): the file holds {len(records)} "
            f"quer{'y' if len(records) == 1 else 'ies'}, not necessarily all of its run; "
            "`ldlloc run ... --resume` continues it")


def _resumed_meta(path: Path, old: dict[str, Any], new: dict[str, Any], any_options: bool) -> dict[str, Any]:
    """The meta of a resumed file: refuses other options unless ``any_options`` (then recorded)."""
    if run_kind(old) != run_kind(new):  # never mixed, even with any_options
        raise InputError(f"--resume: {path} holds the results of {RUN_KINDS[run_kind(old)]} and this is "
                         f"{RUN_KINDS[run_kind(new)]} (never mixed in one file); use another --output")
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


