"""Results records, summaries at the paper's thresholds, resumable JSON/CSV writing."""

from __future__ import annotations

import json

import pytest

from ldlloc.batch.accuracy import QueryResult, summarize, summary_table
from ldlloc.batch.results import ResultsWriter, load_results


def res(name, te, re, split="extreme", scene="room_1", status="ok"):
    return QueryResult(image=f"{name}.jpg", scene=scene, split=split, name=name, R=[[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                       t=[0, 0, 0], t_error_m=te, r_error_deg=re, seconds={"search": 0.01, "total": 0.5},
                       status=status)


def test_summary_thresholds_and_medians():
    rs = [res("a", 0.01, 1.0), res("b", 0.07, 2.0), res("c", 0.15, 6.0), res("d", 1.0, 30.0),
          res("e", None, None, status="failed")]
    s = summarize(rs, device="cpu")
    assert s["count"] == 5 and s["failed"] == 1
    assert s["accuracy"]["0.05m_5deg"] == pytest.approx(1 / 5)
    assert s["accuracy"]["0.1m_5deg"] == pytest.approx(2 / 5)
    assert s["accuracy"]["0.2m_10deg"] == pytest.approx(3 / 5)
    assert s["median_t_error_m"] == pytest.approx(0.15)
    assert s["median_seconds"]["search"] == pytest.approx(0.01)
    assert s["device"] == "cpu"


def test_writer_is_resumable(tmp_path):
    out = tmp_path / "results.json"
    w = ResultsWriter(out, meta={"device": "cpu"})
    w.add(res("a", 0.01, 1.0))
    w.add(res("b", 0.5, 1.0, split="robot"))
    assert [q.name for q in load_results(out)[0]] == ["a", "b"]  # the JSON and its journal, while it runs
    w.finish()  # the whole JSON and CSV
    data = json.loads(out.read_text())
    assert len(data["queries"]) == 2 and data["summary"]["accuracy"]["0.1m_5deg"] == 0.5
    assert out.with_suffix(".csv").read_text().count("\n") == 3
    w.close()  # releases the file's lock: a second writer would be refused while it is held
    w2 = ResultsWriter(out, resume=True)
    assert w2.done() == {"a", "b"}
    w2.add(res("b", 0.02, 1.0, split="robot"))  # replaces, does not duplicate
    w2.finish()
    w2.close()
    qs, meta = load_results(out)
    assert len(qs) == 2 and meta["device"] == "cpu"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.csv", "results.json"]


def test_table_has_total_row():
    from rich.console import Console

    con = Console(record=True, width=200)
    con.print(summary_table([res("a", 0.01, 1.0, split="robot"), res("b", 0.5, 1.0)], "split", "t"))
    text = con.export_text()
    assert "robot" in text and "extreme" in text and "all" in text
