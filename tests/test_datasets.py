"""Dataset readers on tiny trees in the exact OmniScenes / Stanford 2D-3D-S layouts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ldlmap.datasets import (
    DEFAULT_ROOTS,
    OMNISCENES_SPLITS,
    STANFORD_AREAS,
    Dataset,
    OmniScenes,
    Stanford2D3DS,
    detect_kind,
    load_manifest,
    open_dataset,
    read_pose_txt,
    stanford_rotation,
    write_pose_txt,
)
from ldlmap.core.errors import InputError
from ldlmap.core.geometry import pixel_from_bearing, project_to_pixels


def _random_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    return Rotation.random(random_state=rng).as_matrix(), rng.uniform(-3, 3, 3)


def _touch(path: Path, data: bytes = b"\xff\xd8fake") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def _omni_tree(root: Path, rng: np.random.Generator) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """OmniScenes tree as released: note the change splits' folders use the capture prefix."""
    folders = {
        "extreme": ["extreme_room_1_scene_2", "extreme_pyebaekRoom_1_scene_3"],
        "robot": ["robot_room_1_scene_1"],
        "change_handheld": ["handheld_pyebaekRoom_1_scene_2"],
        "change_robot": ["change_robot_room_1_scene_4"],  # synthetic-style prefix
        "extreme_gamma": ["extreme_gamma_room_1_scene_2"],
    }
    poses = {}
    for split, names in folders.items():
        for folder in names:
            for stem, ext in (("00012", ".jpg"), ("00002", ".jpg"), ("pano_10", ".png")):
                img = root / f"{split}_pano" / folder / f"{stem}{ext}"
                _touch(img)
                R, t = _random_pose(rng)
                pose = root / f"{split}_pose" / folder / f"{stem}.txt"
                pose.parent.mkdir(parents=True, exist_ok=True)
                write_pose_txt(pose, R, t)
                poses[str(img)] = (R, t)
    for scene in ("room_1", "pyebaekRoom_1", "room_2"):
        _touch(root / "pcd" / f"{scene}.txt", b"0 0 0 1 2 3\n")
    _touch(root / "pcd" / "room_1.ply", b"ply")
    _touch(root / "pcd_line" / "room_1lines.txt", b"0 0 0 0\n")
    return poses


def test_omniscenes_reader_returns_written_poses_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    poses = _omni_tree(tmp_path, rng)
    ds = OmniScenes(tmp_path)
    assert isinstance(ds, Dataset)
    assert ds.splits() == ["robot", "extreme", "change_robot", "change_handheld", "extreme_gamma"]
    assert ds.scenes() == ["pyebaekRoom_1", "room_1", "room_2"]
    qs = ds.queries()
    assert len(qs) == len(poses) == 18
    for q in qs:
        R, t = poses[str(q.image)]
        assert np.array_equal(q.rot_cam_from_world, R) and np.array_equal(q.center, t)
    # Parsing: the released change split uses the capture type as folder prefix.
    ch = ds.queries("change_handheld")
    assert {q.scene for q in ch} == {"pyebaekRoom_1"} and {q.scene_state for q in ch} == {"scene_2"}
    assert [q.name for q in ch] == ["change_handheld/pyebaekRoom_1_scene_2/00002",
                                    "change_handheld/pyebaekRoom_1_scene_2/00012",
                                    "change_handheld/pyebaekRoom_1_scene_2/pano_10"]
    assert {q.scene for q in ds.queries("change_robot")} == {"room_1"}
    assert {q.scene for q in ds.queries("extreme_gamma")} == {"room_1"}
    # Filters and deterministic order.
    ex = ds.queries(["extreme"], scene="room_1")
    assert [q.name for q in ex] == [f"extreme/room_1_scene_2/{s}" for s in ("00002", "00012", "pano_10")]
    assert all(q.split == "extreme" for q in ex)
    assert [q.name for q in ds.queries()] == [q.name for q in OmniScenes(tmp_path).queries()]
    assert ds.queries("robot", scene="room_2") == []
    # Files: .ply preferred over .txt when both exist; line file found.
    assert ds.point_cloud("room_1").name == "room_1.ply"
    assert ds.point_cloud("room_2").name == "room_2.txt"
    assert ds.line_file("room_1").name == "room_1lines.txt"
    assert ds.line_file("room_2") is None
    assert ds.mesh_file("room_1") is None and ds.gt_line_file("room_1") is None
    _touch(tmp_path / "mesh" / "room_1.obj", b"v 0 0 0\n")
    _touch(tmp_path / "gt_lines" / "room_1.obj", b"v 0 0 0\n")
    assert ds.mesh_file("room_1").name == "room_1.obj" and ds.gt_line_file("room_1").parent.name == "gt_lines"


