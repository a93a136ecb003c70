"""The generated dataset: layout, ground-truth poses (on the written files), scan, determinism."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from ldlmap.synth.generate import generate_dataset
from ldlmap.synth.render import Renderer, apply_illumination
from ldlmap.synth.scene import build_scene
from ldlmap.synth.spec import load_spec
from tests.conftest import TINY_SEED
from tests.test_synth_render import small_rotation, vertex_pixel_offsets

pytestmark = pytest.mark.xdist_group("synth_generate")  # one worker makes the ``demo`` fixture
WIDTH = 512
SPLITS = ("robot", "handheld", "extreme", "change_robot", "change_handheld", "extreme_intensity",
          "extreme_gamma", "extreme_white_balance")


@pytest.fixture(scope="session")
def demo(tmp_path_factory) -> Path:
    """The demo preset at reduced size: 2 scenes, 2 panoramas per split, 512 x 256."""
    out = tmp_path_factory.mktemp("synth") / "demo"
    summary = generate_dataset(out, preset="demo", seed=1, width=WIDTH, per_split=2, progress=False)
    assert summary.scenes == ["synthroom_1", "synthroom_2"]
    return out


def file_hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_layout_and_summary(demo):
    meta = json.loads((demo / "dataset.json").read_text())
    assert meta["seed"] == 1 and meta["layout"] == "omniscenes"
    assert [s["name"] for s in meta["scenes"]] == ["synthroom_1", "synthroom_2"]
    assert {k: v["images"] for k, v in meta["splits"].items()} == {s: 4 for s in SPLITS}
    for scene in ("synthroom_1", "synthroom_2"):
        for rel in (f"pcd/{scene}.txt", f"pcd/{scene}.ply", f"mesh/{scene}.obj", f"gt_lines/{scene}.obj",
                    f"gt_lines/{scene}.txt", f"specs/{scene}.toml", f"specs/{scene}_scene_2.toml"):
            assert (demo / rel).stat().st_size > 0, rel
        for split in SPLITS:
            state = "scene_2" if split.startswith("change_") else "scene_1"
            folder = f"{split}_{scene}_{state}"
            jpgs = sorted((demo / f"{split}_pano" / folder).glob("*.jpg"))
            poses = sorted((demo / f"{split}_pose" / folder).glob("*.txt"))
            assert [p.stem for p in jpgs] == [p.stem for p in poses] == ["0000", "0001"]
            img = cv2.imread(str(jpgs[0]))
            assert img.shape == (WIDTH // 2, WIDTH, 3)
    assert not list(demo.parent.glob(".demo.*"))  # no temporary folder left


def test_dataset_reader_returns_the_written_poses(demo):
    from ldlmap.datasets import OmniScenes

    ds = OmniScenes(demo)
    queries = ds.queries()
    assert len(queries) == 8 * 4
    for q in queries:
        M = np.loadtxt(str(q.image).replace("_pano", "_pose").replace(".jpg", ".txt"))
        np.testing.assert_array_equal(q.rot_cam_from_world, M[:, :3])
        np.testing.assert_array_equal(q.center, M[:, 3])
    assert ds.point_cloud("synthroom_1").parent == demo / "pcd"


def _scene_mesh(demo: Path, scene: str, changed: bool):
    return build_scene(load_spec(demo / "specs" / (f"{scene}_scene_2.toml" if changed else f"{scene}.toml")))


def test_ground_truth_poses_on_the_written_files(demo):
    """For every split: visible mesh vertices, projected with the pose read back from its .txt,
    land within one pixel of the pixel that sees them, and the .jpg is the render at that pose."""
    renderers = {}
    for scene in ("synthroom_1", "synthroom_2"):
        for changed in (False, True):
            renderers[scene, changed] = Renderer(_scene_mesh(demo, scene, changed))
    renders = {}  # the illumination splits reuse the extreme split's poses: render each pose once

    def render(rend, R, t, supersample):
        key = (id(rend), R.tobytes(), t.tobytes(), supersample)
        if key not in renders:
            renders[key] = rend.render(R, t, WIDTH, WIDTH // 2, supersample=supersample)
        return renders[key]

    checked_vertices = 0
    for split in SPLITS:
        for pose_file in sorted((demo / f"{split}_pose").rglob("*.txt")):
            scene = pose_file.parent.name.removeprefix(f"{split}_").rsplit("_scene_", 1)[0]
            rend = renderers[scene, split.startswith("change_")]
            M = np.loadtxt(pose_file)
            R, t = M[:, :3], M[:, 3]
            assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0
            pano = render(rend, R, t, 2)
            off = vertex_pixel_offsets(rend.mesh.vertices, R, t, pano.depth, pano.tri_id, rend)
            assert len(off) >= 8, (pose_file, len(off))
            assert np.max(off) <= 1.0, (pose_file, np.max(off))
            checked_vertices += len(off)
            # The image content is the render at the stored pose (up to JPEG, noise and blur).
            jpg = cv2.imread(str(pose_file).replace("_pose", "_pano").replace(".txt", ".jpg"))[..., ::-1]
            kind = split.removeprefix("extreme_") if split.startswith("extreme_") else None
            ref = apply_illumination(pano.rgb, kind) if kind else pano.rgb
            err = np.mean(np.abs(jpg.astype(float) - ref))
            R_off = R @ small_rotation(np.radians(1.0))
            off_pano = render(rend, R_off, t, 1)
            off_ref = apply_illumination(off_pano.rgb, kind) if kind else off_pano.rgb
            err_off = np.mean(np.abs(jpg.astype(float) - off_ref))
            limit = 9.0 if split.startswith("extreme") else 3.0
            assert err < limit and err < 0.75 * err_off, (pose_file, err, err_off)
    assert checked_vertices > 200


def test_extreme_split_rotations_are_not_upright_and_robot_ones_are(demo):
    tilts = {}
    for split in ("robot", "extreme"):
        Rs = [np.loadtxt(p)[:, :3] for p in sorted((demo / f"{split}_pose").rglob("*.txt"))]
        tilts[split] = np.degrees(np.arccos(np.clip([R[2, 2] for R in Rs], -1, 1)))
    assert np.max(tilts["robot"]) <= 2.0 + 1e-9
    assert np.max(tilts["extreme"]) > 20.0


def test_scan_lies_on_the_unchanged_scene(demo):
    from ldlmap.synth.scan import ScanParams

    rend = Renderer(_scene_mesh(demo, "synthroom_1", False))
    txt = np.loadtxt(demo / "pcd" / "synthroom_1.txt")
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(demo / "pcd" / "synthroom_1.ply"))
    np.testing.assert_allclose(np.asarray(pc.points), txt[:, :3], atol=1e-6)
    np.testing.assert_array_equal(np.rint(np.asarray(pc.colors) * 255), txt[:, 3:])
    d = rend.distance(txt[:, :3])
    noise = ScanParams().noise_std
    assert np.median(d) < 1.5 * noise and np.quantile(d, 0.999) < 5 * noise
    assert len(txt) > 50_000


def test_illumination_flag_changes_nothing_else(tiny_synth, tmp_path):
    """Without illumination, the library call writes the bytes `ldlmap synth` wrote with the same
    seed and sizes (``tiny_synth``) but for the missing illumination splits. (Same seed, same
    bytes: tests/test_cli_synth.py.)"""
    generate_dataset(tmp_path / "c", preset="demo", seed=TINY_SEED, width=64, per_split=1, progress=False,
                     illumination=False)
    a, c = file_hashes(tiny_synth), file_hashes(tmp_path / "c")
    variants = ("extreme_intensity", "extreme_gamma", "extreme_white_balance")
    assert not any(k.startswith(variants) for k in c) and any(k.startswith(variants) for k in a)
    assert {k: v for k, v in a.items() if not k.startswith(variants) and k != "dataset.json"} == \
           {k: v for k, v in c.items() if k != "dataset.json"}


def test_failure_midway_leaves_nothing(tmp_path, monkeypatch):
    import ldlmap.synth.scan as scan_mod
    from ldlmap.core.errors import InputError

    def broken(*args, **kwargs):
        raise InputError("scanner broke")

    monkeypatch.setattr(scan_mod, "sample_scan", broken)
    with pytest.raises(InputError, match="scanner broke"):
        generate_dataset(tmp_path / "out", preset="demo", seed=0, width=64, per_split=1, progress=False)
    assert list(tmp_path.iterdir()) == []
