"""Several rooms in one scan: the synthetic counterpart of the paper's multi-room map (sec. 4.2).

The paper localizes against the whole OmniScenes dataset as ONE map; here ``N`` random rooms
(``random_spec(room_preset, seed, i)``, ``i = 1..N``: the same rooms as the first scenes of that
preset's single-room dataset) are placed side by side in one world frame and written as a
single OmniScenes scene ``multiroom_1``::

    pcd/multiroom_1.txt, .ply                  union of the rooms' scans (room 1's points first)
    mesh/multiroom_1.obj (+ .mtl, .png)        union of the rooms' meshes (one stacked atlas)
    gt_lines/multiroom_1.obj, .txt             union of the rooms' ground-truth edges
    specs/multiroom_1_room_<i>.toml            room i in world coordinates (scene_2: changed room)
    <split>_pano/<split>_multiroom_1_scene_<k>/<id>.jpg   queries of all rooms, numbered on
    <split>_pose/<split>_multiroom_1_scene_<k>/<id>.txt   (room 1's first), poses in the world frame
    dataset.json                               as for one room, plus the room layout (below)

Placement: rooms keep their orientation (real buildings share principal directions), so only
offsets differ. The rooms' bounding boxes are laid out on a near-square grid
(``ceil(sqrt(N))`` columns) with ``gap`` metres between neighbours, so they never overlap, and
the scan's extent (which scales the 3D length filter, ``lambda * mean extent``) grows like
``sqrt(N)`` rather than ``N``. The specs are translated themselves (footprint and furniture
centres; walls, openings and posters are relative to the footprint), so every written spec
builds its room directly in the world frame and ``build_scene(load_spec(...))`` reproduces it.

Each room is scanned from its own stations and its panoramas rendered in the room alone (rooms
are closed solids, so the other rooms could not be seen anyway), with the single-room
generator's code and random streams (:func:`ldlmap.synth.capture.write_split_panoramas`).
``dataset.json`` records per room its spec files, offset, bounds, the slice of the scan that is
its own and the image stems of each split (:func:`read_layout` reads them back).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.datasets.omniscenes import SYNTH_GENERATOR
from ldlmap.io.linefiles import write_lines
from ldlmap.synth import scan  # through the module: tests replace scan.sample_scan to fail midway
from ldlmap.synth.capture import (BASE_SPLITS, GENERATOR_VERSION, ILLUMINATION_SPLITS, CaptureSettings, DatasetSummary,
                                  ProgressTicks, capture_settings, dataset_output, list_generated, read_dataset_meta,
                                  stream_rng, write_split_panoramas)
from ldlmap.synth.edges import mesh_edges
from ldlmap.synth.meshio import write_textured_obj
from ldlmap.synth.presets import changed_spec, random_spec
from ldlmap.synth.render import Renderer
from ldlmap.synth.scene import build_scene
from ldlmap.synth.spec import SceneSpec, dump_spec_toml, load_spec, validate_spec
from ldlmap.synth.types import SceneMesh
from ldlmap.synth.walk import write_walks
from ldlmap.synth.walkplan import WalkRoom

SCENE = "multiroom_1"

# Multi-room presets (data, like ``presets.PRESETS``): rooms, the single-room preset they come
# from, and the gap between neighbouring rooms' bounding boxes.
MULTIROOM_PRESETS: dict[str, dict[str, Any]] = {
    "multiroom": {"rooms": 4, "room_preset": "demo", "gap": 1.0},
}


@dataclass(frozen=True)
class MultiRoomParams:
    """How the rooms of a multi-room scene are chosen and placed."""

    rooms: int = 4  # number of rooms N
    room_preset: str = "demo"  # single-room preset of random_spec (demo, standard)
    gap: float = 1.0  # m, free space between neighbouring rooms' bounding boxes
    columns: int = 0  # rooms per grid row; 0 = ceil(sqrt(rooms))
    scan_density: float = 0.0  # points per m^2 of each room's scan; 0 = the room preset's


@dataclass(frozen=True)
class RoomInfo:
    """One room of a generated multi-room scene (see :func:`read_layout`)."""

    index: int  # 1-based room index (its random streams)
    spec: Path  # room spec in world coordinates
    changed_spec: Path  # the changed room (change_* splits)
    offset: np.ndarray  # (3,) m, translation applied to random_spec's room
    bounds_min: np.ndarray  # (3,) m, bounding box of the room (footprint, floor to ceiling)
    bounds_max: np.ndarray  # (3,)
    points: tuple[int, int]  # [start, end) of the room's own points in the scene's scan
    queries: dict[str, list[str]]  # split -> image stems of the room's panoramas

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """Whether points (N, 3) lie in the room's bounding box."""
        p = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
        return np.all((p >= self.bounds_min) & (p <= self.bounds_max), axis=1)


