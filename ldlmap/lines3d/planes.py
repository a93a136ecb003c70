"""Planar regions of a cloud: dominant normal orientations, then per orientation the strongest
offset peaks claim their points; each plane split into kNN-connected pieces.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import icosphere_points
from ldlmap.core.lazy import lazy_module
from ldlmap.lines3d.params import Lines3DParams, check_points

csgraph = lazy_module("scipy.sparse.csgraph")
ndimage = lazy_module("scipy.ndimage")
sparse = lazy_module("scipy.sparse")
spatial = lazy_module("scipy.spatial")


def _knn(P: np.ndarray, k: int):
    """k-d tree of ``P`` (scipy ``cKDTree``), and the distances and indices (N, k) of each point's
    ``k`` nearest points, itself first: one query serves normals, the plane graph and later
    look-ups."""
    tree = spatial.cKDTree(P)
    dist, idx = tree.query(P, k=min(k, len(P)), workers=-1)
    return tree, dist.reshape(len(P), -1), idx.reshape(len(P), -1)


def _normals_and_curvature(P: np.ndarray, knn: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per point, from the covariance of its neighbourhood ``knn`` (N, k; itself included): normal,
    surface variation, main axis and linearity ``1 - lambda_1 / lambda_2``.

    The neighbourhood means of the coordinates and their products come from one sparse
    averaging matrix (first and second moments about the cloud's centroid, which keeps them
    well conditioned for scenes far from the origin).
    """
    n, k = knn.shape
    A = sparse.csr_matrix((np.full(n * k, 1.0 / k), knn.ravel(), np.arange(0, n * k + 1, k)), shape=(n, n))
    X = P - P.mean(0)
    a, b = np.triu_indices(3)
    M = A @ np.column_stack([X, X[:, a] * X[:, b]])
    m = M[:, :3]
    C = np.empty((n, 3, 3))
    C[:, a, b] = C[:, b, a] = M[:, 3:] - m[:, a] * m[:, b]
    w, V = np.linalg.eigh(C)  # ascending eigenvalues
    curv = w[:, 0] / np.maximum(w.sum(axis=1), 1e-18)
    return V[:, :, 0], curv, V[:, :, 2], 1.0 - w[:, 1] / np.maximum(w[:, 2], 1e-18)


