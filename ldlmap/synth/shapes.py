"""Rooms that are not boxes, for the shape presets: angled walls, curved walls, and the random
sloped, stepped and vaulted ceilings (:class:`~ldlmap.synth.spec.CeilingSpec`).

Each function draws from a numpy generator so that a preset's ``(seed, index)`` fixes the room.
"""

from __future__ import annotations

import math

import numpy as np

from ldlmap.core import polygon as pg
from ldlmap.synth.spec import CeilingSpec

SHAPE_KINDS = ("angled", "sloped", "stepped", "arched", "curved")
_TURNS_DEG = (30.0, 45.0, 60.0, 90.0, 120.0)  # exterior turns of angled rooms: walls 150..60 deg apart
ARC_STEP_M = 0.3  # curved walls: facet length; each facet turns < 20 deg, the generator's crease angle,
# so an arc gives no vertical "true edges" (it has no straight crease to see)
MAX_TOP_M = 5.5  # highest ceiling point of a random sloped room (an attic's ridge, not a church)


def _round(p: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(p, dtype=np.float64), 3)


def rectangle(rng: np.random.Generator, size: tuple[float, float]) -> np.ndarray:
    """An axis-aligned rectangle with sides drawn from ``size`` (m)."""
    w, d = rng.uniform(*size), rng.uniform(*size)
    return _round([(0, 0), (w, 0), (w, d), (0, d)])


def angled_footprint(rng: np.random.Generator, size: tuple[float, float]) -> np.ndarray:
    """A convex room of 5-8 walls whose corners turn by 30, 45, 60, 90 or 120 degrees (at least
    one not 90: walls at 30/45/60 degrees to each other), extent within ``size`` (+30 %)."""
    lo, hi = size
    for _ in range(2000):
        k = int(rng.integers(5, 9))
        turns = rng.choice(_TURNS_DEG, size=k)
        if abs(turns.sum() - 360.0) > 1e-9 or np.all(turns == 90.0):
            continue
        heading = math.radians(rng.uniform(0, 360)) + np.radians(np.concatenate([[0.0], np.cumsum(turns[:-1])]))
        u = np.stack([np.cos(heading), np.sin(heading)], axis=1)
        lengths = rng.uniform(0.25 * lo, 0.6 * hi, size=k)
        # The last two walls close the loop: solve their lengths.
        rest = -(lengths[:-2, None] * u[:-2]).sum(axis=0)
        a = np.stack([u[-2], u[-1]], axis=1)
        if abs(np.linalg.det(a)) < 0.2:
            continue
        lengths[-2:] = np.linalg.solve(a, rest)
        if lengths.min() < 1.0:
            continue
        pts = np.concatenate([[np.zeros(2)], np.cumsum(lengths[:-1, None] * u[:-1], axis=0)])
        extent = np.ptp(pts, axis=0)
        if extent.min() < lo or extent.max() > 1.3 * hi:
            continue
        return _round(pts - pts.min(axis=0))
    raise RuntimeError("no angled footprint found")  # unreachable for the presets' sizes


def _arc(center: np.ndarray, radius: float, a0: float, a1: float) -> np.ndarray:
    """Points on a circle from angle a0 to a1 (radians, counter-clockwise), ends included."""
    n = max(2, int(math.ceil(abs(a1 - a0) * radius / ARC_STEP_M)))
    a = np.linspace(a0, a1, n + 1)
    return center + radius * np.stack([np.cos(a), np.sin(a)], axis=1)


