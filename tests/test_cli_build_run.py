"""`ldlmap build/prepare` and `ldlloc localize/run/report` through Typer's CliRunner.

Uses the shared synthetic demo dataset (``demo_dataset`` fixture); the maps in it were made by
``ldlmap prepare``. Bad input gives one ``error:`` line and exit code 1, or a flagged failure
per query in batch runs.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlmap.cli import app as map_app
from ldlmap.datasets import read_pose_txt
from ldlmap.map.mapfile import FORMAT_VERSION, read_map
from tests._hostile import error_line

runner = CliRunner()


def test_prepare_skips_up_to_date_maps(demo_dataset):
    res = runner.invoke(map_app, ["prepare", str(demo_dataset)])
    assert res.exit_code == 0, res.output
    assert res.output.count("up-to-date") == 2


def test_demo_map_contents(demo_dataset):
    """Principal directions match the room axes, translations are inside, keypoints on surfaces."""
    from scipy.spatial import cKDTree

    from ldlmap.io.pointcloud import read_point_cloud
    from ldlmap.synth.spec import load_spec

    m = read_map(demo_dataset / "maps" / "synthroom_1.h5")
    P = m.principal_directions
    np.testing.assert_allclose(P @ P.T, np.eye(3), atol=np.sin(np.radians(2)))
    # Room axes: the footprint's first wall direction, its normal and z.
    spec = load_spec(demo_dataset / "specs" / "synthroom_1.toml")
    fp = np.array(spec.footprint)
    d = fp[1] - fp[0]
    d /= np.linalg.norm(d)
    axes = np.array([[d[0], d[1], 0], [-d[1], d[0], 0], [0, 0, 1]])
    angles = np.degrees(np.arccos(np.clip(np.abs(P @ axes.T).max(axis=1), -1, 1)))
    assert angles.max() < 2.0, angles
    # Translations inside the footprint and between floor and ceiling.
    from ldlmap.core.polygon import points_in_polygon

    assert points_in_polygon(m.translations[:, :2], fp).all()
    assert (m.translations[:, 2] > 0).all() and (m.translations[:, 2] < spec.ceiling_height).all()
    # Keypoints lie on the scanned surfaces.
    cloud = read_point_cloud(demo_dataset / "pcd" / "synthroom_1.ply")
    dist, _ = cKDTree(cloud.points).query(m.features.xyz.astype(np.float64))
    assert np.median(dist) < 0.02
    assert m.features.descriptors.dtype == np.uint8 and m.features.backend == "sift"


def test_build_writes_map_and_picture(thin_scans, tmp_path):
    src = tmp_path / "room.ply"
    shutil.copy(thin_scans / "pcd" / "synthroom_2.ply", src)
    res = runner.invoke(map_app, ["build", str(src), "--num-views", "4", "--num-trans", "200",
                                  "--png", str(tmp_path / "room.png")])
    assert res.exit_code == 0, res.output
    m = read_map(tmp_path / "room.h5")
    assert m.features.num_views == 4 and abs(len(m.translations) - 200) < 40
    assert cv2.imread(str(tmp_path / "room.png")) is not None
    res = runner.invoke(map_app, ["info", str(tmp_path / "room.h5")])
    assert res.exit_code == 0 and "sift" in res.output


def test_lines_only_map_from_a_line_file(demo_dataset, tmp_path):
    res = runner.invoke(map_app, ["build", str(demo_dataset / "gt_lines" / "synthroom_1.obj"),
                                  "-o", str(tmp_path / "lines.h5"), "--trans-spacing", "0.4"])
    assert res.exit_code == 0, res.output
    m = read_map(tmp_path / "lines.h5")
    assert m.lines_only and len(m.lines) > 10
    # A lines-only map refines geometrically by default (from lines alone): on 6 robot queries,
    # measured 4 within 0.1 m (refined 0.011-0.114 m where the coarse poses were 0.04-0.116 m off;
    # one query's search fails, 3.7 m off, and keeps its coarse pose).
    from ldlloc.pipeline import LocalizeParams, Localizer, load_image

    images = sorted((demo_dataset / "robot_pano").rglob("*.jpg"))[:6]
    res = runner.invoke(loc_app, ["localize", str(tmp_path / "lines.h5"), str(images[0]), "--json", "--refine", "none"])
    assert res.exit_code == 0 and json.loads(res.output)["refine_method"] == "none", res.output
    res = runner.invoke(loc_app, ["localize", str(tmp_path / "lines.h5"), str(images[0]), "--json"])
    assert res.exit_code == 0 and json.loads(res.output)["refine_method"] == "geometric", res.output
    errors = []
    coarse_loc, refine_loc = (Localizer(m, LocalizeParams(refine_mode=mode)) for mode in ("none", "auto"))
    for img in images:
        R_true, t_true = read_pose_txt(Path(str(img).replace("_pano", "_pose")).with_suffix(".txt"))
        pano = load_image(img)
        coarse, out = coarse_loc.localize(pano), refine_loc.localize(pano)
        assert coarse.status == "coarse" and (out.status == "ok") == (out.refine_method == "geometric")
        errors.append([np.linalg.norm(o.center - t_true) for o in (coarse, out)])
    line = error_line(runner.invoke(loc_app, ["localize", str(tmp_path / "lines.h5"), str(images[0]),
                                                  "--refine", "features"]))
    assert "no features" in line
    assert "--refine" in error_line(runner.invoke(loc_app, ["localize", str(tmp_path / "lines.h5"), str(images[0]),
                                                                "--refine", "bogus"]))
    # A map with features: `both` polishes the feature pose with the lines and says what it kept.
    res = runner.invoke(loc_app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(images[0]), "--json",
                                  "--refine", "both"])
    assert res.exit_code == 0, res.output
    both = json.loads(res.output)
    assert both["refine_method"] in ("features+geometric", "features", "geometric") and "geometric polish" in both["message"]
    errors = np.array(errors)
    assert np.sum(errors[:, 1] < 0.1) >= 4 and np.median(errors[:, 1]) < np.median(errors[:, 0]), errors
    # An absolute length threshold (multi-room maps) instead of lambda's.
    res = runner.invoke(map_app, ["build", str(demo_dataset / "gt_lines" / "synthroom_1.obj"),
                                  "-o", str(tmp_path / "short.h5"), "--min-line-length", "0.25",
                                  "--trans-spacing", "2.0"])  # few translations: only its lines are checked
    assert res.exit_code == 0, res.output
    short = read_map(tmp_path / "short.h5")
    assert short.length_threshold == pytest.approx(0.25) and m.length_threshold > 0.3
    assert len(short.lines) > len(m.lines)
    assert np.linalg.norm(short.lines[:, 1] - short.lines[:, 0], axis=1).min() >= 0.25 - 1e-9
    assert "minimum line length" in error_line(runner.invoke(
        map_app, ["build", str(demo_dataset / "gt_lines" / "synthroom_1.obj"), "-o", str(tmp_path / "bad.h5"),
                  "--min-line-length", "0"]))
    assert not (tmp_path / "bad.h5").exists()


def test_build_bad_inputs(tmp_path):
    error_line(runner.invoke(map_app, ["build", str(tmp_path / "missing.ply")]))
    (tmp_path / "cloud.xyzw").write_text("1 2 3\n")
    assert "unsupported" in error_line(runner.invoke(map_app, ["build", str(tmp_path / "cloud.xyzw")]))
    (tmp_path / "empty.txt").write_text("")
    error_line(runner.invoke(map_app, ["build", str(tmp_path / "empty.txt")]))
    pts = np.random.default_rng(0).uniform(0, 3, size=(500, 6))
    pts[10, 1] = np.nan
    np.savetxt(tmp_path / "nan.txt", pts)
    assert "NaN" in error_line(runner.invoke(map_app, ["build", str(tmp_path / "nan.txt")]))
    error_line(runner.invoke(map_app, ["build", str(tmp_path / "nan.txt"), "--features", "orb"]))
    # No partial map files are left behind.
    assert not list(tmp_path.glob("*.h5")) and not list(tmp_path.glob(".*tmp*"))


def test_unreachable_superpoint_weights(thin_scans, tmp_path, monkeypatch):
    monkeypatch.setenv("LDL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("LDL_SUPERPOINT_WEIGHTS", raising=False)
    src = tmp_path / "room.ply"
    shutil.copy(thin_scans / "pcd" / "synthroom_2.ply", src)
    # (few translations: the build gets to the weights after the lines, translations and fields)
    line = error_line(runner.invoke(map_app, ["build", str(src), "--features", "superpoint", "--num-trans", "60",
                                                  "--weights", str(tmp_path / "nope.pth")]))
    assert "SuperPoint" in line or "weights" in line
    assert not (tmp_path / "room.h5").exists()


def test_localize_and_bad_maps(demo_dataset, tmp_path):
    map_path = demo_dataset / "maps" / "synthroom_1.h5"
    img = sorted((demo_dataset / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[0]
    res = runner.invoke(loc_app, ["localize", str(map_path), str(img), "--json", "--vis", str(tmp_path / "v.jpg"),
                                  "--threads", "1"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    pose = np.loadtxt(str(img).replace("_pano", "_pose").replace(".jpg", ".txt"))
    assert np.linalg.norm(np.array(out["t"]) - pose[:, 3]) < 0.1
    h, w, _ = cv2.imread(str(tmp_path / "v.jpg")).shape  # the two 1024 x 512 halves and the caption band
    assert w == 1024 and 1024 < h < 1024 + 200
    # Wrong backend, other format version, corrupt map, missing or broken image.
    assert "built with sift" in error_line(runner.invoke(loc_app, ["localize", str(map_path), str(img),
                                                                       "--features", "superpoint"]))
    old = tmp_path / "old.h5"
    shutil.copy(map_path, old)
    with h5py.File(old, "a") as h5:
        h5.attrs["format_version"] = FORMAT_VERSION + 1
    assert "format version" in error_line(runner.invoke(loc_app, ["localize", str(old), str(img)]))
    (tmp_path / "bad.h5").write_bytes(b"\x89HDF garbage")
    error_line(runner.invoke(loc_app, ["localize", str(tmp_path / "bad.h5"), str(img)]))
    error_line(runner.invoke(loc_app, ["localize", str(map_path), str(tmp_path / "none.jpg")]))
    (tmp_path / "broken.jpg").write_bytes(b"not a jpeg")
    assert "decode" in error_line(runner.invoke(loc_app, ["localize", str(map_path), str(tmp_path / "broken.jpg")]))
    cv2.imwrite(str(tmp_path / "grey.png"), np.full((256, 512, 3), 128, np.uint8))
    assert "lines" in error_line(runner.invoke(loc_app, ["localize", str(map_path), str(tmp_path / "grey.png")]))


def test_run_flags_failures_and_resumes(demo_dataset, tmp_path):
    """A batch run over one split, with a grey image and a missing map among the queries."""
    root = tmp_path / "data"
    shutil.copytree(demo_dataset, root, ignore=shutil.ignore_patterns("*_gamma_*", "*_intensity_*", "*white*"))
    grey = sorted((root / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[0]
    cv2.imwrite(str(grey), np.full((512, 1024, 3), 128, np.uint8))
    (root / "maps" / "synthroom_2.h5").unlink()
    out = tmp_path / "res.json"
    res = runner.invoke(loc_app, ["run", "--root", str(root), "--split", "robot", "--output", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    status = {q["name"]: q for q in data["queries"]}
    assert len(status) == 10 and data["summary"]["count"] == 10
    assert sum(q["status"] == "failed" for q in status.values()) == 6  # 1 grey image + 5 without a map
    assert any("map not found" in q["message"] for q in status.values())
    assert out.with_suffix(".csv").read_text().count("\n") == 11
    ok = [q for q in status.values() if q["status"] != "failed"]
    assert len(ok) == 4 and sum(q["t_error_m"] < 0.1 and q["r_error_deg"] < 5 for q in ok) >= 3
    # --resume does not redo finished queries but retries the failed ones (tests/test_hostile_loc.py:
    # a map built since then localizes them); report prints the tables again.
    before = {q["name"]: q["seconds"] for q in ok}
    res = runner.invoke(loc_app, ["run", "--root", str(root), "--split", "robot", "--output", str(out), "--resume"])
    assert res.exit_code == 0 and "4 of 10 queries done, 0 to run, 6 failed ones retried" in res.output, res.output
    data = json.loads(out.read_text())
    assert sum(q["status"] == "failed" for q in data["queries"]) == 6
    assert {q["name"]: q["seconds"] for q in data["queries"] if q["name"] in before} == before
    res = runner.invoke(loc_app, ["report", str(out)])
    assert res.exit_code == 0 and "robot" in res.output and "synthroom_1" in res.output


def test_privacy_mode_uses_only_features_near_lines(demo_dataset):
    from ldlloc.pipeline import LocalizeParams, Localizer, load_image

    m = read_map(demo_dataset / "maps" / "synthroom_1.h5", load_cloud=False)
    img_path = sorted((demo_dataset / "handheld_pano" / "handheld_synthroom_1_scene_1").glob("*.jpg"))[1]
    pose = np.loadtxt(str(img_path).replace("_pano", "_pose").replace(".jpg", ".txt"))
    img = load_image(img_path)
    full = Localizer(m).localize(img)
    private = Localizer(m, LocalizeParams(privacy=True)).localize(img)
    assert 0 < private.num_query_features < 0.8 * full.num_query_features
    assert np.linalg.norm(private.center - pose[:, 3]) < 0.1


def test_superpoint_map_with_a_checkpoint_written_here(demo_dataset, thin_scans, tmp_path):
    """The SuperPoint path end to end (random weights: the wiring, not the accuracy; a thinned scan)."""
    import torch

    from ldlmap.features.superpoint import build_superpoint

    torch.manual_seed(0)
    ckpt = tmp_path / "sp.pth"
    torch.save(build_superpoint().state_dict(), ckpt)
    src = tmp_path / "room.ply"
    shutil.copy(thin_scans / "pcd" / "synthroom_1.ply", src)
    res = runner.invoke(map_app, ["build", str(src), "--features", "superpoint", "--weights", str(ckpt),
                                  "--num-views", "1", "--num-trans", "100"])
    assert res.exit_code == 0, res.output
    m = read_map(tmp_path / "room.h5")
    assert m.features.backend == "superpoint" and m.features.descriptors.dtype == np.float16
    assert m.features.descriptors.shape[1] == 256
    img = sorted((demo_dataset / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[0]
    # The query as taken: one SuperPoint pass (in the map's frame, random weights fail in each of up
    # to 3 frames; that path is the learned backends' test).
    res = runner.invoke(loc_app, ["localize", str(tmp_path / "room.h5"), str(img), "--weights", str(ckpt), "--json",
                                  "--query-frame", "image"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["num_rotations"] > 0
    # A SIFT query against this map is refused with one line.
    assert "built with superpoint" in error_line(
        runner.invoke(loc_app, ["localize", str(tmp_path / "room.h5"), str(img), "--features", "sift"]))


def test_build_from_a_colmap_workspace(thin_scans, tmp_path):
    """A COLMAP workspace: the fused.ply dense cloud (a thinned scan) is mapped, camera centres join
    the translations."""
    from tests.test_io_colmap import _build_reconstruction

    rec, centers, _, _ = _build_reconstruction(np.random.default_rng(0))
    model = tmp_path / "ws" / "sparse" / "0"
    model.mkdir(parents=True)
    rec.write_binary(str(model))
    shutil.copy(thin_scans / "pcd" / "synthroom_1.ply", tmp_path / "ws" / "sparse" / "fused.ply")
    res = runner.invoke(map_app, ["build", str(tmp_path / "ws"), "-o", str(tmp_path / "sfm.h5"),
                                  "--features", "none", "--num-trans", "100"])
    assert res.exit_code == 0, res.output
    m = read_map(tmp_path / "sfm.h5")
    assert m.lines_only and len(m.lines) > 10 and m.config["source"].startswith("colmap:")
    for c in centers.values():  # the registered camera centres are candidate translations
        assert np.linalg.norm(m.translations - c, axis=1).min() < 1e-5