def is_multiroom_preset(preset: str | None) -> bool:
    """Whether ``preset`` names a multi-room preset (routed here by ``generate_dataset``)."""
    return preset in MULTIROOM_PRESETS


def multiroom_params(preset: str = "multiroom", rooms: int | None = None) -> MultiRoomParams:
    """The :class:`MultiRoomParams` of ``preset``, with ``rooms`` overriding its room count."""
    if preset not in MULTIROOM_PRESETS:
        raise InputError(f"unknown multi-room preset {preset!r}; valid: {', '.join(MULTIROOM_PRESETS)}")
    params = MultiRoomParams(**MULTIROOM_PRESETS[preset])
    return params if rooms is None else replace(params, rooms=int(rooms))


def translate_spec(spec: SceneSpec, offset: tuple[float, float]) -> SceneSpec:
    """``spec`` moved by ``offset`` (dx, dy) in metres: footprint vertices and object centres.

    Openings and posters are placed along walls (relative to the footprint) and move with it;
    coordinates are rounded to micrometres so that the TOML files stay readable.
    """
    dx, dy = float(offset[0]), float(offset[1])
    footprint = tuple((round(x + dx, 6), round(y + dy, 6)) for x, y in spec.footprint)
    objects = tuple(replace(o, center=(round(o.center[0] + dx, 6), round(o.center[1] + dy, 6))) for o in spec.objects)
    return replace(spec, footprint=footprint, objects=objects)


def layout_offsets(footprints: list[np.ndarray], gap: float, columns: int = 0) -> np.ndarray:
    """(N, 2) offsets placing the footprints' bounding boxes on a grid, ``gap`` metres apart.

    Row by row (``columns`` per row, 0 = ceil(sqrt(N))): each box starts ``gap`` after the
    previous box of its row, and each row ``gap`` above the deepest box of the rows below.
    """
    n = len(footprints)
    if n == 0:
        return np.zeros((0, 2))
    if gap < 0:
        raise InputError(f"the gap between rooms must be >= 0 m, got {gap}")
    cols = int(columns) if columns and columns > 0 else int(math.ceil(math.sqrt(n)))
    lo = np.array([np.min(f, axis=0) for f in footprints])
    hi = np.array([np.max(f, axis=0) for f in footprints])
    size = hi - lo
    out = np.zeros((n, 2))
    y = 0.0
    for r0 in range(0, n, cols):
        x = 0.0
        row = range(r0, min(n, r0 + cols))
        for i in row:
            out[i] = (x - lo[i, 0], y - lo[i, 1])
            x += size[i, 0] + gap
        y += max(size[i, 1] for i in row) + gap
    return np.round(out, 6)


def multiroom_specs(seed: int, params: MultiRoomParams = MultiRoomParams()) -> tuple[list[SceneSpec], np.ndarray]:
    """The rooms' specs in world coordinates (named ``room<i>``) and their (N, 2) offsets."""
    if params.rooms < 1:
        raise InputError(f"a multi-room scene needs at least 1 room, got {params.rooms}")
    rooms = [random_spec(params.room_preset, seed, i) for i in range(1, params.rooms + 1)]
    offsets = layout_offsets([np.asarray(s.footprint, dtype=np.float64) for s in rooms], params.gap, params.columns)
    specs = []
    for i, (s, off) in enumerate(zip(rooms, offsets), start=1):
        moved = replace(translate_spec(s, off), name=f"room{i}")
        if params.scan_density > 0:
            moved = replace(moved, scan=replace(moved.scan, density=float(params.scan_density)))
        validate_spec(moved)
        specs.append(moved)
    return specs, offsets


