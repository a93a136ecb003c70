"""Synthetic buildings: floors of offices, hotel rooms, corridors and a stairwell (``--preset building``).

Each floor is the same plan: a corridor (a long thin room) along x, a row of rooms south of it
and a row north of it, every room with its door on the wall it shares with the corridor and a
window on the outer wall, and a stairwell at the corridor's east end (door on the shared wall).
Floors are stacked: floor ``f`` stands at ``z = f * (ceiling + slab)``, so one floor's ceiling
is ``slab`` metres below the next floor's floor, and the stairwell sits at the same xy on every
floor (a shaft: its steps, boxes of rising height, are cut by each floor's ceiling, since every
room is a closed solid). Neighbouring rooms are ``wall`` metres apart (the wall's thickness).

Identical rooms (the hard case for localization): the south row holds ``offices`` copies of one
office and the north row ``suites`` copies of one hotel room, on every floor: the same spec
(footprint, furniture, door, window, posters, materials and texture seed) at other offsets. The
north row's other ``rooms`` are rooms of their own (random furniture per floor and room), the
corridors differ between floors, the stairwells are copies. ``dataset.json`` names each room's
identical group (``office``, ``hotel``, ``stairwell``; ``null`` for a room of its own).

One OmniScenes scene per floor, ``floor_<f>`` (f = 0 for the ground floor), all in one world
frame (the layout as multiroom's: :func:`ldlmap.synth.multiroom.capture_room` does each room)::

    pcd/floor_<f>.txt, .ply                      the floor's scan (its rooms' scans, in room order)
    mesh/floor_<f>.obj (+ .mtl, .png)            the floor's mesh; gt_lines/floor_<f>.obj, .txt
    specs/floor_<f>_<room id>.toml               each room, xy in the world (z: its floor's level)
    <split>_pano/<split>_floor_<f>_scene_<k>/<id>.jpg   queries of all rooms of the floor, with
    <split>_pose/...                             poses in the building's world frame
    dataset.json                                 floors, rooms (id, floor, kind, group, offset,
                                                 bounds, doors, scan slice, query stems)

:func:`read_building` reads the rooms back and :func:`room_at` finds the room holding a point;
the dataset reader names each query's floor and room (``Query.floor``, ``Query.room``).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.datasets.omniscenes import SYNTH_GENERATOR
from ldlmap.io.linefiles import write_lines
from ldlmap.synth.capture import (BASE_SPLITS, GENERATOR_VERSION, ILLUMINATION_SPLITS, CaptureSettings, DatasetSummary,
                                  ProgressTicks, capture_settings, dataset_output, list_generated, read_dataset_meta)
from ldlmap.synth.edges import mesh_edges
from ldlmap.synth.multiroom import CapturedRoom, built_key, capture_room, lift_mesh, translate_spec, write_union
from ldlmap.synth.presets import door_keep_out, place_object
from ldlmap.synth.scene import build_scene
from ldlmap.synth.spec import (FRAME_WIDTH, CaptureSpec, ObjectSpec, OpeningSpec, PosterSpec, ScanSpec, SceneSpec,
                               dump_spec_toml, load_spec, validate_spec)
from ldlmap.synth.types import SceneMesh
from ldlmap.synth.walk import VISITS_PER_FLOOR, check_doors, check_walk_doors, write_walks
from ldlmap.synth.walkplan import CLEARANCE, BuiltRooms, WalkRoom

KINDS = ("office", "hotel", "room", "corridor", "stairwell")

# Building presets (data, like ``presets.PRESETS``): fields of BuildingParams.
BUILDING_PRESETS: dict[str, dict[str, Any]] = {
    # 3 floors of 12 rooms (6 identical offices, 3 identical hotel rooms, 3 of their own) plus a
    # corridor and a stairwell each: the 36-room building of bench/bench_building.py.
    "building": {"floors": 3, "offices": 6, "suites": 3, "rooms": 3},
    # 2 floors of 3 rooms (2 identical offices, 1 of its own), corridor and stairwell: the tests'.
    "building_small": {"floors": 2, "offices": 2, "suites": 0, "rooms": 1, "scan_density": 600.0},
}


@dataclass(frozen=True)
class BuildingParams:
    """The plan of a building (see the module docstring); lengths in metres."""

    floors: int = 3
    offices: int = 6  # identical offices per floor (south row; one group over all floors)
    suites: int = 3  # identical hotel rooms per floor (north row; a second group)
    rooms: int = 3  # rooms of their own per floor (north row, after the hotel rooms)
    room_width: float = 3.6  # along the corridor
    room_depth: float = 4.4  # across the corridor
    corridor_width: float = 2.0
    stair_width: float = 4.6  # stairwell along x
    stair_depth: float = 5.0  # stairwell along y (centred on the corridor)
    wall: float = 0.2  # thickness of the walls between neighbouring rooms
    ceiling: float = 2.7  # floor to ceiling
    slab: float = 0.3  # ceiling to the next floor's floor
    # Scan points per m^2 of every room's surface: ~2.5 M points a floor (docs/measurements.md#building-preset).
    scan_density: float = 1500.0
    views: int = 1  # panoramas per split and room (--per-split overrides)
    width: int = 1024  # panorama width (--width overrides)

    @property
    def storey(self) -> float:
        """Floor-to-floor height."""
        return self.ceiling + self.slab


@dataclass(frozen=True)
class PlannedRoom:
    """One room of the plan: its spec in its own frame (floor at z = 0) and where it stands."""

    id: str  # unique in the building, e.g. ``f1_office3``
    floor: int
    kind: str  # one of KINDS
    group: str | None  # identical group (equal ``spec``), None for a room of its own
    spec: SceneSpec  # footprint from (0, 0)
    offset: tuple[float, float, float]  # m, where the spec's origin stands in the world
    doors: tuple[tuple[int, str], ...] = ()  # (opening index, id of the room behind that door)


@dataclass(frozen=True)
class BuildingRoom:
    """One room of a generated building (:func:`read_building`)."""

    id: str
    index: int  # 1-based room number in the building (its random streams)
    floor: int
    scene: str  # the floor's scene, ``floor_<f>``
    kind: str
    group: str | None
    spec: Path  # spec with world xy (build_scene's floor at z = 0: lift by offset[2])
    changed_spec: Path
    offset: np.ndarray  # (3,) world position of the room's own origin (its floor level in z)
    bounds_min: np.ndarray  # (3,) world box: footprint, floor to ceiling
    bounds_max: np.ndarray
    points: tuple[int, int]  # [start, end) of the room's points in its floor's scan
    queries: dict[str, list[str]]  # split -> image stems in the floor's scene folders
    doors: list[dict] = field(default_factory=list)  # {"opening": j, "wall": w, "to": room id}
    reveal_m: float | None = None  # doors open (``--doors open``): their reveal's depth; None: closed

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """Whether points (N, 3) lie in the room (box of its footprint, floor to ceiling)."""
        p = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
        return np.all((p >= self.bounds_min) & (p <= self.bounds_max), axis=1)


def is_building_preset(preset: str | None) -> bool:
    """Whether ``preset`` names a building preset (routed here by ``generate_dataset``)."""
    return preset in BUILDING_PRESETS


def building_params(preset: str = "building") -> BuildingParams:
    """The :class:`BuildingParams` of ``preset``."""
    if preset not in BUILDING_PRESETS:
        raise InputError(f"unknown building preset {preset!r}; valid: {', '.join(BUILDING_PRESETS)}")
    return BuildingParams(**BUILDING_PRESETS[preset])


def floor_scene(floor: int) -> str:
    """The OmniScenes scene name of a floor."""
    return f"floor_{floor}"


# ------------------------------------------------------------------------------------ rooms


def _capture(p: BuildingParams) -> CaptureSpec:
    c = CaptureSpec(width=p.width, height=p.width // 2)
    n = int(p.views)
    return replace(c, robot=replace(c.robot, count=n), handheld=replace(c.handheld, count=n),
                   extreme=replace(c.extreme, count=n), change=replace(c.change, count=n))


def _scan(p: BuildingParams, footprint: np.ndarray) -> ScanSpec:
    # One station per ~2.5 m of the room's length (docs/measurements.md#scan-stations), at least 4.
    extent = float(np.ptp(footprint, axis=0).max())
    return ScanSpec(density=float(p.scan_density), stations=max(4, int(math.ceil(extent / 2.5))))


def _rect(w: float, d: float) -> np.ndarray:
    return np.array([(0.0, 0.0), (w, 0.0), (w, d), (0.0, d)])


def _materials(rng: np.random.Generator) -> dict[str, str]:
    return {"wall_material": str(rng.choice(["plaster", "plaster", "wallpaper", "concrete"])),
            "floor_material": str(rng.choice(["parquet", "carpet", "tiles", "carpet"]))}


def _posters(rng: np.random.Generator, fp: np.ndarray, walls: list[int], count: int, ceiling: float,
             taken: dict[int, list[tuple[float, float]]]) -> list[PosterSpec]:
    """Up to ``count`` posters on ``walls``, clear of the spans in ``taken`` (wall -> [(a, b)])."""
    lengths = np.linalg.norm(np.roll(fp, -1, axis=0) - fp, axis=1)
    out = []
    for _ in range(count):
        for _try in range(50):
            wall = int(rng.choice(walls))
            w, h = round(float(rng.uniform(0.4, 0.9)), 2), round(float(rng.uniform(0.5, 0.8)), 2)
            bottom = round(float(rng.uniform(1.1, 1.4)), 2)
            if lengths[wall] < w + 0.6 or bottom + h > ceiling - 0.15:
                continue
            off = round(float(rng.uniform(0.3, lengths[wall] - w - 0.3)), 3)
            if any(off - 0.15 < b and a < off + w + 0.15 for a, b in taken.get(wall, [])):
                continue
            taken.setdefault(wall, []).append((off, off + w))
            out.append(PosterSpec(wall, off, bottom, w, h))
            break
    return out


def _furniture(rng: np.random.Generator, kinds: tuple[str, ...], fp: np.ndarray, ceiling: float,
               openings: list[OpeningSpec]) -> list[ObjectSpec]:
    """One object of each of ``kinds`` where it fits in footprint ``fp``, clear of the doors' swing."""
    keep_out = door_keep_out(fp, openings)
    objects: list[ObjectSpec] = []
    for kind in kinds:
        obj = place_object(rng, kind, fp, ceiling, objects, keep_out)
        if obj is not None:
            objects.append(obj)
    return objects


