"""3D lines of a COLMAP model from its photos: ``reconstruct_lines(model, images) -> SfmLines``.

A sparse SfM model carries no surfaces to find lines on, but its photos show them and its
cameras place them. Stages (each timed in ``SfmLines.seconds``):

1. ``segments``: LSD (OpenCV) on every registered photo (contrast-stretched, downscaled to
   ``max_image_size``), collinear pieces joined, segments shorter than ``min_length`` x the image
   diagonal dropped; pixels in COLMAP's convention (the first pixel's centre at 0.5). Each
   segment gets a depth band from the sparse points observed near it (``band_px``), else from
   all of its photo's points.
2. ``triangulate``: each photo is paired with its ``max_neighbours`` most co-visible photos
   (shared sparse points). A segment of each gives a candidate 3D line, the intersection of their
   back-projected planes, when the planes cross at ``tri_angle_deg`` or more, both segments
   overlap on it by ``min_overlap`` (the epipolar overlap) and its ends lie in both depth bands.
3. ``score``: candidates of one segment from partner photos j and k agree when each projects
   within ``match_px`` of the other's partner segment, whose planes cross at ``tri_angle_deg``
   or more. Evidence = agreeing partner photos (its own partner included) + 1 when
   ``min_support`` of the sparse points observed within ``support_px`` of the segment lie on the
   line (``depth_tol``). A segment keeps its best candidate when it has ``min_evidence`` and
   ``ambiguity`` more than any candidate on another line (periodic textures match everywhere),
   re-placed by the least-squares intersection of all agreeing planes and cut to the part the
   partner photos see.
4. ``merge``: the segments' lines are merged (:func:`ldlmap.lines3d.merge_collinear`, distances
   relative to the robust extent of the sparse points: percentiles ``extent_percentiles``, not
   min/max, which outliers stretch); a merged line is kept when lines of ``min_photos`` photos'
   own segments lie on it (a wrong match is made from one photo only).

So a kept line was reconstructed from the segments of three photos, each confirmed by two more
photos, or by one and the sparse points (the sparse points alone never make a line). Everything is
vectorized over segments, candidates and points; the Python loops run over photos and photo
pairs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.imageproc import stretch_contrast
from ldlmap.core.lazy import lazy_module
from ldlmap.core.timing import StageClock
from ldlmap.io.colmap import ColmapViews, read_colmap_views
from ldlmap.io.imagefile import read_image
from ldlmap.lines3d import merge_collinear

cv2 = lazy_module("cv2")
sparse = lazy_module("scipy.sparse")


@dataclass(frozen=True)
class SfmLinesParams:
    """Line reconstruction from a COLMAP model's photos (pixels are the camera's own pixels)."""

    max_image_size: int = 1600  # photos are downscaled so that their longer side is at most this before LSD
    min_length: float = 0.03  # drop LSD segments shorter than this fraction of the image diagonal
    max_neighbours: int = 8  # each photo is matched with its most co-visible photos
    min_covisible: int = 10  # ... that share at least this many sparse points
    tri_angle_deg: float = 4.0  # the two back-projected planes must cross at least this much
    min_overlap: float = 0.5  # both segments cover this fraction of the shorter one on the 3D line
    depth_band: tuple[float, float] = (0.5, 2.0)  # ends within these factors of the photo's point depths
    depth_percentiles: tuple[float, float] = (2.0, 98.0)  # ... taken between these percentiles
    band_px: float = 0.05  # points observed within this fraction of the diagonal of a segment set its depths
    min_band_points: int = 3  # ... when at least this many
    local_band: tuple[float, float] = (0.8, 1.25)  # factors around those points' depths
    match_px: float = 1.5  # candidates agree when each projects this close to the other's partner segment
    depth_tol: float = 0.03  # sparse points lie on a candidate within this fraction of their depth
    support_px: float = 2.0  # a sparse point observed this close to a segment may support it
    max_support: int = 24  # at most this many supporting points (the closest) per segment
    min_support: int = 2  # supporting points on a candidate for them to count as evidence
    min_evidence: int = 2  # other photos (or the points) that must confirm a segment's line
    ambiguity: int = 1  # ... by this much more evidence than any candidate on another line
    distinct_depth: float = 0.05  # candidates whose end depths differ by more than this fraction are other lines
    min_photos: int = 3  # a merged line needs lines from this many photos' own segments (2: floating
    # lines from periodic textures stay; docs/measurements.md#sfm-min-photos)
    merge_angle_deg: float = 3.0
    merge_dist: float = 0.008  # merge distance, fraction of the robust extent
    merge_gap: float = 0.01  # merge gap along the line, fraction of the robust extent
    extent_percentiles: tuple[float, float] = (2.0, 98.0)  # robust extent of the sparse points


@dataclass
class SfmLines:
    """Reconstructed lines (L, 2, 3), per-stage seconds and counts."""

    lines: np.ndarray
    seconds: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)


# ------------------------------------------------------------------------------ 2D segments


_REDUCED = {2: "IMREAD_REDUCED_GRAYSCALE_2", 4: "IMREAD_REDUCED_GRAYSCALE_4", 8: "IMREAD_REDUCED_GRAYSCALE_8"}


def read_gray(path: Path, max_size: int, size_hint: int = 0) -> np.ndarray | None:
    """Contrast-stretched grey photo, downscaled so its longer side is at most ``max_size``;
    None when it cannot be read. ``size_hint``: the photo's longer side when known (the camera's):
    a large JPEG is then decoded at a reduced scale directly."""
    r = max([k for k in _REDUCED if size_hint >= k * max_size], default=1)
    try:  # through Python's open(): any file name; a missing or damaged photo is skipped
        img = read_image(path, getattr(cv2, _REDUCED[r]) if r > 1 else cv2.IMREAD_GRAYSCALE)
    except (OSError, InputError):
        return None
    if img is None:
        return None
    s = min(1.0, max_size / max(img.shape))
    if s < 1.0:
        img = cv2.resize(img, (round(img.shape[1] * s), round(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
    return stretch_contrast(img)  # LSD's gradient threshold is absolute: dim photos lose their lines


def detect_segments(gray: np.ndarray, camera_size: tuple[int, int], min_length: float) -> np.ndarray:
    """LSD segments (n, 2, 2) of ``gray`` in pixels of a camera of ``camera_size`` (W, H), COLMAP
    convention (OpenCV's pixel centres are integers, COLMAP's at +0.5); shorter than
    ``min_length`` x the diagonal dropped."""
    found = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(gray)[0]
    if found is None:
        return np.zeros((0, 2, 2))
    segs = (found.reshape(-1, 2, 2).astype(np.float64) + 0.5) * (np.array(camera_size, float) / gray.shape[::-1])
    diag = float(np.hypot(*camera_size))
    segs = join_segments(segs)
    return segs[np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1) >= min_length * diag]


def join_segments(segs: np.ndarray, angle_deg: float = 1.5, dist_px: float = 1.0, gap_px: float = 4.0) -> np.ndarray:
    """Join LSD's pieces of one image line: collinear within ``angle_deg`` and ``dist_px`` and at
    most ``gap_px`` apart (:func:`ldlmap.lines3d.merge_collinear` on the image plane)."""
    if len(segs) < 2:
        return segs
    flat = np.concatenate([segs, np.zeros((len(segs), 2, 1))], axis=2)
    return merge_collinear(flat, angle_deg=angle_deg, dist=dist_px, gap=gap_px)[..., :2]


def segment_support(segs: np.ndarray, obs_xy: np.ndarray, support_px: float,
                    max_support: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (segment, observation), sorted by segment: observations within ``support_px`` of a
    segment (and between its ends, up to ``support_px`` past them); the closest ``max_support``."""
    if len(segs) == 0 or len(obs_xy) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    a = segs[:, 0]
    v = segs[:, 1] - a
    length = np.linalg.norm(v, axis=1)
    u = v / length[:, None]
    si, oi, dd = [], [], []
    block = max(1, int(2e6 // len(obs_xy)))
    for s in range(0, len(segs), block):
        sl = slice(s, s + block)
        rel = obs_xy[None, :, :] - a[sl, None, :]  # (B, n, 2)
        t = np.einsum("bnk,bk->bn", rel, u[sl])
        d = np.abs(rel[..., 0] * u[sl, None, 1] - rel[..., 1] * u[sl, None, 0])
        ok = (d <= support_px) & (t >= -support_px) & (t <= length[sl, None] + support_px)
        b, n = np.nonzero(ok)
        si.append(b + s)
        oi.append(n)
        dd.append(d[b, n])
    si, oi, dd = np.concatenate(si), np.concatenate(oi), np.concatenate(dd)
    order = np.lexsort((dd, si))
    si, oi = si[order], oi[order]
    keep = np.arange(len(si)) - np.searchsorted(si, si) < max_support
    return si[keep], oi[keep]


# ------------------------------------------------------------------------------ geometry


def _rays(view, xy: np.ndarray) -> np.ndarray:
    """Unit world directions (n, 3) of pixels (n, 2) of a view (its distortion undone)."""
    xn = np.asarray(view.camera.cam_from_img(np.ascontiguousarray(xy, dtype=np.float64)), dtype=np.float64)
    d = np.column_stack([xn, np.ones(len(xn))]) @ view.rot_cam_from_world
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...j,...j->...", a, b)


def _closest_on_line(P: np.ndarray, v: np.ndarray, C: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Parameter tau of the point P + tau v closest to each ray C + s r (v, r unit)."""
    w = P - C
    b = _dot(v, r)
    return (b * _dot(r, w) - _dot(v, w)) / np.maximum(1 - b ** 2, 1e-12)


@dataclass
class _Segments:
    """All photos' segments, flattened: camera centre, unit end rays, plane normal, photo, depth band."""

    C: np.ndarray  # (S, 3)
    ra: np.ndarray  # (S, 3)
    rb: np.ndarray  # (S, 3)
    n: np.ndarray  # (S, 3) unit normal of the plane through C, ra, rb
    view: np.ndarray  # (S,)
    band: np.ndarray  # (S, 2) admissible depth range along the rays
    px_angle: np.ndarray  # (S,) angle (radians) one pixel of the segment's photo subtends at its centre
    start: np.ndarray  # (V + 1,) first segment of each photo


def triangulate_pair(sg: _Segments, i: int, j: int, params: SfmLinesParams) -> tuple[np.ndarray, ...]:
    """Candidate 3D lines from the segments of photos ``i`` and ``j``: (seg_i, seg_j, X (K, 2, 3)
    ends of seg_i on the line, Y (K, 2, 3) ends of seg_j on it)."""
    a = np.arange(sg.start[i], sg.start[i + 1])
    b = np.arange(sg.start[j], sg.start[j + 1])
    empty = np.zeros(0, np.int64)
    if len(a) == 0 or len(b) == 0:
        return empty, empty, np.zeros((0, 2, 3)), np.zeros((0, 2, 3))
    Ci, Cj = sg.C[a[0]], sg.C[b[0]]
    ni, nj = sg.n[a], sg.n[b]
    ok = np.abs(ni @ nj.T) <= np.cos(np.radians(params.tri_angle_deg))

    def depth(den: np.ndarray, num: np.ndarray) -> np.ndarray:
        return np.divide(num, den, out=np.full(den.shape, np.nan), where=np.abs(den) > 1e-12)

    # Depths of i's end rays on j's plane (rows: i's segments) and of j's end rays on i's plane.
    depths = [depth(sg.ra[a] @ nj.T, (nj @ (Cj - Ci))[None, :]), depth(sg.rb[a] @ nj.T, (nj @ (Cj - Ci))[None, :]),
              depth(ni @ sg.ra[b].T, (ni @ (Ci - Cj))[:, None]), depth(ni @ sg.rb[b].T, (ni @ (Ci - Cj))[:, None])]
    for k, lam in enumerate(depths):
        lo, hi = (sg.band[a, 0][:, None], sg.band[a, 1][:, None]) if k < 2 else (sg.band[b, 0][None], sg.band[b, 1][None])
        ok &= (lam >= lo) & (lam <= hi)
    p, q = np.nonzero(ok)
    la, lb, ma, mb = (d[p, q] for d in depths)
    X = np.stack([Ci + la[:, None] * sg.ra[a[p]], Ci + lb[:, None] * sg.rb[a[p]]], 1)
    Y = np.stack([Cj + ma[:, None] * sg.ra[b[q]], Cj + mb[:, None] * sg.rb[b[q]]], 1)
    # Epipolar overlap along the line (both segments' ends lie on it).
    u = X[:, 1] - X[:, 0]
    li = np.linalg.norm(u, axis=1)
    u /= np.maximum(li, 1e-12)[:, None]
    t = np.einsum("kej,kj->ke", Y - X[:, :1], u)
    lj = np.abs(t[:, 1] - t[:, 0])
    ov = np.minimum(t.max(1), li) - np.maximum(t.min(1), 0)
    keep = ov >= params.min_overlap * np.minimum(li, lj)
    return a[p[keep]], b[q[keep]], X[keep], Y[keep]


def _pairs_within_groups(group: np.ndarray, block: int = 2_000_000):
    """Ordered pairs (k, l), k != l, of elements with equal ``group`` (``group`` sorted), yielded
    in chunks of about ``block`` pairs."""
    n = len(group)
    first = np.searchsorted(group, group, side="left")
    size = np.searchsorted(group, group, side="right") - first
    ends = np.cumsum(size)
    c0 = 0
    while c0 < n:
        c1 = max(c0 + 1, int(np.searchsorted(ends, ends[c0] - size[c0] + block, side="right")))
        c1 = min(c1, n)
        sz = size[c0:c1]
        k = np.repeat(np.arange(c0, c1), sz)
        l_ = np.repeat(first[c0:c1], sz) + (np.arange(sz.sum()) - np.repeat(np.cumsum(sz) - sz, sz))
        keep = k != l_
        yield k[keep], l_[keep]
        c0 = c1


def refine_with_planes(lines: np.ndarray, plane_of: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                       max_shift: np.ndarray, max_turn_deg: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares intersection of each line's planes ``normals[k] . X = offsets[k]`` (``plane_of``:
    the line of each plane): a point and unit direction per line. A line keeps its own placement
    when its planes do not fix it or the intersection moves it more than ``max_shift`` (per line)
    or turns it more than ``max_turn_deg``."""
    L = len(lines)
    P = lines.mean(1)
    v = _unit(lines[:, 1] - lines[:, 0])
    A = np.zeros((L, 3, 3))
    b = np.zeros((L, 3))
    np.add.at(A, plane_of, np.einsum("ki,kj->kij", normals, normals))
    np.add.at(b, plane_of, normals * offsets[:, None])
    ev, evec = np.linalg.eigh(A)  # ascending eigenvalues
    v_new = evec[:, :, 0]
    v_new = np.where((_dot(v, v_new) < 0)[:, None], -v_new, v_new)
    eps = 1e-9  # a tiny pull toward P keeps the system regular when the planes do not fix the line
    rhs = b + v_new * _dot(v_new, P)[:, None] + eps * P
    P_new = np.linalg.solve(A + np.einsum("li,lj->lij", v_new, v_new) + eps * np.eye(3), rhs[..., None])[..., 0]
    off = P - P_new
    off -= v_new * _dot(off, v_new)[:, None]
    ok = (ev[:, 1] > 1e-6) & (np.linalg.norm(off, axis=1) <= max_shift) & (_dot(v, v_new) >= np.cos(np.radians(max_turn_deg)))
    return np.where(ok[:, None], P_new, P), np.where(ok[:, None], v_new, v)


def photos_per_line(merged: np.ndarray, lines: np.ndarray, photo: np.ndarray, angle_deg: float,
                    dist: float) -> np.ndarray:
    """Distinct photos (``photo`` of each of ``lines``) whose lines lie on each merged line: within
    ``angle_deg`` of its direction, both ends within ``dist`` of it, overlapping it."""
    out = np.zeros(len(merged), np.int64)
    if len(merged) == 0 or len(lines) == 0:
        return out
    a = merged[:, 0]
    u = merged[:, 1] - a
    length = np.linalg.norm(u, axis=1)
    u /= np.maximum(length, 1e-12)[:, None]
    d = _unit(lines[:, 1] - lines[:, 0])
    cos_t = np.cos(np.radians(angle_deg))
    pairs = []
    block = max(1, int(2e6 // len(lines)))
    for s in range(0, len(merged), block):
        sl = slice(s, s + block)
        w = lines[None, :, :, :] - a[sl, None, None, :]  # (B, n, 2, 3)
        t = np.einsum("bnej,bj->bne", w, u[sl])
        off = np.linalg.norm(w - t[..., None] * u[sl, None, None, :], axis=3).max(2)
        ok = (np.abs(u[sl] @ d.T) >= cos_t) & (off <= dist)
        ok &= (t.max(2) > 0) & (t.min(2) < length[sl, None])
        b, n = np.nonzero(ok)
        pairs.append(np.column_stack([b + s, photo[n]]))
    pairs = np.unique(np.concatenate(pairs), axis=0)
    return np.bincount(pairs[:, 0], minlength=len(merged))


def robust_extent(points: np.ndarray, percentiles: tuple[float, float]) -> float:
    """Mean over the axes of the spread between two percentiles of the points (outliers ignored)."""
    if len(points) == 0:
        return 0.0
    lo, hi = np.percentile(points, percentiles, axis=0)
    return float(np.mean(hi - lo))


def _is_spherical(camera) -> bool:
    """Whether a pycolmap camera is spherical (a method in pycolmap 4, a property before)."""
    flag = getattr(camera, "is_spherical", False)
    return bool(flag() if callable(flag) else flag)


# ------------------------------------------------------------------------------ pipeline


def _collect_segments(views: list, grays: list[np.ndarray], points: np.ndarray,
                      params: SfmLinesParams) -> tuple[_Segments, np.ndarray, np.ndarray]:
    """Segments of every photo, and their supporting points (segment, point row) pairs."""
    C, ra, rb, view, band, pxa, start, sup_s, sup_p = [], [], [], [], [], [], [0], [], []
    for i, (v, g) in enumerate(zip(views, grays)):
        segs = detect_segments(g, (v.camera.width, v.camera.height), params.min_length)
        ends = _rays(v, segs.reshape(-1, 2)).reshape(-1, 2, 3) if len(segs) else np.zeros((0, 2, 3))
        band.append(_depth_bands(v, segs, points, params))
        mid = np.array([[v.camera.width / 2, v.camera.height / 2], [v.camera.width / 2 + 1, v.camera.height / 2]])
        pxa.append(np.full(len(segs), np.arccos(np.clip(np.prod(_rays(v, mid), axis=0).sum(), -1, 1))))
        si, oi = segment_support(segs, v.obs_xy, params.support_px, params.max_support)
        sup_s.append(si + start[-1])
        sup_p.append(v.obs_point[oi])
        C.append(np.broadcast_to(v.center, (len(segs), 3)))
        ra.append(ends[:, 0])
        rb.append(ends[:, 1])
        view.append(np.full(len(segs), i))
        start.append(start[-1] + len(segs))
    ra, rb = np.concatenate(ra), np.concatenate(rb)
    sg = _Segments(np.concatenate(C), ra, rb, _unit(np.cross(ra, rb)), np.concatenate(view), np.concatenate(band),
                   np.concatenate(pxa), np.array(start))
    return sg, np.concatenate(sup_s), np.concatenate(sup_p)


def _depth_bands(view, segs: np.ndarray, points: np.ndarray, params: SfmLinesParams) -> np.ndarray:
    """(n, 2) depths a segment's 3D line may have: ``depth_band`` around the depths (percentiles
    ``depth_percentiles``) of the sparse points observed within ``band_px`` of it; the photo's
    when fewer than ``min_band_points`` are that close."""
    X = points[view.obs_point]
    depth = (X - view.center) @ view.rot_cam_from_world[2]
    front = depth > 0
    out = np.full((len(segs), 2), np.nan)
    if front.sum() < 2:
        return out
    q = np.asarray(params.depth_percentiles) / 100.0
    whole = np.percentile(depth[front], 100 * q)
    out[:] = whole * params.depth_band
    diag = float(np.hypot(view.camera.width, view.camera.height))
    si, oi = segment_support(segs, view.obs_xy[front], params.band_px * diag, 10 ** 6)
    if len(si) == 0:
        return out
    d = depth[front][oi]
    order = np.lexsort((d, si))
    si, d = si[order], d[order]
    first = np.searchsorted(si, np.arange(len(segs)))
    size = np.searchsorted(si, np.arange(len(segs)), side="right") - first
    has = size >= params.min_band_points
    lo = d[first[has] + np.floor(q[0] * (size[has] - 1)).astype(int)]
    hi = d[first[has] + np.ceil(q[1] * (size[has] - 1)).astype(int)]
    out[has] = np.column_stack([lo, hi]) * params.local_band
    return out


def _neighbours(views: list, num_points: int, params: SfmLinesParams) -> list[tuple[int, int]]:
    """Ordered photo pairs (i, j): j among the ``max_neighbours`` photos sharing the most points with i."""
    rows = np.concatenate([np.full(len(v.obs_point), i) for i, v in enumerate(views)])
    cols = np.concatenate([v.obs_point for v in views])
    vis = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(views), num_points))
    vis.data[:] = 1
    covis = (vis @ vis.T).toarray()
    np.fill_diagonal(covis, -1)
    pairs = set()
    for i in range(len(views)):
        best = np.argsort(-covis[i], kind="stable")[: params.max_neighbours]
        for j in best[covis[i, best] >= params.min_covisible]:
            pairs.add((i, int(j)))
            pairs.add((int(j), i))
    return sorted(pairs)


def _point_evidence(X: np.ndarray, seg: np.ndarray, sg: _Segments, sup_s: np.ndarray, sup_pts: np.ndarray,
                    params: SfmLinesParams) -> np.ndarray:
    """Whether ``min_support`` supporting points of each candidate's segment lie on it (within ``depth_tol``)."""
    M = params.max_support
    first = np.searchsorted(sup_s, np.arange(len(sg.C)))
    count = np.searchsorted(sup_s, np.arange(len(sg.C)), side="right") - first
    hits = np.zeros(len(seg), np.int64)
    u = _unit(X[:, 1] - X[:, 0])
    for m in range(M):  # M slots, each vectorized over every candidate
        has = count[seg] > m
        if not has.any():
            break
        k = np.flatnonzero(has)
        P = sup_pts[first[seg[k]] + m]
        w = P - X[k, 0]
        d = np.linalg.norm(w - u[k] * _dot(w, u[k])[:, None], axis=1)
        hits[k] += d <= params.depth_tol * np.linalg.norm(P - sg.C[seg[k]], axis=1)
    return hits >= params.min_support


def _plane_px(X: np.ndarray, plane_seg: np.ndarray, sg: _Segments) -> np.ndarray:
    """Pixels (in the plane's photo) between the ends X (K, 2, 3) and the planes of segments (K,)."""
    w = X - sg.C[plane_seg][:, None]
    s = np.abs(np.einsum("kej,kj->ke", w, sg.n[plane_seg])) / np.maximum(np.linalg.norm(w, axis=2), 1e-12)
    return np.arcsin(np.minimum(s, 1.0)).max(1) / sg.px_angle[plane_seg]


def _score(seg: np.ndarray, pair: np.ndarray, X: np.ndarray, sg: _Segments, on_points: np.ndarray,
           params: SfmLinesParams) -> tuple[np.ndarray, np.ndarray]:
    """Best candidate of each segment with ``min_evidence``, and the pairs (best, other) that agree.

    Candidates of one segment from partner photos j and k agree when each one's ends project within
    ``match_px`` of the other's partner segment and the two partners' planes cross at
    ``tri_angle_deg`` or more (two nearby photos repeating one wrong match do not confirm it).
    Evidence = partner photos that agree (the candidate's own included) + sparse-point support."""
    ks, ls = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for k, l_ in _pairs_within_groups(seg):
        ok = pair[k, 0] != pair[l_, 0]
        k, l_ = k[ok], l_[ok]
        pk, pl = pair[k, 1], pair[l_, 1]
        ok = np.abs(_dot(sg.n[pk], sg.n[pl])) <= np.cos(np.radians(params.tri_angle_deg))
        ok &= (_plane_px(X[k], pl, sg) <= params.match_px) & (_plane_px(X[l_], pk, sg) <= params.match_px)
        ks.append(k[ok])
        ls.append(l_[ok])
    k, l_ = np.concatenate(ks), np.concatenate(ls)
    kv = np.unique(np.column_stack([k, pair[l_, 0]]), axis=0) if len(k) else np.zeros((0, 2), np.int64)
    evidence = 1 + np.bincount(kv[:, 0], minlength=len(seg)) + on_points
    order = np.lexsort((-evidence, seg))
    best = order[np.r_[True, seg[order][1:] != seg[order][:-1]]] if len(seg) else order
    # Unambiguous: no candidate of the segment on another line (depths off by more than
    # distinct_depth) may come within ambiguity of the best one's evidence (periodic textures).
    best_of = np.full(seg.max() + 1 if len(seg) else 0, -1)
    best_of[seg[best]] = best
    b = best_of[seg]
    lam = np.stack([np.linalg.norm(X[:, e] - sg.C[seg], axis=1) for e in (0, 1)], 1)
    other = np.any(np.abs(lam - lam[b]) > params.distinct_depth * lam[b], axis=1)
    rival = np.zeros(len(best_of))
    np.maximum.at(rival, seg[other], evidence[other])
    best = best[(evidence[best] >= params.min_evidence) & (evidence[best] >= rival[seg[best]] + params.ambiguity)]
    chosen = np.zeros(len(seg), bool)
    chosen[best] = True
    sel = chosen[k]
    return best, np.column_stack([k[sel], l_[sel]])


def reconstruct_lines(model, images_dir: str | Path, params: SfmLinesParams = SfmLinesParams()) -> SfmLines:
    """3D lines of a COLMAP model (:class:`ldlmap.io.colmap.ColmapViews`, or its folder) from the
    photos in ``images_dir``. Raises :class:`InputError` when fewer than two photos can be read or
    when no line is confirmed."""
    seconds: dict[str, float] = {}
    clock = StageClock(seconds)
    cv = model if isinstance(model, ColmapViews) else read_colmap_views(model)
    images_dir = Path(images_dir)
    views, grays = read_photos(cv, images_dir, params)
    clock.lap("read")
    sg, sup_s, sup_p = _collect_segments(views, grays, cv.points, params)
    clock.lap("segments")
    seg, pair, X, Y = triangulated_candidates(sg, views, len(cv.points), images_dir, params)
    clock.lap("triangulate")
    on_points = _point_evidence(X, seg, sg, sup_s, cv.points[sup_p], params)
    best, agree = _score(seg, pair, X, sg, on_points, params)
    if len(best) == 0:
        raise InputError(f"no 3D line was confirmed by {params.min_evidence} more photos (or sparse points) "
                         f"among the {len(views)} photos in {images_dir}")
    lines, evidence, photo, ok = placed_lines(seg, pair, X, Y, sg, best, agree, params)
    clock.lap("score")
    ext = robust_extent(cv.points, params.extent_percentiles)
    merged = merge_collinear(lines, weights=evidence.astype(float), angle_deg=params.merge_angle_deg,
                             dist=params.merge_dist * ext, gap=params.merge_gap * ext)
    photos = photos_per_line(merged, lines, photo, params.merge_angle_deg, 2 * params.merge_dist * ext)
    kept = merged[photos >= params.min_photos]
    if len(kept) == 0:
        raise InputError(f"no 3D line was reconstructed from {params.min_photos} of the {len(views)} photos in {images_dir}")
    clock.lap("merge")
    counts = {"photos": len(views), "segments": int(len(sg.C)), "candidates": int(len(seg)),
              "confirmed": int(ok.sum()), "merged": int(len(merged)), "lines": int(len(kept))}
    return SfmLines(kept, seconds, counts)


def read_photos(cv: ColmapViews, images_dir: Path, params: SfmLinesParams) -> tuple[list, list[np.ndarray]]:
    """The model's perspective views whose photo could be read, and those photos in gray; refuses
    (one line) fewer than two."""
    perspective = [v for v in cv.views if not _is_spherical(v.camera)]
    views, grays = [], []
    for v in perspective:
        g = read_gray(images_dir / v.name, params.max_image_size, max(v.camera.width, v.camera.height))
        if g is not None:
            views.append(v)
            grays.append(g)
    if len(views) < 2:
        raise InputError(f"fewer than 2 of the model's {len(cv.views)} registered photos could be read from "
                         f"{images_dir}" + (" (spherical cameras are not supported)" if len(perspective) < len(cv.views) else ""))
    return views, grays


def triangulated_candidates(sg, views: list, n_points: int, images_dir: Path,
                            params: SfmLinesParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every candidate 3D line from a segment matched in a neighbouring photo, ordered by segment:
    its segment, (partner photo, partner segment), its end points and its partner's."""
    seg, pair, X, Y = [], [], [], []  # pair: (partner photo, partner segment) of each candidate
    for i, j in _neighbours(views, n_points, params):
        a, b, Xi, Yj = triangulate_pair(sg, i, j, params)
        seg.append(a)
        pair.append(np.column_stack([np.full(len(a), j), b]))
        X.append(Xi)
        Y.append(Yj)
    if not seg or sum(len(a) for a in seg) == 0:
        raise InputError(f"no segment of the {len(views)} photos in {images_dir} matches one in another photo")
    seg, pair = np.concatenate(seg), np.concatenate(pair)
    X, Y = np.concatenate(X), np.concatenate(Y)
    order = np.argsort(seg, kind="stable")
    return seg[order], pair[order], X[order], Y[order]


def placed_lines(seg: np.ndarray, pair: np.ndarray, X: np.ndarray, Y: np.ndarray, sg, best: np.ndarray,
                 agree: np.ndarray, params: SfmLinesParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kept candidates ``best`` re-placed by their planes (their own, their partner's and the
    agreeing partners') and cut to what the confirming photos see: the lines, their evidence
    (photos), their own photo, and which candidates kept a length."""
    row = np.full(len(seg), -1)
    row[best] = np.arange(len(best))
    members = np.concatenate([best, agree[:, 1]])
    owner = np.concatenate([np.arange(len(best)), row[agree[:, 0]]])
    planes = np.concatenate([seg[best], pair[members, 1]])
    plane_of = np.concatenate([np.arange(len(best)), owner])
    offs = _dot(sg.n[planes], sg.C[planes])
    depth = np.linalg.norm(X[best].mean(1) - sg.C[seg[best]], axis=1)
    P, v = refine_with_planes(X[best], plane_of, sg.n[planes], offs, params.depth_tol * depth)
    # Extent: the segment's own end rays, cut to what the confirming photos see.
    s = seg[best]
    lo = np.minimum(_closest_on_line(P, v, sg.C[s], sg.ra[s]), _closest_on_line(P, v, sg.C[s], sg.rb[s]))
    hi = np.maximum(_closest_on_line(P, v, sg.C[s], sg.ra[s]), _closest_on_line(P, v, sg.C[s], sg.rb[s]))
    t_m = np.einsum("kej,kj->ke", Y[members] - P[owner][:, None], v[owner])
    seen_lo = np.full(len(best), np.inf)
    seen_hi = np.full(len(best), -np.inf)
    np.minimum.at(seen_lo, owner, t_m.min(1))
    np.maximum.at(seen_hi, owner, t_m.max(1))
    lo, hi = np.maximum(lo, seen_lo), np.minimum(hi, seen_hi)
    ok = hi > lo
    lines = np.stack([P + lo[:, None] * v, P + hi[:, None] * v], 1)[ok]
    evidence = 1 + np.bincount(owner, minlength=len(best))[ok]
    return lines, evidence, sg.view[s][ok], ok