def merge_meshes(meshes: list[SceneMesh], name: str = SCENE) -> SceneMesh:
    """One :class:`SceneMesh` holding all ``meshes`` (for the union OBJ).

    Atlases are stacked vertically (left-aligned, zero padding) and texture coordinates remapped
    into the stack; object and part indices are offset so that they stay unique. The footprint
    of the union is the bounding rectangle of the rooms' footprints, the ceiling the highest.
    """
    if not meshes:
        raise InputError("no mesh to merge")
    Wt = max(m.atlas.shape[1] for m in meshes)
    Ht = sum(m.atlas.shape[0] for m in meshes)
    atlas = np.zeros((Ht, Wt, 3), dtype=np.uint8)
    verts, tris, uvs, objs, parts, boxes, fps = [], [], [], [], [], [], []
    v0 = r0 = obj0 = part0 = 0
    for m in meshes:
        h, w = m.atlas.shape[:2]
        atlas[r0:r0 + h, :w] = m.atlas
        uv = np.asarray(m.tri_uvs, dtype=np.float64)
        s = uv[..., 0] * (w / Wt)
        t = 1.0 - ((1.0 - uv[..., 1]) * h + r0) / Ht  # rows are (1 - t) * height, counted from the top
        uvs.append(np.stack([s, t], -1).astype(np.float32))
        verts.append(np.asarray(m.vertices, dtype=np.float64))
        tris.append(np.asarray(m.triangles, dtype=np.int64) + v0)
        o = np.asarray(m.tri_object, dtype=np.int32)
        objs.append(np.where(o >= 0, o + obj0, -1).astype(np.int32))
        p = np.asarray(m.tri_part if m.tri_part is not None else np.zeros(len(m.triangles)), dtype=np.int32)
        parts.append(p + part0)
        boxes.extend(m.object_boxes)
        fps.append(np.asarray(m.footprint, dtype=np.float64))
        v0 += len(m.vertices)
        r0 += h
        obj0 += len(m.object_boxes)
        part0 += int(p.max()) + 1 if len(p) else 0
    allfp = np.concatenate(fps)
    (x0, y0), (x1, y1) = allfp.min(0), allfp.max(0)
    return SceneMesh(vertices=np.concatenate(verts), triangles=np.concatenate(tris), tri_uvs=np.concatenate(uvs),
                     atlas=atlas, tri_object=np.concatenate(objs),
                     footprint=np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]),
                     ceiling_height=float(max(m.ceiling_height for m in meshes)), name=name,
                     object_boxes=boxes, tri_part=np.concatenate(parts))


def lift_mesh(mesh: SceneMesh, offset: Any) -> SceneMesh:
    """``mesh`` moved by ``offset`` (dx, dy, dz) metres: vertices, footprint and object boxes.

    ``ceiling_height`` becomes the world height of the ceiling (``dz`` + the room's height): the
    moved mesh is for writing and merging; render and sample poses in the unmoved one.
    """
    off = np.asarray(offset, dtype=np.float64).reshape(3)
    if not off.any():
        return mesh
    return replace(mesh, vertices=np.asarray(mesh.vertices, dtype=np.float64) + off,
                   footprint=np.asarray(mesh.footprint, dtype=np.float64) + off[:2],
                   ceiling_height=float(mesh.ceiling_height) + float(off[2]),
                   object_boxes=[np.asarray(b, dtype=np.float64) + off for b in mesh.object_boxes])


@dataclass
class CapturedRoom:
    """What :func:`capture_room` made of one room, in the world frame."""

    mesh: SceneMesh  # moved by the room's offset
    edges: np.ndarray  # (E, 2, 3) true 3D edges
    points: np.ndarray  # (N, 3) scan points
    colors: np.ndarray  # (N, 3) uint8
    changed: SceneSpec  # the changed spec (change_* splits), in the spec's own frame
    queries: dict[str, list[str]]  # split -> image stems written


