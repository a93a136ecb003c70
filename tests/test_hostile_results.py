"""Results files under hostile conditions: malformed files are one error line for
`report` and `run --resume`; the writer's lock refuses a second run; a kill at any moment leaves a
JSON and a CSV that agree once the next run opens them; a CSV that cannot be written is a warning;
--resume refuses other options unless told otherwise."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlloc.batch.accuracy import QueryResult, results_csv
from ldlloc.batch.results import ResultsBusy, ResultsWriter, load_results, lock_path, validate_results
from ldlmap.core.errors import FormatVersionError, InputError
from tests._hostile import assert_clean_failure, snapshot

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]


def record(name: str = "robot/a", **kw) -> dict:
    """A valid results record (as in a file) with fields replaced by ``kw``."""
    q = asdict(QueryResult(image="a.jpg", scene="room_1", split="robot", name=name, R=np.eye(3).tolist(),
                           t=[0.0, 1.0, 2.0], t_error_m=0.01, r_error_deg=0.5, seconds={"total": 1.0}))
    q.update(kw)
    return q


def results_text(queries: list | None = None, **top) -> str:
    return json.dumps({"meta": {"device": "cpu"}, "queries": [record()] if queries is None else queries, **top})


# (case, file text, words of the error line)
BAD_FILES = [
    ("empty", "", "not JSON"),
    ("not json", "{nope", "not JSON"),
    ("binary", "\x00\x01\x02\xff", "not JSON"),
    ("top-level list", "[]", "JSON list"),
    ("top-level string", '"queries"', "JSON str"),
    ("top-level null", "null", "JSON NoneType"),
    ("no queries", json.dumps({"meta": {}}), '"queries" must be a list'),
    ("queries an object", json.dumps({"queries": {}}), '"queries" must be a list'),
    ("meta a list", json.dumps({"meta": [], "queries": []}), '"meta" must be an object'),
    ("query a number", results_text([3]), "queries[0] is a int"),
    ("query without name", results_text([{k: v for k, v in record().items() if k != "name"}]), "lacks name"),
    ("name an integer", results_text([record(name=7)]), "queries[0].name"),
    ("t_error NaN", results_text([record(t_error_m=float("nan"))]), "queries[0].t_error_m"),
    ("r_error Infinity", results_text([record(r_error_deg=float("inf"))]), "queries[0].r_error_deg"),
    ("negative error", results_text([record(t_error_m=-1.0)]), "queries[0].t_error_m"),
    ("t of 2 values", results_text([record(t=[0.0, 1.0])]), "queries[0].t "),
    ("R 2x3", results_text([record(R=[[1, 0, 0], [0, 1, 0]])]), "queries[0].R "),
    ("R with a string", results_text([record(R=[[1, 0, 0], [0, "1", 0], [0, 0, 1]])]), "queries[0].R "),
    ("seconds a list", results_text([record(seconds=[1.0])]), "queries[0].seconds"),
    ("seconds NaN", results_text([record(seconds={"total": float("nan")})]), "queries[0].seconds"),
    ("inliers negative", results_text([record(num_inliers=-3)]), "queries[0].num_inliers"),
    ("inliers a bool", results_text([record(num_inliers=True)]), "queries[0].num_inliers"),
    ("refined a string", results_text([record(refined="yes")]), "queries[0].refined"),
    ("unknown status", results_text([record(status="great")]), "queries[0].status"),
    ("bad candidate", results_text([record(candidates=[{"R": [[1]], "t": [0, 0, 0], "loss": 1}])]),
     "queries[0].candidates"),
    ("rank zero", results_text([record(first_good_rank=0)]), "queries[0].first_good_rank"),
    ("query twice", results_text([record(), record()]), "appears twice"),
    ("newer version", results_text(format_version=2), "format_version 2"),
    ("version a string", results_text(format_version="1"), "format_version must be an integer"),
    ("nested too deeply", "[" * 100000 + "]" * 100000, "nested too deeply"),
]


@pytest.mark.parametrize("text, words", [c[1:] for c in BAD_FILES], ids=[c[0] for c in BAD_FILES])
def test_report_refuses_a_malformed_results_file(tmp_path, text, words):
    path = tmp_path / "r.json"
    path.write_text(text)
    before = snapshot(tmp_path)
    line = assert_clean_failure(runner.invoke(loc_app, ["report", str(path)]), tmp_path, before)
    assert words in line and "r.json" in line, line


@pytest.mark.parametrize("case", ["not json", "t_error NaN", "query twice", "newer version"])
def test_resume_refuses_a_malformed_results_file(demo_dataset, tmp_path, case):
    """--resume reads the file through the same validation, before any work."""
    text, words = {c[0]: c[1:] for c in BAD_FILES}[case]
    path = tmp_path / "r.json"
    path.write_text(text)
    before, data = snapshot(tmp_path), snapshot(demo_dataset)
    res = runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "robot", "-o", str(path), "--resume"])
    assert words in assert_clean_failure(res, tmp_path, before)
    assert snapshot(demo_dataset) == data


def test_validation_errors_are_toolkit_errors():
    with pytest.raises(FormatVersionError):
        validate_results({"format_version": 9, "queries": []})
    with pytest.raises(InputError, match="appears twice"):
        validate_results({"queries": [record(), record()]})
    rs, meta = validate_results({"queries": [record(status="failed", R=None, t=None, t_error_m=None)]})
    assert rs[0].status == "failed" and meta == {}


def test_written_files_are_strict_json_and_read_back(tmp_path):
    """Medians over failed queries are infinite: written as null, never as NaN / Infinity."""
    path = tmp_path / "r.json"
    with ResultsWriter(path, meta={"device": "cpu"}) as w:
        w.add(QueryResult(image="a.jpg", scene="s", split="x", name="x/a", status="failed", message="no map"))
    data = json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert data["format_version"] == 1 and data["summary"]["median_t_error_m"] is None
    assert [r.name for r in load_results(path)[0]] == ["x/a"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv", "r.json", "r.json.journal"]  # the lock is gone
    with ResultsWriter(path, meta={"device": "cpu"}, resume=True) as w:
        w.finish()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv", "r.json"]  # a finished run has no journal


# ----------------------------------------------------------------------------- one writer at a time


def test_a_second_writer_is_refused_while_the_first_holds_the_lock(demo_dataset, tmp_path):
    path = tmp_path / "r.json"
    first = ResultsWriter(path, meta={"device": "cpu"})
    first.add(QueryResult(image="a.jpg", scene="s", split="x", name="x/a"))
    with pytest.raises(ResultsBusy, match="another `ldlloc run` is writing"):
        ResultsWriter(path, resume=True)
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "robot", "-o", str(path)])
    assert "another `ldlloc run` is writing" in assert_clean_failure(res, tmp_path, before)
    first.close()
    assert not lock_path(path).exists()
    with ResultsWriter(path, meta={"device": "cpu"}, resume=True) as second:
        assert second.done() == {"x/a"}


# ----------------------------------------------------------------------------- kills and faults

WRITER_SCRIPT = """
import sys, time
from ldlloc.batch.accuracy import QueryResult
from ldlloc.batch.results import ResultsWriter
w = ResultsWriter(sys.argv[1], meta={"device": "cpu"}, resume=True)
for i in range(10_000):
    w.add(QueryResult(image=f"{i}.jpg", scene="s", split="x", name=f"x/{i:05d}", t=[i, 0.0, 0.0],
                      t_error_m=0.001 * i, r_error_deg=0.1, seconds={"total": 0.01}))
