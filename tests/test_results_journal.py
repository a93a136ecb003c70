"""The results file's journal and lock: records are appended (the JSON is rewritten only as the
journal doubles, so a run of n queries writes O(n) bytes, not O(n^2)); a killed run's records in the
journal are read by every reader; a record cut by a kill or a full disk is left out and run again;
a full disk is one line naming the file and the records before it stay; the lock file is removed
only when the run made it; runs of two kinds never share a file."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import ldlloc.batch.results as results_module
from ldlloc.batch.lock import LOCK_MARK
from ldlloc.batch.accuracy import QueryResult
from ldlloc.batch.results import (ResultsWriter, journal_path, load_results, lock_path, read_results_data,
                                  refuse_replacing_results)
from ldlmap.core.errors import InputError, LdlError


def result(i: int, **kw) -> QueryResult:
    """A record with a pose and 20 candidates (about the size of a real one)."""
    rot = np.eye(3).tolist()
    fields = dict(image=f"{i}.jpg", scene="room", split="images", name=f"q{i:05d}", R=rot, t=[i, 0.0, 1.0],
                  seconds={"total": 0.5}, candidates=[{"R": rot, "t": [0.0, 0.0, k], "loss": -k} for k in range(20)],
                  confidence=0.9, verdict="confident")
    return QueryResult(**{**fields, **kw})


def test_a_run_rewrites_the_json_a_logarithmic_number_of_times(tmp_path, monkeypatch):
    """300 queries: the JSON is rewritten at most ~log2(300) + 2 times (it was 300 times), and every
    record is read back, in order, before and after the run finishes."""
    rewrites = []
    real = ResultsWriter._write_json
    monkeypatch.setattr(ResultsWriter, "_write_json", lambda self, token: (rewrites.append(1), real(self, token)))
    path = tmp_path / "r.json"
    names = [f"q{i:05d}" for i in range(300)]
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}) as w:
        for i in range(300):
            w.add(result(i))
        assert [r.name for r in load_results(path)[0]] == names  # a reader during the run sees them all
        assert len(json.loads(path.read_text())["queries"]) < 300  # ... from the JSON and its journal
        assert len(rewrites) <= 11
        w.finish()
    data = json.loads(path.read_text())
    assert [q["name"] for q in data["queries"]] == names and "journal" not in data
    assert not journal_path(path).exists()


def test_bytes_written_per_query_stay_bounded(tmp_path):
    """Bytes written for the 10 queries after 2000 are of the order of 10 records, not 10 files."""
    path = tmp_path / "r.json"
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"})
    w.extend([result(i) for i in range(2000)])
    w.add(result(2000))  # the JSON was just written: this starts appending
    size = lambda: path.stat().st_size + journal_path(path).stat().st_size  # noqa: E731
    one_file = path.stat().st_size
    before = size()
    for i in range(2001, 2011):
        w.add(result(i))
    assert size() - before < one_file / 50
    w.close()


def test_a_record_cut_short_is_left_out_and_run_again(tmp_path):
    path = tmp_path / "r.json"
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"})
    for i in range(6):
        w.add(result(i))
    w._journal.write(b'{"query": {"name": "q00006", "ima')  # killed in the middle of a line
    w._journal.flush()
    w.close()
    assert [r.name for r in load_results(path)[0]] == [f"q{i:05d}" for i in range(6)]
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}, resume=True) as w2:
        assert w2.done() == {f"q{i:05d}" for i in range(6)}  # q00006 runs again
        w2.add(result(6))
        w2.finish()
    assert [r.name for r in load_results(path)[0]] == [f"q{i:05d}" for i in range(7)]


def test_a_journal_of_another_json_is_not_read(tmp_path):
    """Killed between writing a new JSON and starting its journal: the old journal's records are all
    in the JSON already; a reader never counts them twice."""
    path = tmp_path / "r.json"
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"})
    for i in range(5):
        w.add(result(i))
    w.close()
    old_journal = journal_path(path).read_bytes()
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}, resume=True)  # rewrites the JSON
    w.close()
    journal_path(path).write_bytes(old_journal + b'{"query": ' + json.dumps({"name": "q00001"}).encode() + b"}\n")
    assert [r.name for r in load_results(path)[0]] == [f"q{i:05d}" for i in range(5)]


def test_a_replaced_record_moves_to_the_end_as_before(tmp_path):
    path = tmp_path / "r.json"
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}) as w:
        for i in range(4):
            w.add(result(i, status="failed", R=None, t=None, verdict="failed"))
        w.add(result(1))  # a failed query retried
        assert [(r.name, r.status) for r in load_results(path)[0]] == [
            ("q00000", "failed"), ("q00002", "failed"), ("q00003", "failed"), ("q00001", "ok")]


@pytest.mark.parametrize("text, says", [
    (b'{"ldlloc_results_journal": 1, "journal": "TOKEN"}\nnot json\n{"query": {"name": "x"}}\n', "line 2 is not JSON"),
    (b'{"ldlloc_results_journal": 1, "journal": "TOKEN"}\n{"query": 3}\n', "line 2 is not a query record"),
    (b'{"ldlloc_results_journal": 1, "journal": "TOKEN"}\n{"query": {"name": "x"}}\n', "lacks image"),
])
def test_a_damaged_journal_is_one_line(tmp_path, text, says):
    path = tmp_path / "r.json"
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"})
    w.add(result(0))
    w.close()
    token = json.loads(path.read_text())["journal"]
    journal_path(path).write_bytes(text.replace(b"TOKEN", token.encode()))
    with pytest.raises(InputError, match=says):
        load_results(path)


def test_export_reads_the_records_of_the_journal(tmp_path):
    from ldlloc.export.poses import read_records

    path = tmp_path / "r.json"
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"})
    for i in range(5):
        w.add(result(i))
    w.close()  # killed: not finished
    assert [q["name"] for q in read_records(path)[0]] == [f"q{i:05d}" for i in range(5)]
    assert len(read_results_data(path)["queries"]) == 5


def test_a_users_file_named_like_the_journal_is_not_replaced(tmp_path):
    path = tmp_path / "r.json"
    journal_path(path).write_text("my notes\n")
    with pytest.raises(InputError, match=r"r.json.journal .* is not a journal of `ldlloc run`.*--overwrite"):
        refuse_replacing_results(path)
    with pytest.raises(InputError, match="is not a journal"):
        refuse_replacing_results(path, resume=True)
    assert journal_path(path).read_text() == "my notes\n"


# ----------------------------------------------------------------------------- a full disk


def _fill_the_disk(w: ResultsWriter, monkeypatch) -> None:
    """From now on the journal's writes fail half-way, as on a full disk."""
    real_write = w._journal.write

    def full(data):
        real_write(data[: len(data) // 2])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(w._journal, "write", full)


@pytest.mark.parametrize("go_on", [False, True])
def test_a_full_disk_names_the_file_and_keeps_the_records_before(tmp_path, monkeypatch, go_on):
    """The run ends with one line naming the journal; the records before stay, and --resume finishes.
    A caller that goes on writing (Ctrl-C handling keeps what arrived) never appends after the cut line."""
    path = tmp_path / "r.json"
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"})
    for i in range(5):
        w.add(result(i))
    _fill_the_disk(w, monkeypatch)
    with pytest.raises(LdlError, match=r"cannot write .*r.json.journal: No space left on device .*--resume"):
        w.add(result(5))
    monkeypatch.undo()
    if go_on:
        w.add(result(6))
        assert [r.name for r in load_results(path)[0]] == [f"q{i:05d}" for i in range(7)]
    w.close()
    assert [r.name for r in load_results(path)[0]] == [f"q{i:05d}" for i in range(7 if go_on else 5)]
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}, resume=True) as w2:
        w2.add(result(5))
        w2.finish()
    assert len(load_results(path)[0]) == (7 if go_on else 6)


