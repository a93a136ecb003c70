"""Ceilings that are not flat: shed (single slope), gable, stepped and vaulted (segmental barrel).

A ceiling's height varies along one horizontal axis ``d`` (``CeilingSpec.direction_deg``): it is a
piecewise-linear function of ``s = d . (x, y)``, held as knots ``s_k`` with the height reached from
the left (``h_left``) and from the right (``h_right``) of each knot; a step is a knot where the two
differ. Every piece is planar, so the mesh's faces stay planar and the true creases are where the
pieces meet (the ridge of a gable, the facets of a vault, the edges of a step).

``ceiling_height`` of the spec is the lowest ceiling (the eaves); walls rise to the ceiling above
them. Non-flat ceilings need a convex footprint (each strip between two knots is then one polygon).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ldlmap.core import polygon as pg
from ldlmap.core.errors import InputError

CEILING_KINDS = ("flat", "shed", "gable", "stepped", "vault")


@dataclass(frozen=True)
class CeilingProfile:
    """Heights along ``direction``: knots ``s`` (ascending) with left/right heights (metres)."""

    direction: np.ndarray  # (2,) unit vector in the floor plane
    s: np.ndarray  # (M,) knot positions along direction, M >= 2, first/last = the footprint's extent
    h_left: np.ndarray  # (M,) height approached from smaller s
    h_right: np.ndarray  # (M,) height approached from larger s

    def piece(self, j: int) -> tuple[float, float]:
        """``(a, b)`` of piece ``j`` (between knots j and j + 1): ``h = a + b s``."""
        s0, s1 = self.s[j], self.s[j + 1]
        b = (self.h_left[j + 1] - self.h_right[j]) / (s1 - s0)
        return float(self.h_right[j] - b * s0), float(b)

    @property
    def top(self) -> float:
        """The highest point of the ceiling."""
        return float(max(self.h_left.max(), self.h_right.max()))


def ceiling_profile(ceiling, footprint: np.ndarray, height: float) -> CeilingProfile:
    """The profile of ``ceiling`` (a :class:`~ldlmap.synth.spec.CeilingSpec`) over ``footprint``
    (V, 2) with lowest height ``height``."""
    a = math.radians(ceiling.direction_deg)
    d = np.array([math.cos(a), math.sin(a)])
    s = np.asarray(footprint, dtype=np.float64) @ d
    s0, s1 = float(s.min()), float(s.max())
    width, mid = s1 - s0, 0.5 * (s0 + s1)
    tan = math.tan(math.radians(ceiling.slope_deg))
    if ceiling.kind == "flat":
        knots, hl, hr = [s0, s1], [height, height], [height, height]
    elif ceiling.kind == "shed":
        top = height + tan * width
        knots, hl, hr = [s0, s1], [height, top], [height, top]
    elif ceiling.kind == "gable":
        ridge = height + tan * width / 2
        knots, hl, hr = [s0, mid, s1], [height, ridge, height], [height, ridge, height]
    elif ceiling.kind == "stepped":
        split = s0 + ceiling.step_at * width
        high = height + ceiling.step
        knots, hl, hr = [s0, split, s1], [high, high, height], [high, height, height]
    elif ceiling.kind == "vault":  # segmental arch of the given rise over the whole width
        rise = ceiling.rise
        radius = (width * width / 4 + rise * rise) / (2 * rise)
        knots = list(np.linspace(s0, s1, ceiling.segments + 1))
        hk = [height + rise - radius + math.sqrt(max(radius * radius - (k - mid) ** 2, 0.0)) for k in knots]
        hk[0] = hk[-1] = height
        hl = hr = hk
    else:
        raise InputError(f"unknown ceiling kind {ceiling.kind!r} (valid: {', '.join(CEILING_KINDS)})")
    return CeilingProfile(d, np.asarray(knots, float), np.asarray(hl, float), np.asarray(hr, float))


def _clip(poly: np.ndarray, d: np.ndarray, c: float, keep_above: bool) -> np.ndarray:
    """The part of convex ``poly`` (K, 2) with ``d . p >= c`` (or ``<= c``)."""
    sign = 1.0 if keep_above else -1.0
    v = sign * (poly @ d - c)
    out = []
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if v[i] >= 0:
            out.append(poly[i])
        if (v[i] >= 0) != (v[j] >= 0):
            t = v[i] / (v[i] - v[j])
            out.append(poly[i] + t * (poly[j] - poly[i]))
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _dedupe(loop: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    keep = np.linalg.norm(loop - np.roll(loop, -1, axis=0), axis=1) > tol
    return loop[keep]


def ceiling_pieces(profile: CeilingProfile, footprint: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The planar ceiling faces: ``(loop (K, 3), downward normal (3,))`` per piece between knots."""
    fp = np.asarray(footprint, dtype=np.float64)
    d = profile.direction
    if len(profile.s) == 2:  # one piece: the whole footprint (any shape)
        a, b = profile.piece(0)
        normal = np.array([b * d[0], b * d[1], -1.0])
        return [(np.column_stack([fp, a + b * (fp @ d)]), normal / np.linalg.norm(normal))]
    out = []
    for j in range(len(profile.s) - 1):
        strip = _clip(_clip(fp, d, profile.s[j], True), d, profile.s[j + 1], False)
        strip = _dedupe(strip)
        if len(strip) < 3 or abs(pg.signed_area(strip)) < 1e-9:
            continue
        a, b = profile.piece(j)
        z = a + b * (strip @ d)
        normal = np.array([b * d[0], b * d[1], -1.0])
        out.append((np.column_stack([strip, z]), normal / np.linalg.norm(normal)))
    return out