"""


def _csv_is_a_prefix(path: Path) -> bool:
    """The CSV holds the first records of the results (those of the JSON when it was last rewritten),
    never one the results lack."""
    results, _ = load_results(path)
    csv = path.with_suffix(".csv").read_bytes().decode()
    rows = len(csv.splitlines()) - 1
    return 1 <= rows <= len(results) and csv == results_csv(results[:rows])


@pytest.mark.parametrize("seed", range(6))
def test_kill_at_a_random_moment_leaves_agreeing_files(tmp_path, seed):
    """SIGKILL a writing process at a random moment: the JSON and its journal are whole (a record cut
    by the kill is left out), the CSV behind (never ahead); the next writer removes the temporary
    files and brings the CSV level."""
    path = tmp_path / "r.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", WRITER_SCRIPT, str(path)], env=env)
    deadline = time.monotonic() + 60
    while not path.with_suffix(".csv").exists() and time.monotonic() < deadline:  # imports done, writing
        time.sleep(0.01)
    time.sleep(np.random.default_rng(seed).uniform(0.0, 0.3))
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    n = len(load_results(path)[0])
    assert n >= 1 and _csv_is_a_prefix(path)
    assert [r.name for r in load_results(path)[0]] == [f"x/{i:05d}" for i in range(n)]  # none lost, none twice
    with ResultsWriter(path, meta={"device": "cpu"}, resume=True) as w:
        assert len(w.done()) == n
        assert path.with_suffix(".csv").read_bytes().decode() == results_csv(w.results)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv", "r.json", "r.json.journal"]


def test_csv_that_cannot_be_written_is_a_warning(tmp_path, monkeypatch):
    """A fault between the JSON and the CSV write: the result is kept, one warning, recorded."""
    import ldlloc.batch.results as ev

    path, said = tmp_path / "r.json", []
    w = ResultsWriter(path, meta={"device": "cpu"}, warn=said.append)
    w.add(QueryResult(image="a.jpg", scene="s", split="x", name="x/a"))
    monkeypatch.setattr(ev, "results_csv", lambda results: (_ for _ in ()).throw(OSError(28, "No space left")))
    for name in ("x/b", "x/c"):
        w.add(QueryResult(image="b.jpg", scene="s", split="x", name=name))
    w.flush()  # the CSV is written with the JSON (which the journal's growth, or the end, rewrites)
    data = json.loads(path.read_text())
    assert [q["name"] for q in data["queries"]] == ["x/a", "x/b", "x/c"]
    assert data["meta"]["csv_error"] == f"no space left writing {path.with_suffix('.csv')}"  # names the file
    assert len(said) == 1 and said[0].startswith("warning: cannot write") and "r.csv" in said[0]
    monkeypatch.undo()
    w.close()
    with ResultsWriter(path, meta={"device": "cpu"}, resume=True) as w:  # opening brings the CSV level
        assert path.with_suffix(".csv").read_bytes().decode() == results_csv(w.results)
        w.add(QueryResult(image="d.jpg", scene="s", split="x", name="x/d"))
    assert "csv_error" not in json.loads(path.read_text())["meta"]


# ----------------------------------------------------------------------------- resume with other options


def test_resume_with_other_options_is_refused_unless_asked(tmp_path):
    path = tmp_path / "r.json"
    meta = {"device": "cpu", "params": {"search": {"top_k": 20, "loss": "inlier"}}}
    with ResultsWriter(path, meta=meta) as w:
        w.add(QueryResult(image="a.jpg", scene="s", split="x", name="x/a"))
    other = {"device": "cpu", "params": {"search": {"top_k": 5, "loss": "inlier"}}}
    with pytest.raises(InputError, match=r"other options \(params.search.top_k\).*--resume-any-options"):
        ResultsWriter(path, meta=other, resume=True)
    assert not lock_path(path).exists()
    with ResultsWriter(path, meta=other, resume=True, any_options=True) as w:
        w.add(QueryResult(image="b.jpg", scene="s", split="x", name="x/b"))
    meta_now = json.loads(path.read_text())["meta"]
    assert meta_now["params"]["search"]["top_k"] == 5
    assert meta_now["mixed_options"] == [meta]


def test_cli_resume_with_another_device_is_one_line(demo_dataset, tmp_path):
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"meta": {"device": "cuda"}, "queries": []}))
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "robot", "-o", str(path), "--resume"])
    line = assert_clean_failure(res, tmp_path, before)
    assert "other options (device)" in line and "--resume-any-options" in line
