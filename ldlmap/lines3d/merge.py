"""Merging collinear overlapping pieces and joining the pieces of one line across gaps."""

from __future__ import annotations

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.lines3d.params import Lines3DParams, check_lines

csgraph = lazy_module("scipy.sparse.csgraph")
sparse = lazy_module("scipy.sparse")


def merge_collinear(lines: np.ndarray, weights: np.ndarray | None = None, angle_deg: float = 5.0,
                    dist: float = 0.04, gap: float = 0.03) -> np.ndarray:
    """Merge segments that are collinear (angle, line distance) and overlap or nearly touch.

    Groups are the connected components of the "mergeable" relation. A group becomes one segment
    along the weighted mean direction through the weighted mean midpoint (only the members of
    highest weight place it), spanning the projections of all member endpoints.
    """
    L = check_lines(lines)
    n = len(L)
    if n < 2:
        return L.copy()
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    v = L[:, 1] - L[:, 0]
    length = np.linalg.norm(v, axis=1)
    d = v / np.maximum(length, 1e-12)[:, None]
    mid = L.mean(axis=1)
    cos_t = np.cos(np.radians(angle_deg))
    rows, cols = [], []
    block = max(1, int(4e6 // n))
    for s in range(0, n, block):
        ii = np.arange(s, min(n, s + block))
        cosang = np.abs(d[ii] @ d.T)  # (B, n)
        cand = np.argwhere((cosang >= cos_t) & (np.arange(n)[None, :] > ii[:, None]))
        if len(cand) == 0:
            continue
        a, b = ii[cand[:, 0]], cand[:, 1]
        # Reference = longer segment of the pair; distances of the other's endpoints to its line.
        ref = np.where(length[a] >= length[b], a, b)
        oth = np.where(ref == a, b, a)
        rel = L[oth] - L[ref][:, None, 0, :]  # (M, 2, 3)
        t = np.einsum("mkj,mj->mk", rel, d[ref])
        perp = np.linalg.norm(rel - t[..., None] * d[ref][:, None, :], axis=2).max(axis=1)
        lo, hi = t.min(axis=1), t.max(axis=1)
        overlap_gap = np.maximum(lo - length[ref], -hi)  # > 0: gap between the intervals
        ok = (perp <= dist) & (overlap_gap <= gap)
        rows.append(a[ok])
        cols.append(b[ok])
    if not rows:
        return L.copy()
    r, c = np.concatenate(rows), np.concatenate(cols)
    g = sparse.coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n, n))
    n_g, grp = csgraph.connected_components(g, directed=False)
    # Members that place the line: those with the group's highest weight.
    wmax = np.full(n_g, -np.inf)
    np.maximum.at(wmax, grp, w)
    top = w >= wmax[grp]
    # Sign-align directions to the group's longest member, average weighted by length.
    longest = np.zeros(n_g, np.int64)
    order = np.lexsort((length, grp))
    longest[grp[order]] = order  # last write per group = longest
    sgn = np.sign(np.einsum("ij,ij->i", d, d[longest[grp]]))
    sgn[sgn == 0] = 1
    wl = np.where(top, length, 0.0)
    D = np.zeros((n_g, 3))
    M = np.zeros((n_g, 3))
    np.add.at(D, grp, (sgn * wl)[:, None] * d)
    np.add.at(M, grp, wl[:, None] * mid)
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    M /= np.bincount(grp, wl, n_g)[:, None]
    t = np.einsum("ikj,ij->ik", L - M[grp][:, None, :], D[grp])
    tmin = np.full(n_g, np.inf)
    tmax = np.full(n_g, -np.inf)
    np.minimum.at(tmin, grp, t.min(axis=1))
    np.maximum.at(tmax, grp, t.max(axis=1))
    return np.stack([M + tmin[:, None] * D, M + tmax[:, None] * D], axis=1)


def join_lines(lines: np.ndarray, params: Lines3DParams = Lines3DParams()) -> np.ndarray:
    """Final join: pieces of one line (same plane-plane intersection or boundary, broken by
    sampling holes or occluders) become one segment, and short noise pieces are dropped.

    Collinear pieces (``join_angle_deg``, ``join_dist``) whose gap along the line is at most
    ``join_gap`` are merged (:func:`merge_collinear`, longer pieces place the line); joined lines
    shorter than ``min_line`` are dropped, as a line detector would not report them.
    """
    L = check_lines(lines)
    if len(L) == 0:
        return L.copy()
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    out = merge_collinear(L, length, params.merge.join_angle_deg, params.merge.join_dist, params.merge.join_gap)
    return out[np.linalg.norm(out[:, 1] - out[:, 0], axis=1) >= max(params.merge.min_line, params.merge.min_segment)]
