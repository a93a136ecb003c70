"""Which 3D lines a camera sees from each candidate translation, when the map knows its walls.

The line distance functions of the paper project every map line at a pose: in a scan of one room
that is what the camera sees, but in a map of several rooms (a floor plan, the paper's
large-scale setting) it adds the lines of every other room, seen through the walls, and from a
doorway it adds the hidden parts of the room behind the door. A room layout knows its walls
(wall quads with door and opening holes, ``Walkable.walls``), so the map stores, per candidate
translation, the lines that are not hidden (``/lines/visibility``), and the pose search leaves
the others out of the 3D distance functions.

Coverage: from a doorway, or near an opening of a room-level map, part of the view looks into
space the map does not hold (the next room). :func:`coverage_fields` records, per translation and
direction, whether a ray meets a mapped surface (walls, floors, ceilings), so that the pose search
can judge a pose on the directions its map can explain.

A line is seen from ``t`` when at least ``min_fraction`` of ``samples`` points spread along it
are: the segment from ``t`` to the point crosses no wall before ``tolerance`` metres short of
the point (lines lie on walls: a ray reaching its own wall is not hidden). Rays are cast with
open3d's ``RaycastingScene`` (Embree), all translations and samples in a few large batches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.core.polygon import triangulate_polygon
from ldlmap.map.fields3d import grid_directions

o3d = lazy_module("open3d")


@dataclass(frozen=True)
class VisibilityParams:
    """Parameters of :func:`line_visibility`."""

    samples: int = 8  # points per line (at the centres of equal parts)
    min_fraction: float = 0.5  # a line is seen when at least this share of its points are
    tolerance: float = 0.05  # metres: hits closer than this to the point do not hide it
    max_rays: int = 4_000_000  # rays per batch (memory: ~60 bytes each)


def wall_triangles(walls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (4W, 3) and triangles (2W, 3) of wall quads (W, 4, 3) given corner by corner."""
    W = np.asarray(walls, dtype=np.float64).reshape(-1, 4, 3)
    base = 4 * np.arange(len(W))[:, None]
    tris = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
    return W.reshape(-1, 3), tris