def test_a_full_disk_while_the_json_is_rewritten_names_it(tmp_path, monkeypatch):
    path = tmp_path / "r.json"
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"})
    w.add(result(0))
    full = OSError(28, "No space left on device")
    opened = Path.open  # the JSON is written record by record through Path.open
    monkeypatch.setattr(Path, "open", lambda self, mode="r", *a, **k: (_ for _ in ()).throw(full) if "w" in mode
                        else opened(self, mode, *a, **k))
    with pytest.raises(LdlError, match=rf"no space left on device writing {path} .*--resume"):
        w.finish()
    monkeypatch.undo()
    w.close()
    assert [r.name for r in load_results(path)[0]] == ["q00000"]


# ----------------------------------------------------------------------------- the lock


def test_a_users_own_lock_file_is_never_removed(tmp_path):
    path = tmp_path / "r.json"
    lock_path(path).write_text("mine\n")
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}) as w:
        w.add(result(0))
        with pytest.raises(results_module.ResultsBusy):  # still locks out a second run
            ResultsWriter(path, resume=True)
    assert lock_path(path).read_text() == "mine\n"
    with pytest.raises(InputError, match="did not finish"):  # takes the lock to check no run writes: kept
        refuse_replacing_results(path)
    assert lock_path(path).read_text() == "mine\n"


def test_a_lock_left_by_a_killed_run_is_removed(tmp_path):
    path = tmp_path / "r.json"
    lock_path(path).write_bytes(LOCK_MARK)
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}) as w:
        w.add(result(0))
    assert not lock_path(path).exists()


# ----------------------------------------------------------------------------- kinds of runs


def test_runs_of_two_kinds_never_share_a_file(tmp_path):
    path = tmp_path / "r.json"
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "synthetic"}) as w:
        w.add(result(0, split="robot", t_error_m=0.1, r_error_deg=1.0))
        w.finish()
    before = path.read_bytes()
    with pytest.raises(InputError, match="a dataset run and this is an --images run"):
        ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}, resume=True, any_options=True)
    assert path.read_bytes() == before


def test_resume_with_another_images_folder_is_refused(tmp_path):
    path = tmp_path / "r.json"
    meta = {"device": "cpu", "dataset": "images", "images": "a", "images_path": str(tmp_path / "a")}
    with ResultsWriter(path, meta=meta) as w:
        w.add(result(0))
        w.finish()
    with pytest.raises(InputError, match=r"other options \(images_path\)"):
        ResultsWriter(path, meta={**meta, "images_path": str(tmp_path / "b")}, resume=True)