def capture_room(tmp: Path, scene: str, spec: SceneSpec, idx: int, cap: CaptureSettings, seed: int,
                 tick: Callable[[str], None], first_stem: dict[str, int], split_counts: dict[str, int],
                 offset: Any = (0.0, 0.0, 0.0), label: str = "room", cache: dict | None = None,
                 doors: tuple[int, ...] = (), reveal_m: float = 0.0,
                 through: Sequence[tuple[Renderer, np.ndarray]] = ()) -> CapturedRoom:
    """Scan one room and write its panoramas into the scene ``scene`` (numbered on from
    ``first_stem``; ``split_counts`` grows in place), with the room's own random streams (``idx``).

    The room is built, scanned and rendered where ``spec`` puts it (floor at z = 0), then its
    mesh, edges, scan and camera centres are moved by ``offset`` (dx, dy, dz) into the world.
    ``cache`` ((spec, doors, reveal) -> mesh, renderer, edges), when given, holds built rooms for
    identical rooms to share: equal specs give equal meshes and textures. ``doors``: its openings
    standing open (:func:`ldlmap.synth.scene.build_scene`, a reveal ``reveal_m`` deep), in its scan
    and its panoramas, which see ``through`` them the rooms behind (renderers with their meshes'
    origins in this room's frame).
    """
    off = np.asarray(offset, dtype=np.float64).reshape(3)
    key = built_key(spec, doors, reveal_m)
    built = cache.get(key) if cache is not None else None
    if built is None:
        mesh = build_scene(spec, open_doors=key[1], reveal_m=key[2])
        built = (mesh, Renderer(mesh), mesh_edges(mesh))
        if cache is not None:
            cache[key] = built
    mesh, renderer, edges = built
    tick(f"{label}: scan")
    pts, cols = scan.sample_scan(mesh, spec.scan, stream_rng(seed, spec, idx, "scan"), renderer=renderer)
    tick(f"{label}: changed room")
    changed = changed_spec(spec, stream_rng(seed, spec, idx, "change"))
    changed_renderer = Renderer(build_scene(changed, open_doors=key[1], reveal_m=key[2]))
    tick(f"{label}: panoramas")
    stems = write_split_panoramas(tmp, scene, spec, idx, cap, seed, renderer, changed_renderer, split_counts, tick,
                                  first_stem=first_stem, offset=off, through=through)
    return CapturedRoom(mesh=lift_mesh(mesh, off), edges=np.asarray(edges, dtype=np.float64) + off,
                        points=pts + off, colors=cols, changed=changed, queries=stems)


def built_key(spec: SceneSpec, doors: tuple[int, ...] = (), reveal_m: float = 0.0) -> tuple:
    """The key of a built room in :func:`capture_room`'s ``cache``: its spec and the doors standing open."""
    return spec, tuple(doors), float(reveal_m)


def write_union(tmp: Path, name: str, rooms: list[CapturedRoom]) -> tuple[int, SceneMesh, np.ndarray]:
    """Write scene ``name``'s scan, mesh and true lines: the union of ``rooms`` (in their order).
    Returns the scan's point count, the merged mesh and the (E, 2, 3) lines."""
    points, colors = np.concatenate([r.points for r in rooms]), np.concatenate([r.colors for r in rooms])
    (tmp / "pcd").mkdir(exist_ok=True)
    scan.write_ply(tmp / "pcd" / f"{name}.ply", points, colors)
    scan.write_txt(tmp / "pcd" / f"{name}.txt", points, colors)
    (tmp / "mesh").mkdir(exist_ok=True)
    union = merge_meshes([r.mesh for r in rooms], name)
    write_textured_obj(union, tmp / "mesh" / f"{name}.obj")
    segs = np.concatenate([r.edges for r in rooms])
    (tmp / "gt_lines").mkdir(exist_ok=True)
    write_lines(tmp / "gt_lines" / f"{name}.obj", segs)
    write_lines(tmp / "gt_lines" / f"{name}.txt", segs)
    return int(len(points)), union, segs


