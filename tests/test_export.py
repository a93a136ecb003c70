"""`ldlloc export`: each format read back by the library that consumes it (pycolmap for COLMAP, JSON
with nerfstudio's documented fields and its equirectangular ray model, Open3D for PLY), poses equal
to the results file's within 1e-6, on the results of a real run of the demo scene."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlmap.core.geometry import bearing_from_pixel, pose_from_colmap, project_to_pixels

pytestmark = pytest.mark.xdist_group("export")  # one worker runs ``run_results``
runner = CliRunner()
SCENE = "synthroom_1"


def _invoke(args: list[str]):
    return runner.invoke(loc_app, [str(a) for a in args])


def _ok(args: list[str]) -> str:
    res = _invoke(args)
    assert res.exit_code == 0, res.output
    return res.output


def _error(args: list[str]) -> str:
    """The one-line error of a command that must fail (exit 1, no traceback)."""
    res = _invoke(args)
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    return lines[0]


@pytest.fixture(scope="module")
def run_results(demo_dataset, tmp_path_factory) -> Path:
    """Results of `ldlloc run` on the robot split of one demo scene (5 queries, map features)."""
    out = tmp_path_factory.mktemp("export_run") / "robot.json"
    _ok(["run", "--root", demo_dataset, "--split", "robot", "--scene", SCENE, "-o", out])
    return out


def _records(path: Path) -> dict[str, dict]:
    return {q["name"]: q for q in json.loads(path.read_text())["queries"]}


def _size(image: str) -> tuple[int, int]:
    import cv2

    h, w = cv2.imread(image).shape[:2]
    return w, h


def _with_fields(src: Path, dst: Path, **per_name) -> Path:
    """A copy of results ``src`` whose records get the fields ``per_name[name]`` (a dict each)."""
    data = json.loads(src.read_text())
    for q in data["queries"]:
        q.update(per_name.get(q["name"], {}))
    dst.write_text(json.dumps(data))
    return dst


def test_colmap_model_reads_back_binary_and_text(run_results, demo_dataset, tmp_path):
    import pycolmap

    from ldlmap.map.mapfile import read_map

    records = _records(run_results)
    m = read_map(demo_dataset / "maps" / f"{SCENE}.h5", load_cloud=False)
    # A results file of an older run (no verdicts): every localized query is exported.
    no_verdicts = _with_fields(run_results, tmp_path / "old.json",
                               **{n: {"verdict": None, "confidence": None} for n in records})
    for text in (False, True):
        out = tmp_path / ("txt" if text else "bin")
        output = _ok(["export", no_verdicts, "--format", "colmap", "-o", out, *(["--text"] if text else [])])
        assert "holds no verdicts" in output and f"exporting {len(records)} of {len(records)} queries" in output
        assert sorted(p.suffix for p in out.iterdir()) == [".txt" if text else ".bin"] * 5  # + rigs, frames
        rec = pycolmap.Reconstruction(str(out))
        assert rec.num_images() == len(records) and rec.num_points3D() == 2 * len(m.lines)
        by_image = {os.path.abspath(q["image"]): q for q in records.values()}
        root = Path(os.path.commonpath([os.path.dirname(p) for p in by_image]))
        for image in rec.images.values():
            q = by_image[str(root / image.name)]
            cam = rec.cameras[image.camera_id]
            assert cam.model == pycolmap.CameraModelId.EQUIRECTANGULAR and (cam.width, cam.height) == _size(q["image"])
            T = image.cam_from_world()
            R, t = pose_from_colmap(T.rotation.matrix(), T.translation)
            assert np.abs(R - np.asarray(q["R"])).max() < 1e-6 and np.abs(t - np.asarray(q["t"])).max() < 1e-6
            # pycolmap's own camera puts the map's line ends where our convention does
            X = m.lines[:20].reshape(-1, 3)
            uv = cam.img_from_cam(X @ T.rotation.matrix().T + T.translation)
            ours = project_to_pixels(X, q["R"], q["t"], cam.width, cam.height)
            du = np.abs(uv[:, 0] - ours[:, 0])
            assert np.all((np.minimum(du, cam.width - du) < 1e-6) & (np.abs(uv[:, 1] - ours[:, 1]) < 1e-6))


def _nerfstudio_ray(frame: dict, meta: dict, x: float, y: float) -> np.ndarray:
    """World direction of pixel (x, y) as nerfstudio's equirectangular camera computes it
    (nerfstudio.cameras.cameras.Cameras._generate_rays_from_coords)."""
    a = (x - meta["cx"]) / meta["fl_x"]
    b = -(y - meta["cy"]) / meta["fl_y"]
    theta, phi = -np.pi * a, np.pi * (0.5 - b)
    d = np.array([-np.sin(theta) * np.sin(phi), np.cos(phi), -np.cos(theta) * np.sin(phi)])
    return np.asarray(frame["transform_matrix"])[:3, :3] @ d


def test_nerfstudio_transforms_follow_its_documented_fields(run_results, tmp_path):
    from ldlloc.export.nerfstudio import pose_from_opengl

    records = _records(run_results)
    out = tmp_path / "ns" / "transforms.json"
    _ok(["export", run_results, "--format", "nerfstudio", "-o", out])
    meta = json.loads(out.read_text())
    assert meta["camera_model"] == "EQUIRECTANGULAR"
    w, h = _size(next(iter(records.values()))["image"])
    assert (meta["w"], meta["h"], meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]) == (w, h, w / 2, h, w / 2, h / 2)
    assert len(meta["frames"]) == len(records)
    rng = np.random.default_rng(0)
    for frame in meta["frames"]:
        q = records[frame["ldl_name"]]
        assert not Path(frame["file_path"]).is_absolute()
        assert (out.parent / frame["file_path"]).resolve() == Path(q["image"]).resolve()
        T = np.asarray(frame["transform_matrix"])
        assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
        R, t = pose_from_opengl(T)
        assert np.abs(R - np.asarray(q["R"])).max() < 1e-6 and np.abs(t - np.asarray(q["t"])).max() < 1e-6
        # nerfstudio's ray through a pixel centre is our bearing of that pixel, in the world
        for x, y in rng.uniform([0, 0], [meta["w"], meta["h"]], (8, 2)):
            ours = np.asarray(q["R"]).T @ bearing_from_pixel(np.array([x, y]), meta["w"], meta["h"])
            assert np.allclose(_nerfstudio_ray(frame, meta, x, y), ours, atol=1e-9)


def test_ply_holds_cameras_and_map_lines_for_open3d(run_results, demo_dataset, tmp_path):
    import open3d as o3d

    from ldlmap.map.mapfile import read_map
    from ldlloc.export.ply import FORWARD_M

    records = list(_records(run_results).values())
    m = read_map(demo_dataset / "maps" / f"{SCENE}.h5", load_cloud=False)
    out = tmp_path / "cams.ply"
    _ok(["export", run_results, "--format", "ply", "-o", out])
    n, L = len(records), len(m.lines)
    cloud = o3d.io.read_point_cloud(str(out))
    pts, normals = np.asarray(cloud.points), np.asarray(cloud.normals)
    assert len(pts) == 3 * n + 2 * L and cloud.has_colors()
    for i, q in enumerate(records):  # the file's order
        forward = np.asarray(q["R"])[0]
        assert np.abs(pts[3 * i] - q["t"]).max() < 1e-6
        assert np.allclose(pts[3 * i + 1], np.asarray(q["t"]) + FORWARD_M * forward, atol=1e-6)
        assert np.allclose(normals[3 * i], forward, atol=1e-6)
    assert np.allclose(pts[3 * n:], m.lines.reshape(-1, 3), atol=1e-6)
    lines = o3d.io.read_line_set(str(out))
    idx = np.asarray(lines.lines)
    assert len(idx) == 2 * n + L and lines.has_colors()
    assert np.array_equal(idx[0], [0, 1]) and np.array_equal(idx[2 * n], [3 * n, 3 * n + 1])


def test_only_confident_queries_unless_all(run_results, tmp_path):
    names = list(_records(run_results))
    fields = {names[0]: {"verdict": "confident", "confidence": 0.95}, names[1]: {"verdict": "ambiguous",
              "confidence": 0.4}, names[2]: {"verdict": "failed", "confidence": 0.05},
              names[3]: {"verdict": "confident", "confidence": 0.9},
              names[4]: {"status": "failed", "R": None, "t": None, "verdict": "failed", "confidence": 0.0}}
    results = _with_fields(run_results, tmp_path / "verdicts.json", **fields)
    out = _ok(["export", results, "--format", "nerfstudio", "-o", tmp_path / "a.json"])
    assert "holds no verdicts" not in out and "2 of 5 queries (1 failed, 2 not confident (--all keeps them)" in out
    got = [f["ldl_name"] for f in json.loads((tmp_path / "a.json").read_text())["frames"]]
    assert got == [names[0], names[3]]
    _ok(["export", results, "--format", "nerfstudio", "-o", tmp_path / "b.json", "--all"])
    got = [f["ldl_name"] for f in json.loads((tmp_path / "b.json").read_text())["frames"]]
    assert got == names[:4]  # a failed query has no pose: never exported


def test_input_frame(run_results, tmp_path, monkeypatch):
    from ldlloc.export import poses
    from ldlloc.export.nerfstudio import pose_from_opengl
    from scipy.spatial.transform import Rotation

    names = list(_records(run_results))
    R_in = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix()
    frame = {"input_frame": {"R": R_in.tolist(), "t": [1.0, 2.0, 3.0]}}
    results = _with_fields(run_results, tmp_path / "in.json", **{n: frame for n in names})
    _ok(["export", results, "--format", "nerfstudio", "-o", tmp_path / "in_t.json", "--frame", "input"])
    for f in json.loads((tmp_path / "in_t.json").read_text())["frames"]:
        R, t = pose_from_opengl(f["transform_matrix"])
        assert np.abs(R - R_in).max() < 1e-9 and np.allclose(t, [1, 2, 3])
    # without input_frame: the map's pose when the map was built in its input's frame (the demo's)
    _ok(["export", run_results, "--format", "nerfstudio", "-o", tmp_path / "same.json", "--frame", "input"])
    monkeypatch.setattr(poses, "input_to_map_of", lambda path: np.diag([2.0, 2.0, 2.0, 1.0]))
    line = _error(["export", run_results, "--format", "nerfstudio", "-o", tmp_path / "x.json", "--frame", "input"])
    assert "has no input_frame pose but its map" in line and "built from another frame" in line
    alone = _with_fields(run_results, tmp_path / "alone.json", **{n: {"map": str(tmp_path / "gone.h5")} for n in names})
    data = json.loads(alone.read_text())
    data["meta"] = {}
    alone.write_text(json.dumps(data))
    line = _error(["export", alone, "--format", "nerfstudio", "-o", tmp_path / "y.json", "--frame", "input"])
    assert "its map is not found" in line and "--map" in line
    assert not (tmp_path / "x.json").exists() and not (tmp_path / "y.json").exists()


def test_image_root_names_colmap_images(run_results, demo_dataset, tmp_path):
    import pycolmap

    _ok(["export", run_results, "--format", "colmap", "-o", tmp_path / "m", "--image-root", demo_dataset])
    names = sorted(im.name for im in pycolmap.Reconstruction(str(tmp_path / "m")).images.values())
    want = sorted(Path(os.path.abspath(q["image"])).relative_to(demo_dataset.resolve()).as_posix()
                  for q in _records(run_results).values())
    assert names == want and all(n.startswith("robot_pano/") for n in names)
    line = _error(["export", run_results, "--format", "colmap", "-o", tmp_path / "m2", "--image-root", tmp_path])
    assert "is not under --image-root" in line and not (tmp_path / "m2").exists()


def test_outputs_are_not_replaced_without_overwrite(run_results, tmp_path):
    out = tmp_path / "cams.ply"
    out.write_text("mine")
    assert "exists; use --overwrite" in _error(["export", run_results, "--format", "ply", "-o", out])
    assert out.read_text() == "mine"
    _ok(["export", run_results, "--format", "ply", "-o", out, "--overwrite"])
    assert out.read_bytes().startswith(b"ply\n")
    model = tmp_path / "model"
    model.mkdir()
    (model / "notes.txt").write_text("mine")
    assert "not empty; use --overwrite" in _error(["export", run_results, "--format", "colmap", "-o", model])
    _ok(["export", run_results, "--format", "colmap", "-o", model, "--overwrite"])
    assert (model / "notes.txt").read_text() == "mine" and (model / "images.bin").exists()  # only model files replaced
    umask = os.umask(0)
    os.umask(umask)
    assert model.stat().st_mode & 0o777 == 0o777 & ~umask  # a folder like any other, not mkdtemp's 0700


@pytest.mark.parametrize("args, expect", [
    (["--format", "obj", "-o", "{tmp}/x.obj"], "unknown --format 'obj'"),
    (["--format", "ply", "-o", "{tmp}/x.json"], "writes a .ply file"),
    (["--format", "nerfstudio", "-o", "{tmp}/x"], "writes a .json file"),
    (["--format", "ply", "-o", "{tmp}/x.ply", "--text"], "--text is for --format colmap"),
    (["--format", "ply", "-o", "{tmp}/x.ply", "--frame", "world"], "--frame must be map or input"),
    (["--format", "ply", "-o", "{tmp}/x.ply", "--scene", "nowhere"], "no query of scene nowhere"),
])
def test_bad_options_are_one_line_errors(run_results, tmp_path, args, expect):
    line = _error(["export", run_results, *[a.format(tmp=tmp_path) for a in args]])
    assert expect in line
    assert list(tmp_path.iterdir()) == []


def test_bad_results_files_are_one_line_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"queries": [{"image": "a.jpg", "scene": "s", "split": "x", "name": "q", "status": "ok", "t_error_m": null, '
                   '"r_error_deg": null, "R": [1, 2]}]}')
    assert "queries[0].R must be" in _error(["export", bad, "--format", "ply", "-o", tmp_path / "o.ply"])
    bad.write_text('{"queries": [{"image": "a.jpg", "scene": "s", "split": "x", "name": "q", "status": "ok", "t_error_m": null, '
                   '"r_error_deg": null, "verdict": "sure"}]}')
    assert "queries[0].verdict must be" in _error(["export", bad, "--format", "ply", "-o", tmp_path / "o.ply"])
    bad.write_text("not json")
    assert "not JSON" in _error(["export", bad, "--format", "ply", "-o", tmp_path / "o.ply"])
    assert "results file not found" in _error(["export", tmp_path / "none.json", "--format", "ply", "-o",
                                               tmp_path / "o.ply"])
    empty = tmp_path / "empty.json"
    empty.write_text('{"queries": []}')
    assert "holds no queries" in _error(["export", empty, "--format", "ply", "-o", tmp_path / "o.ply"])
    empty.write_text('{"queries": [{"image": "a.jpg", "scene": "s", "split": "x", "name": "q", "status": "failed", '
                     '"t_error_m": null, "r_error_deg": null}]}')
    assert "nothing to export" in _error(["export", empty, "--format", "ply", "-o", tmp_path / "o.ply"])
    assert not (tmp_path / "o.ply").exists()


def test_missing_image_leaves_no_model(run_results, tmp_path):
    names = list(_records(run_results))
    results = _with_fields(run_results, tmp_path / "r.json", **{names[0]: {"image": str(tmp_path / "gone.jpg")}})
    line = _error(["export", results, "--format", "colmap", "-o", tmp_path / "model"])
    assert "image not found" in line and "gone.jpg" in line
    assert not (tmp_path / "model").exists() and not any(p.name.startswith(".model") for p in tmp_path.iterdir())
