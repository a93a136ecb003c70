"""3D line segments from an unorganized point cloud (DESIGN.md 5.1, paper sec. 3.1).

An equivalent of Lu Xiaohu et al. 2019 ("Fast 3D line segment detection from unorganized point
cloud") on numpy / scipy / open3d / OpenCV:

1. voxel downsampling (``voxel_size``) when the cloud is denser than that;
2. normals and surface variation ``lambda_0 / (lambda_0 + lambda_1 + lambda_2)`` from k-nearest
   neighbour covariances (open3d);
3. planar regions (robust to scan noise, down to 8 cm faces): dominant normal orientations
   (greedy peaks of the sign-free normal histogram on an icosphere), then per orientation the
   strongest peaks of the histogram of offsets ``x . n`` claim, strongest first, every point
   within ``plane_tol`` whose normal agrees; each plane is split into kNN-connected pieces and
   each piece gets a least-squares plane. Offsets pool all points of a plane, so a table leg's
   face or a frame 4 cm in front of a wall is found although few of its points have a clean
   normal;
4. per plane: points projected to 2D plane coordinates, rasterised to an occupancy image
   (``cell_size``), morphologically closed, boundary contours approximated by polygons
   (Douglas-Peucker) whose sides are lifted back to 3D; sides with no other surface nearby
   (rims of occlusion shadows and of the scan's reach, not edges of the scene) are dropped
   unless the scene was scanned past them on both sides of the plane (an object's edge whose
   other face is hidden, :func:`_seen_past`), and so are sides across which the surface goes on
   in nearly the same plane (facets of a curved wall); long sides along a structural direction
   regain the length the raster's rounded corners took (:func:`_extend_sides`);
   narrow pieces (``strip_width``: a table leg, the front of a shelf board, the side of a table
   top) give both long sides directly, placed by percentiles of their points, since one of the
   two faces at such an edge is often never scanned;
5. intersection lines of adjacent, non-parallel planes, clipped to where both supports lie near
   the line;
6. merge of collinear overlapping pieces (intersection lines, being more accurate, fix the
   position of the merged segment), then a final join of the pieces of one line across gaps up
   to ``join_gap`` and removal of short noise pieces (:func:`join_lines`), so that long edges
   come out whole and the raw output holds what a line detector reports.

Then the paper's length filter (:func:`filter_by_length`) drops segments shorter than
``lambda (b_x + b_y + b_z) / 3`` of the scene's robust box (:func:`robust_bounds`), optionally
keeping at least / at most a number of the longest lines. :func:`line_precision_recall` measures
extracted segments against true edges.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ldlmap.errors import InputError


@dataclass(frozen=True)
class Lines3DParams:
    """Parameters of :func:`extract_lines` (metres and degrees)."""

    voxel_size: float = 0.01  # downsampling grid; 0 disables it
    max_points: int = 400_000  # the grid grows (surfaces: ~ 1 / voxel^2) until at most this many remain
    normal_k: int = 16  # neighbours for normals and surface variation
    graph_k: int = 10  # neighbours linked into connected plane pieces
    max_curvature: float = 0.06  # surface variation above which a point does not vote for planes
    orient_radius_deg: float = 6.0  # plane orientations: vote smoothing radius
    orient_cone_deg: float = 15.0  # normals this close to a found orientation belong to it
    min_orientation_points: int = 60  # smallest normal cluster that makes an orientation
    max_orientations: int = 60  # at most this many orientations
    offset_bin: float = 0.002  # histogram bin of plane offsets x . n
    offset_sigma: float = 0.004  # smoothing of the offset histogram (about the scan noise)
    max_planes_per_orientation: int = 300  # at most this many parallel planes per orientation
    assign_angle_deg: float = 35.0  # a point joins a plane when its normal is within this angle ...
    plane_tol: float = 0.015  # ... and it lies this close to the plane
    link_dist: float = 0.08  # neighbours farther apart than this do not connect plane pieces
    min_region_points: int = 40  # smallest planar piece kept
    min_plane_voters: int = 20  # flat points (clean normal) needed to start a plane hypothesis
    max_plane_rms: float = 0.02  # pieces less planar than this RMS are not planes
    cell_size: float = 0.025  # raster cell of the per-plane occupancy images
    close_cells: int = 2  # closing radius (cells) that bridges sampling gaps
    poly_eps: float = 0.03  # Douglas-Peucker tolerance of boundary polygons
    min_segment: float = 0.08  # raw pieces shorter than this are dropped before merging
    min_plane_angle_deg: float = 20.0  # planes meeting at a smaller angle give no intersection
    support_dist: float = 0.05  # points this close to an intersection line support it
    support_bin: float = 0.05  # bins along an intersection line that need support from both planes
    support_gap: float = 0.25  # unsupported stretches up to this long are bridged (sparse scans)
    min_adjacent_links: int = 5  # kNN links needed between two planes to call them adjacent
    min_linearity: float = 0.7  # thin structures (legs, rails, frames): 1 - lambda_1 / lambda_2 above this
    min_linear_points: int = 12  # smallest cluster of linear points that gives a segment
    normal_angle_deg: float = 12.0  # linear structures: max axis difference of linked neighbours
    linear_tol: float = 0.025  # linear structures: max offset of linked neighbours from the axis
    merge_angle_deg: float = 5.0  # collinear pieces: direction difference ...
    merge_dist: float = 0.04  # ... distance between the lines ...
    merge_gap: float = 0.03  # ... and largest gap along the line to still merge
    edge_radius: float = 0.06  # boundary sides need points of another surface this close ...
    edge_support: float = 0.3  # ... along this fraction of their length (else: occlusion shadow)
    extend_sides: bool = True  # lengthen boundary sides over the corners rounded by the raster
    see_past: bool = True  # keep unsupported sides past which the scene was scanned on both sides
    strip_width: float = 0.12  # planes narrower than this (legs, board fronts, frame sides) give both long sides
    join_angle_deg: float = 3.0  # final join of collinear pieces of one line: direction difference ...
    join_dist: float = 0.03  # ... distance between the lines ...
    join_gap: float = 0.25  # ... and largest gap along the line bridged
    min_line: float = 0.1  # joined lines shorter than this are dropped (noise pieces)
    lam: float = 0.1  # lambda: length filter ratio of the paper (sec. 3.1)


# ------------------------------------------------------------------------------------ validation


def _check_points(points: np.ndarray) -> np.ndarray:
    P = np.asarray(points)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"point cloud must have shape (N, 3), got {P.shape}")
    if len(P) == 0:
        raise InputError("point cloud is empty")
    P = P.astype(np.float64, copy=False)
    if not np.all(np.isfinite(P)):
        raise InputError("point cloud contains NaN or infinite coordinates")
    return P


def _check_lines(lines: np.ndarray) -> np.ndarray:
    L = np.asarray(lines, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (2, 3):
        raise InputError(f"lines must have shape (N, 2, 3), got {L.shape}")
    if not np.all(np.isfinite(L)):
        raise InputError("lines contain NaN or infinite coordinates")
    return L


# --------------------------------------------------------------------------------- length filter


def robust_bounds(points: np.ndarray, percentiles: tuple[float, float] = (2.0, 98.0),
                  margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Box (min, max) of the bulk of ``points`` (N, 3): the extremes of the points that lie, on
    every axis, within ``margin`` of the ``percentiles``' span beyond them.

    A scan or line map has its walls at the extremes, so a clean one gets its full bounding box
    (the paper's); a few far outlier points or segments (SfM) fall outside and are ignored.
    """
    P = _check_points(points)
    lo, hi = np.percentile(P, percentiles, axis=0)
    pad = margin * (hi - lo)
    inside = np.all((P >= lo - pad) & (P <= hi + pad), axis=1)
    return (P[inside].min(0), P[inside].max(0)) if inside.any() else (lo, hi)


