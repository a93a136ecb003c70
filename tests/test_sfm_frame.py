"""SfM maps: up axis, scale, input frame, orthonormal directions, length filter.

The SfM-like line sets (``tests._sfm_lines``) are true edges of the synthetic generator's rooms,
cut into short noisy pieces with clutter and far outliers, under a rotation, a scale and an offset.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from ldlmap.cli import app as map_app
from ldlmap.core.errors import InputError
from ldlmap.core.frame import (apply, decompose, invert, parse_up, pose_to_input, pose_to_map, rotation_to_z,
                               scale_warning, similarity)
from ldlmap.sfm.gravity import estimate_up, map_rotation
from ldlmap.map.mapfile import read_map
from tests._sfm_lines import rotation_with_up, sfm_like_lines, write_line3dpp_txt

from tests._hostile import error_line

runner = CliRunner()
Z = np.array([0.0, 0.0, 1.0])
AXES = {"x": [1, 0, 0], "-x": [-1, 0, 0], "y": [0, 1, 0], "-y": [0, -1, 0], "z": [0, 0, 1], "-z": [0, 0, -1],
        "random": Rotation.random(random_state=3).apply(Z)}


def angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.fixture(scope="module")
def room_edges() -> np.ndarray:
    """True edges of a synthetic room (doors, windows, furniture), metric and z-up."""
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.presets import random_spec

    return mesh_edges(build_scene(random_spec("demo", 2, 1)))


def sfm_file(tmp_path: Path, edges: np.ndarray, up: str, units_per_metre: float, name: str = "l3d.txt",
             seed: int = 0) -> tuple[Path, np.ndarray, np.ndarray]:
    """An SfM-like Line3D++ file; returns it, its segments and the rotation map -> input."""
    R0 = rotation_with_up(AXES[up], 30.0)
    segs = sfm_like_lines(edges, np.random.default_rng(seed), R0, units_per_metre, (5.0, -2.0, 1.0))
    return write_line3dpp_txt(tmp_path / name, segs), segs, R0


# ------------------------------------------------------------------------------------- frame math


def test_similarity_and_pose_conversions():
    rng = np.random.default_rng(0)
    A = similarity(0.37, Rotation.random(random_state=1).as_matrix(), [2.0, -1.0, 0.5])
    s, R, t = decompose(A)
    assert s == pytest.approx(0.37) and np.allclose(R @ R.T, np.eye(3))
    X = rng.normal(size=(5, 3))
    np.testing.assert_allclose(apply(invert(A), apply(A, X)), X, atol=1e-12)
    # A camera sees every point in the same direction in both frames.
    R_in, t_in = Rotation.random(random_state=2).as_matrix(), rng.normal(size=3)
    R_map, t_map = pose_to_map(R_in, t_in, A)
    bear = lambda Rc, tc, P: (P - tc) @ Rc.T / np.linalg.norm(P - tc, axis=1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(bear(R_map, t_map, apply(A, X)), bear(R_in, t_in, X), atol=1e-12)
    back = pose_to_input(R_map, t_map, A)
    np.testing.assert_allclose(back[0], R_in, atol=1e-12)
    np.testing.assert_allclose(back[1], t_in, atol=1e-12)
    for up in AXES.values():
        Rz = rotation_to_z(up)
        assert np.allclose(Rz @ Rz.T, np.eye(3)) and np.linalg.det(Rz) == pytest.approx(1.0)
        assert angle_deg(Rz @ up, Z) < 1e-6
    Rz = rotation_to_z(AXES["y"], horizontal=[1.0, 1.0, 0.0])  # its part normal to y is x
    assert angle_deg(Rz @ [0, 1, 0], Z) < 1e-6 and angle_deg(Rz @ [1, 0, 0], [1, 0, 0]) < 1e-6
    assert parse_up("auto") is None and np.array_equal(parse_up("-Y"), [0, -1, 0])
    with pytest.raises(InputError, match="--up"):
        parse_up("w")
    assert "--scale 0.001" in scale_warning(4500.0) and "--scale S" in scale_warning(0.2)
    assert scale_warning(5.0) is None


# ------------------------------------------------------------------------------------- up axis


@pytest.mark.parametrize("up", ["x", "-x", "y", "-y", "random"])
def test_up_axis_from_lines_alone(room_edges, up):
    segs = sfm_like_lines(room_edges, np.random.default_rng(1), rotation_with_up(AXES[up], 30.0), 0.37, (5, -2, 1))
    est, P = estimate_up(segs)
    assert est.source == "lines" and not est.weak, est.note
    R = map_rotation(est, P)
    assert angle_deg(R @ AXES[up], Z) < 2.0
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)


@pytest.mark.parametrize("up", ["z", "-z"])
def test_lines_never_turn_a_z_axis_input(room_edges, up):
    """Scans and datasets are z-up: lines, which only guess the sign, keep a frame whose vertical
    is the z axis (an upside-down input needs --up or cameras)."""
    segs = sfm_like_lines(room_edges, np.random.default_rng(1), rotation_with_up(AXES[up], 30.0), 1.0)
    est, P = estimate_up(segs)
    assert angle_deg(np.abs(est.up), Z) < 2.0
    assert np.array_equal(map_rotation(est, P), np.eye(3))


def upright_camera_downs(R0: np.ndarray, n: int, rng: np.random.Generator, tilt_deg: float = 15.0) -> np.ndarray:
    """Image-down axes, in the input frame, of ``n`` photos pitched / rolled up to ``tilt_deg``."""
    tilt = Rotation.from_rotvec(np.column_stack([rng.uniform(-1, 1, (n, 2)), np.zeros(n)])
                                * np.radians(tilt_deg)).apply(-Z)
    return tilt @ R0.T


@pytest.mark.parametrize("up", list(AXES))
def test_up_axis_from_cameras(room_edges, up):
    rng = np.random.default_rng(5)
    R0 = rotation_with_up(AXES[up], 30.0)
    segs = sfm_like_lines(room_edges, rng, R0, 0.37, (5, -2, 1))
    est, P = estimate_up(segs, camera_down=upright_camera_downs(R0, 12, rng))
    assert est.source == "cameras" and est.snapped_deg is not None and est.camera_agreement > 0.9
    assert angle_deg(map_rotation(est, P) @ AXES[up], Z) < 2.0
    # Cameras in every orientation say nothing: the lines decide.
    est, _ = estimate_up(segs, camera_down=Rotation.random(12, random_state=4).apply(Z))
    assert est.source == "lines" and "disagree" in est.note


# ------------------------------------------------------------------------------------ the build


def test_sfm_line_file_build_frame_scale_filter(tmp_path, room_edges):
    """One SfM-like file in millimetres, up = -y: refused in one line naming --scale 0.001
    (millimetres are detected before any work), then --scale and --up give a
    metric z-up map whose stored transform maps the input onto it; the length filter keeps a
    sensible number of lines and the query keeps 10 %, not the map's kept fraction."""
    from ldlloc.lines2d import query_keep_ratio
    from ldlmap.lines3d import robust_bounds

    path, segs, R0 = sfm_file(tmp_path, room_edges, "-y", 1000.0)
    res = runner.invoke(map_app, ["build", str(path), "-o", str(tmp_path / "mm.h5"), "--trans-spacing", "2000"])
    line = error_line(res)
    assert "millimetres" in line and "--scale 0.001" in line and not (tmp_path / "mm.h5").exists()
    res = runner.invoke(map_app, ["build", str(path), "-o", str(tmp_path / "m.h5"), "--scale", "0.001",
                                  "--up", "-y", "--trans-spacing", "2.0"])
    assert res.exit_code == 0, res.output
    assert "warning" not in res.output and "--up -y" in res.output
    m = read_map(tmp_path / "m.h5")
    s, R, _ = decompose(m.input_to_map)
    assert s == pytest.approx(0.001) and angle_deg(R @ [0, -1, 0], Z) < 2.0
    np.testing.assert_allclose(apply(m.input_to_map, segs), m.lines_raw, atol=1e-4)  # float32 storage
    extent = np.subtract(*robust_bounds(m.lines_raw.reshape(-1, 3))[::-1])
    assert np.all((extent > 2.0) & (extent < 7.0))  # a room, in metres (far outliers left out)
    P = m.principal_directions
    np.testing.assert_allclose(P @ P.T, np.eye(3), atol=1e-9)
    assert min(angle_deg(np.abs(p), Z) for p in P) < 2.0
    # Length filter: the paper's threshold keeps a handful of these short pieces; the floor keeps the
    # longest that hold 60 % of the line length (a third of them), within [100, 3000].
    length = np.linalg.norm(m.lines_raw[:, 1] - m.lines_raw[:, 0], axis=1)
    assert np.sum(length >= m.config["length_filter"]["lambda_threshold"]) < 50
    kept = np.linalg.norm(m.lines[:, 1] - m.lines[:, 0], axis=1)
    assert m.config["length_filter"]["rule"] == "floor" and 100 <= len(m.lines) <= 3000
    assert 0.6 <= kept.sum() / length.sum() < 0.6 + 2 * kept.min() / length.sum()
    assert m.kept_ratio == pytest.approx(len(m.lines) / len(segs)) and m.kept_ratio < 0.5
    assert 0.1 <= query_keep_ratio(m.kept_ratio) <= 0.2 and query_keep_ratio(0.008) == 0.1
    # Auto: the lines find the same up axis; a tiny frame gets the other unit warning.
    res = runner.invoke(map_app, ["build", str(path), "-o", str(tmp_path / "auto.h5"), "--scale", "0.001",
                                  "--trans-spacing", "2.0"])
    assert res.exit_code == 0 and "from the lines" in res.output, res.output
    assert angle_deg(decompose(read_map(tmp_path / "auto.h5").input_to_map)[1] @ [0, -1, 0], Z) < 2.0
    res = runner.invoke(map_app, ["build", str(path), "-o", str(tmp_path / "tiny.h5"), "--scale", "0.00005",
                                  "--trans-spacing", "0.1"])
    assert res.exit_code == 0 and "unscaled SfM frame" in res.output, res.output
    for opts, what in ((["--up", "w"], "--up"), (["--scale", "-2"], "--scale"), (["--scale", "0"], "--scale")):
        res = runner.invoke(map_app, ["build", str(path), "-o", str(tmp_path / "bad.h5"), *opts])
        lines = [x for x in res.output.splitlines() if x.strip()]
        assert res.exit_code == 1 and len(lines) == 1 and lines[0].startswith("error:") and what in lines[0]
    assert not (tmp_path / "bad.h5").exists()


