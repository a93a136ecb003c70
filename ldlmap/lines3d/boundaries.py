"""Boundary segments of each plane piece: occupancy raster, contour polygons lifted to 3D, narrow
strips, and the checks that keep scene edges and drop rims of occlusion shadows.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.frame import check_memory
from ldlmap.core.lazy import lazy_module
from ldlmap.lines3d.metrics import sample_segments
from ldlmap.lines3d.params import Lines3DParams
from ldlmap.lines3d.planes import PlaneRegions

cv2 = lazy_module("cv2")


def _plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def boundary_segments(Q: np.ndarray, c: np.ndarray, n: np.ndarray, params: Lines3DParams) -> np.ndarray:
    """Boundary polygon sides (M, 2, 3) of one planar region's occupancy image."""
    e1, e2 = _plane_basis(n)
    uv = np.stack([(Q - c) @ e1, (Q - c) @ e2], 1)
    cs = params.boundaries.cell_size
    pad = params.boundaries.close_cells + 2
    lo = uv.min(0) - pad * cs
    h, w = (np.floor((uv.max(0) - lo) / cs)[::-1] + pad + 1).astype(np.float64)
    check_memory(f"the occupancy image of a {w * cs:.3g} x {h * cs:.3g} plane", h * w * 3,
                 "is the input in metres (--scale)?")
    ij = np.floor((uv - lo) / cs).astype(np.int64)
    h, w = ij[:, 1].max() + pad + 1, ij[:, 0].max() + pad + 1
    img = np.zeros((h, w), np.uint8)
    img[ij[:, 1], ij[:, 0]] = 255
    r = params.boundaries.close_cells
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    img = cv2.morphologyEx(img, cv2.MORPH_CLOSE, ker)
    img = cv2.morphologyEx(img, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3)))
    contours, _ = cv2.findContours(img, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    segs = []
    eps = params.boundaries.poly_eps / cs
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
    return S3[np.linalg.norm(S3[:, 1] - S3[:, 0], axis=1) >= params.merge.min_segment]


def find_strips(reg: PlaneRegions, params: Lines3DParams) -> tuple[np.ndarray, np.ndarray]:
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
        if b1 - b0 > params.boundaries.strip_width or a1 - a0 < max(params.merge.min_segment, 3 * (b1 - b0)):
            continue
        c = Q.mean(0) + (a0 + a1) / 2 * u + (b0 + b1) / 2 * v
        out.append([c, (a1 - a0) / 2 * u, (b1 - b0) / 2 * v, n])
        owner.append(i)
    return np.asarray(out, dtype=np.float64).reshape(-1, 4, 3), np.asarray(owner, dtype=np.int64)


def strip_sides(strips: np.ndarray, owner: np.ndarray, reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """The long sides (M, 2, 3) of the strips of :func:`find_strips` that are edges.

    The long sides of a thin object's face are edges of the object even where the adjacent face
    is never scanned (the underside of a board, the hidden face of a leg), which is where the
    boundary test of :func:`edge_supported` cannot tell them from occlusion rims; and a raster
    boundary is coarse across a strip a few cells wide. Sides across which the surface goes on
    smoothly (:func:`smooth_continuation`: facets of a curved wall) are dropped.
    """
    if len(strips) == 0:
        return np.zeros((0, 2, 3))
    c, a, b = strips[:, 0], strips[:, 1], strips[:, 2]
    sides = np.stack([np.stack([c + s * b - a, c + s * b + a], 1) for s in (-1.0, 1.0)], 1).reshape(-1, 2, 3)
    owner2 = np.repeat(owner, 2)
    return sides[~smooth_continuation(sides, owner2, reg, params)]


def _across(segs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit directions (M, 3) in each segment's plane (``normals``), perpendicular to the segment."""
    w = np.cross(normals, segs[:, 1] - segs[:, 0])
    return w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)


def smooth_continuation(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """Mask of segments on plane ``owner`` across which the surface goes on in nearly the same
    plane: along most of the segment, 2 cm beyond it on either side within the owner's plane, a
    point of another plane lies within 1.5 cm of the owner's plane and that plane's normal is
    within ``min_plane_angle_deg`` (the facets of a curved wall, which meet at no edge). Facets
    with a strip of unassigned points between them are left to the final check of the lines
    (:func:`ldlmap.lines3d.smooth.smooth_lines`).
    """
    if len(segs) == 0:
        return np.zeros(0, bool)
    n = reg.normals[owner]
    w = _across(segs, n)
    x, seg = sample_segments(segs, 0.05)
    cos_t = np.cos(np.radians(params.intersections.min_plane_angle_deg))
    smooth = np.zeros(len(x), bool)
    for sgn in (-1.0, 1.0):
        dist, idx = reg.tree.query(x + sgn * 0.02 * w[seg], distance_upper_bound=0.015, workers=-1)
        hit = np.isfinite(dist)
        j = np.minimum(idx, len(reg.points) - 1)
        lab = np.where(hit, reg.labels[j], -1)
        on_plane = hit & (np.abs(np.einsum("ij,ij->i", reg.points[j] - x, n[seg])) <= 0.015)
        same = np.abs(np.einsum("ij,ij->i", reg.normals[np.maximum(lab, 0)], n[seg])) > cos_t
        smooth |= (lab >= 0) & (lab != owner[seg]) & on_plane & same
    return np.bincount(seg, smooth, len(segs)) / np.bincount(seg, minlength=len(segs)) >= 0.5


def inside_strips(lines: np.ndarray, strips: np.ndarray, margin: float = 0.01, off_plane: float = 0.025) -> np.ndarray:
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


def true_runs(mask: np.ndarray) -> np.ndarray:
    """(R, 2) start / end (exclusive) indices of True runs of a 1D boolean array."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1)], 1)


def edge_supported(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
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
    x, seg = sample_segments(segs, params.boundaries.edge_radius)
    k = 32
    d, idx = reg.tree.query(x, k=min(k, len(reg.points)), distance_upper_bound=params.boundaries.edge_radius, workers=-1)
    hit = np.isfinite(d)
    lab = np.where(hit, reg.labels[np.minimum(idx, len(reg.points) - 1)], -2)
    foreign = np.any(hit & (lab != owner[seg][:, None]), axis=1)
    frac = np.bincount(seg, foreign, len(segs)) / np.bincount(seg, minlength=len(segs))
    return frac >= params.boundaries.edge_support


def extend_sides(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, step: float = 0.02,
                  reach: float = 0.15, radius: float = 0.02, min_length: float = 0.2) -> np.ndarray:
    """Boundary sides (M, 2, 3) lengthened at each end while their plane's boundary goes on.

    Closing and polygon approximation round the corners of a plane's occupancy image, which
    shortens every side by several centimetres at each end, enough to push a short edge below the
    length threshold (docs/measurements.md#extend-sides). Past each end, every ``step`` up to
    ``reach``, the boundary goes on where the owner plane has points within ``radius`` on one side
    of the line (``2 radius`` off it) but not on the other; the side grows to the last such sample
    before two misses in a row. Only sides at least ``min_length`` long and within 3 degrees of a
    direction where the owner plane meets another plane's orientation grow: short or oblique sides
    are the chords of rounded or staircase outlines, which would grow into false lines.
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


def seen_past(segs: np.ndarray, owner: np.ndarray, reg: PlaneRegions, reach: float = 4.0,
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
    x, seg = sample_segments(segs, 0.1)
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
