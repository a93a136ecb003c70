"""The journal of a results file: the records a run appended since its JSON was last written.

``r.json`` -> ``r.json.journal`` (JSON Lines): a first line ``{"ldlloc_results_journal": 1,
"journal": TOKEN}``, then one ``{"query": RECORD}`` per line. The JSON of an unfinished run names
its journal's TOKEN; a journal with another token belongs to an earlier JSON that already holds its
records (a run killed between writing a new JSON and starting its journal). Written by
:class:`ldlloc.batch.results.ResultsWriter`, read by :func:`ldlloc.batch.results.read_results_data`.
"""

from __future__ import annotations

import json
from pathlib import Path

from ldlmap.core.errors import InputError

JOURNAL_MARK = "ldlloc_results_journal"  # key of a journal's first line (is_journal)
MAX_RESULTS_BYTES = 2 << 30  # a results file (or journal) larger than this is not one of ours (~1 million queries)


def journal_path(path: str | Path) -> Path:
    """The journal of results file ``path`` (``r.json`` -> ``r.json.journal``): the records of a run
    that goes on (or was killed) appended since the JSON was last written."""
    p = Path(path)
    return p.with_name(p.name + ".journal")


def journal_header(token: str) -> bytes:
    """The first line of a journal: says whose it is and which JSON it extends (``token``)."""
    return json.dumps({JOURNAL_MARK: 1, "journal": token}).encode() + b"\n"


def is_journal(path: str | Path) -> bool:
    """Whether ``path`` starts as a journal of :class:`ResultsWriter` (one of ours, not a user's file)."""
    try:
        with open(path, "rb") as fh:
            first = fh.readline(4096)
        return JOURNAL_MARK in json.loads(first)
    except (OSError, ValueError, TypeError):
        return False


def read_journal(path: Path, token: str) -> list[dict]:
    """The records of journal ``path`` when it extends the JSON whose token is ``token`` (else none:
    the JSON already holds them). Only whole lines count: a line cut by a kill or a full disk (the
    last one, without its newline) is left out, and its query runs again on ``--resume``."""
    try:
        size = path.stat().st_size
    except OSError:
        return []
    if size > MAX_RESULTS_BYTES:
        raise InputError(f"not a journal of `ldlloc run`: {path} ({size} bytes)")
    lines = path.read_bytes().split(b"\n")[:-1]  # the part after the last newline is unfinished
    bad = f"journal of `ldlloc run` is damaged: {path}"
    try:
        header = json.loads(lines[0]) if lines else {}
    except ValueError:
        raise InputError(f"{bad} (line 1 is not JSON)") from None
    if not isinstance(header, dict) or header.get("journal") != token:
        return []  # another JSON's journal (the run was killed while starting a new one): all in the JSON
    records = []
    for i, line in enumerate(lines[1:], start=2):
        try:
            entry = json.loads(line)
        except (ValueError, RecursionError):
            raise InputError(f"{bad} (line {i} is not JSON)") from None
        rec = entry.get("query") if isinstance(entry, dict) else None
        if not isinstance(rec, dict) or not isinstance(rec.get("name"), str):
            raise InputError(f"{bad} (line {i} is not a query record)")
        records.append(rec)
    return records