def test_non_orthogonal_directions_atlanta_frame_or_warn(tmp_path):
    """Voted directions 33 deg apart, the lines running in exactly those directions with no
    perpendicular wall: the map keeps them as an Atlanta frame, which the map file
    accepts; forced onto the Manhattan frame (``atlanta_frame`` off) it warns how far off they are."""
    from ldlmap.map.build import BuildParams, build_lines_map

    rng = np.random.default_rng(2)
    dirs = np.array([[0, 0, 1.0], [1.0, 0, 0], [np.cos(np.radians(33)), np.sin(np.radians(33)), 0]])
    segs = []
    for d, n in zip(dirs, (60, 60, 45)):
        a = rng.uniform([0, 0, 0], [6, 5, 3], (n, 3))
        segs.append(np.stack([a, a + rng.uniform(0.8, 2.5, (n, 1)) * d], 1))
    write_line3dpp_txt(tmp_path / "wing.txt", np.concatenate(segs))
    res = runner.invoke(map_app, ["build", str(tmp_path / "wing.txt"), "-o", str(tmp_path / "w.h5"),
                                  "--trans-spacing", "1.0"])
    assert res.exit_code == 0, res.output
    assert "Atlanta frame" in res.output and "off the nearest orthogonal" not in res.output
    m = read_map(tmp_path / "w.h5")
    assert m.config["principal_frame"] == "atlanta" and max(m.config["principal_deviation_deg"]) < 1.0
    assert np.all(np.abs(dirs @ m.principal_directions.T).max(axis=1) > np.cos(np.radians(1.0)))
    report = build_lines_map(np.concatenate(segs), tmp_path / "m.h5",
                             BuildParams().replaced(features="none", trans_spacing=1.0, atlanta_frame=False))
    assert any("off the nearest orthogonal" in w for w in report.warnings)
    m = read_map(tmp_path / "m.h5")
    assert m.config["principal_frame"] == "manhattan"
    np.testing.assert_allclose(m.principal_directions @ m.principal_directions.T, np.eye(3), atol=1e-9)
    assert max(m.config["principal_deviation_deg"]) == pytest.approx(57.0, abs=2.0)