def curved_footprint(rng: np.random.Generator, size: tuple[float, float]) -> np.ndarray:
    """A room with curved walls as fine polygons: a rectangle with one wall bowed out (a bay), a
    rectangle with one rounded corner, or a round room (a stairwell)."""
    w, d = rng.uniform(*size), rng.uniform(*size)
    kind = rng.choice(["bay", "corner", "round"], p=[0.4, 0.4, 0.2])
    if kind == "bay":  # the top wall bows out by a sagitta of 0.6-1.4 m
        sag = rng.uniform(0.6, 1.4)
        r = (w * w / 4 + sag * sag) / (2 * sag)
        c = np.array([w / 2, d + sag - r])
        half = math.asin(w / 2 / r)
        top = _arc(c, r, math.pi / 2 - half, math.pi / 2 + half)
        top[0], top[-1] = (w, d), (0.0, d)  # the arc's ends are the rectangle's top corners exactly
        pts = np.concatenate([[(0.0, 0.0), (w, 0.0)], top])
    elif kind == "corner":  # the top-right corner rounded with radius 1.2-2 m
        r = min(rng.uniform(1.2, 2.0), 0.6 * min(w, d))
        arc = _arc(np.array([w - r, d - r]), r, 0.0, math.pi / 2)
        pts = np.concatenate([[(0.0, 0.0), (w, 0.0)], arc, [(0.0, d)]])
    else:
        r = 0.5 * min(w, d)
        pts = _arc(np.array([r, r]), r, 0.0, 2 * math.pi)[:-1]
    keep = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1) > 1e-6
    return _round(pts[keep])


def _wall_heading_deg(rng: np.random.Generator, fp: np.ndarray) -> float:
    """The direction of one of the room's longer walls (ceilings slope along or across walls)."""
    e = np.roll(fp, -1, axis=0) - fp
    lengths = np.linalg.norm(e, axis=1)
    i = int(rng.choice(np.flatnonzero(lengths >= 0.5 * lengths.max())))
    a = math.degrees(math.atan2(e[i, 1], e[i, 0])) + float(rng.choice([0.0, 90.0]))
    return round(a % 180.0, 2)


def random_ceiling(rng: np.random.Generator, kind: str, fp: np.ndarray, height: float) -> CeilingSpec:
    """A random ceiling for room kind ``kind`` (flat for angled and curved rooms)."""
    direction = _wall_heading_deg(rng, fp)
    a = math.radians(direction)
    width = float(np.ptp(fp @ np.array([math.cos(a), math.sin(a)])))
    if kind == "sloped":
        shape = str(rng.choice(["shed", "gable"], p=[0.4, 0.6]))
        run = width if shape == "shed" else width / 2  # horizontal run of one slope
        cap = math.degrees(math.atan((MAX_TOP_M - height) / run))
        slope = round(float(min(rng.uniform(15.0, 45.0), max(cap, 15.0))), 1)
        return CeilingSpec(shape, direction_deg=direction, slope_deg=slope)
    if kind == "stepped":
        return CeilingSpec("stepped", direction_deg=direction, step=round(float(rng.uniform(0.3, 0.7)), 2),
                           step_at=round(float(rng.uniform(0.3, 0.7)), 2))
    if kind == "arched":
        return CeilingSpec("vault", direction_deg=direction, rise=round(float(rng.uniform(0.5, 1.2)), 2),
                           segments=int(rng.integers(10, 17)))
    return CeilingSpec()


def shape_footprint(rng: np.random.Generator, kind: str, size: tuple[float, float]) -> np.ndarray:
    """The footprint of a room of kind ``kind`` (one of :data:`SHAPE_KINDS`)."""
    if kind == "angled":
        return angled_footprint(rng, size)
    if kind == "curved":
        return curved_footprint(rng, size)
    if kind == "sloped" and rng.random() < 0.3:  # attics under angled walls too
        return angled_footprint(rng, size)
    return rectangle(rng, size)


def classify_room(spec) -> str:
    """What kind of room a scene spec is: its ceiling's (sloped, stepped, arched), else ``curved``
    (a wall corner turning < 20 deg), ``angled`` (a corner that is not a right angle), or ``box``."""
    c = spec.ceiling.kind
    if c != "flat":
        return {"shed": "sloped", "gable": "sloped", "stepped": "stepped", "vault": "arched"}[c]
    turn = pg.corner_turns_deg(spec.footprint)
    if np.any(turn < 20.0):
        return "curved"
    return "angled" if np.any(np.abs(turn - 90.0) > 1.0) else "box"