def _furnished(rng: np.random.Generator, name: str, p: BuildingParams, door_wall: int, window_wall: int,
               kinds: tuple[str, ...]) -> SceneSpec:
    """A rectangular room with a door, a window, posters on the side walls and ``kinds`` furniture."""
    w, d, h = p.room_width, p.room_depth, p.ceiling
    fp = _rect(w, d)
    door = OpeningSpec("door", door_wall, round(float(rng.uniform(0.3, w - 0.9 - 0.3)), 3), 0.9, 2.1, 0.0)
    win_w = round(float(rng.uniform(1.0, 1.6)), 2)
    window = OpeningSpec("window", window_wall, round(float(rng.uniform(0.3, w - win_w - 0.3)), 3), win_w, 1.2, 0.9)
    openings = [door, window]
    taken = {o.wall: [(o.offset - FRAME_WIDTH, o.offset + o.width + FRAME_WIDTH)] for o in openings}
    posters = _posters(rng, fp, [1, 3], int(rng.integers(1, 3)), h, taken)
    objects = _furniture(rng, kinds, fp, h, openings)
    spec = SceneSpec(name=name, footprint=tuple(map(tuple, fp)), ceiling_height=h, objects=tuple(objects),
                     openings=tuple(openings), posters=tuple(posters), seed=int(rng.integers(0, 2**31 - 1)),
                     **_materials(rng), capture=_capture(p), scan=_scan(p, fp))
    validate_spec(spec)
    return spec


