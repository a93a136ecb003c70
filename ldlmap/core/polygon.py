"""Small 2D polygon helpers for room footprints (simple polygons, metres).

Footprints have a handful of vertices, so loops over vertices are fine here; the per-point
tests are vectorized over query points.
"""

from __future__ import annotations

import numpy as np


def signed_area(poly: np.ndarray) -> float:
    """Shoelace area: positive for counter-clockwise vertex order."""
    p = np.asarray(poly, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    return 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _sides(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> tuple[float, float, float, float]:
    """Signed areas telling on which side of each segment the other's end points lie."""
    return (float(_cross2(a1 - a0, b0 - a0)), float(_cross2(a1 - a0, b1 - a0)),
            float(_cross2(b1 - b0, a0 - b0)), float(_cross2(b1 - b0, a1 - b0)))


def _straddle(d1: float, d2: float, d3: float, d4: float, eps: float) -> bool:
    return ((d1 > eps and d2 < -eps) or (d1 < -eps and d2 > eps)) and \
        ((d3 > eps and d4 < -eps) or (d3 < -eps and d4 > eps))


def segments_intersect(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray,
                       eps: float = 1e-9) -> bool:
    """True when closed segments ``a0a1`` and ``b0b1`` share at least one point."""
    a0, a1, b0, b1 = (np.asarray(x, dtype=np.float64) for x in (a0, a1, b0, b1))
    d1, d2, d3, d4 = _sides(a0, a1, b0, b1)
    if _straddle(d1, d2, d3, d4, eps):
        return True

    def on_seg(p0: np.ndarray, p1: np.ndarray, q: np.ndarray, d: float) -> bool:
        return abs(d) <= eps and min(p0[0], p1[0]) - eps <= q[0] <= max(p0[0], p1[0]) + eps and \
            min(p0[1], p1[1]) - eps <= q[1] <= max(p0[1], p1[1]) + eps

    return on_seg(a0, a1, b0, d1) or on_seg(a0, a1, b1, d2) or on_seg(b0, b1, a0, d3) or on_seg(b0, b1, a1, d4)


def segments_cross_properly(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray,
                            eps: float = 1e-9) -> bool:
    """True when the open segments cross at a single interior point of both."""
    a0, a1, b0, b1 = (np.asarray(x, dtype=np.float64) for x in (a0, a1, b0, b1))
    return _straddle(*_sides(a0, a1, b0, b1), eps)


def simple_polygon_problem(poly: np.ndarray, min_turn_deg: float = 0.5) -> str | None:
    """Why ``poly`` (K, 2) is not a usable simple polygon, or None when it is.

    Rejects fewer than 3 vertices, non-finite values, repeated vertices, (nearly) collinear
    consecutive vertices, zero area and self-intersections (edges touching other than at a
    shared corner).
    """
    p = np.asarray(poly, dtype=np.float64)
    k = len(p)
    if p.ndim != 2 or p.shape[1] != 2:
        return "must be a list of [x, y] pairs"
    if k < 3:
        return f"needs at least 3 vertices, got {k}"
    if not np.all(np.isfinite(p)):
        return "has non-finite coordinates"
    dist = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(k)
    if np.any(dist < 1e-6):
        i, j = np.argwhere(dist < 1e-6)[0]
        return f"has repeated vertices {int(i)} and {int(j)}"
    turn = corner_turns_deg(p)
    bad = np.flatnonzero((turn < min_turn_deg) | (turn > 180.0 - min_turn_deg))
    if len(bad):
        return f"vertex {int(bad[0])} is collinear with its neighbours (degenerate corner)"
    crossing = self_intersection(p)
    if crossing is not None:
        return f"is self-intersecting (edges {crossing[0]} and {crossing[1]} meet)"
    if abs(signed_area(p)) < 1e-9:
        return "has zero area"
    return None


def self_intersection(poly: np.ndarray) -> tuple[int, int] | None:
    """The first pair of edges ``(i, j)`` of ``poly`` (K, 2) that meet other than at a shared
    corner (edge i joins vertices i and i + 1), or None when the boundary does not cross itself."""
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    k = len(p)
    for i in range(k):
        a0, a1 = p[i], p[(i + 1) % k]
        for j in range(i + 1, k):
            if (j + 1) % k == i or j == (i + 1) % k:
                continue  # adjacent edges share a corner
            if segments_intersect(a0, a1, p[j], p[(j + 1) % k]):
                return i, j
    return None


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test for points (..., 2); boundary points may go either way."""
    pts = np.asarray(points, dtype=np.float64)
    p = np.asarray(poly, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    x, y = pts[..., 0, None], pts[..., 1, None]
    crosses = (p[:, 1] > y) != (q[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_int = p[:, 0] + (y - p[:, 1]) * (q[:, 0] - p[:, 0]) / (q[:, 1] - p[:, 1])
    return (np.count_nonzero(crosses & (x < x_int), axis=-1) % 2) == 1


def distance_to_boundary(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance from points (..., 2) to the polygon outline."""
    pts = np.asarray(points, dtype=np.float64)[..., None, :]
    a = np.asarray(poly, dtype=np.float64)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    t = np.clip(np.sum((pts - a) * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.min(np.linalg.norm(pts - closest, axis=-1), axis=-1)


def corner_turns_deg(poly: np.ndarray) -> np.ndarray:
    """How far the boundary turns at each corner (degrees, 0 = straight on), corner i between
    edges i - 1 and i."""
    p = np.asarray(poly, dtype=np.float64)
    e = np.roll(p, -1, axis=0) - p
    prev = np.roll(e, 1, axis=0)
    return np.degrees(np.abs(np.arctan2(prev[:, 0] * e[:, 1] - prev[:, 1] * e[:, 0], np.sum(prev * e, axis=1))))


def is_convex(poly: np.ndarray, eps: float = 1e-9) -> bool:
    """True when every corner of the simple polygon ``poly`` turns the same way (straight corners allowed)."""
    p = np.asarray(poly, dtype=np.float64)
    e = np.roll(p, -1, axis=0) - p
    f = np.roll(e, -1, axis=0)
    cross = e[:, 0] * f[:, 1] - e[:, 1] * f[:, 0]
    return bool(np.all(cross >= -eps) or np.all(cross <= eps))


def convex_inside_polygon(convex: np.ndarray, poly: np.ndarray, eps: float = 1e-7) -> bool:
    """True when the convex polygon ``convex`` lies inside simple polygon ``poly`` (touching allowed)."""
    c = np.asarray(convex, dtype=np.float64)
    p = np.asarray(poly, dtype=np.float64)
    centroid = c.mean(axis=0)
    # Shrink slightly so that corners lying on a wall count as inside.
    shrunk = centroid + (c - centroid) * (1.0 - 1e-6)
    if not np.all(points_in_polygon(shrunk, p) | (distance_to_boundary(c, p) < eps)):
        return False
    if not points_in_polygon(centroid[None], p)[0]:
        return False
    for i in range(len(c)):
        for j in range(len(p)):
            if segments_cross_properly(c[i], c[(i + 1) % len(c)], p[j], p[(j + 1) % len(p)], eps):
                return False
    # A reflex corner of the room poking into the convex shape.
    return not np.any(convex_contains(c, p, margin=eps))


def convex_contains(convex: np.ndarray, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Points (N, 2) strictly inside a counter-clockwise convex polygon (by more than ``margin``)."""
    c = np.asarray(convex, dtype=np.float64)
    if signed_area(c) < 0:
        c = c[::-1]
    e = np.roll(c, -1, axis=0) - c
    n = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.linalg.norm(e, axis=1, keepdims=True)  # outward
    d = np.einsum("pkd,kd->pk", np.asarray(points, dtype=np.float64)[:, None, :] - c[None], n)
    return np.all(d < -margin, axis=1)


def convex_overlap(a: np.ndarray, b: np.ndarray, eps: float = 1e-7) -> bool:
    """True when two convex polygons overlap with positive area (separating-axis test)."""
    for poly in (np.asarray(a, float), np.asarray(b, float)):
        e = np.roll(poly, -1, axis=0) - poly
        axes = np.stack([-e[:, 1], e[:, 0]], axis=1)
        pa, pb = np.asarray(a, float) @ axes.T, np.asarray(b, float) @ axes.T
        sep = (pa.max(axis=0) <= pb.min(axis=0) + eps * np.linalg.norm(axes, axis=1)) | \
              (pb.max(axis=0) <= pa.min(axis=0) + eps * np.linalg.norm(axes, axis=1))
        if np.any(sep):
            return False
    return True


def triangulate_polygon(poly: np.ndarray) -> np.ndarray:
    """Ear-clipping triangulation of a simple polygon (K, 2) -> (K - 2, 3) vertex indices.

    Triangles keep the polygon's orientation (counter-clockwise for a counter-clockwise input).
    """
    p = np.asarray(poly, dtype=np.float64)
    ccw = signed_area(p) > 0
    idx = list(range(len(p)))
    tris: list[tuple[int, int, int]] = []
    guard = 0
    while len(idx) > 3 and guard < 10 * len(p) ** 2:
        guard += 1
        n = len(idx)
        best = None
        for k in range(n):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % n]
            a, b, c = p[i0], p[i1], p[i2]
            cr = float(_cross2(b - a, c - b))
            if (cr <= 1e-12) if ccw else (cr >= -1e-12):
                continue  # reflex or degenerate corner
            others = [j for j in idx if j not in (i0, i1, i2)]
            tri = np.array([a, b, c]) if ccw else np.array([a, c, b])
            if others and np.any(convex_contains(tri, p[others], margin=-1e-12)):
                continue
            # Prefer well-shaped ears (largest minimum angle) for nicer triangles.
            ang = _min_angle(a, b, c)
            if best is None or ang > best[0]:
                best = (ang, k)
        if best is None:
            raise ValueError("polygon could not be triangulated (not simple?)")
        k = best[1]
        tris.append((idx[k - 1], idx[k], idx[(k + 1) % n]))
        del idx[k]
    tris.append((idx[0], idx[1], idx[2]))
    return np.asarray(tris, dtype=np.int64)


def _min_angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    def ang(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> float:
        u, v = q - p, r - p
        return float(np.arccos(np.clip(np.dot(u, v) / (np.linalg.norm(u) * np.linalg.norm(v)), -1, 1)))
    return min(ang(a, b, c), ang(b, c, a), ang(c, a, b))
