"""Random scene specs: the presets (``demo``, ``standard``; the non-box rooms ``angled``, ``sloped``,
``stepped``, ``arched``, ``curved`` and the mix ``shapes``) and the random rooms, furniture, wall
items and scene changes drawn from them; every spec is validated before it is returned.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core import polygon as pg
from ldlmap.synth.shapes import SHAPE_KINDS, random_ceiling, shape_footprint
from ldlmap.synth.spec import (FRAME_WIDTH, OBJECT_KINDS, CaptureSpec, CeilingSpec, ObjectSpec, OpeningSpec, PosterSpec,
                               ScanSpec, SceneSpec, dataclass_from_dict, object_footprint, validate_spec)


PRESETS: dict[str, dict] = {
    # Small rooms, few panoramas: the whole dataset renders in well under 2 minutes on 2 cores.
    "demo": {
        "scenes": 2,
        "size": (4.0, 6.0),  # m, room extent range
        "ceiling": (2.5, 3.0),  # m
        "objects": (3, 5),
        "doors": (1, 2),
        "windows": (1, 2),
        "posters": (1, 3),
        "non_orthogonal": 0.35,  # probability of a chamfered (non-orthogonal) corner
        "capture": {"width": 1024, "height": 512,
                    "robot": {"count": 3}, "handheld": {"count": 3}, "extreme": {"count": 3},
                    "change": {"count": 3}},
        "scan": {"density": 4000.0, "stations": 6},  # ~450-600 k points per room
    },
    "standard": {
        "scenes": 6,
        "size": (4.5, 8.0),
        "ceiling": (2.5, 3.2),
        "objects": (3, 7),
        "doors": (1, 2),
        "windows": (1, 3),
        "posters": (1, 4),
        "non_orthogonal": 0.35,
        "capture": {"width": 1024, "height": 512,
                    "robot": {"count": 10}, "handheld": {"count": 10}, "extreme": {"count": 10},
                    "change": {"count": 8}},
        "scan": {"density": 6000.0, "stations": 8},  # ~1-1.5 M points per room
    },
}

# Rooms that are not boxes (ldlmap/synth/shapes.py): demo-sized capture, one preset per kind, and
# "shapes" cycling through the kinds (scene i is kind i mod 5).
_SHAPE_BASE = {
    "scenes": 2,
    "size": (4.5, 6.5),
    "ceiling": (2.3, 2.7),  # m, the lowest ceiling (eaves, springing of a vault)
    "objects": (3, 5),
    "doors": (1, 2),
    "windows": (1, 2),
    "posters": (1, 3),
    "non_orthogonal": 0.0,
    "capture": PRESETS["demo"]["capture"],
    "scan": PRESETS["demo"]["scan"],
}
for _kind in SHAPE_KINDS:
    PRESETS[_kind] = {**_SHAPE_BASE, "shape": _kind}
PRESETS["shapes"] = {**_SHAPE_BASE, "scenes": len(SHAPE_KINDS), "shape": "mixed"}

# Rooms furnished as densely as homes, with their layout line files (ldlmap/synth/furnished.py draws
# them; only "scenes", "capture" and "scan" are read from here): kitchens, bathrooms, bedrooms and
# living rooms cycling through the shapes; cameras 1.1-2.2 m above the floor, upright within 2-3 deg.
PRESETS["furnished"] = {
    "scenes": 12,
    "shape": "furnished",
    "layout": True,
    "capture": {"width": 1024, "height": 512,
                "robot": {"count": 1, "camera_height": 1.45, "height_jitter": 0.35, "max_tilt_deg": 2.0},
                "handheld": {"count": 1, "camera_height": 1.65, "height_jitter": 0.55, "max_tilt_deg": 3.0},
                "extreme": {"count": 0}, "change": {"count": 0}, "illumination": {"enabled": False}},
    "scan": {"density": 300.0, "stations": 2, "holes": 2},  # a light scan: the preset is for layout maps
}

_OBJECT_SIZES = {  # kind -> (min (sx, sy, sz), max (sx, sy, sz)) in m
    "box": ((0.35, 0.35, 0.3), (0.8, 0.8, 0.9)),
    "table": ((0.9, 0.6, 0.7), (1.8, 1.0, 0.8)),
    "shelf": ((0.7, 0.3, 1.2), (1.4, 0.45, 2.0)),
    "cabinet": ((0.6, 0.4, 0.7), (1.4, 0.6, 1.1)),
    "sofa": ((1.4, 0.8, 0.75), (2.2, 1.0, 0.9)),
}
_AGAINST_WALL = {"shelf", "cabinet", "sofa"}


def get_preset(preset: str) -> dict:
    """The preset named ``preset``; unknown names raise :class:`InputError` listing valid ones."""
    if preset not in PRESETS:
        valid = sorted(PRESETS) + ["multiroom", "building", "building_small"]
        raise InputError(f"unknown preset {preset!r} (valid: {', '.join(valid)})")
    return PRESETS[preset]


def _footprint(rng: np.random.Generator, size: tuple[float, float], p_chamfer: float) -> np.ndarray:
    lo, hi = size
    w, d = rng.uniform(lo, hi), rng.uniform(lo, hi)
    shape = rng.choice(["rect", "L", "T", "U", "Z"], p=[0.2, 0.35, 0.15, 0.15, 0.15])
    f = lambda a, b: rng.uniform(a, b)  # noqa: E731
    if shape == "rect":
        poly = [(0, 0), (w, 0), (w, d), (0, d)]
    elif shape == "L":
        cw, cd = w * f(0.35, 0.55), d * f(0.35, 0.55)
        poly = [(0, 0), (w, 0), (w, d - cd), (w - cw, d - cd), (w - cw, d), (0, d)]
    elif shape == "T":  # wide top bar, narrower stem
        sw, sd = w * f(0.45, 0.6), d * f(0.35, 0.5)
        x0 = (w - sw) * f(0.3, 0.7)
        poly = [(x0, 0), (x0 + sw, 0), (x0 + sw, sd), (w, sd), (w, d), (0, d), (0, sd), (x0, sd)]
    elif shape == "U":  # notch in the middle of the top wall
        nw, nd = w * f(0.25, 0.4), d * f(0.2, 0.35)
        x0 = (w - nw) * f(0.35, 0.65)
        poly = [(0, 0), (w, 0), (w, d), (x0 + nw, d), (x0 + nw, d - nd), (x0, d - nd), (x0, d), (0, d)]
    else:  # "Z": two offset rectangles
        cw, cd1, cd2 = w * f(0.3, 0.45), d * f(0.25, 0.4), d * f(0.25, 0.4)
        poly = [(0, 0), (w - cw, 0), (w - cw, cd1), (w, cd1), (w, d), (cw, d), (cw, d - cd2), (0, d - cd2)]
    p = np.asarray(poly, dtype=np.float64)
    if rng.random() < p_chamfer:  # cut a convex corner with a diagonal wall
        k = len(p)
        e_in = p - np.roll(p, 1, axis=0)
        e_out = np.roll(p, -1, axis=0) - p
        convex = np.flatnonzero(e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0] > 0)
        lens_in, lens_out = np.linalg.norm(e_in, axis=1), np.linalg.norm(e_out, axis=1)
        ok = [i for i in convex if min(lens_in[i], lens_out[i]) > 1.6]
        if ok:
            i = int(rng.choice(ok))
            c1, c2 = f(0.5, 0.45 * lens_in[i]), f(0.5, 0.45 * lens_out[i])
            a = p[i] - e_in[i] / lens_in[i] * c1
            b = p[i] + e_out[i] / lens_out[i] * c2
            p = np.concatenate([p[:i], [a, b], p[i + 1:]])
            assert len(p) == k + 1
    return np.round(p, 3)


def place_object(rng: np.random.Generator, kind: str, fp: np.ndarray, ceiling: float,
                 placed: list[ObjectSpec], keep_out: list[np.ndarray], tries: int = 300,
                 sizes: tuple | None = None, against_wall: bool | None = None, gap: float = 0.35) -> ObjectSpec | None:
    """A random ``kind`` object inside footprint ``fp``, clear of ``placed`` and ``keep_out``; None after ``tries``.

    ``sizes``: ``(min (sx, sy, sz), max (sx, sy, sz))`` instead of the kind's; ``against_wall``: back
    against a wall always (True), never (False) or as the kind goes (None); ``gap``: walking space
    kept free around the object (m)."""
    lo, hi = sizes if sizes is not None else _OBJECT_SIZES[kind]
    wall_p = {True: 1.0, False: 0.0, None: 0.8 if kind in _AGAINST_WALL else 0.0}[against_wall]
    size = tuple(float(np.round(rng.uniform(a, b), 2)) for a, b in zip(lo, hi))
    size = (size[0], size[1], min(size[2], round(ceiling - 0.3, 2)))
    xmin, ymin = fp.min(axis=0)
    xmax, ymax = fp.max(axis=0)
    edges = np.roll(fp, -1, axis=0) - fp
    material = str(rng.choice({"box": ["painted", "wood", "metal"], "table": ["wood", "dark_wood", "marble"],
                               "shelf": ["wood", "dark_wood", "painted"], "cabinet": ["painted", "wood", "metal"],
                               "sofa": ["fabric", "fabric", "carpet"]}[kind]))
    for _ in range(tries):
        if wall_p > 0 and rng.random() < wall_p:
            # Back against a random wall, facing into the room (front = local -y).
            i = int(rng.integers(len(fp)))
            length = float(np.linalg.norm(edges[i]))
            if length < size[0] + 0.4:
                continue
            t = rng.uniform(0.2 + size[0] / 2, length - 0.2 - size[0] / 2)
            tangent = edges[i] / length
            inward = np.array([-tangent[1], tangent[0]])
            center = fp[i] + tangent * t + inward * (size[1] / 2 + 0.06)
            yaw = math.degrees(math.atan2(tangent[1], tangent[0])) + 180.0
        else:
            center = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
            yaw = float(rng.choice([0.0, 90.0])) + (rng.uniform(-30, 30) if rng.random() < 0.4 else 0.0)
        obj = ObjectSpec(kind, (round(float(center[0]), 3), round(float(center[1]), 3)), size,
                         round(float(yaw) % 360.0, 2), material)
        rect = object_footprint(obj)
        if not pg.convex_inside_polygon(_inflate(rect, 0.05), fp):
            continue
        walk = _inflate(rect, gap)  # keep walking space between objects
        if any(pg.convex_overlap(walk, object_footprint(o)) for o in placed):
            continue
        if any(pg.convex_overlap(rect, k) for k in keep_out):
            continue
        return obj
    return None


def _inflate(rect: np.ndarray, d: float) -> np.ndarray:
    c = rect.mean(axis=0)
    ex = rect[1] - rect[0]
    ey = rect[3] - rect[0]
    ux, uy = ex / np.linalg.norm(ex), ey / np.linalg.norm(ey)
    signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
    hx, hy = np.linalg.norm(ex) / 2 + d, np.linalg.norm(ey) / 2 + d
    return c + signs[:, :1] * ux * hx + signs[:, 1:] * uy * hy


def wall_items(rng: np.random.Generator, fp: np.ndarray, ceiling: float, counts: dict[str, int]
                ) -> tuple[list[OpeningSpec], list[PosterSpec]]:
    lengths = np.linalg.norm(np.roll(fp, -1, axis=0) - fp, axis=1)
    used: dict[int, list[tuple[float, float, float, float]]] = {}
    openings: list[OpeningSpec] = []
    posters: list[PosterSpec] = []
    for kind in ("door", "window", "poster"):
        for _ in range(counts[kind]):
            for _ in range(100):
                wall = int(rng.integers(len(fp)))
                if kind == "door":
                    w, h = rng.uniform(0.8, 1.0), min(rng.uniform(2.0, 2.2), ceiling - 0.25)
                    bottom, frame = 0.0, FRAME_WIDTH
                elif kind == "window":
                    w, h = rng.uniform(0.7, 1.6), rng.uniform(0.8, 1.3)
                    bottom = rng.uniform(0.8, 1.0)
                    h = min(h, ceiling - 0.25 - bottom)
                    frame = FRAME_WIDTH
                else:
                    w, h = rng.uniform(0.4, 1.0), rng.uniform(0.5, 1.0)
                    bottom = rng.uniform(1.0, 1.4)
                    h = min(h, ceiling - 0.15 - bottom)
                    frame = 0.0
                w, h, bottom = round(float(w), 2), round(float(h), 2), round(float(bottom), 2)
                room = lengths[wall] - w - 2 * frame - 0.3
                if room <= 0 or h < 0.3:
                    continue
                off = round(float(frame + 0.15 + rng.uniform(0, room)), 3)
                box = (off - frame - 0.1, off + w + frame + 0.1, bottom - frame, bottom + h + frame)
                if any(box[0] < o[1] and o[0] < box[1] and box[2] < o[3] and o[2] < box[3]
                       for o in used.get(wall, [])):
                    continue
                used.setdefault(wall, []).append(box)
                if kind == "poster":
                    posters.append(PosterSpec(wall, off, bottom, w, h))
                else:
                    openings.append(OpeningSpec(kind, wall, off, w, h, bottom))
                break
    return openings, posters


def door_keep_out(fp: np.ndarray, openings: list[OpeningSpec]) -> list[np.ndarray]:
    """The floor area (a quad, 0.9 m deep) before each door of ``openings``, where no furniture goes."""
    out = []
    for op in openings:
        if op.kind != "door":
            continue
        a, b = fp[op.wall], fp[(op.wall + 1) % len(fp)]
        t = (b - a) / np.linalg.norm(b - a)
        n = np.array([-t[1], t[0]])
        p0 = a + t * (op.offset - 0.1)
        p1 = a + t * (op.offset + op.width + 0.1)
        out.append(np.array([p0, p1, p1 + n * 0.9, p0 + n * 0.9]))
    return out


def _capture_from_preset(cfg: dict) -> CaptureSpec:
    return dataclass_from_dict(CaptureSpec, cfg.get("capture", {}), "capture")


def room_kind(preset: str, index: int) -> str:
    """The kind of room scene ``index`` of ``preset`` is: ``box`` (demo, standard) or one of
    :data:`~ldlmap.synth.shapes.SHAPE_KINDS` (``shapes`` cycles through them from index 1)."""
    shape = get_preset(preset).get("shape", "box")
    return SHAPE_KINDS[(int(index) - 1) % len(SHAPE_KINDS)] if shape == "mixed" else shape


def random_spec(preset: str, seed: int, index: int = 0) -> SceneSpec:
    """A random but reproducible room for ``preset``; ``(seed, index)`` selects the layout."""
    cfg = get_preset(preset)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, int(index), 0x1D1])
    shape = room_kind(preset, index)
    for _attempt in range(50):
        if shape == "box":
            fp = _footprint(rng, cfg["size"], cfg["non_orthogonal"])
        else:
            fp = shape_footprint(rng, shape, cfg["size"])
        if pg.simple_polygon_problem(fp) is None:
            break
    ceiling = round(float(rng.uniform(*cfg["ceiling"])), 2)
    # Box presets draw nothing more, so that their rooms stay the ones measured before.
    ceiling_shape = CeilingSpec() if shape == "box" else random_ceiling(rng, shape, fp, ceiling)
    counts = {"door": int(rng.integers(cfg["doors"][0], cfg["doors"][1] + 1)),
              "window": int(rng.integers(cfg["windows"][0], cfg["windows"][1] + 1)),
              "poster": int(rng.integers(cfg["posters"][0], cfg["posters"][1] + 1))}
    openings, posters = wall_items(rng, fp, ceiling, counts)
    keep_out = door_keep_out(fp, openings)
    n_obj = int(rng.integers(cfg["objects"][0], cfg["objects"][1] + 1))
    kinds = list(OBJECT_KINDS)
    objects: list[ObjectSpec] = []
    for j in range(n_obj):
        kind = ("table", "shelf", "box")[j] if j < 3 else str(rng.choice(kinds))  # variety first
        obj = place_object(rng, kind, fp, ceiling, objects, keep_out)
        if obj is not None:
            objects.append(obj)
    # Random rooms avoid strongly line-patterned large surfaces (brick): long texture lines
    # would outnumber the structural lines that a 3D scan can give (specs may still use brick).
    walls = ["plaster", "plaster", "wallpaper", "concrete"]
    floors = ["parquet", "carpet", "tiles", "carpet"]
    return room_spec(rng, cfg, f"{preset}{index:02d}", fp, ceiling, ceiling_shape, objects, openings, posters,
                     (walls, floors))


def room_spec(rng: np.random.Generator, cfg: dict, name: str, fp: np.ndarray, ceiling: float,
              ceiling_shape: CeilingSpec | None, objects: list[ObjectSpec], openings: list[OpeningSpec],
              posters: list[PosterSpec], materials: tuple[list[str], list[str]]) -> SceneSpec:
    """A random room's validated spec from its parts: the render seed and the wall and floor
    materials (one of ``materials``' walls and floors each) drawn from ``rng`` in that order, the
    capture and scan settings from the preset ``cfg``."""
    walls, floors = materials
    spec = SceneSpec(
        name=name,
        footprint=tuple((float(x), float(y)) for x, y in fp),
        ceiling_height=ceiling,
        objects=tuple(objects),
        openings=tuple(openings),
        posters=tuple(posters),
        seed=int(rng.integers(0, 2**31 - 1)),
        wall_material=str(rng.choice(walls)),
        floor_material=str(rng.choice(floors)),
        ceiling_material="ceiling",
        ceiling=ceiling_shape,
        capture=_capture_from_preset(cfg),
        scan=dataclass_from_dict(ScanSpec, cfg.get("scan", {}), "scan"),
    )
    validate_spec(spec)
    return spec


def changed_spec(spec: SceneSpec, rng: np.random.Generator) -> SceneSpec:
    """``spec`` with some furniture moved, removed and added (``spec.capture.change``); still valid."""
    ch = spec.capture.change
    fp = np.asarray(spec.footprint, dtype=np.float64)
    objects = list(spec.objects)
    keep_out = door_keep_out(fp, list(spec.openings))
    order = rng.permutation(len(objects))
    n_move = min(ch.moved, len(objects))
    for i in order[:n_move]:
        others = [o for j, o in enumerate(objects) if j != i]
        for _ in range(200):
            a = rng.uniform(0, 2 * math.pi)
            r = rng.uniform(0.3 * ch.max_shift, ch.max_shift) if ch.max_shift > 0 else 0.0
            o = objects[i]
            cand = replace(o, center=(round(o.center[0] + r * math.cos(a), 3), round(o.center[1] + r * math.sin(a), 3)),
                           yaw_deg=round((o.yaw_deg + rng.uniform(-ch.max_turn_deg, ch.max_turn_deg)) % 360.0, 2))
            rect = object_footprint(cand)
            if pg.convex_inside_polygon(rect, fp) and not any(pg.convex_overlap(rect, object_footprint(x)) for x in others):
                objects[i] = cand
                break
    removable = [int(i) for i in order[n_move:]] or [int(i) for i in order]
    remove = set(removable[:min(ch.removed, len(objects))])
    objects = [o for j, o in enumerate(objects) if j not in remove]
    for _ in range(ch.added):
        obj = place_object(rng, str(rng.choice(["box", "box", "cabinet", "table"])), fp, spec.ceiling_height,
                           objects, keep_out)
        if obj is not None:
            objects.append(obj)
    out = replace(spec, objects=tuple(objects))
    validate_spec(out)
    return out