def _plane_fits(P: np.ndarray, labels: np.ndarray, n_labels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per label least-squares plane: (centroid (L,3), normal (L,3), rms (L,), count (L,))."""
    cnt = np.bincount(labels, minlength=n_labels).astype(np.float64)
    c = np.stack([np.bincount(labels, P[:, i], n_labels) for i in range(3)], 1) / np.maximum(cnt, 1)[:, None]
    Q = P - c[labels]
    cov = np.empty((n_labels, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(labels, Q[:, i] * Q[:, j], n_labels)
    cov /= np.maximum(cnt, 1)[:, None, None]
    w, V = np.linalg.eigh(cov)
    return c, V[:, :, 0], np.sqrt(np.maximum(w[:, 0], 0.0)), cnt


@dataclass
class PlaneRegions:
    """Planar regions of a (downsampled) cloud."""

    points: np.ndarray  # (N, 3) the processed points
    labels: np.ndarray  # (N,) region index or -1
    centroids: np.ndarray  # (L, 3)
    normals: np.ndarray  # (L, 3)
    neighbours: np.ndarray  # (N, k) kNN indices used for growing
    spacing: float = 0.0  # voxel size actually used (0: no downsampling)
    axes: np.ndarray | None = None  # (N, 3) main axis of each point's neighbourhood
    linearity: np.ndarray | None = None  # (N,) 1 - lambda_1 / lambda_2 (1: points along a line)
    kdtree: object | None = None  # k-d tree of ``points`` when already built (see :attr:`tree`)

    @cached_property
    def members(self) -> list[np.ndarray]:
        """Point indices of each region (L arrays)."""
        order = np.argsort(self.labels, kind="stable")
        starts = np.searchsorted(self.labels[order], np.arange(len(self.normals) + 1))
        return [order[starts[i]:starts[i + 1]] for i in range(len(self.normals))]

    @cached_property
    def tree(self):
        """k-d tree of the points (scipy ``cKDTree``), built once for every look-up."""
        return self.kdtree if self.kdtree is not None else spatial.cKDTree(self.points)


def voxel_cells(P: np.ndarray, v: float) -> tuple[np.ndarray, np.ndarray]:
    """Grid cells (integer (N, 3)) of the points on a ``v`` grid anchored half a cell below the
    cloud's minimum (open3d's ``voxel_down_sample`` grid), and a number per cell (ordered as the
    cells' (x, y, z))."""
    q = np.floor((P - (P.min(0) - 0.5 * v)) / v).astype(np.int64)
    dims = q.max(0) + 1
    return q, (q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]


def _morton_order(q: np.ndarray) -> np.ndarray:
    """Indices that sort integer cells (N, 3) along a Z-order curve (21 bits an axis; coarser
    cells when the grid is wider): nearby cells end up nearby in memory, which makes the
    k-nearest-neighbour queries that follow several times faster."""
    q = q - q.min(0)
    shift = max(0, int(q.max()).bit_length() - 21)
    q = q >> shift
    code = np.zeros(len(q), np.int64)
    for bit in range(21):
        for ax in range(3):
            code |= ((q[:, ax] >> bit) & 1) << (3 * bit + ax)
    return np.argsort(code, kind="stable")


def canonical_order(P: np.ndarray) -> np.ndarray:
    """The points sorted by (x, y, z): every later reduction (voxel means, centroids, sums) then
    adds them in the same order whatever order the scan came in, so the lines do not depend on it."""
    return P[np.lexsort((P[:, 2], P[:, 1], P[:, 0]))]


def point_cap(P: np.ndarray, params: Lines3DParams) -> int:
    """How many points the downsampling keeps at most: ``max_points`` per ``max_points_area_m2`` of
    the scan's footprint (the product of its two largest extents), never fewer than ``max_points``:
    a room keeps the cap, a building floor of 300 m2 six times it."""
    if len(P) == 0:
        return int(params.planes.max_points)
    e = np.sort(P.max(0) - P.min(0))
    area = float(e[1] * e[2])
    return int(params.planes.max_points * max(1.0, area / max(params.planes.max_points_area_m2, 1e-9)))


def _downsample(P: np.ndarray, params: Lines3DParams) -> tuple[np.ndarray, float]:
    """Voxel-grid downsampling to at most :func:`point_cap` points: the mean of each occupied
    voxel (as open3d's ``voxel_down_sample``), in Z-order of the voxels; returns (points, voxel)."""
    if params.planes.voxel_size <= 0:
        return P, 0.0
    v = params.planes.voxel_size
    cap = point_cap(P, params)
    q, key = voxel_cells(P, v)
    for _ in range(4):
        srt = np.sort(key)
        nv = 1 + int(np.count_nonzero(srt[1:] != srt[:-1]))  # occupied voxels
        if nv <= cap:
            break
        v *= 1.03 * np.sqrt(nv / cap)
        q, key = voxel_cells(P, v)
    _, inv = np.unique(key, return_inverse=True)
    inv = inv.reshape(-1)
    nv = int(inv.max()) + 1
    cnt = np.bincount(inv, minlength=nv)
    Q = np.stack([np.bincount(inv, P[:, i], nv) for i in range(3)], 1) / cnt[:, None]
    cell = np.empty((nv, 3), np.int64)
    cell[inv] = q
    return Q[_morton_order(cell)], v


def _dominant_orientations(normals: np.ndarray, params: Lines3DParams) -> np.ndarray:
    """Plane orientations (D, 3): greedy peaks of the (sign-free) normal histogram on a sphere.

    Normals vote (with both signs) for their nearest vertex of a level-4 icosphere (~4 degree
    cells); votes are summed over ``orient_radius_deg``; the top vertex is refined to the principal
    axis of the normals within ``orient_radius_deg`` of it, those normals are removed, repeat while
    a peak holds ``min_orientation_points`` normals.
    """
    V = np.asarray(icosphere_points(4))
    tree = spatial.cKDTree(V)
    r = 2.0 * np.sin(np.radians(params.planes.orient_radius_deg) / 2.0)
    pairs = tree.query_pairs(r, output_type="ndarray")
    nv = len(V)
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(nv)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(nv)])
    S = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(nv, nv))
    _, vi = tree.query(normals)
    vj = tree.query(-V)[1][vi]  # the vertex nearest to -n: the antipode of n's (the icosphere is symmetric)
    alive = np.ones(len(normals), bool)
    votes0 = np.bincount(vi, minlength=nv) + np.bincount(vj, minlength=nv)  # of the alive normals
    # Normals bucketed by their vertex: those within an angle of d (either sign) are found among
    # the buckets of vertices within that angle plus the largest normal-to-vertex angle.
    by_vertex = np.argsort(vi, kind="stable")
    starts = np.searchsorted(vi[by_vertex], np.arange(nv + 1))
    slack = float(np.arccos(np.clip(np.einsum("ij,ij->i", normals, V[vi]).min(initial=1.0), -1.0, 1.0)))

    def near(d: np.ndarray, cos_t: float) -> np.ndarray:
        """Indices (ascending) of the alive normals with ``|n . d| >= cos_t``."""
        ang = min(float(np.arccos(cos_t)) + slack + 1e-6, np.pi / 2)
        verts = np.unique(np.concatenate(tree.query_ball_point([d, -d], 2.0 * np.sin(ang / 2.0))).astype(np.int64))
        idx = np.sort(np.concatenate([by_vertex[starts[u]:starts[u + 1]] for u in verts] + [np.zeros(0, np.int64)]))
        idx = idx[alive[idx]]
        return idx[np.abs(normals[idx] @ d) >= cos_t]

    def drop(idx: np.ndarray) -> None:
        alive[idx] = False
        votes0[:] -= np.bincount(vi[idx], minlength=nv) + np.bincount(vj[idx], minlength=nv)

    cos_r = np.cos(np.radians(params.planes.orient_radius_deg))
    cos_c = np.cos(np.radians(params.planes.orient_cone_deg))
    out: list[np.ndarray] = []
    for _ in range(params.planes.max_orientations):
        votes = S @ votes0.astype(np.float64)
        top = int(np.argmax(votes))
        if votes[top] / 2.0 < params.planes.min_orientation_points:
            break
        d = V[top]
        for _ in range(2):  # refine: principal axis of the normals near the peak
            sel = near(d, cos_r)
            if not len(sel):
                break
            w, U = np.linalg.eigh(normals[sel].T @ normals[sel])
            d = U[:, 2]
        if len(near(d, cos_r)) < params.planes.min_orientation_points:
            drop(near(V[top], cos_r))
            continue
        out.append(d)
        drop(near(d, cos_c))
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def _claim_planes(off: np.ndarray, voter: np.ndarray, free: np.ndarray, params: Lines3DParams) -> list[tuple[float, np.ndarray]]:
    """Parallel planes of one orientation, strongest first.

    ``off`` are the offsets ``x . n`` of the candidate points (normal within
    ``assign_angle_deg``), ``voter`` marks the flat ones whose normal lies within
    ``orient_cone_deg`` and ``free`` those not yet in a plane. Repeatedly: the top of the smoothed
    histogram of the free voters' offsets, if at least ``min_plane_voters`` voters lie within
    ``plane_tol``, becomes a plane (offset: mean of those voters) that claims every free candidate
    within ``plane_tol``; its voters leave the histogram. Returns ``[(offset, claimed index)]``.
    """
    if voter.sum() < params.planes.min_plane_voters:
        return []
    b = params.planes.offset_bin
    lo = off.min() - 5 * b
    bins = np.floor((off - lo) / b).astype(np.int64)
    nb = int(bins.max()) + 6
    order = np.argsort(off, kind="stable")
    srt = off[order]
    live = voter & free
    h = np.bincount(bins[live], minlength=nb).astype(np.float64)
    k = int(round(params.planes.plane_tol / b))
    out = []
    for _ in range(params.planes.max_planes_per_orientation):
        hs = ndimage.gaussian_filter1d(h, params.planes.offset_sigma / b)
        top = int(np.argmax(hs))
        cum = h[max(top - k, 0):top + k + 1].sum()
        if cum < params.planes.min_plane_voters:
            break
        c = lo + (top + 0.5) * b
        i0, i1 = np.searchsorted(srt, [c - params.planes.plane_tol / 2, c + params.planes.plane_tol / 2])
        idx = order[i0:i1]
        idx = idx[live[idx]]
        if len(idx):
            c = float(off[idx].mean())
        i0, i1 = np.searchsorted(srt, [c - params.planes.plane_tol, c + params.planes.plane_tol])
        idx = order[i0:i1]
        idx = idx[free[idx]]
        gone = idx[live[idx]]
        h -= np.bincount(bins[gone], minlength=nb)
        h[max(top - 1, 0):top + 2] = np.minimum(h[max(top - 1, 0):top + 2], 0.0)  # never the same bin twice
        free[idx] = False
        live[idx] = False
        out.append((c, idx))
    return out


