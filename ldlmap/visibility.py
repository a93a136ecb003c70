"""Which 3D lines a camera sees from each candidate translation, when the map knows its walls.

The line distance functions of the paper project every map line at a pose: in a scan of one room
that is what the camera sees, but in a map of several rooms (a floor plan, the paper's
large-scale setting) it adds the lines of every other room, seen through the walls, and from a
doorway it adds the hidden parts of the room behind the door. A room layout knows its walls
(wall quads with door and opening holes, ``Walkable.walls``), so the map stores, per candidate
translation, the lines that are not hidden (``/lines/visibility``), and the pose search leaves
the others out of the 3D distance functions.

A line is seen from ``t`` when at least ``min_fraction`` of ``samples`` points spread along it
are: the segment from ``t`` to the point crosses no wall before ``tolerance`` metres short of
the point (lines lie on walls: a ray reaching its own wall is not hidden). Rays are cast with
open3d's ``RaycastingScene`` (Embree), all translations and samples in a few large batches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.errors import InputError


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


def line_visibility(lines: np.ndarray, translations: np.ndarray, walls: np.ndarray,
                    params: VisibilityParams = VisibilityParams()) -> np.ndarray:
    """(N_t, L) bool: line ``l`` is seen from translation ``i`` (see the module docstring).

    ``lines`` (L, 2, 3), ``translations`` (N_t, 3), ``walls`` (W, 4, 3) quads; no walls: all seen.
    """
    import open3d as o3d

    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    T = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    Wq = np.asarray(walls, dtype=np.float64).reshape(-1, 4, 3)
    for name, a in (("lines", L), ("translations", T), ("walls", Wq)):
        if not np.all(np.isfinite(a)):
            raise InputError(f"visibility: {name} contain NaN or infinite values")
    if len(Wq) == 0 or len(L) == 0 or len(T) == 0:
        return np.ones((len(T), len(L)), dtype=bool)
    verts, tris = wall_triangles(Wq)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris.astype(np.uint32)))
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
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().reshape(len(t), -1)
        # Hidden: a wall crossed before (dist - tolerance); t_hit is in units of |d|.
        free = hit * dist >= dist - params.tolerance
        seen[a:a + per] = free.reshape(len(t), len(L), S).mean(-1) >= params.min_fraction - 1e-9
    return seen
