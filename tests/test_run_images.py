"""`ldlloc run --images`: your own panoramas against a map or a folder of maps, no ground truth.

On the shared synthetic demo dataset (``demo_dataset``: two rooms, SIFT maps in ``maps/``), a
few of its panoramas are copied (linked) into a plain folder, without their poses; the run does
not see the truth, the tests compare with it. Which map: each panorama's own room is chosen among
the two maps.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app
from ldlmap.core.geometry import rotation_error_deg, translation_error
from ldlmap.datasets import open_dataset
from tests._hostile import error_line

pytestmark = pytest.mark.xdist_group("run_images")  # one worker: the module's image run is made once
runner = CliRunner()
PICK = {"synthroom_1": ("0000", "0001"), "synthroom_2": ("0000", "0003")}  # robot split: 2 per room, one stem twice


@pytest.fixture(scope="module")
def picked(demo_dataset, tmp_path_factory):
    """A folder ``imgs/<room>/<stem>.jpg`` of linked panoramas, a corrupt ``imgs/broken.jpg``, and
    the truth of each (by file)."""
    folder = tmp_path_factory.mktemp("own") / "imgs"
    truth = {}
    for q in open_dataset(demo_dataset, "omniscenes").queries(["robot"]):
        if Path(q.image).stem in PICK[q.scene]:
            link = folder / q.scene / Path(q.image).name
            link.parent.mkdir(parents=True, exist_ok=True)
            link.symlink_to(q.image)
            truth[f"{q.scene}/{Path(q.image).stem}"] = q
    (folder / "broken.jpg").write_bytes(b"\xff\xd8 not a jpeg at all" + b"\x00" * 100 + b"\xff\xd9")
    return folder, truth


@pytest.fixture(scope="module")
def image_run(demo_dataset, picked, tmp_path_factory):
    folder, _ = picked
    out = tmp_path_factory.mktemp("run") / "r.json"
    res = runner.invoke(app, ["run", "--images", str(folder), "--maps", str(demo_dataset / "maps"),
                              "--output", str(out), "--top-maps", "2"])
    return res, out


def test_image_run_chooses_the_room_and_localizes(demo_dataset, picked, image_run):
    folder, truth = picked
    res, out = image_run
    assert res.exit_code == 0, res.output
    assert "images by map" in res.output and "broken" in res.output
    data = json.loads(out.read_text())
    recs = {r["name"]: r for r in data["queries"]}
    assert set(recs) == {*truth, "broken"}  # the same stem in two folders: two names
    for name, q in truth.items():
        r = recs[name]
        assert r["split"] == "images" and r["t_error_m"] is None and r["status"] == "ok", r
        assert r["scene"] == q.scene and r["map"] == str(demo_dataset / "maps" / f"{q.scene}.h5")
        other = "synthroom_2" if q.scene == "synthroom_1" else "synthroom_1"
        assert r["map_runner_up"]["map"] == str(demo_dataset / "maps" / f"{other}.h5")
        assert translation_error(np.array(r["t"]), q.center) < 0.1, (name, r["t"], q.center)
        assert rotation_error_deg(np.array(r["R"]), q.rot_cam_from_world) < 5.0
    s = data["summary"]
    assert s["count"] == 5 and s["failed"] == 1 and s["localized"] == 4 and s["accuracy"]["0.1m_5deg"] is None
    assert s["maps"][str(demo_dataset / "maps" / "synthroom_1.h5")]["ok"] == 2


def test_corrupt_image_is_a_failed_record(image_run):
    _, out = image_run
    broken = [r for r in json.loads(out.read_text())["queries"] if r["name"] == "broken"][0]
    assert broken["status"] == "failed" and "corrupt" in broken["message"] and broken["R"] is None


def test_resume_skips_done_images_and_retries_failed_ones(demo_dataset, picked, image_run, tmp_path):
    folder, _ = picked
    _, out = image_run
    copy = tmp_path / "r.json"
    copy.write_text(out.read_text())
    before = {r["name"]: r for r in json.loads(copy.read_text())["queries"]}
    res = runner.invoke(app, ["run", "--images", str(folder), "--maps", str(demo_dataset / "maps"),
                              "--output", str(copy), "--top-maps", "2", "--resume"])
    assert res.exit_code == 0, res.output
    assert "4 of 5 queries done, 0 to run, 1 failed ones retried" in res.output
    after = {r["name"]: r for r in json.loads(copy.read_text())["queries"]}
    assert all(after[n]["seconds"] == before[n]["seconds"] for n in before if n != "broken")
    res = runner.invoke(app, ["run", "--images", str(folder), "--maps", str(demo_dataset / "maps"),
                              "--output", str(copy), "--top-maps", "1", "--resume"])
    assert "other options (top_maps)" in error_line(res)


def test_one_map_file_and_a_non_map_beside_it(demo_dataset, picked, tmp_path):
    folder, truth = picked
    maps = tmp_path / "maps"
    (maps / "sub").mkdir(parents=True)
    (maps / "sub" / "room.h5").symlink_to(demo_dataset / "maps" / "synthroom_2.h5")
    with h5py.File(maps / "notes.h5", "w") as f:
        f["x"] = np.zeros(3)
    pano = folder / "synthroom_2" / "0003.jpg"
    out = tmp_path / "one.json"
    res = runner.invoke(app, ["run", "--images", str(folder / "synthroom_2" / "0*3.jpg"), "--maps", str(maps),
                              "--output", str(out), "--save-vis", str(tmp_path / "vis")])
    assert res.exit_code == 0, res.output
    assert "warning:" in res.output and "notes.h5 left out" in res.output.replace("\n", "")
    (r,) = json.loads(out.read_text())["queries"]
    assert r["name"] == "0003" and r["scene"] == "sub/room" and r["map_runner_up"] is None
    q = truth["synthroom_2/0003"]
    assert translation_error(np.array(r["t"]), q.center) < 0.1 and Path(r["image"]) == pano
    assert (tmp_path / "vis" / "0003.jpg").stat().st_size > 0


@pytest.mark.parametrize("maps, why", [("missing", "--maps not found"), ("empty", "no .h5 map"),
                                       ("junk.h5", "no usable map")])
def test_bad_maps_are_error_line(picked, tmp_path, maps, why):
    folder, _ = picked
    (tmp_path / "empty").mkdir()
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    res = runner.invoke(app, ["run", "--images", str(folder), "--maps", str(tmp_path / maps),
                              "--output", str(tmp_path / "r.json")])
    assert why in error_line(res)
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("args, why", [(["--root", "x"], "drop --root"), ([], "needs --maps"),
                                       (["--top-maps", "0"], "--top-maps")])
def test_bad_image_run_options_are_error_line(picked, demo_dataset, tmp_path, args, why):
    folder, _ = picked
    maps = [] if not args else ["--maps", str(demo_dataset / "maps")]
    res = runner.invoke(app, ["run", "--images", str(folder), *maps, *args, "--output", str(tmp_path / "r.json")])
    assert why in error_line(res)


def test_no_images_is_error_line(demo_dataset, tmp_path):
    res = runner.invoke(app, ["run", "--images", str(tmp_path / "*.jpg"), "--maps", str(demo_dataset / "maps"),
                              "--output", str(tmp_path / "r.json")])
    assert "no file matches" in error_line(res)
