"""Rooms furnished as densely as homes, for maps made from the room's layout alone (the
``furnished`` preset of ``ldlmap synth``).

Room ``i`` (1, 2, ...) of a seed is a kitchen, bathroom, bedroom or living room
(:data:`FUNCTIONS`, cycling) of one of the shapes :data:`SHAPES` (cycling on its own, shifted by
one every 12 rooms, so that rooms 1-24 hold every pair of a function and a shape once): a box, a
sloped, stepped or arched ceiling, a
curved wall (the generator's shapes, :mod:`ldlmap.synth.shapes`) or an apartment-like L-shaped
room. Each is filled with the furniture of its function (cabinets and counters along the walls,
beds, sofas, tables, chairs, appliances, lamps, plants as boxes of plausible sizes: at least
:data:`MIN_OBJECTS`), one door, windows and posters. :func:`layout_spec` is the same room
empty, whose true edges are the room's layout: the shell's creases only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ldlmap.core import polygon as pg
from ldlmap.synth.presets import door_keep_out, get_preset, place_object, room_spec, wall_items
from ldlmap.synth.shapes import random_ceiling, rectangle, shape_footprint
from ldlmap.synth.spec import CeilingSpec, ObjectSpec, SceneSpec

FUNCTIONS = ("kitchen", "bathroom", "bedroom", "living")
SHAPES = ("box", "sloped", "stepped", "arched", "curved", "apartment")
MIN_OBJECTS = 8  # furniture pieces per room, at least
CAMERA_BAND_M = (1.1, 2.2)  # camera heights above the floor the preset's splits stay within

_SIZE = {"kitchen": (3.0, 4.8), "bathroom": (2.4, 3.4), "bedroom": (3.2, 4.8), "living": (4.0, 6.0)}  # m

# function -> [(object kind, (min size), (max size), against a wall, how many (lo, hi))]; the
# furniture goes in this order (large first), sizes (sx, sy, sz) in m, the front along -y.
_FURNITURE: dict[str, list] = {
    "kitchen": [
        ("cabinet", (1.2, 0.6, 0.88), (2.4, 0.65, 0.92), True, (2, 3)),  # counter runs
        ("cabinet", (0.6, 0.65, 1.7), (0.8, 0.7, 1.9), True, (1, 1)),  # fridge
        ("cabinet", (0.6, 0.6, 0.85), (0.6, 0.6, 0.9), True, (1, 1)),  # stove / dishwasher
        ("shelf", (0.6, 0.3, 1.2), (1.0, 0.4, 2.0), True, (1, 2)),
        ("table", (0.8, 0.7, 0.72), (1.4, 0.9, 0.76), False, (1, 1)),
        ("box", (0.4, 0.4, 0.85), (0.45, 0.45, 1.0), False, (2, 4)),  # chairs
        ("box", (0.3, 0.3, 0.25), (0.5, 0.4, 0.4), False, (1, 2)),  # bins, crates
        ("box", (0.25, 0.25, 0.6), (0.4, 0.4, 1.4), False, (1, 2)),  # plants
    ],
    "bathroom": [
        ("box", (1.5, 0.7, 0.5), (1.7, 0.8, 0.6), True, (1, 1)),  # bathtub
        ("cabinet", (0.8, 0.8, 1.9), (0.9, 0.9, 2.0), True, (0, 1)),  # shower cabin
        ("cabinet", (0.6, 0.45, 0.8), (1.2, 0.55, 0.9), True, (1, 1)),  # vanity
        ("box", (0.38, 0.6, 0.7), (0.42, 0.7, 0.8), True, (1, 1)),  # toilet
        ("cabinet", (0.6, 0.6, 0.85), (0.6, 0.6, 0.9), True, (0, 1)),  # washing machine
        ("shelf", (0.4, 0.25, 1.0), (0.7, 0.35, 1.8), True, (1, 2)),
        ("box", (0.3, 0.3, 0.3), (0.45, 0.4, 0.6), False, (2, 3)),  # basket, bin, stool
        ("box", (0.25, 0.25, 0.5), (0.35, 0.35, 1.0), False, (1, 2)),  # plant, towel stand
    ],
    "bedroom": [
        ("box", (1.4, 2.0, 0.45), (1.8, 2.1, 0.6), True, (1, 1)),  # bed
        ("cabinet", (1.0, 0.6, 1.9), (2.0, 0.65, 2.1), True, (1, 1)),  # wardrobe
        ("box", (0.4, 0.4, 0.5), (0.5, 0.45, 0.6), True, (2, 2)),  # night stands
        ("cabinet", (0.8, 0.45, 0.8), (1.2, 0.5, 1.0), True, (1, 1)),  # dresser
        ("table", (1.0, 0.55, 0.72), (1.4, 0.7, 0.76), True, (1, 1)),  # desk
        ("box", (0.45, 0.45, 0.85), (0.5, 0.5, 1.0), False, (1, 1)),  # chair
        ("shelf", (0.6, 0.3, 1.2), (1.0, 0.4, 1.9), True, (1, 1)),
        ("box", (0.25, 0.25, 1.4), (0.35, 0.35, 1.7), False, (1, 1)),  # floor lamp
        ("box", (0.3, 0.3, 0.5), (0.45, 0.45, 1.3), False, (1, 2)),  # plants, laundry
    ],
    "living": [
        ("sofa", (1.8, 0.85, 0.8), (2.4, 1.0, 0.9), True, (1, 2)),
        ("sofa", (0.8, 0.8, 0.8), (0.95, 0.9, 0.95), False, (1, 2)),  # armchairs
        ("table", (0.9, 0.5, 0.4), (1.3, 0.7, 0.46), False, (1, 1)),  # coffee table
        ("cabinet", (1.2, 0.4, 0.45), (2.0, 0.5, 0.6), True, (1, 1)),  # TV stand
        ("shelf", (0.8, 0.3, 1.6), (1.4, 0.4, 2.1), True, (1, 2)),
        ("table", (1.2, 0.8, 0.72), (1.8, 1.0, 0.76), False, (0, 1)),  # dining table
        ("box", (0.42, 0.42, 0.85), (0.48, 0.48, 1.0), False, (0, 3)),  # chairs
        ("box", (0.25, 0.25, 1.4), (0.35, 0.35, 1.7), False, (1, 2)),  # floor lamps
        ("box", (0.3, 0.3, 0.6), (0.5, 0.5, 1.5), False, (1, 3)),  # plants
        ("box", (0.4, 0.4, 0.4), (0.6, 0.6, 0.5), False, (0, 1)),  # pouf, side table
    ],
}
_MATERIALS = {"kitchen": (["tiles", "plaster"], ["tiles", "parquet"]),
              "bathroom": (["tiles", "plaster"], ["tiles", "tiles"]),
              "bedroom": (["wallpaper", "plaster"], ["carpet", "parquet"]),
              "living": (["plaster", "wallpaper", "concrete"], ["parquet", "carpet"])}


def room_function(index: int) -> str:
    """What room ``index`` (1, 2, ...) of the preset is for: one of :data:`FUNCTIONS`."""
    return FUNCTIONS[(int(index) - 1) % len(FUNCTIONS)]


def room_shape(index: int) -> str:
    """The shape of room ``index`` (1, 2, ...): one of :data:`SHAPES` (rooms 1-24: every function
    with every shape once)."""
    k = int(index) - 1
    return SHAPES[(k + k // 12) % len(SHAPES)]


def _l_footprint(rng: np.random.Generator, size: tuple[float, float]) -> np.ndarray:
    """An apartment-like L: a room with a smaller wing (living-kitchen, hall corner)."""
    lo, hi = size
    w, d = rng.uniform(lo, hi) * 1.3, rng.uniform(lo, hi) * 1.2
    cw, cd = w * rng.uniform(0.35, 0.5), d * rng.uniform(0.35, 0.5)
    return np.round(np.array([(0, 0), (w, 0), (w, d - cd), (w - cw, d - cd), (w - cw, d), (0, d)]), 3)


def _shell(rng: np.random.Generator, shape: str, size: tuple[float, float]) -> tuple[np.ndarray, float, CeilingSpec]:
    """Footprint, lowest ceiling height and ceiling shape of a room of ``shape``."""
    for _ in range(50):
        if shape == "apartment":
            fp = _l_footprint(rng, size)
        elif shape == "box":
            fp = rectangle(rng, size)
        else:
            fp = shape_footprint(rng, shape, size)
        if pg.simple_polygon_problem(fp) is None:
            break
    ceiling = round(float(rng.uniform(2.4, 2.8)), 2)
    ceil = random_ceiling(rng, shape, fp, ceiling) if shape in ("sloped", "stepped", "arched") else CeilingSpec()
    return fp, ceiling, ceil


def _furnish(rng: np.random.Generator, function: str, fp: np.ndarray, ceiling: float,
             keep_out: list[np.ndarray]) -> list[ObjectSpec]:
    """The furniture of a ``function`` room, densely placed (0.12 m between pieces)."""
    objects: list[ObjectSpec] = []
    for kind, lo, hi, wall, (n_lo, n_hi) in _FURNITURE[function]:
        for _ in range(int(rng.integers(n_lo, n_hi + 1))):
            obj = place_object(rng, kind, fp, ceiling, objects, keep_out, tries=200, sizes=(lo, hi),
                               against_wall=wall or None, gap=0.12)
            if obj is None and wall:  # no wall long enough left: anywhere
                obj = place_object(rng, kind, fp, ceiling, objects, keep_out, tries=200, sizes=(lo, hi),
                                   against_wall=False, gap=0.12)
            if obj is not None:
                objects.append(obj)
    fillers = 0
    while len(objects) < MIN_OBJECTS and fillers < 40:  # small rooms: small boxes (bins, stools, plants)
        fillers += 1
        obj = place_object(rng, "box", fp, ceiling, objects, keep_out, tries=200,
                           sizes=((0.2, 0.2, 0.3), (0.35, 0.35, 1.0)), against_wall=False, gap=0.04)
        if obj is not None:
            objects.append(obj)
    return objects


def furnished_spec(seed: int, index: int) -> SceneSpec:
    """Room ``index`` (1, 2, ...) of the ``furnished`` preset for ``seed``: reproducible, validated."""
    cfg = get_preset("furnished")
    function, shape = room_function(index), room_shape(index)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, int(index), 0xF0F])
    fp, ceiling, ceil = _shell(rng, shape, _SIZE[function])
    counts = {"door": 1, "window": int(rng.integers(0, 3)), "poster": int(rng.integers(1, 3))}
    openings, posters = wall_items(rng, fp, ceiling, counts)
    objects = _furnish(rng, function, fp, ceiling, door_keep_out(fp, openings))
    return room_spec(rng, cfg, f"{function}{index:02d}", fp, ceiling, ceil, objects, openings, posters,
                     _MATERIALS[function])


def layout_spec(spec: SceneSpec) -> SceneSpec:
    """``spec`` emptied: no furniture, doors, windows or posters; its true edges are the layout."""
    return replace(spec, objects=(), openings=(), posters=())
