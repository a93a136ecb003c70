"""Results files read from another folder than the run's, and results of runs that did not finish:
relative image and map paths start from the run's working folder (``meta.base_dir``), so `export`
and `report` work from anywhere (files written before ``base_dir`` existed still read from their
own folder); `report` and `report --html` of a killed run's file say it did not finish and how many
queries it holds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from tests._hostile import error_line
from tests._results_files import record, write_panorama, write_results

runner = CliRunner()


def _invoke(args: list):
    return runner.invoke(loc_app, [str(a) for a in args])


@pytest.fixture
def work(tmp_path, monkeypatch) -> Path:
    """A working folder with ``shots/p0.jpg``, ``shots/p1.jpg`` and results naming them relative to it."""
    work = tmp_path / "work"
    for i in range(2):
        write_panorama(work / "shots" / f"p{i}.jpg")
    (tmp_path / "elsewhere").mkdir()
    return work


# (case, meta of the results file, where the commands run, whether they find the images)
CASES = [
    ("base_dir, run from elsewhere", True, "elsewhere", True),
    ("base_dir, run from the work folder", True, "work", True),
    ("no base_dir (older file), from the work folder", False, "work", True),
    ("no base_dir (older file), from elsewhere", False, "elsewhere", False),
]


@pytest.mark.parametrize("with_base, where, found", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_export_and_report_from_another_folder(work, tmp_path, monkeypatch, with_base, where, found):
    meta = {"base_dir": str(work)} if with_base else {}
    results = write_results(tmp_path / "r.json", [record(f"p{i}", f"shots/p{i}.jpg") for i in range(2)], **meta)
    monkeypatch.chdir(tmp_path / where)
    res = _invoke(["export", results, "--format", "nerfstudio", "-o", tmp_path / "t.json"])
    if not found:
        assert "image not found: shots/p0.jpg" in error_line(res)
        return
    assert res.exit_code == 0, res.output
    frames = json.loads((tmp_path / "t.json").read_text())["frames"]
    assert [(tmp_path / f["file_path"]).resolve() for f in frames] == [(work / f"shots/p{i}.jpg").resolve()
                                                                        for i in range(2)]
    res = _invoke(["report", results, "--html", tmp_path / "page.html"])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "page.html").read_text()
    assert page.count('class="thumb"') == 2 and "image not found" not in page


def test_a_run_records_its_working_folder(tmp_path, monkeypatch):
    from ldlloc.batch.run import run_meta
    from ldlloc.pipeline import LocalizeParams

    monkeypatch.chdir(tmp_path)
    assert run_meta(LocalizeParams(), "cpu")["base_dir"] == str(tmp_path)


def test_map_paths_start_from_the_base_folder_too(work, tmp_path, monkeypatch):
    from ldlloc.export.poses import map_path_for

    (work / "maps").mkdir()
    (work / "maps" / "room.h5").write_bytes(b"\x89HDF\r\n\x1a\n")
    monkeypatch.chdir(tmp_path / "elsewhere")
    found, _ = map_path_for({"scene": "room"}, {"maps": "maps", "base_dir": str(work)})
    assert found == work / "maps" / "room.h5"
    found, _ = map_path_for({"scene": "x", "map": "maps/room.h5"}, {"base_dir": str(work)})
    assert found == work / "maps" / "room.h5"


# (case, meta "finished", the note expected in `report` and the page)
FINISHED = [
    ("killed", False, "did not finish"),
    ("finished", True, None),
    ("written before the flag", None, None),
]


@pytest.mark.parametrize("finished, note", [c[1:] for c in FINISHED], ids=[c[0] for c in FINISHED])
def test_report_says_a_run_did_not_finish(work, tmp_path, finished, note):
    records = [record(f"p{i}", work / f"shots/p{i}.jpg") for i in range(2)]
    results = write_results(tmp_path / "r.json", records, finished=finished)
    if finished is None:
        data = json.loads(results.read_text())
        del data["meta"]["finished"]
        results.write_text(json.dumps(data))
    res = _invoke(["report", results, "--html", tmp_path / "page.html"])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "page.html").read_text()
    text = " ".join(res.output.split())
    if note is None:
        assert "did not finish" not in text and "did not finish" not in page
    else:
        assert "did not finish" in text and "holds 2 queries" in text
        assert "did not finish" in page and "holds 2 queries" in page