def generate_multiroom(out: Path, preset: str = "multiroom", seed: int = 0, rooms: int | None = None,
                       overwrite: bool = False, progress: bool = True, illumination: bool = True,
                       width: int | None = None, per_split: int | None = None,
                       params: MultiRoomParams | None = None, walk: tuple[str, ...] = (),
                       walk_step: float | None = None) -> DatasetSummary:
    """Generate a multi-room dataset into ``out`` (atomically); returns a ``DatasetSummary``.

    ``params`` (default: the preset's, with ``rooms`` overriding its room count) places the
    rooms; ``width`` and ``per_split`` (panoramas per split *per room*) override the specs.
    ``walk``: the walk captures (:mod:`ldlmap.synth.walk`), a loop in each room, room after room
    (no door joins them: each room is a jump). Same seed, same bytes.
    """
    start = time.perf_counter()
    out = Path(out)
    if params is None:
        params = multiroom_params(preset, rooms)
    elif rooms is not None:
        params = replace(params, rooms=int(rooms))
    specs, offsets = multiroom_specs(seed, params)  # bad settings fail before anything is written
    settings = [capture_settings(s.capture, width, per_split, illumination) for s in specs]
    if len({(c.width, c.height) for c in settings}) != 1:
        raise InputError("the rooms of a multi-room scene must share one panorama size")
    splits = list(BASE_SPLITS) + [v for v in ILLUMINATION_SPLITS if any(v in c.illumination for c in settings)]
    split_counts = {s: 0 for s in splits}
    total = sum(3 + sum(c.counts.values()) for c in settings) + 1
    name = SCENE
    captured, rooms_info = [], []
    first = {s: 0 for s in BASE_SPLITS}  # next image number of each split in the shared scene folder
    n_points = 0

    with dataset_output(out, overwrite) as tmp, ProgressTicks(progress, total) as tick:
        (tmp / "specs").mkdir(parents=True)
        for idx, (spec, cap, off) in enumerate(zip(specs, settings, offsets), start=1):
            room = f"{name}_room_{idx}"
            (tmp / "specs" / f"{room}.toml").write_text(dump_spec_toml(spec))
            # Every split is numbered on from the previous rooms' images (one stem, one image).
            got = capture_room(tmp, name, spec, idx, cap, seed, tick, first, split_counts, label=f"room {idx}")
            (tmp / "specs" / f"{room}_scene_2.toml").write_text(dump_spec_toml(got.changed))
            captured.append(got)
            for split in BASE_SPLITS:
                first[split] += len(got.queries.get(split, []))
            z_top = float(spec.ceiling_height)
            fp = np.asarray(spec.footprint, dtype=np.float64)
            rooms_info.append({
                "index": idx, "spec": f"specs/{room}.toml", "changed_spec": f"specs/{room}_scene_2.toml",
                "offset": [float(off[0]), float(off[1]), 0.0],
                "bounds_min": [float(x) for x in fp.min(0)] + [0.0],
                "bounds_max": [float(x) for x in fp.max(0)] + [z_top],
                "points": [n_points, n_points + int(len(got.points))], "triangles": int(got.mesh.num_triangles),
                "gt_lines": int(len(got.edges)), "queries": got.queries})
            n_points += int(len(got.points))
        tick(f"{name}: writing the union")
        points, union, segs = write_union(tmp, name, captured)
        spaces = [[WalkRoom(id=f"room{i}", scene=name, spec=spec)] for i, spec in enumerate(specs, start=1)]
        walks = write_walks(tmp, spaces, walk, seed, settings[0], split_counts, tick, walk_step) if walk else {}
        W, H = settings[0].width, settings[0].height
        scene_info = {"name": name, "points": points, "triangles": int(union.num_triangles),
                      "gt_lines": int(len(segs)), "width": W, "height": H, "rooms": rooms_info}
        meta = {"generator": SYNTH_GENERATOR, "version": GENERATOR_VERSION, "seed": int(seed), "preset": preset,
                "multiroom": asdict(params),
                "illumination": sorted({v for c in settings for v in c.illumination}),
                "layout": "omniscenes", "scenes": [scene_info],
                "splits": {s: {"images": split_counts[s]} for s in split_counts}, **({"walks": walks} if walks else {})}
        (tmp / "dataset.json").write_text(json.dumps(list_generated(tmp, meta), indent=2) + "\n")

    return DatasetSummary(out=out, seed=int(seed), scenes=[name], splits=split_counts, points={name: points},
                          width=W, height=H, seconds=time.perf_counter() - start)


def read_layout(root: str | Path, scene: str = SCENE) -> list[RoomInfo]:
    """The rooms of the multi-room ``scene`` of a generated dataset (from its ``dataset.json``)."""
    root = Path(root)
    meta = read_dataset_meta(root)
    for s in meta.get("scenes", []):
        if s.get("name") == scene:
            if "rooms" not in s:
                raise InputError(f"scene {scene} of {root} is not a multi-room scene")
            return [RoomInfo(index=int(r["index"]), spec=root / r["spec"], changed_spec=root / r["changed_spec"],
                             offset=np.asarray(r["offset"], dtype=np.float64),
                             bounds_min=np.asarray(r["bounds_min"], dtype=np.float64),
                             bounds_max=np.asarray(r["bounds_max"], dtype=np.float64),
                             points=(int(r["points"][0]), int(r["points"][1])),
                             queries={k: list(v) for k, v in r["queries"].items()})
                    for r in s["rooms"]]
    raise InputError(f"no scene {scene} in {root / 'dataset.json'}")


def room_meshes(root: str | Path, scene: str = SCENE, changed: bool = False) -> list[SceneMesh]:
    """The rooms' meshes in the world frame, rebuilt from the written specs (``changed``: scene_2)."""
    return [build_scene(load_spec(r.changed_spec if changed else r.spec)) for r in read_layout(root, scene)]