def _stairwell(rng: np.random.Generator, p: BuildingParams) -> SceneSpec:
    """The stairwell of every floor: a door in the west wall (centred), a flight of steps up the
    north wall to a landing along the east wall, and the next flight down the south wall until
    the ceiling cuts it; its change adds one object and moves nothing (the steps stay)."""
    W, D, h = p.stair_width, p.stair_depth, p.ceiling
    fp = _rect(W, D)
    flight, tread, margin = 1.1, 0.28, 0.02  # m: flight width, step depth, clearance from the walls
    n_half = 9  # steps per half storey
    rise = p.storey / (2 * n_half)
    x0 = 0.8  # m, first step (clear of the door's swing)
    steps = []
    for k in range(n_half - 1):  # up the north wall, eastwards; the landing is the last step
        steps.append(ObjectSpec("box", (round(x0 + (k + 0.5) * tread, 4), round(D - margin - flight / 2, 4)),
                                (tread, flight, round((k + 1) * rise, 4)), 0.0, "concrete"))
    x_land = x0 + (n_half - 1) * tread
    land_w = W - margin - x_land
    if land_w < flight:
        raise InputError(f"the stairwell is too short for its stairs: {W} m (need {x_land + flight + margin:.2f} m)")
    steps.append(ObjectSpec("box", (round(x_land + land_w / 2, 4), D / 2), (round(land_w, 4), D - 2 * margin,
                                                                        round(n_half * rise, 4)), 0.0, "concrete"))
    k = 1
    while (n_half + k) * rise <= h - 0.35 and x_land - k * tread > x0:  # down the south wall, westwards
        steps.append(ObjectSpec("box", (round(x_land - (k - 0.5) * tread, 4), round(margin + flight / 2, 4)),
                                (tread, flight, round((n_half + k) * rise, 4)), 0.0, "concrete"))
        k += 1
    door = OpeningSpec("door", 3, round(D / 2 - 0.45, 4), 0.9, 2.1, 0.0)
    window = OpeningSpec("window", 1, round(D / 2 - 0.5, 4), 1.0, 0.5, round(n_half * rise + 0.4, 2))
    cap = _capture(p)
    cap = replace(cap, change=replace(cap.change, moved=0, removed=0, added=1))
    spec = SceneSpec(name="stairwell", footprint=tuple(map(tuple, fp)), ceiling_height=h, objects=tuple(steps),
                     openings=(door, window), seed=int(rng.integers(0, 2**31 - 1)), wall_material="concrete",
                     floor_material="tiles", capture=cap, scan=_scan(p, fp))
    validate_spec(spec)
    return spec