def segment_planes(points: np.ndarray, params: Lines3DParams = Lines3DParams()) -> PlaneRegions:
    """Planar regions (steps 1-3 of the module docstring).

    Plane hypotheses come from the whole cloud, so that small faces (table legs, frames, shelf
    boards) are found as reliably as walls: dominant normal orientations, then per orientation
    the peaks of the histogram of offsets ``x . n``, strongest first (:func:`_claim_planes`); a
    plane claims the free points within ``plane_tol`` whose normal agrees within
    ``assign_angle_deg``; each plane is split
    into connected pieces (kNN links within ``link_dist``), pieces with fewer than
    ``min_region_points`` points are dropped, and each piece gets its own least-squares plane.
    """
    P, v = _downsample(canonical_order(check_points(points)), params)
    if len(P) < max(params.planes.normal_k, 10):
        raise InputError(f"point cloud too small for line extraction ({len(P)} points)")
    tree, dist, knn = _knn(P, max(params.planes.normal_k, params.planes.graph_k + 1))
    normals, curv, axes, linearity = _normals_and_curvature(P, knn[:, :params.planes.normal_k])
    nbr, dist = knn[:, 1:params.planes.graph_k + 1], dist[:, 1:params.planes.graph_k + 1]
    flat = curv <= params.planes.max_curvature
    D = _dominant_orientations(normals[flat], params)
    n = len(P)
    lab = np.full(n, -1)
    cos_peak = np.cos(np.radians(params.planes.orient_cone_deg))
    cos_assign = np.cos(np.radians(params.planes.assign_angle_deg))
    free = np.ones(n, bool)
    n_planes = 0
    for d in D:
        cosn = np.abs(normals @ d)
        cand = np.flatnonzero(cosn >= cos_assign)
        if len(cand) == 0:
            continue
        sub_free = free[cand]
        claimed = _claim_planes(P[cand] @ d, flat[cand] & (cosn[cand] >= cos_peak), sub_free, params)
        for _, idx in claimed:
            lab[cand[idx]] = n_planes
            n_planes += 1
        free[cand] = sub_free
    # Connected pieces of each plane.
    link = (lab[:, None] >= 0) & (lab[:, None] == lab[nbr]) & (dist <= params.planes.link_dist)
    indptr = np.concatenate([[0], np.cumsum(link.sum(1))])
    g = sparse.csr_matrix((np.ones(indptr[-1], np.int8), nbr[link], indptr), shape=(n, n))
    n_comp, comp = csgraph.connected_components(g, directed=False)
    comp = np.where(lab >= 0, comp, -1)
    sizes = np.bincount(comp[comp >= 0], minlength=n_comp)
    big = sizes >= params.planes.min_region_points
    remap = np.where(big, np.cumsum(big) - 1, -1)
    labels = np.where(comp >= 0, remap[np.maximum(comp, 0)], -1)
    L = int(big.sum())
    if L == 0:
        return PlaneRegions(P, labels, np.zeros((0, 3)), np.zeros((0, 3)), nbr, v, axes, linearity, tree)
    sel = labels >= 0
    c, nrm, rms, _ = _plane_fits(P[sel], labels[sel], L)
    good = rms <= params.planes.max_plane_rms
    remap = np.where(good, np.cumsum(good) - 1, -1)
    labels = np.where(labels >= 0, remap[np.maximum(labels, 0)], -1)
    return PlaneRegions(P, labels, c[good], nrm[good], nbr, v, axes, linearity, tree)
