"""Intersection lines of adjacent non-parallel planes and long linear pieces, clipped to where both
supports lie near the line.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.lines3d.boundaries import true_runs
from ldlmap.lines3d.params import Lines3DParams
from ldlmap.lines3d.planes import PlaneRegions

csgraph = lazy_module("scipy.sparse.csgraph")
sparse = lazy_module("scipy.sparse")


def intersection_segments(reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """Intersection lines of adjacent planes clipped to both supports (M, 2, 3)."""
    P, lab, nbr = reg.points, reg.labels, reg.neighbours
    L = len(reg.normals)
    if L < 2:
        return np.zeros((0, 2, 3))
    a = np.repeat(lab, nbr.shape[1])
    b = lab[nbr.ravel()]
    ok = (a >= 0) & (b >= 0) & (a != b)
    lo, hi = np.minimum(a[ok], b[ok]), np.maximum(a[ok], b[ok])
    pairs, counts = np.unique(lo * L + hi, return_counts=True)
    pairs = pairs[counts >= params.intersections.min_adjacent_links]
    members = reg.members
    sin_min = np.sin(np.radians(params.intersections.min_plane_angle_deg))
    cs = params.intersections.support_bin
    out = []
    for key in pairs:
        i, j = divmod(int(key), L)
        ni, nj = reg.normals[i], reg.normals[j]
        d = np.cross(ni, nj)
        s = np.linalg.norm(d)
        if s < sin_min:
            continue
        d /= s
        A = np.stack([ni, nj, d])
        x0 = np.linalg.solve(A, [ni @ reg.centroids[i], nj @ reg.centroids[j], d @ (reg.centroids[i] + reg.centroids[j]) / 2])
        occ = []
        for m in (members[i], members[j]):
            Q = P[m] - x0
            t = Q @ d
            near = np.linalg.norm(Q - t[:, None] * d, axis=1) <= params.intersections.support_dist
            occ.append(t[near])
        if len(occ[0]) == 0 or len(occ[1]) == 0:
            continue
        t0 = max(occ[0].min(), occ[1].min())
        t1 = min(occ[0].max(), occ[1].max())
        if t1 - t0 < params.merge.min_segment:
            continue
        nb = int(np.ceil((t1 - t0) / cs)) + 1
        both = np.ones(nb, bool)
        for t in occ:
            tb = np.floor((t[(t >= t0) & (t <= t1)] - t0) / cs).astype(np.int64)
            hit = np.bincount(tb, minlength=nb)[:nb] > 0
            # Close gaps of up to ``close_cells`` bins (sampling holes, not real gaps).
            gap = int(round(params.intersections.support_gap / cs))
            run = true_runs(~hit)
            for s0, s1 in run[(run[:, 1] - run[:, 0] <= gap) & (run[:, 0] > 0) & (run[:, 1] < nb)]:
                hit[s0:s1] = True
            both &= hit
        for s0, s1 in true_runs(both):
            ta, tb_ = t0 + s0 * cs, t0 + s1 * cs
            if tb_ - ta >= params.merge.min_segment:
                out.append([x0 + ta * d, x0 + tb_ * d])
    return np.asarray(out, dtype=np.float64).reshape(-1, 2, 3)


def linear_segments(reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """Segments (M, 2, 3) along thin structures: clusters of points whose neighbourhood is linear.

    Plane boundaries miss rods and strips narrower than the normal neighbourhood (table legs,
    frames); their points have one dominant covariance axis. Linear neighbours with agreeing axes
    that lie along each other's axis are linked; each connected cluster gives the segment of its
    principal axis between the 1st and 99th percentile of the projections.
    """
    if reg.axes is None or reg.linearity is None:
        return np.zeros((0, 2, 3))
    P, nbr, ax = reg.points, reg.neighbours, reg.axes
    lin = reg.linearity >= params.linear.min_linearity
    idx = np.flatnonzero(lin)
    if len(idx) < params.linear.min_linear_points:
        return np.zeros((0, 2, 3))
    n, k = nbr.shape
    i = np.repeat(idx, k)
    j = nbr[idx].ravel()
    d = P[j] - P[i]
    cos_t = np.cos(np.radians(params.linear.normal_angle_deg))
    along = np.linalg.norm(d - np.einsum("ij,ij->i", d, ax[i])[:, None] * ax[i], axis=1)
    ok = lin[j] & (np.abs(np.einsum("ij,ij->i", ax[i], ax[j])) >= cos_t) & (along <= params.linear.linear_tol)
    g = sparse.coo_matrix((np.ones(ok.sum(), np.int8), (i[ok], j[ok])), shape=(n, n))
    _, comp = csgraph.connected_components(g, directed=False)
    comp = np.where(lin, comp, -1)
    ids, cnt = np.unique(comp[comp >= 0], return_counts=True)
    out = []
    for cid in ids[cnt >= params.linear.min_linear_points]:
        Q = P[comp == cid]
        c = Q.mean(0)
        _, _, Vt = np.linalg.svd(Q - c, full_matrices=False)
        u = Vt[0]
        t = (Q - c) @ u
        off = np.linalg.norm((Q - c) - t[:, None] * u, axis=1)
        if np.percentile(off, 90) > 2 * params.linear.linear_tol:
            continue  # not a thin straight structure
        t0, t1 = np.percentile(t, [1, 99])
        if t1 - t0 >= params.merge.min_segment:
            out.append([c + t0 * u, c + t1 * u])
    return np.asarray(out, dtype=np.float64).reshape(-1, 2, 3)