# ---------------------------------------------------------------------------- poses in the input frame


def test_run_errors_in_map_frame_and_pose_in_input_frame():
    """`ldlloc run`: dataset ground truth (input frame) is compared in the map frame (metres)."""
    from ldlloc.pipeline import Localization
    from ldlloc.batch.run import result_from_localization

    A = similarity(2.5, rotation_with_up(AXES["-y"], 20.0).T, [1.0, 2.0, -3.0])
    R_in, t_in = Rotation.random(random_state=7).as_matrix(), np.array([0.3, -0.2, 0.9])
    R_map, t_map = pose_to_map(R_in, t_in, A)
    loc = Localization(R_map, t_map + [0.05, 0, 0], R_map, t_map, R_map[None], t_map[None], {"total": 0.1},
                       num_rotations=1, num_lines=10, refined=True, input_to_map=A)
    q = SimpleNamespace(image="a.jpg", scene="s", split="robot", name="a", rot_cam_from_world=R_in, center=t_in)
    r = result_from_localization(q, loc)
    assert r.t_error_m == pytest.approx(0.05) and r.r_error_deg == pytest.approx(0.0, abs=1e-4)
    np.testing.assert_allclose(r.input_frame["t"], apply(invert(A), t_map + [0.05, 0, 0]), atol=1e-9)
    np.testing.assert_allclose(r.input_frame["R"], R_in, atol=1e-9)
    loc.input_to_map = None
    assert result_from_localization(q, loc).input_frame is None


