"""The hostile pass over the new commands (`run --images`, `export`, `report --html`, confidence):
each problem it found, as a test (docs/measurements.md#hostile-new-features).

One image run on the demo dataset (one panorama copied into a plain folder, a corrupt one beside
it, against one room map) gives the results file the export cases edit by hand.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app
from tests._hostile import error_line

pytestmark = pytest.mark.xdist_group("hostile_new")  # one worker runs ``image_run``
runner = CliRunner()


@pytest.fixture(scope="module")
def image_run(demo_dataset, tmp_path_factory):
    """``run --images imgs --maps maps/synthroom_1.h5``: a good panorama and a corrupt one."""
    work = tmp_path_factory.mktemp("hostile_new")
    (work / "imgs").mkdir()
    pano = sorted((demo_dataset / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[0]
    shutil.copy(pano, work / "imgs" / "good.jpg")
    (work / "imgs" / "bad.jpg").write_bytes(b"\xff\xd8 not a jpeg" + b"\x00" * 64)
    (work / "maps").mkdir()
    shutil.copy(demo_dataset / "maps" / "synthroom_1.h5", work / "maps" / "synthroom_1.h5")
    args = ["run", "--images", str(work / "imgs"), "--maps", str(work / "maps" / "synthroom_1.h5"),
            "--output", str(work / "r.json")]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    return work, args


def test_image_run_records_carry_confidence_and_verdict(image_run):
    """Image runs gave `confidence: null, verdict: null` on every record (dataset runs had them)."""
    work, _ = image_run
    recs = {q["name"]: q for q in json.loads((work / "r.json").read_text())["queries"]}
    good, bad = recs["good"], recs["bad"]
    assert good["status"] != "failed" and good["verdict"] in ("confident", "ambiguous")
    assert 0.0 <= good["confidence"] <= 1.0 and good["confidence_signals"]
    assert bad["status"] == "failed" and bad["verdict"] == "failed" and bad["confidence"] == 0.0


def test_finished_image_run_can_be_run_again(image_run):
    """A complete image run left `meta.finished: false`, so running it again without --resume was
    refused as 'a run that did not finish (killed or interrupted)'."""
    work, args = image_run
    assert json.loads((work / "r.json").read_text())["meta"]["finished"] is True
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert json.loads((work / "r.json").read_text())["meta"]["finished"] is True


def test_localize_json_failure_says_failed(demo_dataset, tmp_path):
    """`localize --json` on a panorama that cannot be localized printed only `{"error": ...}`."""
    import cv2

    blank = tmp_path / "blank.jpg"
    cv2.imwrite(str(blank), np.full((256, 512, 3), 128, np.uint8))
    res = runner.invoke(app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(blank), "--json"])
    assert res.exit_code == 1, res.output
    out = json.loads(res.output)
    assert out["status"] == "failed" and out["verdict"] == "failed" and out["confidence"] == 0.0
    assert "too few lines" in out["error"]


@pytest.mark.parametrize("edit", ["reflection", "scaled"])
def test_export_refuses_a_pose_that_is_not_a_rotation(image_run, tmp_path, edit):
    """A hand-edited R with det -1, or scaled by 2, was exported as a camera (exit 0)."""
    work, _ = image_run
    data = json.loads((work / "r.json").read_text())
    q = next(q for q in data["queries"] if q["name"] == "good")
    R = np.asarray(q["R"])
    q["R"] = (np.diag([1.0, 1.0, -1.0]) @ R if edit == "reflection" else 2.0 * R).tolist()
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data))
    for fmt, out in (("nerfstudio", tmp_path / "t.json"), ("colmap", tmp_path / "model")):
        res = runner.invoke(app, ["export", str(edited), "--format", fmt, "-o", str(out), "--all"])
        assert "R is not a rotation" in error_line(res)
        assert not out.exists()


def test_export_overwrite_keeps_the_maps_folder(image_run):
    """`export -o MAPS_FOLDER --overwrite --format colmap` replaced the folder holding the map it
    had just read (the maps were deleted). A COLMAP export now replaces only model files: the map
    it read stays, byte for byte, beside the model."""
    work, _ = image_run
    the_map = (work / "maps" / "synthroom_1.h5").read_bytes()
    res = runner.invoke(app, ["export", str(work / "r.json"), "--format", "colmap", "-o", str(work / "maps"),
                              "--all", "--overwrite"])
    assert res.exit_code == 0, res.output
    assert (work / "maps" / "synthroom_1.h5").read_bytes() == the_map and (work / "maps" / "images.bin").is_file()


def test_report_html_refusal_names_no_missing_option(image_run):
    """`report --html mine.html` onto a user's page said "use --overwrite", an option `report` lacks."""
    work, _ = image_run
    mine = work / "mine.html"
    mine.write_text("<html>mine</html>")
    line = error_line(runner.invoke(app, ["report", str(work / "r.json"), "--html", str(mine)]))
    assert "--overwrite" not in line and "remove it first" in line
    assert mine.read_text() == "<html>mine</html>"


def test_run_refusing_a_user_json_gives_a_whole_reason(image_run):
    """`run --images ... -o notes.json` onto a user's JSON said `(esults file of \\`ldlloc run\\`:
    notes.json ("queries" must be a list, got None`: the reason cut mid-word, the path twice."""
    work, args = image_run
    notes = work / "notes.json"
    notes.write_text('{"a": 1}')
    line = error_line(runner.invoke(app, [*args[:-1], str(notes)]))
    assert line.count(str(notes)) == 1 and "(\"queries\" must be a list, got NoneType);" in line, line
    assert notes.read_text() == '{"a": 1}'