def test_omniscenes_bad_inputs(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        OmniScenes(tmp_path / "missing")
    with pytest.raises(InputError, match="not an OmniScenes root"):
        OmniScenes(tmp_path)
    _omni_tree(tmp_path, np.random.default_rng(1))
    ds = OmniScenes(tmp_path)
    with pytest.raises(InputError, match="unknown OmniScenes split nope; available: robot"):
        ds.queries("nope")
    with pytest.raises(InputError, match="unknown OmniScenes scene"):
        ds.queries(scene="kitchen_9")
    with pytest.raises(InputError, match="no point cloud for scene kitchen_9"):
        ds.point_cloud("kitchen_9")
    pose = tmp_path / "robot_pose" / "robot_room_1_scene_1" / "00002.txt"
    for text, msg in [("1 0 0 0\n0 1 0 0\n", "expected a 3x4"), ("1 0 0 a\n0 1 0 0\n0 0 1 0\n", "malformed"),
                      ("2 0 0 0\n0 1 0 0\n0 0 1 0\n", "not a proper rotation"),
                      ("-1 0 0 0\n0 1 0 0\n0 0 1 0\n", "not a proper rotation"),
                      ("1 0 0 nan\n0 1 0 0\n0 0 1 0\n", "non-finite")]:
        pose.write_text(text)
        with pytest.raises(InputError, match=msg) as info:
            ds.queries("robot")
        assert str(pose) in str(info.value) and "\n" not in str(info.value)
    pose.unlink()
    with pytest.raises(InputError, match="no pose file for query"):
        ds.queries("robot")
    (tmp_path / "robot_pano" / "badfolder").mkdir()
    with pytest.raises(InputError, match="unrecognised OmniScenes scene folder"):
        ds.queries("robot")


def test_pose_txt_accepts_4x4_and_roundtrips(tmp_path: Path) -> None:
    R, t = _random_pose(np.random.default_rng(2))
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, t
    np.savetxt(tmp_path / "p.txt", M)
    R2, t2 = read_pose_txt(tmp_path / "p.txt")
    assert np.allclose(R2, R, atol=1e-15) and np.allclose(t2, t, atol=1e-15)


# -------------------------------------------------------------------------------- Stanford


def _blender_upright(yaw: float) -> np.ndarray:
    """Euler 'xyz' angles of an upright Blender camera turned by ``yaw`` about world z."""
    return np.array([np.pi / 2, 0.0, yaw])


def test_stanford_rotation_against_blender_camera_model() -> None:
    """Independent check: a Blender camera (looks along its local -Z, +Y up, +X right) with
    rotation M = from_euler('xyz', a) sees world direction -M[:, 2] at the image centre, M[:, 1]
    at the top row and M[:, 0] a quarter turn right of centre."""
    W, H = 2048, 1024
    rng = np.random.default_rng(3)
    angles = [_blender_upright(y) for y in (0.0, 0.7, -2.5)] + [rng.uniform(-np.pi, np.pi, 3) for _ in range(5)]
    for a in angles:
        R = stanford_rotation(a)
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
        M = Rotation.from_euler("xyz", a).as_matrix()
        t = rng.uniform(-5, 5, 3)
        forward, up, right = -M[:, 2], M[:, 1], M[:, 0]
        assert np.allclose(project_to_pixels(t + 2.0 * forward, R, t, W, H), [W / 2, H / 2])
        assert np.isclose(project_to_pixels(t + 1.5 * up, R, t, W, H)[1], 0.0, atol=1e-6)
        assert np.allclose(project_to_pixels(t + 3.0 * right, R, t, W, H), [3 * W / 4, H / 2])
    # Upright cameras keep world z as camera up; yaw 0 looks along world +y (Blender: -Z -> +y).
    R0 = stanford_rotation(_blender_upright(0.0))
    assert np.allclose(R0[2], [0, 0, 1], atol=1e-12)
    assert np.allclose(pixel_from_bearing(R0 @ np.array([0.0, 1.0, 0.0]), W, H), [W / 2, H / 2])


def _stanford_tree(root: Path, rng: np.random.Generator) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    cams = {"area_3": [("0a70cd8d4f2b48239aaa5db59719158a", "office_1"), ("1b2c3d4e5f60718293a4b5c6d7e8f901", "office_1"),
                       ("00d10d86db1e435081a837ced388375f", "conferenceRoom_2")],
            "area_5a": [("9f3e2d1c0b0a09080706050403020100", "hallway_12")],
            "area_1": [("7e8f9a0b1c2d3e4f5a6b7c8d9e0f1a2b", "WC_1")]}
    truth = {}
    for area, items in cams.items():
        for cam, room in items:
            img = root / "pano" / area / f"camera_{cam}_{room}_frame_equirectangular_domain_rgb.png"
            _touch(img, b"\x89PNG")
            angles = rng.uniform(-np.pi, np.pi, 3)
            loc = rng.uniform(-10, 10, 3)
            pose = root / "pose" / area / f"camera_{cam}_{room}_frame_equirectangular_domain_pose.json"
            pose.parent.mkdir(parents=True, exist_ok=True)
            pose.write_text(json.dumps({"camera_location": loc.tolist(), "final_camera_rotation": angles.tolist(),
                                        "camera_uuid": cam, "room": room, "frame_num": 0}))
            # Expected R written out step by step from the dataset's recipe.
            M = Rotation.from_euler("xyz", angles).as_matrix()
            reordered = np.stack([M[:, 2], M[:, 0], M[:, 1]], axis=1)
            truth[str(img)] = (np.diag([-1.0, -1.0, 1.0]) @ np.linalg.inv(reordered), loc)
            _touch(root / "pcd" / area / f"{room}.txt", b"0 0 0 1 2 3\n")
    _touch(root / "pcd_line" / "area_3" / "office_1lines.txt", b"0 0 0 0\n")
    return truth


def test_stanford_reader(tmp_path: Path) -> None:
    truth = _stanford_tree(tmp_path, np.random.default_rng(4))
    ds = Stanford2D3DS(tmp_path)
    assert isinstance(ds, Dataset)
    assert ds.splits() == ["area_1", "area_3", "area_5a"]
    assert ds.scenes() == ["area_1/WC_1", "area_3/conferenceRoom_2", "area_3/office_1", "area_5a/hallway_12"]
    qs = ds.queries()
    assert len(qs) == 5 and [q.split for q in qs] == ["area_1", "area_3", "area_3", "area_3", "area_5a"]
    for q in qs:
        R, t = truth[str(q.image)]
        assert np.allclose(q.rot_cam_from_world, R, atol=1e-12) and np.array_equal(q.center, t)
        assert q.scene_state == q.split
    office = ds.queries("area_3", scene="office_1")
    assert [q.name for q in office] == ["area_3/office_1/0a70cd8d4f2b48239aaa5db59719158a",
                                        "area_3/office_1/1b2c3d4e5f60718293a4b5c6d7e8f901"]
    assert [q.name for q in ds.queries(scene="area_3/office_1")] == [q.name for q in office]
    assert ds.point_cloud("area_3/office_1") == tmp_path / "pcd" / "area_3" / "office_1.txt"
    assert ds.line_file("office_1") == tmp_path / "pcd_line" / "area_3" / "office_1lines.txt"
    assert ds.line_file("area_1/WC_1") is None


def test_stanford_alignment_file(tmp_path: Path) -> None:
    truth = _stanford_tree(tmp_path, np.random.default_rng(5))
    A = Rotation.from_euler("z", 0.3).as_matrix()
    b = np.array([1.0, -2.0, 0.5])
    write_pose_txt(tmp_path / "pose" / "area_5a" / "hallway_12.txt", A, b)
    (q,) = Stanford2D3DS(tmp_path).queries("area_5a")
    R, t = truth[str(q.image)]
    X = np.array([0.3, 4.0, 1.2])  # a point in the pose file's frame; the same point in the cloud frame:
    assert np.allclose(project_to_pixels(A @ (X - b), q.rot_cam_from_world, q.center, 64, 32),
                       project_to_pixels(X, R, t, 64, 32))


def test_stanford_bad_inputs(tmp_path: Path) -> None:
    _stanford_tree(tmp_path, np.random.default_rng(6))
    ds = Stanford2D3DS(tmp_path)
    pose = next((tmp_path / "pose" / "area_1").glob("*.json"))
    for text, msg in [("{not json", "cannot read pose JSON"), ('{"camera_location": [0, 0, 0]}', "lacks"),
                      ('{"camera_location": [0, 0], "final_camera_rotation": [0, 0, 0]}', "3 values"),
                      ('{"camera_location": [0, 0, NaN], "final_camera_rotation": [0, 0, 0]}', "non-finite")]:
        pose.write_text(text)
        with pytest.raises(InputError, match=msg):
            ds.queries("area_1")
    with pytest.raises(InputError, match="unknown Stanford area area_9"):
        ds.queries("area_9")
    with pytest.raises(InputError, match="unknown"):
        ds.point_cloud("lobby_1")
    _touch(tmp_path / "pano" / "area_1" / "random_name.png")
    with pytest.raises(InputError, match="unrecognised Stanford"):
        ds.queries("area_1")


def test_open_dataset_and_detection(tmp_path: Path) -> None:
    omni, stan = tmp_path / "omni", tmp_path / "stan"
    _omni_tree(omni, np.random.default_rng(7))
    _stanford_tree(stan, np.random.default_rng(8))
    assert detect_kind(omni) == "omniscenes" and detect_kind(stan) == "stanford"
    assert isinstance(open_dataset(omni, "omniscenes"), OmniScenes)
    assert isinstance(open_dataset(stan, None), Stanford2D3DS)
    with pytest.raises(InputError, match="unknown dataset kind"):
        open_dataset(omni, "scannet")
    with pytest.raises(InputError, match="root not found"):
        open_dataset(tmp_path / "nope", "stanford")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no recognisable dataset layout"):
        open_dataset(tmp_path / "empty", None)
    assert DEFAULT_ROOTS["omniscenes"] == Path("data/omniscenes")


def test_manifests_match_reader_constants() -> None:
    om, st = load_manifest("omniscenes"), load_manifest("stanford")
    assert tuple(om["splits"]) == OMNISCENES_SPLITS and tuple(st["splits"]) == STANFORD_AREAS
    assert om["params"]["num_translations"] == 800 and st["params"]["num_translations"] == 1700
    assert [s for s, v in om["splits"].items() if not v["change"]] == ["robot", "handheld"]
    with pytest.raises(InputError, match="unknown dataset kind"):
        load_manifest("kitti")


def test_reader_on_generated_synthetic_dataset(tiny_synth: Path) -> None:
    """The OmniScenes reader on ``ldlmap synth`` output: every panorama is a query whose pose is
    exactly the file the generator wrote, and scenes/splits match its dataset.json."""
    out = tiny_synth
    meta = json.loads((out / "dataset.json").read_text())
    ds = open_dataset(out, None)
    assert isinstance(ds, OmniScenes)
    assert set(ds.splits()) == {s for s, v in meta["splits"].items() if v["images"] > 0}
    assert ds.scenes() == sorted(s["name"] for s in meta["scenes"])
    qs = ds.queries()
    assert len(qs) == sum(v["images"] for v in meta["splits"].values()) == len(list(out.glob("*_pano/*/*.jpg")))
    for q in qs:
        M = np.loadtxt(out / f"{q.split}_pose" / q.image.parent.name / f"{q.image.stem}.txt")
        assert np.array_equal(q.rot_cam_from_world, M[:, :3]) and np.array_equal(q.center, M[:, 3])
        assert q.scene in ds.scenes() and q.scene_state == ("scene_2" if q.split.startswith("change_") else "scene_1")
    for scene in ds.scenes():
        assert ds.point_cloud(scene).suffix == ".ply" and ds.mesh_file(scene) is not None


# ------------------------------------------------------------------- maps from pcd_line/ (prepare)


def _write_3dlinedetection(path: Path, edges: np.ndarray, step: float = 0.05) -> None:
    """Rows ``x y z line_id``: points every ``step`` along each edge (ends included), as distributed."""
    rows = []
    for k, (a, b) in enumerate(edges):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        pts = a + np.linspace(0, 1, n)[:, None] * (b - a)
        rows.append(np.column_stack([pts, np.full(n, k)]))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.concatenate(rows), fmt="%.5f %.5f %.5f %d")


