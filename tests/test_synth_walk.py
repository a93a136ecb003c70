"""``ldlmap synth --walk tour|video``: walks through doors, down corridors and up the stairwell, never
through a wall, sampled at the asked spacing, written as splits (and an mp4) that
``ldlloc run --root ... --walk`` reads in walk order and localizes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlmap.cli import app
from ldlmap.core.errors import InputError
from ldlmap.core.geometry import rotation_error_deg
from ldlmap.core.polygon import points_in_polygon
from ldlmap.synth.building import building_params, plan_building, walk_spaces
from ldlmap.synth.capture import capture_settings
from ldlmap.synth.generate import load_specs
from ldlmap.synth.multiroom import MultiRoomParams, multiroom_specs
from ldlmap.synth.render import render_through
from ldlmap.synth.scene import build_scene
from ldlmap.synth.walk import WALK_STEP_M, check_walk_doors, write_walks
from ldlmap.synth.walkplan import EYE_HEIGHT, MAX_TURN_DEG, STEP_RANGE, BuiltRooms, WalkRoom, plan_walk
from ldlloc.walk.relative import RelativeParams, panorama_features, relative_pose
from tests.conftest import DEMO_SEED
from tests.test_cli_synth import L_ROOM

runner = CliRunner()

SMALL_ROOM = L_ROOM + """
[scan]
density = 150.0
stations = 4
"""


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def wall_crossings(a: np.ndarray, b: np.ndarray, rooms: list[WalkRoom]) -> list[tuple[str, int]]:
    """The walls (room id, wall) that the xy segment a-b crosses outside their doors' openings."""
    bad = []
    for r in rooms:
        fp = r.footprint()
        for w in range(len(fp)):
            p, q = fp[w], fp[(w + 1) % len(fp)]
            d1, d2 = b[:2] - a[:2], q - p
            den = _cross(d1, d2)
            if abs(den) < 1e-12:
                continue
            t, u = _cross(p - a[:2], d2) / den, _cross(p - a[:2], d1) / den
            if 0 <= t <= 1 and 0 <= u <= 1:
                along = u * np.linalg.norm(d2)
                doors = [(o.offset, o.offset + o.width) for o in r.spec.openings if o.kind == "door" and o.wall == w]
                if not any(lo <= along <= hi for lo, hi in doors):
                    bad.append((r.id, w))
    return bad


def check_walk(poses, rooms: list[WalkRoom], step: float) -> np.ndarray:
    """Every frame in a room, clear of its objects' footprints, at walking height and tilt; no step
    through a wall; walked steps within the spacing. Returns the walked steps' lengths."""
    steps = []
    for k, p in enumerate(poses):
        r = p.room
        assert points_in_polygon(p.t[None, :2], r.footprint())[0], (k, p.t, r.id)
        up = p.R.T @ np.array([0.0, 0.0, 1.0])  # the camera's up axis in the world
        assert 0.9 <= np.degrees(np.arccos(np.clip(up[2], -1, 1))) <= 3.1
        if r.kind != "stairwell":
            assert EYE_HEIGHT[0] - 0.03 <= p.t[2] - r.z <= EYE_HEIGHT[1] + 0.03
        if k and p.jump is None:
            prev = poses[k - 1]
            assert prev.room.floor == r.floor and prev.room.scene == r.scene
            assert not wall_crossings(prev.t, p.t, [x for x in rooms if x.floor == r.floor and x.scene == r.scene])
            steps.append(float(np.linalg.norm(p.t[:2] - prev.t[:2])))
    steps = np.asarray(steps)
    assert steps.max() <= step * STEP_RANGE[1] + 1e-6
    assert step * STEP_RANGE[0] <= np.median(steps) <= step * STEP_RANGE[1]
    return steps


@pytest.fixture(scope="module")
def building_tour():
    """The tour of ``building_small`` (2 floors: offices, a room, corridor, stairwell), planned only."""
    params = building_params("building_small")
    spaces = walk_spaces(plan_building(3, params), params)
    return spaces, plan_walk(spaces, WALK_STEP_M["tour"], np.random.default_rng(21), BuiltRooms())