def _raycasting_scene(verts: np.ndarray, tris: np.ndarray):
    """An open3d ``RaycastingScene`` holding the triangles ``tris`` (T, 3) over ``verts`` (V, 3)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(verts, np.float32)), o3d.core.Tensor(np.asarray(tris, np.uint32)))
    return scene


def _hits(scene, rays: np.ndarray) -> np.ndarray:
    """``t_hit`` (R,) of rays (R, 6) ``(origin, direction)``: the first hit at origin + t_hit *
    direction (in units of the direction's length), inf when nothing is hit."""
    return scene.cast_rays(o3d.core.Tensor(np.asarray(rays, dtype=np.float32).reshape(-1, 6)))["t_hit"].numpy()


def line_visibility(lines: np.ndarray, translations: np.ndarray, walls: np.ndarray,
                    params: VisibilityParams = VisibilityParams()) -> np.ndarray:
    """(N_t, L) bool: line ``l`` is seen from translation ``i`` (see the module docstring).

    ``lines`` (L, 2, 3), ``translations`` (N_t, 3), ``walls`` (W, 4, 3) quads; no walls: all seen.
    """
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    T = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    Wq = np.asarray(walls, dtype=np.float64).reshape(-1, 4, 3)
    for name, a in (("lines", L), ("translations", T), ("walls", Wq)):
        if not np.all(np.isfinite(a)):
            raise InputError(f"visibility: {name} contain NaN or infinite values")
    if len(Wq) == 0 or len(L) == 0 or len(T) == 0:
        return np.ones((len(T), len(L)), dtype=bool)
    scene = _raycasting_scene(*wall_triangles(Wq))
    S = max(1, int(params.samples))
    f = (np.arange(S) + 0.5) / S
    P = L[:, None, 0] + f[None, :, None] * (L[:, None, 1] - L[:, None, 0])  # (L, S, 3)
    P = P.reshape(-1, 3)
    seen = np.empty((len(T), len(L)), dtype=bool)
    per = max(1, int(params.max_rays) // len(P))  # translations per batch
    for a in range(0, len(T), per):  # a few batches of many rays each
        t = T[a:a + per]
        d = P[None] - t[:, None]  # (c, L*S, 3)
        dist = np.linalg.norm(d, axis=-1)
        rays = np.concatenate([np.broadcast_to(t[:, None], d.shape), d], -1).reshape(-1, 6).astype(np.float32)
        hit = _hits(scene, rays).reshape(len(t), -1)
        # Hidden: a wall crossed before (dist - tolerance); t_hit is in units of |d|.
        free = hit * dist >= dist - params.tolerance
        seen[a:a + per] = free.reshape(len(t), len(L), S).mean(-1) >= params.min_fraction - 1e-9
    return seen


def room_surfaces(walls: np.ndarray, polygons, ceiling_heights) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a layout's surfaces: wall quads, and each room's floor (z = 0) and
    ceiling (its height) as triangulated polygons."""
    verts, tris = wall_triangles(walls)
    vs, ts, off = [verts], [tris], len(verts)
    for poly, h in zip(polygons, ceiling_heights):
        P = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
        tri = np.asarray(triangulate_polygon(P), dtype=np.int64).reshape(-1, 3)
        for z in (0.0, float(h)):
            vs.append(np.column_stack([P, np.full(len(P), z)]))
            ts.append(tri + off)
            off += len(P)
    return np.concatenate(vs), np.concatenate(ts)


def coverage_fields(translations: np.ndarray, verts: np.ndarray, tris: np.ndarray, rows: int = 32,
                    max_rays: int = 4_000_000) -> np.ndarray:
    """(N_t, G + 1, 2G) bool: the direction of each node (the distance fields' grid,
    :func:`ldlmap.map.fields3d.grid_directions`) seen from each translation meets a mapped surface.

    A direction that leaves the mapped space (through a door or opening of a room-level map,
    into a room the map does not hold) is not covered: no map line can explain the image there,
    and the pose search does not count it against a pose (:mod:`ldlloc.search.pose_search`).
    """
    T = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    dirs = grid_directions(rows).reshape(-1, 3)
    out = np.zeros((len(T), len(dirs)), dtype=bool)
    if len(tris) == 0:
        return out.reshape(len(T), rows + 1, 2 * rows)
    scene = _raycasting_scene(verts, tris)
    per = max(1, int(max_rays) // len(dirs))
    for a in range(0, len(T), per):
        t = T[a:a + per]
        rays = np.concatenate([np.broadcast_to(t[:, None], (len(t), len(dirs), 3)),
                               np.broadcast_to(dirs[None], (len(t), len(dirs), 3))], -1)
        hit = _hits(scene, rays)
        out[a:a + per] = np.isfinite(hit).reshape(len(t), -1)
    return out.reshape(len(T), rows + 1, 2 * rows)


def coverage_at(coverage: np.ndarray, translation_index: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Look up coverage fields (N_t, G + 1, 2G) at world directions (M, Q, 3) seen from
    ``translations[translation_index]`` (M,): (M, Q) bool, nearest node."""
    C = np.asarray(coverage)
    G = C.shape[1] - 1
    d = np.asarray(directions, dtype=np.float64)
    theta = np.arccos(np.clip(d[..., 2] / np.maximum(np.linalg.norm(d, axis=-1), 1e-12), -1.0, 1.0))
    phi = np.arctan2(d[..., 1], d[..., 0])
    i = np.clip(np.rint(theta / np.pi * G).astype(np.int64), 0, G)
    j = np.rint((phi + np.pi) / np.pi * G).astype(np.int64) % (2 * G)
    return C[np.asarray(translation_index)[:, None], i, j]
