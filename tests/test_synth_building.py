"""Synthetic buildings: stacked floors, identical rooms, corridors with doors, a stairwell per
floor, and queries that name their floor and room in the ground truth."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from ldlmap.core.polygon import points_in_polygon
from ldlmap.synth.building import (BuildingParams, building_params, door_segment, floor_scene, plan_building,
                                   read_building, room_at, room_mesh)
from ldlmap.synth.render import Renderer
from ldlmap.synth.spec import load_spec

pytestmark = pytest.mark.xdist_group("synth_building")  # one worker makes ``small_building``
WIDTH = 128
SEED = 3
PARAMS = building_params("building_small")


@pytest.fixture(scope="module")
def small_building(tmp_path_factory) -> Path:
    """``ldlmap synth --preset building_small`` (2 floors of 5 rooms), one panorama per split and room."""
    from typer.testing import CliRunner

    from ldlmap.cli import app

    out = tmp_path_factory.mktemp("building") / "b"
    res = CliRunner().invoke(app, ["synth", str(out), "--preset", "building_small", "--seed", str(SEED),
                                   "--width", str(WIDTH), "--per-split", "1", "--quiet"])
    assert res.exit_code == 0, res.output
    assert "floor_0" in res.output and "floor_1" in res.output
    return out


def test_floors_are_stacked_with_a_stairwell_on_each(small_building):
    rooms = read_building(small_building)
    meta = json.loads((small_building / "dataset.json").read_text())
    assert [s["name"] for s in meta["scenes"]] == ["floor_0", "floor_1"]
    assert sorted({r.floor for r in rooms}) == [0, 1]
    for r in rooms:
        assert r.scene == floor_scene(r.floor)
        assert r.bounds_min[2] == pytest.approx(r.floor * (PARAMS.ceiling + PARAMS.slab))
        assert r.bounds_max[2] == pytest.approx(r.bounds_min[2] + PARAMS.ceiling)
    s0, s1 = meta["scenes"]
    assert s1["z_floor"] == pytest.approx(s0["z_ceiling"] + PARAMS.slab)  # one floor's ceiling slab under the next
    stairs = [r for r in rooms if r.kind == "stairwell"]
    assert [r.floor for r in stairs] == [0, 1]
    np.testing.assert_allclose(stairs[0].bounds_min[:2], stairs[1].bounds_min[:2])  # a shaft: same xy
    np.testing.assert_allclose(stairs[0].bounds_max[:2], stairs[1].bounds_max[:2])
    spec = load_spec(stairs[0].spec)
    heights = sorted(o.size[2] for o in spec.objects)
    assert len(heights) >= 10 and heights[-1] <= PARAMS.ceiling  # steps rising under the ceiling
    # The rooms of a floor do not overlap (walls between them), and each floor's scan lies on its floor.
    for f in (0, 1):
        floor = [r for r in rooms if r.floor == f]
        for i, a in enumerate(floor):
            for b in floor[i + 1:]:
                sep = np.maximum(b.bounds_min - a.bounds_max, a.bounds_min - b.bounds_max)[:2]
                assert sep.max() >= PARAMS.wall - 1e-6, (a.id, b.id)
        xyz = np.asarray(np.loadtxt(small_building / "pcd" / f"floor_{f}.txt", usecols=(0, 1, 2)))
        assert xyz[:, 2].min() > s0["z_floor"] + f * PARAMS.storey - 0.05
        assert xyz[:, 2].max() < s0["z_ceiling"] + f * PARAMS.storey + 0.05
        for r in floor:  # each room's slice of the scan is inside the room
            P = xyz[r.points[0]:r.points[1]]
            near = np.all(np.abs(P - np.clip(P, r.bounds_min, r.bounds_max)) < 0.03, axis=1)  # scan noise 5 mm
            assert len(P) > 1000 and np.mean(near) > 0.999, r.id


def test_identical_rooms_are_identical(small_building):
    rooms = read_building(small_building)
    offices = [r for r in rooms if r.group == "office"]
    assert len(offices) == PARAMS.offices * PARAMS.floors and len({r.floor for r in offices}) == 2
    specs = [load_spec(r.spec) for r in offices]
    meshes = [room_mesh(r) for r in offices]
    ref, ref_off, ref_spec = meshes[0], offices[0].offset, specs[0]

    def rest(spec):  # everything but the name and the placement
        return replace(spec, name="", footprint=(), objects=tuple(replace(o, center=(0, 0)) for o in spec.objects))

    for r, spec, m in zip(offices[1:], specs[1:], meshes[1:]):
        # Same spec at another offset: footprint, furniture, openings, posters, materials, texture seed.
        np.testing.assert_allclose(np.asarray(spec.footprint) - r.offset[:2],
                                   np.asarray(ref_spec.footprint) - ref_off[:2], atol=1e-6)
        np.testing.assert_allclose([o.center for o in spec.objects] - r.offset[:2],
                                   [o.center for o in ref_spec.objects] - ref_off[:2], atol=1e-6)
        assert rest(spec) == rest(ref_spec)
        # Same geometry relative to the offsets (rebuilt meshes: the triangulation of a face may
        # pick other diagonals, the surfaces are the same) and the same look from the same place.
        np.testing.assert_allclose(m.vertices - r.offset, ref.vertices - ref_off, atol=1e-5)
        for mesh_part in np.unique(ref.tri_part):
            assert _area(m, m.tri_part == mesh_part) == pytest.approx(_area(ref, ref.tri_part == mesh_part), abs=1e-6)
        assert np.mean(np.abs(_view(m, r.offset) - _view(ref, ref_off))) < 2.0  # texels, not textures, may differ
    # A room of its own is not a copy: it looks different from the same place.
    own = next(r for r in rooms if r.group is None and r.kind == "room")
    assert np.mean(np.abs(_view(room_mesh(own), own.offset) - _view(ref, ref_off))) > 10.0


def _view(mesh, offset) -> np.ndarray:
    """The panorama 1.3 m above the room's point (1.8, 2.2) of its own frame."""
    centre = np.asarray(offset) + [1.8, 2.2, 1.3]
    return Renderer(mesh).render(np.eye(3), centre, 256, 128, supersample=2).rgb.astype(float)