@pytest.mark.xdist_group("synth_walk")  # one worker plans ``building_tour``
def test_building_tour_walks_through_doors_never_walls(building_tour):
    spaces, poses = building_tour
    check_walk(poses, [r for s in spaces for r in s], WALK_STEP_M["tour"])
    kinds = {p.room.kind for p in poses}
    assert {"corridor", "office", "room", "stairwell"} <= kinds
    rooms = [p.room.id for p in poses]
    changes = [(a, b) for a, b in zip(rooms[:-1], rooms[1:]) if a != b]
    assert all("corridor" in a or "corridor" in b or "stairwell" in a for a, b in changes), changes


@pytest.mark.xdist_group("synth_walk")  # one worker plans ``building_tour``
def test_building_tour_sees_the_next_room_through_the_door_it_takes(building_tour):
    """With ``--walk-doors open`` the doors a tour walks through stand open: the frame before a door
    sees into the room behind it, no ray is lost at the doorway (its reveal closes the wall's
    thickness), and the motion between the two frames is fitted from their images
    (:mod:`ldlloc.walk.relative`): through a closed door they share nothing."""
    spaces, poses = building_tour
    assert check_walk_doors("open", ("tour",), building=True) == "open" and check_walk_doors(None, (), True) == "closed"
    k = next(k for k in range(1, len(poses)) if poses[k].jump is None and poses[k].room is not poses[k - 1].room)
    a, b = poses[k - 1], poses[k]
    space = next(s for s in spaces if any(r is a.room for r in s))
    built = BuiltRooms()
    pa, pb = (render_through(built.seen_from(p.room, space, True), p.R, p.t, 1024, supersample=1) for p in (a, b))
    assert np.isfinite(pa.depth).all() and np.isfinite(pb.depth).all()
    closed = built.get(a.room.spec)[1].render(a.R, a.t - np.asarray(a.room.offset), 1024, supersample=1)
    assert np.mean(pa.depth > closed.depth + 0.05) > 0.01  # through the door, beyond the room's wall
    rel = relative_pose(*(panorama_features(p.rgb) for p in (pa, pb)), RelativeParams(), a.R, b.R)
    assert rel is not None and rel.inliers >= 60
    step = (b.t - a.t) / np.linalg.norm(b.t - a.t)
    assert np.degrees(np.arccos(np.clip(rel.in_world(a.R)[1] @ step, -1, 1))) < 1.0


@pytest.mark.xdist_group("synth_walk")  # one worker plans ``building_tour``
def test_only_doors_open(building_tour):
    spaces, _ = building_tour
    room = next(r for s in spaces for r in s if r.doors)
    window = next(j for j, o in enumerate(room.spec.openings) if o.kind == "window")
    with pytest.raises(InputError, match="open doors must be door openings"):
        build_scene(room.spec, open_doors=(window,))


@pytest.mark.xdist_group("synth_walk")  # one worker plans ``building_tour``
def test_building_tour_changes_floor_by_the_stairwell(building_tour):
    _, poses = building_tour
    floors = [p.room.floor for p in poses]
    assert floors == sorted(floors) and set(floors) == {0, 1}
    k = floors.index(1)
    before, after = poses[k - 1], poses[k]
    assert after.jump == "stairs" and [p.jump for p in poses].count("stairs") == 1
    assert before.room.kind == after.room.kind == "stairwell"
    assert before.t[2] - before.room.z > EYE_HEIGHT[1] + 0.3  # it climbed the flight first
    assert abs(after.t[2] - after.room.z - (before.t[2] - before.room.z)) > 0.3
    climb = [p for p in poses[:k] if p.room.kind == "stairwell" and p.t[2] - p.room.z > EYE_HEIGHT[1] + 0.05]
    assert len(climb) >= 1 and all(p.t[2] < p.room.z + p.room.spec.ceiling_height for p in climb)


