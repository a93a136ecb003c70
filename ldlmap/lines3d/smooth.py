"""Lines on smooth surfaces: the final check that drops extracted lines across which the scanned
surface goes on, bending less than a crease (facets of a vault or of a curved wall).
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.lines3d.metrics import sample_segments
from ldlmap.lines3d.params import Lines3DParams
from ldlmap.lines3d.planes import voxel_cells

spatial = lazy_module("scipy.spatial")


def thin_points(P: np.ndarray, v: float) -> np.ndarray:
    """Indices of one point per occupied ``v`` grid cell (the first): an even, sparser surface."""
    return np.unique(voxel_cells(P, v)[1], return_index=True)[1]


def _moments(a: np.ndarray, b: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per row: count, mean (2) and central second moments (3) of the masked 2D points ``(a, b)``."""
    n = m.sum(1)
    nn = np.maximum(n, 1)
    ma, mb = (a * m).sum(1) / nn, (b * m).sum(1) / nn
    caa = ((a - ma[:, None]) ** 2 * m).sum(1) / nn
    cbb = ((b - mb[:, None]) ** 2 * m).sum(1) / nn
    cab = ((a - ma[:, None]) * (b - mb[:, None]) * m).sum(1) / nn
    return n, ma, mb, caa, cbb, cab


def _line_fit(caa: np.ndarray, cbb: np.ndarray, cab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normal (N, 2) of the 2D line fitted to points of these central moments, and the RMS
    distance of the points to it (the square root of the smaller eigenvalue)."""
    half_tr, det = (caa + cbb) / 2, caa * cbb - cab ** 2
    small = half_tr - np.sqrt(np.maximum(half_tr ** 2 - det, 0.0))
    # Eigenvector of the smaller eigenvalue: (cab, small - caa) or (small - cbb, cab), the better conditioned.
    v1 = np.stack([cab, small - caa], 1)
    v2 = np.stack([small - cbb, cab], 1)
    v = np.where((np.linalg.norm(v1, axis=1) >= np.linalg.norm(v2, axis=1))[:, None], v1, v2)
    nv = np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(nv > 1e-18, v / np.maximum(nv, 1e-18), np.array([0.0, 1.0]))
    return v, np.sqrt(np.maximum(small, 0.0))


def smooth_lines(lines: np.ndarray, points: np.ndarray, params: Lines3DParams) -> np.ndarray:
    """Mask of ``lines`` (N, 2, 3) that lie on a smooth stretch of the surface in ``points``.

    Every 5 cm along a line, the points (one per ``smooth_grid`` cell) within ``smooth_slab`` along it
    and ``smooth_reach`` across it are seen in the line's cross-section, split into two sides by
    their main direction through the line, and a straight line is fitted to each side. The sample
    is smooth when each side holds one surface (RMS under ``smooth_rms``) that passes within
    ``smooth_on`` of the line, the two meet within ``smooth_step`` of each other at the line and
    bend by less than ``smooth_crease_deg``: the surface goes on across the line without a crease
    or a step. A side with no points (a free or occluding edge), a second surface, a corner or a
    step (a frame standing out of a wall) keeps the sample an edge. Lines with at least half of
    their samples smooth are on a smooth surface.
    """
    if len(lines) == 0 or params.smooth.crease_deg <= 0:
        return np.zeros(len(lines), bool)
    Q = points[thin_points(points, params.smooth.grid)]
    r0, r1 = params.smooth.reach
    x, seg = sample_segments(lines, 0.05)
    u = lines[:, 1] - lines[:, 0]
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    a = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    k = min(params.smooth.neighbours, len(Q))
    d, j = spatial.cKDTree(Q).query(x, k=k, distance_upper_bound=np.hypot(r1, params.smooth.slab), workers=-1)
    d, j = d.reshape(len(x), -1), j.reshape(len(x), -1)
    R = Q[np.minimum(j, len(Q) - 1)] - x[:, None, :]  # (S, k, 3)
    along = np.einsum("skj,sj->sk", R, u[seg])
    pa, pb = np.einsum("skj,sj->sk", R, e1[seg]), np.einsum("skj,sj->sk", R, e2[seg])
    rad = np.hypot(pa, pb)
    m = np.isfinite(d) & (np.abs(along) <= params.smooth.slab) & (rad >= r0) & (rad <= r1)
    # The main direction of the cross-section through the line (second moments about the line).
    saa, sbb, sab = (pa * pa * m).sum(1), (pb * pb * m).sum(1), (pa * pb * m).sum(1)
    ang = 0.5 * np.arctan2(2 * sab, saa - sbb)
    side = (pa * np.cos(ang)[:, None] + pb * np.sin(ang)[:, None]) >= 0
    ok = np.ones(len(x), bool)
    nrm, off = [], []
    for s in (side, ~side):
        n, ma, mb, caa, cbb, cab = _moments(pa, pb, m & s)
        v, rms = _line_fit(caa, cbb, cab)
        nrm.append(v)
        off.append(ma * v[:, 0] + mb * v[:, 1])  # signed distance of the side's surface from the line
        ok &= (n >= params.smooth.min_points) & (rms <= params.smooth.rms) & (np.abs(off[-1]) <= params.smooth.on)
    bend_cos = np.einsum("ij,ij->i", nrm[0], nrm[1])
    step = np.abs(off[0] - np.sign(bend_cos) * off[1])  # the two surfaces' offsets, with their normals aligned
    smooth = ok & (np.abs(bend_cos) >= np.cos(np.radians(params.smooth.crease_deg))) & (step <= params.smooth.step)
    return np.bincount(seg, smooth, len(lines)) / np.bincount(seg, minlength=len(lines)) >= params.smooth.share