def _area(mesh, mask) -> float:
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)[mask]]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


def _door_segment(spec, j):
    fp = np.asarray(spec.footprint, dtype=np.float64)
    op = spec.openings[j]
    a, b = fp[op.wall], fp[(op.wall + 1) % len(fp)]
    t = (b - a) / np.linalg.norm(b - a)
    return a + t * op.offset, a + t * (op.offset + op.width), op


def test_corridors_connect_every_room_through_doors_on_shared_walls(small_building):
    rooms = read_building(small_building)
    by_id = {r.id: r for r in rooms}
    for f in (0, 1):
        corridor = next(r for r in rooms if r.floor == f and r.kind == "corridor")
        cspec = load_spec(corridor.spec)
        others = {r.id for r in rooms if r.floor == f and r.kind != "corridor"}
        assert {d["to"] for d in corridor.doors} == others  # every room of the floor opens onto it
        for d in corridor.doors:
            room = by_id[d["to"]]
            back = [e for e in room.doors if e["to"] == corridor.id]
            assert len(back) == 1
            a0, a1, op_c = _door_segment(cspec, d["opening"])
            b0, b1, op_r = _door_segment(load_spec(room.spec), back[0]["opening"])
            assert op_c.kind == op_r.kind == "door"
            assert (op_c.sill, op_c.height, op_c.width) == pytest.approx((op_r.sill, op_r.height, op_r.width))
            # Facing each other across the shared wall: the same span, the wall's thickness apart.
            along = (a1 - a0) / np.linalg.norm(a1 - a0)
            normal = np.array([-along[1], along[0]])
            for p, q in ((a0, b1), (a1, b0)):  # the two sides run in opposite directions
                assert abs(np.dot(p - q, along)) < 1e-3
            assert abs(np.dot(b0 - a0, normal)) == pytest.approx(PARAMS.wall, abs=1e-3)


def test_queries_name_the_floor_and_room_holding_their_camera(small_building):
    from ldlmap.datasets import open_dataset

    ds = open_dataset(small_building, "omniscenes")
    assert ds.scenes() == ["floor_0", "floor_1"]
    rooms = read_building(small_building)
    queries = ds.queries()
    assert len(queries) == 8 * len(rooms)  # 5 splits + 3 illumination variants, one panorama each per room
    seen = set()
    for q in queries:
        assert q.floor is not None and q.room is not None, q.name
        assert q.scene == floor_scene(q.floor)
        room = room_at(rooms, q.center)
        assert room is not None and (room.id, room.floor) == (q.room, q.floor), q.name
        fp = np.asarray(load_spec(room.spec).footprint)
        assert points_in_polygon(q.center[None, :2], fp)[0]
        assert q.image.stem in room.queries[q.split]
        seen.add(q.room)
    assert seen == {r.id for r in rooms}  # every room has queries
    # Camera heights are the splits' heights above the floor's own level.
    for q in ds.queries("robot"):
        assert 0.9 < q.center[2] - q.floor * PARAMS.storey < 1.1