def door_segment(spec: SceneSpec, offset: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
    """World xy end points of opening ``j`` of ``spec`` standing at ``offset``."""
    fp = np.asarray(spec.footprint, dtype=np.float64) + offset[:2]
    op = spec.openings[j]
    a, b = fp[op.wall], fp[(op.wall + 1) % len(fp)]
    t = (b - a) / np.linalg.norm(b - a)
    return a + t * op.offset, a + t * (op.offset + op.width)


def _matching_door(fp_world: np.ndarray, wall: int, seg: tuple[np.ndarray, np.ndarray]) -> OpeningSpec:
    """The door on wall ``wall`` of a footprint (world xy) facing the door segment ``seg``."""
    a, b = fp_world[wall], fp_world[(wall + 1) % len(fp_world)]
    t = (b - a) / np.linalg.norm(b - a)
    s0, s1 = sorted(float(np.dot(q - a, t)) for q in seg)
    return OpeningSpec("door", wall, round(s0, 4), round(s1 - s0, 4), 2.1, 0.0)


def _corridor(rng: np.random.Generator, p: BuildingParams, floor: int, length: float, offset: np.ndarray,
              neighbours: list[tuple[str, SceneSpec, np.ndarray, int, int]]) -> tuple[SceneSpec, tuple]:
    """The corridor of ``floor``: a door facing each neighbour's door (``(id, spec, offset,
    opening, corridor wall)``), a window in the west wall, posters and a cabinet or two."""
    fp = _rect(length, p.corridor_width)
    world = fp + offset[:2]
    openings, doors = [], []
    for rid, spec, off, j, wall in neighbours:
        op = _matching_door(world, wall, door_segment(spec, off, j))
        doors.append((len(openings), rid))
        openings.append(op)
    openings.append(OpeningSpec("window", 3, round(p.corridor_width / 2 - 0.5, 4), 1.0, 1.2, 0.9))
    taken: dict[int, list[tuple[float, float]]] = {}
    for o in openings:
        taken.setdefault(o.wall, []).append((o.offset - FRAME_WIDTH, o.offset + o.width + FRAME_WIDTH))
    posters = _posters(rng, fp, [0, 2], max(2, int(length / 4)), p.ceiling, taken)
    objects = _furniture(rng, ("cabinet", "shelf"), fp, p.ceiling, openings)
    spec = SceneSpec(name=f"corridor{floor}", footprint=tuple(map(tuple, fp)), ceiling_height=p.ceiling,
                     objects=tuple(objects), openings=tuple(openings), posters=tuple(posters),
                     seed=int(rng.integers(0, 2**31 - 1)), **_materials(rng), capture=_capture(p), scan=_scan(p, fp))
    validate_spec(spec)
    return spec, tuple(doors)


def plan_building(seed: int, p: BuildingParams = BuildingParams()) -> list[list[PlannedRoom]]:
    """The rooms of every floor (corridor first, then the south row, the north row, the stairwell)."""
    if p.floors < 1 or p.offices < 0 or p.suites < 0 or p.rooms < 0 or p.offices + p.suites + p.rooms < 1:
        raise InputError(f"a building needs at least 1 floor and 1 room a floor, got {p.floors} floors, "
                         f"{p.offices} offices, {p.suites} hotel rooms and {p.rooms} rooms")
    if min(p.wall, p.slab) < 0 or p.corridor_width < 1.2:
        raise InputError("walls and slabs must be >= 0 m thick and the corridor at least 1.2 m wide")

    def rng(*tags: int) -> np.random.Generator:
        return np.random.default_rng([int(seed) & 0xFFFFFFFF, 0xB1D, *tags])

    office = _furnished(rng(1), "office", p, door_wall=2, window_wall=0, kinds=("table", "shelf", "cabinet", "box"))
    hotel = _furnished(rng(2), "hotel", p, door_wall=0, window_wall=2, kinds=("sofa", "table", "cabinet", "box"))
    stair = _stairwell(rng(3), p)
    w, d, t, cw = p.room_width, p.room_depth, p.wall, p.corridor_width
    slots = max(p.offices, p.suites + p.rooms)
    length = slots * w + (slots - 1) * t
    y_corr, y_north = d + t, d + t + cw + t
    floors = []
    for f in range(p.floors):
        z = round(f * p.storey, 6)
        rooms: list[PlannedRoom] = []
        for i in range(p.offices):
            rooms.append(PlannedRoom(f"f{f}_office{i + 1}", f, "office", "office", office, (i * (w + t), 0.0, z)))
        for i in range(p.suites + p.rooms):
            x = i * (w + t)
            if i < p.suites:
                rooms.append(PlannedRoom(f"f{f}_hotel{i + 1}", f, "hotel", "hotel", hotel, (x, y_north, z)))
            else:
                k = i - p.suites + 1
                r = rng(5, f, k)
                kinds = ("table", "shelf", "box") + tuple(str(r.choice(["box", "cabinet", "sofa", "table"]))
                                                        for _ in range(int(r.integers(0, 3))))
                spec = _furnished(r, f"room{f}x{k}", p, door_wall=0, window_wall=2, kinds=kinds)
                rooms.append(PlannedRoom(f"f{f}_room{k}", f, "room", None, spec, (x, y_north, z)))
        stair_room = PlannedRoom(f"f{f}_stairwell", f, "stairwell", "stairwell", stair,
                                 (length + t, y_corr + cw / 2 - p.stair_depth / 2, z))
        corr_off = np.array([0.0, y_corr, z])
        # Every room's door is its opening 0, facing the corridor's south wall (0, offices) or
        # north wall (2, the north row); the stairwell's faces the corridor's east wall (1).
        neighbours = [(r.id, r.spec, np.asarray(r.offset), 0, 0 if r.kind == "office" else 2) for r in rooms]
        neighbours.append((stair_room.id, stair, np.asarray(stair_room.offset), 0, 1))
        corridor, doors = _corridor(rng(4, f), p, f, length, corr_off, neighbours)
        corridor_id = f"f{f}_corridor"
        rooms = [replace(r, doors=((0, corridor_id),)) for r in rooms]
        stair_room = replace(stair_room, doors=((0, corridor_id),))
        floors.append([PlannedRoom(corridor_id, f, "corridor", None, corridor, tuple(corr_off), doors)]
                      + rooms + [stair_room])
    return floors


def _passage(room: PlannedRoom, j: int, p: BuildingParams) -> np.ndarray:
    """The (4, 2) world xy rectangle a walk crosses door ``j`` of ``room`` in: the door's width less
    0.25 m a side, from ``CLEARANCE`` + 0.15 m inside the room to as far beyond the wall."""
    a, b = door_segment(room.spec, np.asarray(room.offset, dtype=np.float64), j)
    t = (b - a) / np.linalg.norm(b - a)
    n = np.array([t[1], -t[0]])  # outward: the footprints run counter-clockwise
    a, b = a + 0.25 * t, b - 0.25 * t
    inner, outer = CLEARANCE + 0.15, p.wall + CLEARANCE + 0.15
    return np.array([a - inner * n, b - inner * n, b + outer * n, a + outer * n])


def walk_spaces(plan: list[list[PlannedRoom]], p: BuildingParams) -> list[list[WalkRoom]]:
    """The building's floors as walk spaces (:mod:`ldlmap.synth.walkplan`), ground floor first."""
    return [[WalkRoom(id=r.id, scene=floor_scene(r.floor), spec=r.spec, offset=tuple(float(x) for x in r.offset),
                      floor=r.floor, kind=r.kind, passages=tuple(_passage(r, j, p) for j, _ in r.doors),
                      doors=tuple(j for j, _ in r.doors), reveal_m=p.wall / 2)
             for r in rooms] for rooms in plan]


# -------------------------------------------------------------------------------- generating


def generate_building(out: Path, preset: str = "building", seed: int = 0, overwrite: bool = False,
                      progress: bool = True, illumination: bool = True, width: int | None = None,
                      per_split: int | None = None, params: BuildingParams | None = None,
                      walk: tuple[str, ...] = (), walk_step: float | None = None,
                      walk_visits: int = VISITS_PER_FLOOR, doors: str = "closed",
                      walk_doors: str | None = None) -> DatasetSummary:
    """Generate a building dataset into ``out`` (atomically); returns a ``DatasetSummary``.

    ``params`` (default: the preset's) is the plan; ``width`` and ``per_split`` (panoramas per
    split *per room*) override it. ``doors``: closed or open (:data:`ldlmap.synth.walk.DOORS`) in the
    scans and the panoramas. ``walk``: the walk captures (:mod:`ldlmap.synth.walk`) from floor to
    floor, ``walk_visits`` rooms entered on each, its doors ``walk_doors`` (default ``doors``).
    Same seed, same bytes.
    """
    check_doors(doors, building=True)
    walk_doors = check_walk_doors(walk_doors, walk, building=True, default=doors) if walk else doors
    start = time.perf_counter()
    out = Path(out)
    params = params or building_params(preset)
    plan = plan_building(seed, params)  # bad settings fail before anything is written
    all_rooms = [r for floor in plan for r in floor]
    settings = {id(r): capture_settings(r.spec.capture, width, per_split, illumination) for r in all_rooms}
    cap0 = settings[id(all_rooms[0])]
    splits = list(BASE_SPLITS) + [v for v in ILLUMINATION_SPLITS if v in cap0.illumination]
    split_counts = {s: 0 for s in splits}
    total = sum(3 + sum(settings[id(r)].counts.values()) for r in all_rooms) + len(plan)
    copies: dict[SceneSpec, int] = {}
    for r in all_rooms:
        copies[r.spec] = copies.get(r.spec, 0) + 1
    run = _FloorRun(seed=int(seed), settings=settings, split_counts=split_counts,
                    shared={spec for spec, n in copies.items() if n > 1}, spaces=walk_spaces(plan, params),
                    doors_open=doors == "open")
    scenes = []
    with dataset_output(out, overwrite) as tmp, ProgressTicks(progress, total) as tick:
        (tmp / "specs").mkdir(parents=True)
        for f, rooms in enumerate(plan):
            scenes.append(_write_floor(tmp, f, rooms, params, cap0, run, tick))
        walks = write_walks(tmp, run.spaces, walk, seed, cap0, split_counts, tick, walk_step, walk_visits, walk_doors,
                            run.built) if walk else {}
        meta = {"generator": SYNTH_GENERATOR, "version": GENERATOR_VERSION, "seed": int(seed), "preset": preset,
                "building": asdict(params), "illumination": sorted(cap0.illumination),
                "layout": "omniscenes", **({"doors": doors} if run.doors_open else {}), "scenes": scenes,
                "splits": {s: {"images": split_counts[s]} for s in split_counts}, **({"walks": walks} if walks else {})}
        (tmp / "dataset.json").write_text(json.dumps(list_generated(tmp, meta), indent=2) + "\n")

    return DatasetSummary(out=out, seed=int(seed), scenes=[s["name"] for s in scenes], splits=split_counts,
                          points={s["name"]: s["points"] for s in scenes}, width=cap0.width, height=cap0.height,
                          seconds=time.perf_counter() - start)


@dataclass
class _FloorRun:
    """What the floors of one :func:`generate_building` call share while they are written."""

    seed: int
    settings: dict[int, CaptureSettings]  # id(PlannedRoom) -> its capture settings
    split_counts: dict[str, int]  # split -> images written so far (grows in place)
    shared: set[SceneSpec]  # specs of the identical groups (built once for all their copies)
    spaces: list[list[WalkRoom]]  # the floors' rooms as a walk sees them (doors, reveals), plan order
    doors_open: bool = False  # the doors stand open in the scans and panoramas
    cache: dict = field(default_factory=dict)  # (spec, doors, reveal) -> built room: the shared specs (doors open:
    # every room, built once for its scan, its panoramas, the rooms that see it through a door and the walk)
    built: BuiltRooms = field(default_factory=BuiltRooms)  # the rooms seen through open doors; the walk's
    rooms_done: int = 0  # rooms captured so far: the next room's index is one more

    def capture_args(self, f: int, i: int) -> dict:
        """:func:`capture_room`'s arguments for room ``i`` of floor ``f``: with the doors open, its
        doors, their reveal, and the floor's other rooms seen through them (this room's own built
        mesh shared with the walk's cache)."""
        if not self.doors_open:
            return {}
        room = self.spaces[f][i]
        parts = self.built.seen_from(room, self.spaces[f], True)
        off = np.asarray(room.offset, dtype=np.float64)
        own, key = parts[0][0], built_key(room.spec, room.doors, room.reveal_m)
        if key not in self.cache:
            self.cache[key] = (own.mesh, own, mesh_edges(own.mesh))
        return {"doors": room.doors, "reveal_m": room.reveal_m, "through": [(r, o - off) for r, o in parts[1:]],
                "cache": self.cache}


def _write_floor(tmp: Path, f: int, rooms: list[PlannedRoom], params: BuildingParams, cap0: CaptureSettings,
                 run: _FloorRun, tick: Callable[[str], None]) -> dict:
    """Capture the rooms of floor ``f`` and write its scene (scan, mesh, true lines); its ``dataset.json`` entry."""
    name = floor_scene(f)
    captured, infos = [], []
    first = {s: 0 for s in BASE_SPLITS}
    n_points = 0
    for i, r in enumerate(rooms):
        run.rooms_done += 1
        idx = run.rooms_done
        off = np.asarray(r.offset, dtype=np.float64)
        got = capture_room(tmp, name, r.spec, idx, run.settings[id(r)], run.seed, tick, first, run.split_counts,
                           offset=off, label=r.id,
                           **(run.capture_args(f, i) or {"cache": run.cache if r.spec in run.shared else None}))
        for split in BASE_SPLITS:
            first[split] += len(got.queries.get(split, []))
        infos.append(_write_room_specs(tmp, name, f, r, idx, off, got, n_points))
        n_points += int(len(got.points))
        captured.append(got)
    tick(f"{name}: writing the floor")
    points, union, segs = write_union(tmp, name, captured)
    z = f * params.storey
    return {"name": name, "floor": f, "z_floor": round(z, 6), "z_ceiling": round(z + params.ceiling, 6),
            "points": points, "triangles": int(union.num_triangles), "gt_lines": int(len(segs)),
            "width": cap0.width, "height": cap0.height, "rooms": infos}


def _write_room_specs(tmp: Path, name: str, f: int, r: PlannedRoom, idx: int, off: np.ndarray, got: CapturedRoom,
                      n_points: int) -> dict:
    """Write room ``r``'s specs in world xy (unchanged and changed); its ``dataset.json`` entry."""
    stem = f"specs/{name}_{r.id}"
    world = translate_spec(replace(r.spec, name=r.id), off[:2])
    (tmp / f"{stem}.toml").write_text(dump_spec_toml(world))
    (tmp / f"{stem}_scene_2.toml").write_text(dump_spec_toml(translate_spec(replace(got.changed, name=r.id), off[:2])))
    fp = np.asarray(world.footprint, dtype=np.float64)
    return {"id": r.id, "index": idx, "floor": f, "kind": r.kind, "group": r.group,
            "spec": f"{stem}.toml", "changed_spec": f"{stem}_scene_2.toml",
            "offset": [float(x) for x in off],
            "bounds_min": [float(x) for x in fp.min(0)] + [float(off[2])],
            "bounds_max": [float(x) for x in fp.max(0)] + [float(off[2] + r.spec.ceiling_height)],
            "doors": [{"opening": j, "wall": int(r.spec.openings[j].wall), "to": to} for j, to in r.doors],
            "points": [n_points, n_points + int(len(got.points))], "triangles": int(got.mesh.num_triangles),
            "gt_lines": int(len(got.edges)), "queries": got.queries}


# ---------------------------------------------------------------------------------- reading


def read_building(root: str | Path) -> list[BuildingRoom]:
    """The rooms of a generated building (from its ``dataset.json``), floor by floor."""
    root = Path(root)
    meta = read_dataset_meta(root)
    if "building" not in meta:
        raise InputError(f"{root} is not a synthetic building (generate one with --preset building)")
    return [BuildingRoom(id=r["id"], index=int(r["index"]), floor=int(r["floor"]), scene=s["name"], kind=r["kind"],
                         group=r["group"], spec=root / r["spec"], changed_spec=root / r["changed_spec"],
                         offset=np.asarray(r["offset"], dtype=np.float64),
                         bounds_min=np.asarray(r["bounds_min"], dtype=np.float64),
                         bounds_max=np.asarray(r["bounds_max"], dtype=np.float64),
                         points=(int(r["points"][0]), int(r["points"][1])),
                         queries={k: list(v) for k, v in r["queries"].items()}, doors=list(r.get("doors", [])),
                         reveal_m=meta["building"]["wall"] / 2 if meta.get("doors") == "open" else None)
            for s in meta["scenes"] for r in s["rooms"]]


def room_at(rooms: list[BuildingRoom], xyz: Any) -> BuildingRoom | None:
    """The room whose box (footprint, floor to ceiling) holds the point ``xyz``, or None."""
    for r in rooms:
        if r.contains(xyz)[0]:
            return r
    return None


def room_mesh(room: BuildingRoom, changed: bool = False) -> SceneMesh:
    """The room's mesh in the world frame, rebuilt from its written spec (``changed``: scene_2), its
    doors open where the building's are."""
    spec = load_spec(room.changed_spec if changed else room.spec)
    mesh = build_scene(spec) if room.reveal_m is None else \
        build_scene(spec, open_doors=tuple(d["opening"] for d in room.doors), reveal_m=room.reveal_m)
    return lift_mesh(mesh, (0.0, 0.0, float(room.offset[2])))