def _line_file_tree(root: Path) -> dict[str, np.ndarray]:
    """OmniScenes-like root: room_1 has only pcd_line/room_1lines.txt, room_2 a scan and a line file."""
    from tests._room_cloud import box_room

    edges = {}
    for seed, scene in ((1, "room_1"), (2, "room_2")):
        pts, e = box_room(seed=seed, density=300.0)
        edges[scene] = e
        _write_3dlinedetection(root / "pcd_line" / f"{scene}lines.txt", e)
        if scene == "room_2":
            rgb = np.random.default_rng(seed).integers(0, 256, (len(pts), 3))
            (root / "pcd").mkdir(parents=True, exist_ok=True)
            np.savetxt(root / "pcd" / f"{scene}.txt", np.column_stack([pts, rgb]), fmt="%.4f %.4f %.4f %d %d %d")
    R, t = _random_pose(np.random.default_rng(3))
    _touch(root / "robot_pano" / "robot_room_1_scene_1" / "0000.jpg")
    (root / "robot_pose" / "robot_room_1_scene_1").mkdir(parents=True)
    write_pose_txt(root / "robot_pose" / "robot_room_1_scene_1" / "0000.txt", R, t)
    return edges


def test_line_files_alone_make_scenes(tmp_path: Path) -> None:
    (tmp_path / "omni" / "pcd_line").mkdir(parents=True)
    (tmp_path / "omni" / "pcd_line" / "room_7lines.txt").write_text("0 0 0 1\n1 0 0 1\n")
    (tmp_path / "omni" / "pcd_line" / "hall_2_lines.obj").write_text("v 0 0 0\nv 1 0 0\nl 1 2\n")
    assert detect_kind(tmp_path / "omni") == "omniscenes"
    ds = OmniScenes(tmp_path / "omni")
    assert ds.scenes() == ["hall_2", "room_7"]
    assert ds.line_file("hall_2").name == "hall_2_lines.obj"
    with pytest.raises(InputError, match="no point cloud for scene room_7"):
        ds.point_cloud("room_7")
    _touch(tmp_path / "stan" / "pcd_line" / "area_2" / "office_3lines.txt", b"0 0 0 1\n")
    assert detect_kind(tmp_path / "stan") == "stanford"
    st = Stanford2D3DS(tmp_path / "stan")
    assert st.scenes() == ["area_2/office_3"] and st.line_file("office_3").parent.name == "area_2"