def test_world_frame_poses_see_their_rooms(small_building):
    """A written pose rendered in the room's world-frame mesh reproduces the written image."""
    from ldlmap.datasets import open_dataset

    rooms = {r.id: r for r in read_building(small_building)}
    checked = 0
    for q in open_dataset(small_building, "omniscenes").queries("robot"):
        if q.floor != 1:  # the upper floor: z offsets matter
            continue
        pano = Renderer(room_mesh(rooms[q.room])).render(q.rot_cam_from_world, q.center, WIDTH, WIDTH // 2,
                                                         supersample=2)
        jpg = cv2.imread(str(q.image))[..., ::-1].astype(float)
        assert np.isfinite(pano.depth).all()
        assert np.mean(np.abs(jpg - pano.rgb)) < 4.0, q.name
        checked += 1
    assert checked == len([r for r in rooms.values() if r.floor == 1])


def _doorway_points(root: Path, room) -> int:
    """Scan points of ``room``'s floor in the middle of its doors' openings: within 0.3 m of the
    door's line, its middle 60 %, 0.3-1.8 m above the floor (a closed door's panel, or nothing)."""
    xyz = np.loadtxt(root / "pcd" / f"floor_{room.floor}.txt", usecols=(0, 1, 2))
    spec, n = load_spec(room.spec), 0
    for d in room.doors:
        a, b = door_segment(spec, np.zeros(3), d["opening"])
        u = (b - a) / np.linalg.norm(b - a)
        rel = xyz[:, :2] - a
        along, across = rel @ u, np.abs(rel @ np.array([-u[1], u[0]]))
        w = float(np.linalg.norm(b - a))
        up = xyz[:, 2] - room.offset[2]
        n += int(np.count_nonzero((across < 0.3) & (along > 0.2 * w) & (along < 0.8 * w) & (up > 0.3) & (up < 1.8)))
    return n


def test_doors_open_in_scans_panoramas_and_walk(small_building, tmp_path):
    """``--doors open``: the scans hold no door panel (a closed building's do), the rooms' meshes let a
    ray through the doorway, and the walk's frames follow (``--walk-doors`` defaults to ``--doors``)."""
    from typer.testing import CliRunner

    from ldlmap.cli import app

    out = tmp_path / "open"
    res = CliRunner().invoke(app, ["synth", str(out), "--preset", "building_small", "--seed", str(SEED), "--width",
                                   str(WIDTH), "--per-split", "1", "--no-illumination", "--walk", "tour", "--doors",
                                   "open", "--quiet"])
    assert res.exit_code == 0, res.output
    meta = json.loads((out / "dataset.json").read_text())
    assert meta["doors"] == "open" and meta["walks"]["walk_tour"]["doors"] == "open"
    assert "doors" not in json.loads((small_building / "dataset.json").read_text())
    closed = {r.id: r for r in read_building(small_building)}
    for r in read_building(out):
        if not r.doors:
            continue
        assert _doorway_points(small_building, closed[r.id]) > 50 and _doorway_points(out, r) == 0, r.id
        spec = load_spec(r.spec)
        a, b = door_segment(spec, np.zeros(3), r.doors[0]["opening"])
        door = np.append((a + b) / 2, r.offset[2] + 1.0)
        inside = np.append(np.asarray(spec.footprint, dtype=float).mean(0), r.offset[2] + 1.0)
        ray = (door - inside) / np.linalg.norm(door - inside)
        hit_open = Renderer(room_mesh(r)).cast(inside[None], ray[None])
        hit_closed = Renderer(room_mesh(closed[r.id])).cast(inside[None], ray[None])
        assert hit_open["tri"][0] < 0 and hit_closed["tri"][0] >= 0, r.id  # the corridor's room: out the door


def test_reader_names_no_room_outside_synthetic_scenes_of_several_rooms(tmp_path):
    from ldlmap.datasets.omniscenes import query_rooms

    assert query_rooms(tmp_path) == {}
    (tmp_path / "dataset.json").write_text(json.dumps({"generator": "other", "scenes": [
        {"name": "a_1", "rooms": [{"id": "x", "floor": 0, "queries": {"robot": ["0000"]}}]}]}))
    assert query_rooms(tmp_path) == {}


def test_the_plan_has_twelve_rooms_a_floor_and_bad_plans_fail(tmp_path):
    from ldlmap.core.errors import InputError
    from ldlmap.synth.building import generate_building

    plan = plan_building(0, building_params("building"))
    assert len(plan) == 3
    for floor in plan:
        kinds = [r.kind for r in floor]
        assert kinds.count("corridor") == 1 and kinds.count("stairwell") == 1
        assert len(floor) - 2 >= 12
        assert sum(r.group == "office" for r in floor) >= 2 and sum(r.group == "hotel" for r in floor) >= 2
    with pytest.raises(InputError, match="at least 1 floor"):
        generate_building(tmp_path / "x", params=BuildingParams(floors=0), progress=False)
    with pytest.raises(InputError, match="valid: building"):
        building_params("tower")
    assert list(tmp_path.iterdir()) == []