def test_localized_pose_given_back_in_the_input_frame(demo_dataset, tmp_path):
    """A synthetic room's true lines in an SfM frame (up = -y, 0.37 units per metre, offset): the
    map is built with --scale, localization runs in the map frame, and the pose comes back in the
    input frame matching the truth there."""
    from ldlloc.cli import app as loc_app
    from ldlloc.pipeline import LocalizeParams, Localizer, load_image
    from ldlmap.datasets import read_pose_txt
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.io.linefiles import read_lines

    k, offset = 0.37, np.array([5.0, -2.0, 1.0])
    R0 = rotation_with_up(AXES["-y"], 30.0)
    edges = read_lines(demo_dataset / "gt_lines" / "synthroom_1.txt")
    write_line3dpp_txt(tmp_path / "room.txt", k * edges @ R0.T + offset)
    res = runner.invoke(map_app, ["build", str(tmp_path / "room.txt"), "-o", str(tmp_path / "room.h5"),
                                  "--scale", str(1 / k), "--trans-spacing", "0.4"])
    assert res.exit_code == 0, res.output
    m = read_map(tmp_path / "room.h5")
    A_true = similarity(1 / k, R0.T, -R0.T @ offset / k)  # input -> the generator's frame
    s, R, _ = decompose(m.input_to_map)
    assert s == pytest.approx(1 / k) and angle_deg(R @ R0 @ Z, Z) < 1.0
    images = sorted((demo_dataset / "robot_pano").rglob("*.jpg"))[:3]
    loc = Localizer(m, LocalizeParams())
    good = 0
    for img in images:
        R_true, t_true = read_pose_txt(Path(str(img).replace("_pano", "_pose")).with_suffix(".txt"))
        R_in_true, t_in_true = pose_to_input(R_true, t_true, A_true)
        out = loc.localize(load_image(img))
        R_in, t_in = out.input_frame_pose()
        good += bool(np.linalg.norm(t_in - t_in_true) / k < 0.1 and rotation_error_deg(R_in, R_in_true) < 5.0)
    assert good >= 2, good
    res = runner.invoke(loc_app, ["localize", str(tmp_path / "room.h5"), str(images[0]), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    R_in, t_in = pose_to_input(np.array(out["R"]), np.array(out["t"]), m.input_to_map)
    np.testing.assert_allclose(out["input_frame"]["t"], t_in, atol=1e-5)
    np.testing.assert_allclose(out["input_frame"]["R"], R_in, atol=1e-6)


def test_colmap_cameras_set_the_up_axis(thin_scans, tmp_path):
    """A COLMAP workspace in a y-down SfM frame (a scan turned so that up = -y, upright panoramas):
    the cameras' down axes make the map z-up, the camera centres stay candidate translations."""
    import pycolmap

    from ldlmap.core.geometry import colmap_cam_from_world
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.pointcloud import read_point_cloud, write_point_cloud

    rng = np.random.default_rng(0)
    R0 = rotation_with_up(AXES["-y"], 30.0)  # generator frame -> input frame
    cloud = read_point_cloud(thin_scans / "pcd" / "synthroom_1.ply")
    model = tmp_path / "ws" / "sparse" / "0"
    model.mkdir(parents=True)
    write_point_cloud(tmp_path / "ws" / "sparse" / "fused.ply", PointCloud(cloud.points @ R0.T, cloud.colors))
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_id(1, pycolmap.CameraModelId.EQUIRECTANGULAR, 0.0, 64, 32)
    cam.params = [64, 32]
    rec.add_camera_with_trivial_rig(cam)
    centers = []
    for i in range(6):
        yaw = Rotation.from_euler("xyz", [*rng.uniform(-5, 5, 2), rng.uniform(0, 360)], degrees=True).as_matrix()
        t = np.array([rng.uniform(1, 3), rng.uniform(1, 3), 1.4])
        R_c, t_c = colmap_cam_from_world(yaw @ R0.T, R0 @ t)  # the camera in the input frame
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"p{i}.jpg", camera_id=1, image_id=i + 1),
                                         pycolmap.Rigid3d(pycolmap.Rotation3d(R_c), t_c))
        centers.append(R0 @ t)
    rec.add_point3D(cloud.points[0] @ R0.T, pycolmap.Track(), cloud.colors[0])
    rec.write_binary(str(model))
    res = runner.invoke(map_app, ["build", str(tmp_path / "ws"), "-o", str(tmp_path / "sfm.h5"),
                                  "--features", "none", "--num-trans", "60"])
    assert res.exit_code == 0, res.output
    assert "from the cameras" in res.output, res.output
    m = read_map(tmp_path / "sfm.h5")
    assert m.config["frame"]["up_source"] == "cameras"
    assert angle_deg(decompose(m.input_to_map)[1] @ R0 @ Z, Z) < 1.0
    mapped = apply(m.input_to_map, np.array(centers))
    assert all(np.linalg.norm(m.translations - c, axis=1).min() < 1e-4 for c in mapped)
    assert min(angle_deg(np.abs(p), Z) for p in m.principal_directions) < 1.0


def test_layout_maps_stay_in_their_frame(tmp_path):
    """Room layouts are built metric and z-up: --up / --scale are refused, auto keeps the identity."""
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.map.translations import Walkable

    poly = np.array([[0, 0], [4, 0], [4, 3], [0, 3]], dtype=float)
    floor = np.column_stack([poly, np.zeros(4)])
    ceiling = floor + [0, 0, 2.5]
    lines = np.concatenate([np.stack([floor, np.roll(floor, -1, 0)], 1), np.stack([ceiling, np.roll(ceiling, -1, 0)], 1),
                            np.stack([floor, ceiling], 1)])
    walk = Walkable(polygons=(poly,), z_range=(1.4, 1.4))
    params = BuildParams().replaced(features="none", distance_fields=False)
    report = build_lines_map(lines, tmp_path / "room.h5", params, walkable=walk)
    assert read_map(report.path).config["frame"]["up_source"] == "layout" and not report.notes
    for bad in ({"up": "x"}, {"scale": 2.0}):
        with pytest.raises(InputError, match="layouts"):
            build_lines_map(lines, tmp_path / "bad.h5", BuildParams().replaced(features="none", **bad), walkable=walk)
    assert not (tmp_path / "bad.h5").exists()