def test_prepare_with_line_files(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from ldlmap.cli import app
    from ldlmap.map.mapfile import read_map

    runner = CliRunner()
    root = tmp_path / "omni"
    edges = _line_file_tree(root)
    args = ["prepare", str(root), "--features", "none", "--num-trans", "60", "--trans-spacing", "1.0"]
    # Without --line-files the scene without a scan fails, pointing at its line file.
    res = runner.invoke(app, args)
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "no point cloud for scene room_1" in res.output and "--line-files" in res.output
    res = runner.invoke(app, args + ["--line-files"])
    assert res.exit_code == 0, res.output
    assert "1 scene(s) without a scan, lines-only map(s) from their line files (features none): room_1" in res.output
    lines_only, with_scan = read_map(root / "maps" / "room_1.h5"), read_map(root / "maps" / "room_2.h5")
    assert lines_only.lines_only and lines_only.cloud_points is None
    assert lines_only.config["features"] == "none" and lines_only.config["translations"]["method"] == "spacing"
    assert np.allclose(lines_only.lines_raw, edges["room_1"], atol=1e-4)  # the file's lines, ends as written
    assert with_scan.cloud_points is not None and len(with_scan.cloud_points) > 1000  # the scan beside the lines
    assert np.allclose(with_scan.lines_raw, edges["room_2"], atol=1e-4)
    assert with_scan.config["translations"]["method"] == "octree"
    again = runner.invoke(app, args + ["--line-files"])
    assert again.exit_code == 0 and again.output.count("up-to-date") == 2, again.output
    # A scan without a line file cannot use --line-files.
    (root / "pcd_line" / "room_2lines.txt").unlink()
    res = runner.invoke(app, args + ["--line-files", "--overwrite"])
    assert res.exit_code == 1 and "no 3D line file for scene room_2" in res.output