def step_faces(profile: CeilingProfile, footprint: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Vertical faces at the steps, ``(loop (4, 3), normal)``, facing the higher side (the room
    below it sees them)."""
    fp = np.asarray(footprint, dtype=np.float64)
    d = profile.direction
    out = []
    for j in range(1, len(profile.s) - 1):
        lo, hi = sorted((profile.h_left[j], profile.h_right[j]))
        if hi - lo < 1e-9:
            continue
        chord = _chord(fp, d, profile.s[j])
        if chord is None:
            continue
        p, q = chord
        loop = np.array([[p[0], p[1], lo], [q[0], q[1], lo], [q[0], q[1], hi], [p[0], p[1], hi]])
        toward_high = -d if profile.h_left[j] > profile.h_right[j] else d
        out.append((loop, np.array([toward_high[0], toward_high[1], 0.0])))
    return out


def wall_loop(profile: CeilingProfile, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The wall from ``a`` to ``b`` (2D) as a planar loop: floor edge, then its top following the
    ceiling back from ``b`` to ``a`` (one corner per knot crossed, two at a step)."""
    d = profile.direction
    sa, sb = float(a @ d), float(b @ d)
    top = [(0.0, _height_toward(profile, sa, sb - sa))]
    if abs(sb - sa) > 1e-12:
        inner = [j for j in range(1, len(profile.s) - 1) if min(sa, sb) + 1e-9 < profile.s[j] < max(sa, sb) - 1e-9]
        inner.sort(key=lambda j: (profile.s[j] - sa) / (sb - sa))
        for j in inner:
            t = (profile.s[j] - sa) / (sb - sa)
            first, second = (profile.h_left[j], profile.h_right[j]) if sb > sa else (profile.h_right[j], profile.h_left[j])
            top.append((t, first))
            if abs(second - first) > 1e-9:
                top.append((t, second))
    top.append((1.0, _height_toward(profile, sb, sa - sb)))
    pts = [np.array([a[0], a[1], 0.0]), np.array([b[0], b[1], 0.0])]
    for t, h in reversed(top):
        p = (1.0 - t) * a + t * b  # exactly a and b at the ends
        pts.append(np.array([p[0], p[1], h]))
    return np.asarray(pts)


def _height_toward(profile: CeilingProfile, s: float, direction: float) -> float:
    """The height at ``s`` on the side of ``s + direction`` (the piece a wall runs into)."""
    j = int(np.clip(np.searchsorted(profile.s, s + 1e-9 * np.sign(direction), side="right") - 1,
                    0, len(profile.s) - 2))
    a, b = profile.piece(j)
    return a + b * s


def _chord(poly: np.ndarray, d: np.ndarray, c: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the line ``d . p = c`` crosses convex ``poly``: its two end points (None: it misses)."""
    v = poly @ d - c
    pts = []
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if (v[i] < 0) != (v[j] < 0):
            t = v[i] / (v[i] - v[j])
            pts.append(poly[i] + t * (poly[j] - poly[i]))
    return (pts[0], pts[1]) if len(pts) == 2 else None