@pytest.mark.xdist_group("synth_walk")  # one worker plans ``building_tour``
def test_building_video_walks_on_through_open_doors(building_tour):
    """A video whose doors stand open walks through each doorway frame by frame (no ``door`` jump,
    every step within the video's spacing), and a frame in a doorway, in the wall's thickness, sees
    both rooms with no ray lost; through closed doors the same walk has no frame there."""
    spaces, _ = building_tour
    built, step = BuiltRooms(), WALK_STEP_M["video"]
    poses = plan_walk(spaces, step, np.random.default_rng(5), built, smooth=True, visits=1, doorways=True)
    closed = plan_walk(spaces, step, np.random.default_rng(5), built, smooth=True, visits=1)
    assert [p.jump for p in poses].count("door") == 0 and [p.jump for p in closed].count("door") >= 4
    walked = [np.linalg.norm(b.t[:2] - a.t[:2]) for a, b in zip(poses[:-1], poses[1:]) if b.jump is None]
    assert max(walked) <= step * STEP_RANGE[1] + 1e-6
    in_wall = [p for p in poses if not points_in_polygon(p.t[None, :2], p.room.footprint())[0]]
    assert len(in_wall) >= 4 and not any(not points_in_polygon(p.t[None, :2], p.room.footprint())[0] for p in closed)
    p = in_wall[0]
    space = next(s for s in spaces if any(r is p.room for r in s))
    pano = render_through(built.seen_from(p.room, space, True), p.R, p.t, 256, supersample=1)
    assert np.isfinite(pano.depth).all() and pano.depth.max() > 4.0  # down the corridor or across the room


def test_video_spacing_and_room_jumps():
    specs, _ = multiroom_specs(4, MultiRoomParams(rooms=2))
    spaces = [[WalkRoom(id=f"room{i}", scene="multiroom_1", spec=s)] for i, s in enumerate(specs, start=1)]
    poses = plan_walk(spaces, WALK_STEP_M["video"], np.random.default_rng(2), BuiltRooms(), smooth=True)
    steps = check_walk(poses, [s[0] for s in spaces], WALK_STEP_M["video"])
    assert len(steps) > 40 and steps.max() <= 0.3 + 1e-6
    turns = [rotation_error_deg(a.R, b.R) for a, b in zip(poses[:-1], poses[1:]) if b.jump is None]
    assert max(turns) <= MAX_TURN_DEG + 1.0 and np.median(turns) < 10  # + the tilt's drift; a loop's far ends reverse
    assert [p.jump for p in poses].count("cut") == 1
    k = [p.jump for p in poses].index("cut")
    assert poses[k - 1].room.id == "room1" and poses[k].room.id == "room2"
    again = plan_walk(spaces, WALK_STEP_M["video"], np.random.default_rng(2), BuiltRooms(), smooth=True)
    assert all(np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t) for a, b in zip(poses, again))


def test_video_split_and_mp4(tmp_path):
    """A room of one's own (an L) through the CLI: the video split, its poses, the mp4 of as many frames."""
    from ldlloc.walk.video import decoded_frames, video_info
    from ldlmap.datasets import open_dataset

    spec = tmp_path / "l.toml"
    spec.write_text(SMALL_ROOM)
    out = tmp_path / "ds"
    r = runner.invoke(app, ["synth", str(out), "--spec", str(spec), "--per-split", "0", "--no-illumination",
                            "--width", "64", "--walk", "video", "--walk-step", "0.3", "--quiet"])
    assert r.exit_code == 0, r.output
    walk = json.loads((out / "dataset.json").read_text())["walks"]["walk_video"]
    n = len(walk["frames"])
    assert n > 20 and walk["fps"] == pytest.approx(1 / 0.3) and walk["video"] == "video/walk_video.mp4"
    assert [f["stem"] for f in walk["frames"]] == [f"{k:04d}" for k in range(n)]
    steps = [f["step_m"] for f in walk["frames"][1:]]
    assert max(steps) <= 0.45 + 0.05 and min(steps) > 0  # 3D steps: the 2 cm bounce on top
    info = video_info(out / walk["video"])
    assert (info.width, info.height) == (64, 32)
    assert sum(1 for _ in decoded_frames(info)) == n
    queries = open_dataset(out, "omniscenes").queries("walk_video")
    assert [Path(q.name).name for q in queries] == [f["stem"] for f in walk["frames"]]


