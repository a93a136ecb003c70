"""`ldlloc run --scene-unknown`: a dataset's queries localized without being told their scene.

On the shared synthetic demo dataset (two rooms, SIFT maps in ``maps/``) each query of the robot
split is localized against both maps of its scene's folder, judged together as ``run --images``
judges a folder; the test compares with the dataset's ground truth, which the run reads only to
measure errors.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ldlloc.cli import app
from tests._hostile import error_line

pytestmark = pytest.mark.xdist_group("scene_unknown")  # one worker: the module's run is made once
runner = CliRunner()


@pytest.fixture(scope="module")
def unknown_run(demo_dataset, tmp_path_factory):
    """The robot split with the scene not given, against a folder of the two maps and a file that
    is not a map."""
    tmp = tmp_path_factory.mktemp("unknown")
    maps = tmp / "maps"
    maps.mkdir()
    for room in ("synthroom_1", "synthroom_2"):
        (maps / f"{room}.h5").symlink_to(demo_dataset / "maps" / f"{room}.h5")
    (maps / "notes.h5").write_bytes(b"not hdf5 at all")
    out = tmp / "r.json"
    res = runner.invoke(app, ["run", "--root", str(demo_dataset), "--split", "robot", "--scene-unknown",
                              "--top-maps", "2", "--maps", str(maps), "--output", str(out)])
    return res, out, maps


def test_each_query_finds_its_room_and_pose(unknown_run):
    res, out, maps = unknown_run
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    recs = data["queries"]
    assert len(recs) == 10 and data["meta"]["scene_unknown"] is True and data["meta"]["top_maps"] == 2
    for r in recs:
        assert r["status"] == "ok", r
        assert r["map"] == str(maps / f"{r['scene']}.h5"), (r["name"], r["map"])
        other = "synthroom_2" if r["scene"] == "synthroom_1" else "synthroom_1"
        assert r["map_runner_up"]["map"] == str(maps / f"{other}.h5")
        assert r["t_error_m"] < 0.1 and r["r_error_deg"] < 5.0, (r["name"], r["t_error_m"], r["r_error_deg"])
    assert "chosen map is the query's own for 10 / 10" in res.output


def test_a_non_map_in_the_folder_is_left_out_with_a_warning(unknown_run):
    res, _, _ = unknown_run
    assert res.output.count("notes.h5 left out") == 1, res.output


def test_resume_refuses_mixing_scene_given_and_unknown(demo_dataset, unknown_run, tmp_path):
    _, out, maps = unknown_run
    copy = tmp_path / "r.json"
    copy.write_text(out.read_text())
    res = runner.invoke(app, ["run", "--root", str(demo_dataset), "--split", "robot", "--maps", str(maps),
                              "--output", str(copy), "--resume"])
    assert "other options (scene_unknown" in error_line(res)


@pytest.mark.parametrize("args, why", [(["--top-maps", "2"], "--top-maps goes with --images or --scene-unknown"),
                                       (["--scene-unknown", "--top-maps", "0"], "--top-maps")])
def test_bad_options_are_error_line(demo_dataset, tmp_path, args, why):
    res = runner.invoke(app, ["run", "--root", str(demo_dataset), "--split", "robot", *args,
                              "--output", str(tmp_path / "r.json")])
    assert why in error_line(res)
    assert not (tmp_path / "r.json").exists()


def test_images_run_refuses_scene_unknown(demo_dataset, tmp_path):
    img = next((demo_dataset / "robot_pano").rglob("*.jpg"))
    res = runner.invoke(app, ["run", "--images", str(img), "--maps", str(demo_dataset / "maps"), "--scene-unknown",
                              "--output", str(tmp_path / "r.json")])
    assert "drop --scene-unknown" in error_line(res)


def test_folder_without_maps_says_how_to_build(demo_dataset, tmp_path):
    res = runner.invoke(app, ["run", "--root", str(demo_dataset), "--split", "robot", "--scene-unknown",
                              "--maps", str(tmp_path / "none"), "--output", str(tmp_path / "r.json")])
    assert "ldlmap prepare" in error_line(res)


def test_report_says_how_often_the_own_map_was_chosen(unknown_run):
    res, out, _ = unknown_run
    assert res.exit_code == 0, res.output
    rep = runner.invoke(app, ["report", str(out)])
    assert rep.exit_code == 0, rep.output
    assert "chosen map is the query's own for 10 / 10" in rep.output

