"""Multi-room synthetic scenes: layout, world-frame poses, scan coverage, reader, determinism."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from ldlmap.core.polygon import points_in_polygon
from ldlmap.synth.multiroom import (MultiRoomParams, generate_multiroom, layout_offsets, merge_meshes,
                                    read_layout, room_meshes, translate_spec)
from ldlmap.synth.render import Renderer
from ldlmap.synth.scene import build_scene
from ldlmap.synth.spec import load_spec
from ldlmap.synth.presets import random_spec
from tests.test_synth_render import vertex_pixel_offsets

pytestmark = pytest.mark.xdist_group("synth_multiroom")  # one worker makes ``two_rooms``
WIDTH = 512
SEED = 1
PARAMS = MultiRoomParams(rooms=2, scan_density=1000.0)  # a light scan: ~120 k points per room
GAP = PARAMS.gap


@pytest.fixture(scope="module")
def two_rooms(tmp_path_factory) -> Path:
    """Two demo rooms in one (light) scan, one panorama per split and room, 512 x 256."""
    out = tmp_path_factory.mktemp("multiroom") / "mr"
    s = generate_multiroom(out, seed=SEED, width=WIDTH, per_split=1, progress=False, params=PARAMS)
    assert s.scenes == ["multiroom_1"] and s.width == WIDTH
    return out


def test_layout_offsets_keep_gaps_on_a_grid():
    rng = np.random.default_rng(0)
    fps = [rng.uniform(-3, 3, (2, 2)) + np.array([[0, 0], [4, 5]]) * rng.uniform(0.5, 1.5) for _ in range(7)]
    fps = [np.array([f.min(0), f.max(0)]) for f in fps]  # boxes as two corners
    off = layout_offsets(fps, gap=1.0)
    boxes = [(f.min(0) + o, f.max(0) + o) for f, o in zip(fps, off)]
    assert len({round(float(lo[1]), 4) for lo, _ in boxes}) == 3  # ceil(sqrt(7)) = 3 columns -> 3 rows
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            (lo1, hi1), (lo2, hi2) = boxes[i], boxes[j]
            sep = np.maximum(lo2 - hi1, lo1 - hi2)  # > 0 along an axis: separated along it
            assert sep.max() >= 1.0 - 1e-5, (i, j, sep)
    assert np.allclose(np.min([lo for lo, _ in boxes], axis=0), 0.0, atol=1e-5)


def test_translated_spec_builds_the_translated_room():
    spec = random_spec("demo", 3, 1)
    a, b = build_scene(spec), build_scene(translate_spec(spec, (7.25, -2.5)))
    np.testing.assert_allclose(b.vertices, a.vertices + [7.25, -2.5, 0.0], atol=1e-5)
    np.testing.assert_array_equal(b.triangles, a.triangles)


def test_merged_mesh_keeps_every_triangle_colour():
    meshes = [build_scene(random_spec("demo", 2, i)) for i in (1, 2)]
    union = merge_meshes(meshes)
    assert len(union.triangles) == sum(len(m.triangles) for m in meshes)
    assert len(union.object_boxes) == sum(len(m.object_boxes) for m in meshes)

    def centroid_colours(m, uv):
        H, W = m.atlas.shape[:2]
        c = uv.astype(np.float64).mean(1)
        rows = np.clip(np.floor((1.0 - c[:, 1]) * H).astype(int), 0, H - 1)
        cols = np.clip(np.floor(c[:, 0] * W).astype(int), 0, W - 1)
        return m.atlas[rows, cols]

    want = np.concatenate([centroid_colours(m, m.tri_uvs) for m in meshes])
    got = centroid_colours(union, union.tri_uvs)
    assert np.mean(np.all(want == got, axis=1)) > 0.99
    n0 = len(meshes[0].vertices)
    np.testing.assert_array_equal(union.triangles[len(meshes[0].triangles):], meshes[1].triangles + n0)


def test_rooms_do_not_overlap_and_layout_is_recorded(two_rooms):
    rooms = read_layout(two_rooms)
    assert [r.index for r in rooms] == [1, 2]
    fps = [np.asarray(load_spec(r.spec).footprint) for r in rooms]
    for r, fp in zip(rooms, fps):
        np.testing.assert_allclose(fp.min(0), r.bounds_min[:2])
        np.testing.assert_allclose(fp.max(0), r.bounds_max[:2])
        original = np.asarray(random_spec("demo", SEED, r.index).footprint)
        np.testing.assert_allclose(fp, original + r.offset[:2], atol=1e-6)
    (lo1, hi1), (lo2, hi2) = (rooms[0].bounds_min, rooms[0].bounds_max), (rooms[1].bounds_min, rooms[1].bounds_max)
    assert np.maximum(lo2 - hi1, lo1 - hi2)[:2].max() >= GAP - 1e-6
    meta = json.loads((two_rooms / "dataset.json").read_text())
    assert meta["preset"] == "multiroom" and meta["multiroom"]["rooms"] == 2
    assert [s["name"] for s in meta["scenes"]] == ["multiroom_1"]
    assert meta["scenes"][0]["points"] == rooms[-1].points[1]


def test_scan_is_the_union_and_covers_every_room(two_rooms):
    txt = np.loadtxt(two_rooms / "pcd" / "multiroom_1.txt")
    rooms = read_layout(two_rooms)
    assert rooms[0].points[0] == 0 and rooms[-1].points[1] == len(txt)
    for r, mesh in zip(rooms, room_meshes(two_rooms)):
        P = txt[r.points[0]:r.points[1], :3]
        assert len(P) > 30_000
        assert np.mean(np.all((P > r.bounds_min - 0.03) & (P < r.bounds_max + 0.03), axis=1)) > 0.999
        d = Renderer(mesh).distance(P[::20])
        assert np.median(d) < 0.01  # on the room's own surfaces (scan noise 5 mm)
        # Coverage: the floor and the ceiling of every 0.5 m cell inside the room have points.
        fp = mesh.footprint
        g = np.stack(np.meshgrid(np.arange(fp[:, 0].min() + 0.25, fp[:, 0].max(), 0.5),
                                 np.arange(fp[:, 1].min() + 0.25, fp[:, 1].max(), 0.5)), -1).reshape(-1, 2)
        g = g[points_in_polygon(g, fp)]
        for z in (0.0, mesh.ceiling_height):
            near = P[np.abs(P[:, 2] - z) < 0.05, :2]
            cells = {tuple(c) for c in np.floor(near / 0.5).astype(int)}
            hit = np.mean([tuple(c) in cells for c in np.floor(g / 0.5).astype(int)])
            assert hit > 0.85, (r.index, z, hit)


def test_reader_and_world_frame_poses_project_the_meshes(two_rooms):
    """One scene with both rooms' queries; each written pose projects its room's visible mesh
    vertices within one pixel of the pixels that see them, and the .jpg is the render there."""
    from ldlmap.datasets import open_dataset

    ds = open_dataset(two_rooms, "omniscenes")
    assert ds.scenes() == ["multiroom_1"]
    assert ds.point_cloud("multiroom_1").parent == two_rooms / "pcd"
    assert ds.mesh_file("multiroom_1").name == "multiroom_1.obj"
    rooms = read_layout(two_rooms)
    renderers = {(r.index, ch): Renderer(m) for ch in (False, True)
                 for r, m in zip(rooms, room_meshes(two_rooms, changed=ch))}
    queries = ds.queries()
    assert len(queries) == 8 * 2
    renders = {}  # the illumination splits reuse the extreme split's poses: render each pose once
    checked = 0
    for q in queries:
        inside = [r for r in rooms if r.contains(q.center)[0]]
        assert len(inside) == 1, q.image
        room = inside[0]
        assert q.image.stem in room.queries[q.split]
        rend = renderers[room.index, q.split.startswith("change_")]
        key = (room.index, q.split.startswith("change_"), q.rot_cam_from_world.tobytes(), q.center.tobytes())
        if key not in renders:
            renders[key] = rend.render(q.rot_cam_from_world, q.center, WIDTH, WIDTH // 2, supersample=2)
        pano = renders[key]
        off = vertex_pixel_offsets(rend.mesh.vertices, q.rot_cam_from_world, q.center, pano.depth, pano.tri_id, rend)
        assert len(off) >= 8 and np.max(off) <= 1.0, (q.image, len(off), np.max(off) if len(off) else None)
        checked += len(off)
        if q.split in ("robot", "handheld", "change_robot"):  # no blur, no illumination change
            jpg = cv2.imread(str(q.image))[..., ::-1].astype(float)
            assert np.mean(np.abs(jpg - pano.rgb)) < 3.0, q.image
    assert checked > 150
    # The union OBJ holds both rooms' vertices.
    n_v = sum(1 for line in (two_rooms / "mesh" / "multiroom_1.obj").read_text().splitlines() if line.startswith("v "))
    assert n_v == sum(len(rend.mesh.vertices) for (i, ch), rend in renderers.items() if not ch)


def test_deterministic_apart_from_the_panorama_size(two_rooms, tmp_path):
    """Same seed: identical scan, specs, mesh, edges and poses (the images depend on the width)."""
    out = tmp_path / "again"
    generate_multiroom(out, seed=SEED, width=64, per_split=1, progress=False, params=PARAMS)

    def h(root: Path) -> dict[str, str]:
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file() and p.suffix != ".jpg" and p.name != "dataset.json"}

    a, b = h(two_rooms), h(out)
    assert a == b and any(k.endswith(".txt") and "_pose" in k for k in a)
    meta_a, meta_b = (json.loads((r / "dataset.json").read_text()) for r in (two_rooms, out))
    assert meta_a["scenes"][0]["rooms"] == meta_b["scenes"][0]["rooms"]


def test_cli_preset_routes_here_and_failure_leaves_nothing(tmp_path, monkeypatch):
    import ldlmap.synth.multiroom as mr
    import ldlmap.synth.scan as scan_mod
    from typer.testing import CliRunner

    from ldlmap.cli import app
    from ldlmap.core.errors import InputError

    calls = []

    def broken(*args, **kwargs):
        calls.append(1)
        raise InputError("scanner broke")

    monkeypatch.setitem(mr.MULTIROOM_PRESETS, "multiroom", {**mr.MULTIROOM_PRESETS["multiroom"], "rooms": 1})
    monkeypatch.setattr(scan_mod, "sample_scan", broken)
    res = CliRunner().invoke(app, ["synth", str(tmp_path / "out"), "--preset", "multiroom", "--width", "64",
                                   "--per-split", "1", "--quiet"])
    assert res.exit_code != 0 and calls == [1]
    assert "scanner broke" in res.output and "Traceback" not in res.output
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="valid: multiroom"):
        mr.multiroom_params("nope")
    with pytest.raises(InputError, match="at least 1 room"):
        generate_multiroom(tmp_path / "x", rooms=0, progress=False)
    assert list(tmp_path.iterdir()) == []