@pytest.mark.parametrize("args, needle", [
    (["--walk", "jog"], "--walk must be tour, video or tour,video"),
    (["--walk", "tour,tour"], "--walk must be"),
    (["--walk", ""], "--walk must be"),
    (["--walk", "tour", "--walk-step", "0"], "--walk-step must be a number in [0.05, 5]"),
    (["--walk", "video", "--walk-step", "nan"], "--walk-step must be"),
    (["--walk-step", "1"], "--walk-step goes with --walk"),
    (["--walk-doors", "open"], "--walk-doors goes with --walk"),
    (["--walk", "tour", "--walk-doors", "ajar"], "--walk-doors must be closed or open"),
    (["--walk", "tour", "--walk-doors", "open"], "--walk-doors open needs a building preset"),
    (["--preset", "multiroom", "--walk", "tour", "--walk-doors", "open"], "--walk-doors open needs a building"),
    (["--doors", "ajar"], "--doors must be closed or open"),
    (["--doors", "open"], "--doors open needs a building preset"),
    (["--preset", "multiroom", "--doors", "open", "--walk", "tour"], "--doors open needs a building preset"),
])
def test_bad_walk_options_one_line_error(tmp_path, args, needle):
    out = tmp_path / "out"
    r = runner.invoke(app, ["synth", str(out), "--width", "64", "--quiet", *args])
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], r.output
    assert not out.exists()


def test_tour_localizes_as_a_walk(demo_dataset, tmp_path):
    """The demo rooms' tour (written as `synth --preset demo --seed 7 --walk tour --width 512` writes it)
    against the demo maps with `ldlloc run --root ... --walk`: >= 0.85 of the frames within 0.1 m / 5 deg."""
    from ldlloc.cli import app as loc_app

    root = tmp_path / "walk"
    names = [f"synthroom_{i}" for i in (1, 2)]
    spaces = [[WalkRoom(id="", scene=n, spec=s)] for n, (_, s) in zip(names, load_specs("demo", [], DEMO_SEED))]
    counts: dict[str, int] = {}
    meta = write_walks(root, spaces, ("tour",), DEMO_SEED, capture_settings(spaces[0][0].spec.capture, 512, 0),
                       counts, lambda description="": None)
    assert counts == {"walk_tour": len(meta["walk_tour"]["frames"])} and counts["walk_tour"] >= 8
    out = tmp_path / "res.json"
    r = runner.invoke(loc_app, ["run", "--root", str(root), "--dataset", "omniscenes", "--walk",
                                "--maps", str(demo_dataset / "maps"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    recs = json.loads(out.read_text())["queries"]
    assert len(recs) == counts["walk_tour"]
    ok = [x["t_error_m"] is not None and x["t_error_m"] < 0.1 and x["r_error_deg"] < 5 for x in recs]
    assert np.mean(ok) >= 0.85, [(x["name"], x["t_error_m"]) for x in recs]
    for x in recs:  # frames in walk order within each room's walk
        assert x["walk"]["frame"] == int(Path(x["name"]).name) - (0 if x["scene"] == "synthroom_1" else
                                                                  sum(1 for y in recs if y["scene"] == "synthroom_1"))


def test_reader_names_walk_frames_rooms(tmp_path):
    """A walk's frames carry their floor and room in dataset.json: the reader's ``query_rooms`` reads them."""
    from ldlmap.datasets.omniscenes import SYNTH_GENERATOR, query_rooms

    frames = [{"stem": "0000", "scene": "floor_0", "floor": 0, "room": "f0_corridor"},
              {"stem": "0001", "scene": "floor_1", "floor": 1, "room": "f1_office2", "jump": "stairs"},
              {"stem": "0002", "scene": "synthroom_1", "floor": None, "room": None}]
    (tmp_path / "dataset.json").write_text(json.dumps({"generator": SYNTH_GENERATOR, "scenes": [],
                                                       "walks": {"walk_tour": {"frames": frames}}}))
    assert query_rooms(tmp_path) == {("walk_tour", "floor_0", "0000"): (0, "f0_corridor"),
                                     ("walk_tour", "floor_1", "0001"): (1, "f1_office2")}