def length_threshold(bounds_min: np.ndarray, bounds_max: np.ndarray, lam: float = 0.1) -> float:
    """The paper's length threshold ``lambda (b_x + b_y + b_z) / 3`` for a bounding box."""
    b = np.asarray(bounds_max, dtype=np.float64) - np.asarray(bounds_min, dtype=np.float64)
    if b.shape != (3,) or not np.all(np.isfinite(b)) or np.any(b < 0):
        raise InputError("bounding box must be two finite 3-vectors with max >= min")
    return float(lam * b.sum() / 3.0)


def filter_by_length(lines: np.ndarray, bounds_min: np.ndarray, bounds_max: np.ndarray, lam: float = 0.1,
                     min_keep: int = 0, max_keep: int | None = None,
                     min_length_share: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Drop segments shorter than ``lam * (b_x + b_y + b_z) / 3`` (paper, lambda = 0.1).

    Floor and cap, for maps the paper's threshold does not fit: keep at least ``min(min_keep, N)``
    lines and at least the longest lines holding ``min_length_share`` of the total line length
    (a dense SfM map of short pieces keeps almost nothing under the threshold), and at most
    ``max_keep`` (huge maps), the longest first; the returned threshold is then the shortest
    kept length. Returns ``(kept_lines (M, 2, 3), kept_mask (N,) bool, threshold)``; the kept
    ratio that the 2D filter matches is ``kept_mask.mean()``.
    """
    L = _check_lines(lines)
    thr = length_threshold(bounds_min, bounds_max, lam)
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    mask = length >= thr
    order = np.argsort(-length, kind="stable")
    floor = min(int(min_keep), len(L))
    if min_length_share > 0 and len(L):
        share = np.cumsum(length[order]) / max(float(length.sum()), 1e-300)
        floor = max(floor, min(int(np.searchsorted(share, min(min_length_share, 1.0) - 1e-12)) + 1, len(L)))
    if mask.sum() < floor:
        mask[order[:floor]] = True
        thr = float(length[order[floor - 1]])
    if max_keep is not None and mask.sum() > max_keep:
        if max_keep < 1:
            raise InputError(f"max_keep must be >= 1, got {max_keep}")
        mask = np.zeros(len(L), bool)
        mask[order[:max_keep]] = True
        thr = float(length[order[max_keep - 1]])
    return L[mask], mask, thr


# ------------------------------------------------------------------------------ plane detection


def _neighbours(P: np.ndarray, k: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    k = min(k + 1, len(P))
    _, idx = cKDTree(P).query(P, k=k, workers=-1)
    return idx[:, 1:] if k > 1 else idx[:, :0]


def _normals_and_curvature(P: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per point: normal, surface variation, main axis and linearity ``1 - lambda_1 / lambda_2``."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pcd.estimate_covariances(o3d.geometry.KDTreeSearchParamKNN(knn=int(k)))
    C = np.asarray(pcd.covariances)
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

    @cached_property
    def members(self) -> list[np.ndarray]:
        """Point indices of each region (L arrays)."""
        order = np.argsort(self.labels, kind="stable")
        starts = np.searchsorted(self.labels[order], np.arange(len(self.normals) + 1))
        return [order[starts[i]:starts[i + 1]] for i in range(len(self.normals))]

    @cached_property
    def tree(self):
        """k-d tree of the points (scipy ``cKDTree``), built once for every look-up."""
        from scipy.spatial import cKDTree

        return cKDTree(self.points)


def _downsample(P: np.ndarray, params: Lines3DParams) -> tuple[np.ndarray, float]:
    """Voxel-grid downsampling to at most ``params.max_points`` points; returns (points, voxel)."""
    if params.voxel_size <= 0:
        return P, 0.0
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    v = params.voxel_size
    Q = np.asarray(pcd.voxel_down_sample(v).points)
    for _ in range(4):
        if len(Q) <= params.max_points:
            break
        v *= 1.03 * np.sqrt(len(Q) / params.max_points)
        Q = np.asarray(pcd.voxel_down_sample(v).points)
    return Q, v


def _dominant_orientations(normals: np.ndarray, params: Lines3DParams) -> np.ndarray:
    """Plane orientations (D, 3): greedy peaks of the (sign-free) normal histogram on a sphere.

    Normals vote (with both signs) for their nearest vertex of a level-4 icosphere (~4 degree
    cells); votes are summed over ``orient_radius_deg``; the top vertex is refined to the principal
    axis of the normals within ``orient_radius_deg`` of it, those normals are removed, repeat while
    a peak holds ``min_orientation_points`` normals.
    """
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree

    from ldlmap.geometry import icosphere_points

    V = np.asarray(icosphere_points(4))
    tree = cKDTree(V)
    r = 2.0 * np.sin(np.radians(params.orient_radius_deg) / 2.0)
    pairs = tree.query_pairs(r, output_type="ndarray")
    nv = len(V)
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(nv)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(nv)])
    S = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(nv, nv))
    _, vi = tree.query(normals)
    _, vj = tree.query(-normals)
    alive = np.ones(len(normals), bool)
    cos_r = np.cos(np.radians(params.orient_radius_deg))
    cos_c = np.cos(np.radians(params.orient_cone_deg))
    out: list[np.ndarray] = []
    for _ in range(params.max_orientations):
        votes = S @ (np.bincount(vi[alive], minlength=nv) + np.bincount(vj[alive], minlength=nv)).astype(np.float64)
        top = int(np.argmax(votes))
        if votes[top] / 2.0 < params.min_orientation_points:
            break
        d = V[top]
        for _ in range(2):  # refine: principal axis of the normals near the peak
            sel = alive & (np.abs(normals @ d) >= cos_r)
            if not sel.any():
                break
            w, U = np.linalg.eigh(normals[sel].T @ normals[sel])
            d = U[:, 2]
        if (alive & (np.abs(normals @ d) >= cos_r)).sum() < params.min_orientation_points:
            alive &= ~(np.abs(normals @ V[top]) >= cos_r)
            continue
        out.append(d)
        alive &= ~(np.abs(normals @ d) >= cos_c)
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
    from scipy.ndimage import gaussian_filter1d

    if voter.sum() < params.min_plane_voters:
        return []
    b = params.offset_bin
    lo = off.min() - 5 * b
    bins = np.floor((off - lo) / b).astype(np.int64)
    nb = int(bins.max()) + 6
    order = np.argsort(off, kind="stable")
    srt = off[order]
    live = voter & free
    h = np.bincount(bins[live], minlength=nb).astype(np.float64)
    k = int(round(params.plane_tol / b))
    out = []
    for _ in range(params.max_planes_per_orientation):
        hs = gaussian_filter1d(h, params.offset_sigma / b)
        top = int(np.argmax(hs))
        cum = h[max(top - k, 0):top + k + 1].sum()
        if cum < params.min_plane_voters:
            break
        c = lo + (top + 0.5) * b
        i0, i1 = np.searchsorted(srt, [c - params.plane_tol / 2, c + params.plane_tol / 2])
        idx = order[i0:i1]
        idx = idx[live[idx]]
        if len(idx):
            c = float(off[idx].mean())
        i0, i1 = np.searchsorted(srt, [c - params.plane_tol, c + params.plane_tol])
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
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    P = _check_points(points)
    P, v = _downsample(P, params)
    if len(P) < max(params.normal_k, 10):
        raise InputError(f"point cloud too small for line extraction ({len(P)} points)")
    normals, curv, axes, linearity = _normals_and_curvature(P, params.normal_k)
    nbr = _neighbours(P, params.graph_k)
    flat = curv <= params.max_curvature
    D = _dominant_orientations(normals[flat], params)
    n = len(P)
    lab = np.full(n, -1)
    cos_peak = np.cos(np.radians(params.orient_cone_deg))
    cos_assign = np.cos(np.radians(params.assign_angle_deg))
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
    i = np.repeat(np.arange(n), nbr.shape[1])
    j = nbr.ravel()
    ok = (lab[i] >= 0) & (lab[i] == lab[j]) & (np.linalg.norm(P[i] - P[j], axis=1) <= params.link_dist)
    g = coo_matrix((np.ones(ok.sum(), np.int8), (i[ok], j[ok])), shape=(n, n))
    n_comp, comp = connected_components(g, directed=False)
    comp = np.where(lab >= 0, comp, -1)
    sizes = np.bincount(comp[comp >= 0], minlength=n_comp)
    big = sizes >= params.min_region_points
    remap = np.where(big, np.cumsum(big) - 1, -1)
    labels = np.where(comp >= 0, remap[np.maximum(comp, 0)], -1)
    L = int(big.sum())
    if L == 0:
        return PlaneRegions(P, labels, np.zeros((0, 3)), np.zeros((0, 3)), nbr, v, axes, linearity)
    sel = labels >= 0
    c, nrm, rms, _ = _plane_fits(P[sel], labels[sel], L)
    good = rms <= params.max_plane_rms
    remap = np.where(good, np.cumsum(good) - 1, -1)
    labels = np.where(labels >= 0, remap[np.maximum(labels, 0)], -1)
    return PlaneRegions(P, labels, c[good], nrm[good], nbr, v, axes, linearity)


# ---------------------------------------------------------------------------- per-plane segments


def _plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def _boundary_segments(Q: np.ndarray, c: np.ndarray, n: np.ndarray, params: Lines3DParams) -> np.ndarray:
    """Boundary polygon sides (M, 2, 3) of one planar region's occupancy image."""
    import cv2

    from ldlmap.frame import check_memory

    e1, e2 = _plane_basis(n)
    uv = np.stack([(Q - c) @ e1, (Q - c) @ e2], 1)
    cs = params.cell_size
    pad = params.close_cells + 2
    lo = uv.min(0) - pad * cs
    h, w = (np.floor((uv.max(0) - lo) / cs)[::-1] + pad + 1).astype(np.float64)
    check_memory(f"the occupancy image of a {w * cs:.3g} x {h * cs:.3g} plane", h * w * 3,
                 "is the input in metres (--scale)?")
    ij = np.floor((uv - lo) / cs).astype(np.int64)
    h, w = ij[:, 1].max() + pad + 1, ij[:, 0].max() + pad + 1
    img = np.zeros((h, w), np.uint8)
    img[ij[:, 1], ij[:, 0]] = 255
    r = params.close_cells
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    img = cv2.morphologyEx(img, cv2.MORPH_CLOSE, ker)
    img = cv2.morphologyEx(img, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3)))
    contours, _ = cv2.findContours(img, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    segs = []
    eps = params.poly_eps / cs
    for cnt in contours:
        if len(cnt) < 4:
            continue
        poly = cv2.approxPolyDP(cnt, eps, True)[:, 0, :].astype(np.float64)
        if len(poly) < 2:
            continue
        a, b = poly, np.roll(poly, -1, axis=0)
        segs.append(np.stack([a, b], 1))
    if not segs:
        return np.zeros((0, 2, 3))
    S = np.concatenate(segs)  # pixel (col, row) of boundary pixel centres
    S2 = lo + (S + 0.5) * cs
    S3 = c + S2[..., :1] * e1 + S2[..., 1:] * e2
    return S3[np.linalg.norm(S3[:, 1] - S3[:, 0], axis=1) >= params.min_segment]


def _strips(reg: PlaneRegions, params: Lines3DParams) -> tuple[np.ndarray, np.ndarray]:
    """Narrow plane pieces as rectangles (M, 4, 3): centre, long axis, across axis, normal; and
    their plane labels (M,).

    The long axis is scaled to half the length (1st-99th percentile of the points along it) and
    the across axis to half the width (2nd-98th percentile), both about the rectangle's centre.
    Pieces at most ``strip_width`` wide and at least 3 times and ``min_segment`` longer than wide
    count: a table leg, the front of a shelf board, the side of a table top.
    """
    out, owner = [], []
    for i, m in enumerate(reg.members):
        Q = reg.points[m]
        n = reg.normals[i]
        X = Q - Q.mean(0)
        X = X - np.outer(X @ n, n)
        _, _, Vt = np.linalg.svd(X, full_matrices=False)
        u, v = Vt[0], Vt[1]
        a0, a1 = np.percentile(X @ u, [1, 99])
        b0, b1 = np.percentile(X @ v, [2, 98])
        if b1 - b0 > params.strip_width or a1 - a0 < max(params.min_segment, 3 * (b1 - b0)):
            continue
        c = Q.mean(0) + (a0 + a1) / 2 * u + (b0 + b1) / 2 * v
        out.append([c, (a1 - a0) / 2 * u, (b1 - b0) / 2 * v, n])
        owner.append(i)
    return np.asarray(out, dtype=np.float64).reshape(-1, 4, 3), np.asarray(owner, dtype=np.int64)


def _strip_sides(strips: np.ndarray, owner: np.ndarray, reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """The long sides (M, 2, 3) of the strips of :func:`_strips` that are edges.

    The long sides of a thin object's face are edges of the object even where the adjacent face
    is never scanned (the underside of a board, the hidden face of a leg), which is where the
    boundary test of :func:`_edge_supported` cannot tell them from occlusion rims; and a raster
    boundary is coarse across a strip a few cells wide. Sides across which the surface goes on
    smoothly (:func:`_smooth_continuation`: facets of a curved wall) are dropped.
    """
    if len(strips) == 0:
        return np.zeros((0, 2, 3))
    c, a, b = strips[:, 0], strips[:, 1], strips[:, 2]
    sides = np.stack([np.stack([c + s * b - a, c + s * b + a], 1) for s in (-1.0, 1.0)], 1).reshape(-1, 2, 3)
    owner2 = np.repeat(owner, 2)
    return sides[~_smooth_continuation(sides, owner2, reg, params)]


def _across(segs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit directions (M, 3) in each segment's plane (``normals``), perpendicular to the segment."""
    w = np.cross(normals, segs[:, 1] - segs[:, 0])
    return w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)


def _smooth_continuation(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """Mask of segments on plane ``owner`` across which the surface goes on in nearly the same
    plane: along most of the segment, 2 cm beyond it on either side within the owner's plane, a
    point of another plane lies within 1.5 cm of the owner's plane and that plane's normal is
    within ``min_plane_angle_deg`` (the facets of a curved wall, which meet at no edge).
    """
    if len(segs) == 0:
        return np.zeros(0, bool)
    n = reg.normals[owner]
    w = _across(segs, n)
    x, seg = _sample_segments(segs, 0.05)
    cos_t = np.cos(np.radians(params.min_plane_angle_deg))
    smooth = np.zeros(len(x), bool)
    for sgn in (-1.0, 1.0):
        probe = x + sgn * 0.02 * w[seg]
        dist, idx = reg.tree.query(probe, distance_upper_bound=0.015, workers=-1)
        hit = np.isfinite(dist)
        j = np.minimum(idx, len(reg.points) - 1)
        lab = np.where(hit, reg.labels[j], -1)
        on_plane = np.abs(np.einsum("ij,ij->i", reg.points[j] - x, n[seg])) <= 0.015
        same = np.abs(np.einsum("ij,ij->i", reg.normals[np.maximum(lab, 0)], n[seg])) > cos_t
        smooth |= (lab >= 0) & (lab != owner[seg]) & on_plane & same
    return np.bincount(seg, smooth, len(segs)) / np.bincount(seg, minlength=len(segs)) >= 0.5


def _inside_strips(lines: np.ndarray, strips: np.ndarray, margin: float = 0.01, off_plane: float = 0.025) -> np.ndarray:
    """Mask of lines whose both endpoints lie inside a strip (``margin`` in from its long sides).

    Such lines (raster boundary pieces across a narrow face, intersections placed mid-face) would
    chain the two sides of a strip into one line when collinear pieces are merged.
    """
    if len(lines) == 0 or len(strips) == 0:
        return np.zeros(len(lines), bool)
    c, a, b, n = (strips[:, k] for k in range(4))
    la = np.linalg.norm(a, axis=1)
    lb = np.linalg.norm(b, axis=1)
    out = np.zeros(len(lines), bool)
    step = max(1, int(2e6 // len(strips)))  # bounded (N, 2, M) blocks on large maps
    for s in range(0, len(lines), step):
        rel = lines[s:s + step, :, None, :] - c[None, None]  # (n, 2, M, 3)
        along = np.abs(np.einsum("nkmj,mj->nkm", rel, a / la[:, None])) <= la + margin
        across = np.abs(np.einsum("nkmj,mj->nkm", rel, b / lb[:, None])) <= lb - margin
        near = np.abs(np.einsum("nkmj,mj->nkm", rel, n)) <= off_plane
        out[s:s + step] = np.any(np.all(along & across & near, axis=1), axis=1)
    return out


def _runs(mask: np.ndarray) -> np.ndarray:
    """(R, 2) start / end (exclusive) indices of True runs of a 1D boolean array."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1)], 1)


def _intersection_segments(reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
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
    pairs = pairs[counts >= params.min_adjacent_links]
    members = reg.members
    sin_min = np.sin(np.radians(params.min_plane_angle_deg))
    cs = params.support_bin
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
            near = np.linalg.norm(Q - t[:, None] * d, axis=1) <= params.support_dist
            occ.append(t[near])
        if len(occ[0]) == 0 or len(occ[1]) == 0:
            continue
        t0 = max(occ[0].min(), occ[1].min())
        t1 = min(occ[0].max(), occ[1].max())
        if t1 - t0 < params.min_segment:
            continue
        nb = int(np.ceil((t1 - t0) / cs)) + 1
        both = np.ones(nb, bool)
        for t in occ:
            tb = np.floor((t[(t >= t0) & (t <= t1)] - t0) / cs).astype(np.int64)
            hit = np.bincount(tb, minlength=nb)[:nb] > 0
            # Close gaps of up to ``close_cells`` bins (sampling holes, not real gaps).
            gap = int(round(params.support_gap / cs))
            run = _runs(~hit)
            for s0, s1 in run[(run[:, 1] - run[:, 0] <= gap) & (run[:, 0] > 0) & (run[:, 1] < nb)]:
                hit[s0:s1] = True
            both &= hit
        for s0, s1 in _runs(both):
            ta, tb_ = t0 + s0 * cs, t0 + s1 * cs
            if tb_ - ta >= params.min_segment:
                out.append([x0 + ta * d, x0 + tb_ * d])
    return np.asarray(out, dtype=np.float64).reshape(-1, 2, 3)


def _linear_segments(reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """Segments (M, 2, 3) along thin structures: clusters of points whose neighbourhood is linear.

    Plane boundaries miss rods and strips narrower than the normal neighbourhood (table legs,
    frames); their points have one dominant covariance axis. Linear neighbours with agreeing axes
    that lie along each other's axis are linked; each connected cluster gives the segment of its
    principal axis between the 1st and 99th percentile of the projections.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if reg.axes is None or reg.linearity is None:
        return np.zeros((0, 2, 3))
    P, nbr, ax = reg.points, reg.neighbours, reg.axes
    lin = reg.linearity >= params.min_linearity
    idx = np.flatnonzero(lin)
    if len(idx) < params.min_linear_points:
        return np.zeros((0, 2, 3))
    n, k = nbr.shape
    i = np.repeat(idx, k)
    j = nbr[idx].ravel()
    d = P[j] - P[i]
    cos_t = np.cos(np.radians(params.normal_angle_deg))
    along = np.linalg.norm(d - np.einsum("ij,ij->i", d, ax[i])[:, None] * ax[i], axis=1)
    ok = lin[j] & (np.abs(np.einsum("ij,ij->i", ax[i], ax[j])) >= cos_t) & (along <= params.linear_tol)
    g = coo_matrix((np.ones(ok.sum(), np.int8), (i[ok], j[ok])), shape=(n, n))
    _, comp = connected_components(g, directed=False)
    comp = np.where(lin, comp, -1)
    ids, cnt = np.unique(comp[comp >= 0], return_counts=True)
    out = []
    for cid in ids[cnt >= params.min_linear_points]:
        Q = P[comp == cid]
        c = Q.mean(0)
        _, _, Vt = np.linalg.svd(Q - c, full_matrices=False)
        u = Vt[0]
        t = (Q - c) @ u
        off = np.linalg.norm((Q - c) - t[:, None] * u, axis=1)
        if np.percentile(off, 90) > 2 * params.linear_tol:
            continue  # not a thin straight structure
        t0, t1 = np.percentile(t, [1, 99])
        if t1 - t0 >= params.min_segment:
            out.append([c + t0 * u, c + t1 * u])
    return np.asarray(out, dtype=np.float64).reshape(-1, 2, 3)


# ----------------------------------------------------------------------------------------- merge


def merge_collinear(lines: np.ndarray, weights: np.ndarray | None = None, angle_deg: float = 5.0,
                    dist: float = 0.04, gap: float = 0.03) -> np.ndarray:
    """Merge segments that are collinear (angle, line distance) and overlap or nearly touch.

    Groups are the connected components of the "mergeable" relation. A group becomes one segment
    along the weighted mean direction through the weighted mean midpoint (only the members of
    highest weight place it), spanning the projections of all member endpoints.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    L = _check_lines(lines)
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
    g = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n, n))
    n_g, grp = connected_components(g, directed=False)
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
    L = _check_lines(lines)
    if len(L) == 0:
        return L.copy()
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    out = merge_collinear(L, length, params.join_angle_deg, params.join_dist, params.join_gap)
    return out[np.linalg.norm(out[:, 1] - out[:, 0], axis=1) >= max(params.min_line, params.min_segment)]


def _edge_supported(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """Mask of boundary sides that lie on a real edge of the scene.

    A side of a plane's boundary polygon is either a fold or free edge of the geometry (another
    surface - the other face of the fold, the thickness of a board, a frame - has points within
    ``edge_radius`` of it) or the rim of an occlusion shadow or of the scan's reach (nothing but
    the plane itself there). Sides whose samples (every ``edge_radius``) find a point of another
    region or an unassigned point within ``edge_radius`` along at least ``edge_support`` of their
    length are kept.
    """
    if len(segs) == 0:
        return np.zeros(0, bool)
    x, seg = _sample_segments(segs, params.edge_radius)
    k = 32
    d, idx = reg.tree.query(x, k=min(k, len(reg.points)), distance_upper_bound=params.edge_radius, workers=-1)
    hit = np.isfinite(d)
    lab = np.where(hit, reg.labels[np.minimum(idx, len(reg.points) - 1)], -2)
    foreign = np.any(hit & (lab != owner[seg][:, None]), axis=1)
    frac = np.bincount(seg, foreign, len(segs)) / np.bincount(seg, minlength=len(segs))
    return frac >= params.edge_support


def _extend_sides(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, step: float = 0.02,
                  reach: float = 0.15, radius: float = 0.02, min_length: float = 0.2) -> np.ndarray:
    """Boundary sides (M, 2, 3) lengthened at each end while their plane's boundary goes on.

    Closing and polygon approximation round the corners of a plane's occupancy image, which
    shortens every side by several centimetres at each end (a box's 62 cm vertical edge comes out
    40 cm long, below the length threshold). Past each end, every ``step`` up to ``reach``, the
    boundary goes on where the owner plane has points within ``radius`` on one side of the line
    (``2 radius`` off it) but not on the other; the side grows to the last such sample before two
    misses in a row. Only sides at least ``min_length`` long and within 3 degrees of a direction
    where the owner plane meets another plane's orientation grow: short or oblique sides are the
    chords of rounded or staircase outlines, which would grow into false lines.
    """
    d = segs[:, 1] - segs[:, 0]
    length = np.linalg.norm(d, axis=1)
    # Structural directions: where the owner plane would meet another plane's orientation.
    cand = np.cross(reg.normals[owner][:, None, :], reg.normals[None, :, :])  # (M, L, 3)
    cn = np.linalg.norm(cand, axis=2)
    cos_side = np.abs(np.einsum("mlj,mj->ml", cand, d)) / np.maximum(cn * length[:, None], 1e-12)
    structural = np.any((cn > np.sin(np.radians(20.0))) & (cos_side > np.cos(np.radians(3.0))), axis=1)
    sel = np.flatnonzero((length >= min_length) & structural)
    out = segs.copy()
    if len(sel) == 0:
        return out
    S, own = segs[sel], owner[sel]
    u = d[sel] / length[sel, None]
    w = _across(S, reg.normals[own])
    s = np.arange(1, int(reach / step) + 1) * step  # (K,)
    idx = np.arange(len(s))[None, :]
    for end, sgn in ((1, 1.0), (0, -1.0)):
        x = S[:, end, None, :] + sgn * s[None, :, None] * u[:, None, :]  # (m, K, 3)
        sides = []
        for off in (-2 * radius, 2 * radius):
            _, j = reg.tree.query((x + off * w[:, None, :]).reshape(-1, 3), distance_upper_bound=radius, workers=-1)
            hit = (j < len(reg.points)) & (reg.labels[np.minimum(j, len(reg.points) - 1)] == np.repeat(own, len(s)))
            sides.append(hit.reshape(len(S), len(s)))
        on = sides[0] ^ sides[1]  # (m, K): own points on exactly one side
        miss2 = ~on[:, :-1] & ~on[:, 1:]
        gap = np.where(miss2.any(axis=1), np.argmax(miss2, axis=1), len(s))  # first of two misses
        ok = on & (idx < gap[:, None])
        grow = np.where(ok.any(axis=1), s[(ok * idx).max(axis=1)], 0.0)  # the last "on" sample before it
        out[sel, end] = S[:, end] + sgn * grow[:, None] * u
    return out


def _seen_past(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, reach: float = 4.0,
               radius: float = 0.04) -> np.ndarray:
    """Mask of boundary sides past which the scene was scanned on both sides of their plane.

    A side without another surface nearby is either the rim of an occlusion shadow or of the
    scan's reach on a surface that bounds the scene (wall, floor: nothing lies behind them), or
    an edge of an object whose face across the edge was never scanned (a box standing near a
    wall). Just past the side, in the plane, rays along both normal directions find scan points
    within ``reach`` (within ``radius`` of the ray) only in the second case: the object ends there
    and the scanner saw the scene around it. Sides where both rays hit along at least half of
    their length count.
    """
    if len(segs) == 0:
        return np.zeros(0, bool)
    P, lab, tree = reg.points, reg.labels, reg.tree
    n = reg.normals[owner]
    w = _across(segs, n)
    x, seg = _sample_segments(segs, 0.1)
    # Outward: the side of the segment where the owner plane has no point.
    _, j = tree.query(x + 0.03 * w[seg], distance_upper_bound=0.02, workers=-1)
    own = (j < len(P)) & (lab[np.minimum(j, len(P) - 1)] == owner[seg])
    out = np.where(own[:, None], -w[seg], w[seg])
    probe = x + 0.05 * out
    steps = np.arange(0.1, reach, 1.5 * radius)
    hit_both = np.ones(len(x), bool)
    for sgn in (-1.0, 1.0):
        ray = probe[:, None, :] + sgn * steps[None, :, None] * n[seg][:, None, :]  # (S, K, 3)
        dist, _ = tree.query(ray.reshape(-1, 3), distance_upper_bound=radius, workers=-1)
        hit_both &= np.isfinite(dist).reshape(len(x), -1).any(axis=1)
    return np.bincount(seg, hit_both, len(segs)) / np.bincount(seg, minlength=len(segs)) >= 0.5


# ------------------------------------------------------------------------------------ extraction


def extract_lines_with_stats(points: np.ndarray, params: Lines3DParams = Lines3DParams()) -> tuple[np.ndarray, dict]:
    """:func:`extract_lines` plus per-stage seconds and counts (for benchmarks and the CLI)."""
    import time

    stats: dict = {}
    t = time.perf_counter()
    reg = segment_planes(points, params)
    stats["planes_s"] = time.perf_counter() - t
    stats["points_processed"] = len(reg.points)
    stats["planes"] = len(reg.normals)
    t = time.perf_counter()
    from dataclasses import replace

    bparams = replace(params, cell_size=max(params.cell_size, reg.spacing))
    bnd = [_boundary_segments(reg.points[m], reg.centroids[i], reg.normals[i], bparams)
           for i, m in enumerate(reg.members)]
    B = np.concatenate(bnd) if bnd else np.zeros((0, 2, 3))
    owner = np.repeat(np.arange(len(bnd)), [len(b) for b in bnd])
    stats["boundary_sides"] = len(B)
    supported = _edge_supported(B, owner, reg, params)
    if params.see_past:
        supported[~supported] = _seen_past(B[~supported], owner[~supported], reg)
    keep = supported & ~_smooth_continuation(B, owner, reg, params)
    B, owner = B[keep], owner[keep]
    if params.extend_sides:
        B = _extend_sides(B, owner, reg)
    stats["boundary_s"] = time.perf_counter() - t
    t = time.perf_counter()
    X = _intersection_segments(reg, params)
    stats["intersections_s"] = time.perf_counter() - t
    stats["boundary_segments"], stats["intersection_segments"] = len(B), len(X)
    t = time.perf_counter()
    T = _linear_segments(reg, params)
    stats["linear_s"] = time.perf_counter() - t
    stats["linear_segments"] = len(T)
    strips, strip_owner = _strips(reg, params)
    S = _strip_sides(strips, strip_owner, reg, params)
    stats["strip_segments"] = len(S)
    t = time.perf_counter()
    raw = np.concatenate([X, B, T])
    w = np.concatenate([np.full(len(X), 2.0), np.ones(len(B) + len(T))])
    out = merge_collinear(raw, w, params.merge_angle_deg, params.merge_dist, params.merge_gap)
    out = np.concatenate([out[~_inside_strips(out, strips)], S])
    stats["merged_pieces"] = len(out)
    out = join_lines(out, params)
    stats["merge_s"] = time.perf_counter() - t
    stats["lines"] = len(out)
    return out, stats


def extract_lines(points: np.ndarray, colors: np.ndarray | None = None,
                  params: Lines3DParams = Lines3DParams()) -> np.ndarray:
    """3D line segments (N, 2, 3) of a point cloud (N_p, 3), before the length filter.

    ``colors`` is accepted for interface symmetry and currently unused: lines come from
    geometry only (plane boundaries and plane intersections), as in Lu et al. 2019.
    """
    P = _check_points(points)
    if colors is not None and len(np.asarray(colors)) != len(P):
        raise InputError("colors must have one row per point")
    return extract_lines_with_stats(P, params)[0]


# ------------------------------------------------------------------------------------- evaluation


def _sample_segments(L: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along each segment every ``step`` (at least 2 per segment) and their segment index."""
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    k = np.maximum(2, np.ceil(length / step).astype(np.int64) + 1)
    seg = np.repeat(np.arange(len(L)), k)
    first = np.cumsum(k) - k
    f = (np.arange(k.sum()) - first[seg] + 0.5) / k[seg]  # bin centres: each point = equal length
    return L[seg, 0] + f[:, None] * (L[seg, 1] - L[seg, 0]), seg


def _covered(samples: np.ndarray, sdir: np.ndarray, ref: np.ndarray, dist: float, cos_t: float) -> np.ndarray:
    """For each sample point: is there a reference segment within ``dist`` and the angle?"""
    a, b = ref[:, 0], ref[:, 1]
    v = b - a
    vv = np.maximum(np.einsum("ij,ij->i", v, v), 1e-18)
    rdir = v / np.sqrt(vv)[:, None]
    out = np.zeros(len(samples), bool)
    block = max(1, int(2e6 // max(len(ref), 1)))
    for s in range(0, len(samples), block):
        x = samples[s:s + block]
        t = np.clip(((x[:, None, :] - a[None]) * v[None]).sum(-1) / vv[None], 0.0, 1.0)
        dd = np.linalg.norm(x[:, None, :] - (a[None] + t[..., None] * v[None]), axis=2)
        par = np.abs(sdir[s:s + block] @ rdir.T) >= cos_t
        out[s:s + block] = np.any((dd <= dist) & par, axis=1)
    return out


def line_precision_recall(pred: np.ndarray, gt: np.ndarray, dist: float = 0.05, angle_deg: float = 5.0,
                          min_cover: float = 0.7, step: float = 0.01) -> tuple[float, float]:
    """Segment-level precision and recall of ``pred`` against ``gt`` (both (N, 2, 3)).

    A ground-truth segment is found when at least ``min_cover`` of its length lies within
    ``dist`` of a predicted segment whose direction is within ``angle_deg``; precision is the
    same with the roles swapped. Lengths are measured by sampling points every ``step``.
    Returns ``(precision, recall)``; an empty set scores 0 (1 when both are empty).
    """
    P, G = _check_lines(pred), _check_lines(gt)
    if len(P) == 0 or len(G) == 0:
        both_empty = float(len(P) == 0 and len(G) == 0)
        return both_empty, both_empty
    cos_t = np.cos(np.radians(angle_deg))

    def frac(A: np.ndarray, B: np.ndarray) -> np.ndarray:
        x, seg = _sample_segments(A, step)
        da = A[:, 1] - A[:, 0]
        da = da / np.maximum(np.linalg.norm(da, axis=1, keepdims=True), 1e-12)
        cov = _covered(x, da[seg], B, dist, cos_t)
        return np.bincount(seg, cov, len(A)) / np.bincount(seg, minlength=len(A))

    precision = float(np.mean(frac(P, G) >= min_cover))
    recall = float(np.mean(frac(G, P) >= min_cover))
    return precision, recall


# ------------------------------------------------------------------------------- outputs (CLI)


def write_line_files(path: str, lines: np.ndarray) -> list:
    """Write ``lines`` as ``.obj`` and ``.txt`` (same stem as ``path``, via
    :func:`ldlmap.io.linefiles.write_lines`, atomically); returns the two paths."""
    from pathlib import Path

    from ldlmap.io.linefiles import write_lines

    L = _check_lines(lines)
    base = Path(path)
    targets = [base.with_suffix(".obj"), base.with_suffix(".txt")]
    for t in targets:
        write_lines(t, L)
    return targets


def top_view_image(lines: np.ndarray, size: int = 1000, principal: np.ndarray | None = None,
                   dropped: np.ndarray | None = None) -> np.ndarray:
    """Top view (x right, y up) of 3D lines as a BGR image (size, size, 3), colored by group.

    Lines of the three principal groups are red, green and blue, others grey; ``dropped`` lines
    (e.g. removed by the length filter) are drawn thin and light.
    """
    import cv2

    L = _check_lines(lines)
    D = _check_lines(dropped) if dropped is not None else np.zeros((0, 2, 3))
    allp = np.concatenate([L, D]).reshape(-1, 3)
    img = np.full((size, size, 3), 255, np.uint8)
    if len(allp):
        lo, hi = allp[:, :2].min(0), allp[:, :2].max(0)
        margin = 20
        scale = (size - 2 * margin) / max(float((hi - lo).max()), 1e-6)

        def px(X: np.ndarray) -> np.ndarray:
            xy = (X[..., :2] - lo) * scale + margin
            return np.stack([xy[..., 0], size - 1 - xy[..., 1]], -1).round().astype(np.int32)

        for a, b in px(D):
            cv2.line(img, tuple(map(int, a)), tuple(map(int, b)), (200, 200, 200), 1, cv2.LINE_AA)
        groups = np.full(len(L), -1)
        if principal is not None and len(L):
            from ldlmap.principal3d import assign_line_groups

            v = L[:, 1] - L[:, 0]
            groups = assign_line_groups(v, principal)
        colors = {0: (40, 40, 220), 1: (40, 170, 40), 2: (220, 80, 40), -1: (90, 90, 90)}  # BGR
        for (a, b), g in zip(px(L), groups):
            cv2.line(img, tuple(map(int, a)), tuple(map(int, b)), colors.get(int(g), (90, 90, 90)), 2, cv2.LINE_AA)
    return img


def draw_top_view(lines: np.ndarray, path: str, size: int = 1000, principal: np.ndarray | None = None,
                  dropped: np.ndarray | None = None) -> None:
    """Write :func:`top_view_image` atomically, in the format of ``path``'s extension."""
    from ldlmap.pictures import write_picture

    write_picture(path, top_view_image(lines, size, principal, dropped))
