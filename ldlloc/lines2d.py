"""2D line segments of an equirectangular panorama as great-circle arcs.

LSD (OpenCV) runs on perspective crops that cover the sphere: by default 26 views of 60 degree
field of view looking at the faces, edges and corners of a cube (neighbouring views are 35-45
degrees apart, so every direction lies well inside at least one view). The crops are sampled
from the panorama by one ``cv2.remap`` with fixed-point maps that are computed once per image
size and cached. Segment endpoints become crop rays, then unit bearings in the camera frame of
:mod:`ldlmap.core.geometry`, i.e. arcs ``(s, e)`` on the sphere.

Overlapping views detect the same line more than once, and a line cut by a crop border is
detected in pieces; both are resolved by merging: arcs whose great circles agree (normals within
``merge_angle_deg`` up to sign, endpoints within the same angle of the other's circle) and whose
extents overlap or are separated by less than ``merge_gap_deg`` are joined (transitively) into
one arc spanning their union on the length-weighted mean circle.

Pole caps: arcs that come near camera -z (the tripod at the nadir; ``nadir_mask_deg``) or
into a flat band found at the image's bottom or top rows (black padding, a blurred nadir) are
dropped, so that neither the rig nor a band's boundary becomes a line (:class:`Lines2DParams`).
The query keeps the longest fraction of its arcs given by :func:`query_keep_ratio`: the map's 3D
kept ratio (the paper's rule) within ``keep_ratio_bounds``.

The first call in a process pays only for the crop maps of its image size (float32); merging uses
numpy only, since importing scipy's k-d tree and sparse graphs would cost a fresh process more than
the detection (docs/measurements.md#lines2d-startup).

Pixel convention: crop pixel ``(c, r)`` has its centre at crop coordinates ``(c, r)``, which is
the convention of OpenCV's LSD output; the crop's principal point is ``((S-1)/2, (S-1)/2)``.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.imageproc import stretch_contrast
from ldlmap.core.lazy import lazy_module

cv2 = lazy_module("cv2")


@dataclass(frozen=True)
class Lines2DParams:
    """Parameters of 2D line extraction.

    Pole masks. Real panoramas see the capture rig at the nadir (a tripod head and its feet), where
    LSD finds segments. Arcs that come within ``nadir_mask_deg`` of camera -z are dropped: the
    default covers the rig of the real ZInD panoramas while the cap stays a small share of the
    sphere, so a panorama at an arbitrary rotation loses only the few lines near its nadir
    (docs/measurements.md#nadir-mask). ``zenith_mask_deg`` is the same cap around +z (off by
    default).

    On top of these fixed caps, a band found in the image itself grows them
    (``detect_pole_bands``): when the rows next to the bottom (or top) of the image are a
    near-constant dark or flat (blurred, padded) band, e.g. the black padding of a panorama with
    a limited vertical field of view, the cap grows to the band's extent plus
    ``band_margin_deg``, so that the band's boundary (a long circle of constant latitude) gives no
    line. See :func:`pole_band_extents` for the test; a flat region that reaches beyond
    ``band_max_deg`` or fades out gradually (an untextured floor seen up to its walls) is scene,
    not a band.

    ``keep_ratio_bounds``: the paper keeps the longest fraction of 2D lines equal to the map's 3D
    kept ratio; real maps break that rule both ways (room layouts keep nearly all their 3D lines,
    Line3D++ maps almost none), so :func:`query_keep_ratio` clips the map's ratio to these bounds:
    below them too few arcs remain for three vanishing points, above them short texture arcs come
    in (chosen on the real ZInD panoramas: docs/measurements.md#keep-ratio-bounds).
    """

    fov_deg: float = 60.0
    """Field of view of each perspective crop (the authors': 26 views of 60 deg)."""
    views: str = "cube26"
    """Crop directions: cube26 (faces, edges, corners) or cube14 (faces, corners)."""
    crop_scale: float = 1.0
    """Crop pixels per panorama pixel at the crop centre."""
    min_length_px: float = 6.0
    """Drop LSD segments shorter than this (crop pixels)."""
    merge_angle_deg: float = 1.0
    """Great circles closer than this are the same line."""
    merge_gap_deg: float = 0.5
    """Arcs on one circle closer than this along it are joined."""
    lsd_refine: int = 1
    """cv2.LSD_REFINE_* (0 none, 1 standard, 2 advanced)."""
    normalize_contrast: bool = True
    """Stretch the grey levels (1st-99th percentile) before LSD: dark or washed-out panoramas keep their gradients."""
    lsd_threads: int = 0
    """Threads running LSD over the crops (0: up to 4, at most the CPU count); results do not depend on it."""
    nadir_mask_deg: float = 18.0
    """Drop arcs that come this close to camera -z (tripod); 0: off."""
    zenith_mask_deg: float = 0.0
    """Drop arcs that come this close to camera +z; 0: off."""
    detect_pole_bands: bool = True
    """Grow the caps over a dark or flat band found at the image's bottom or top rows (pole_band_extents)."""
    band_margin_deg: float = 3.0
    """A detected band's cap reaches this far beyond the band."""
    band_max_deg: float = 45.0
    """A flat region reaching farther from the pole is scene, not a band."""
    keep_ratio_bounds: tuple[float, float] = (0.1, 0.2)
    """The 2D kept ratio is the map's 3D kept ratio clipped to these bounds (query_keep_ratio)."""


def query_keep_ratio(map_kept_ratio: float, params: Lines2DParams = Lines2DParams()) -> float:
    """The fraction of a query's 2D arcs to keep (longest first) for a map that kept ``map_kept_ratio``.

    The paper keeps the same fraction as the map's 3D length filter kept; here that ratio is
    clipped to ``params.keep_ratio_bounds`` (see :class:`Lines2DParams`).
    """
    lo, hi = (float(b) for b in params.keep_ratio_bounds)
    if not (0.0 < lo <= hi <= 1.0):
        raise InputError(f"keep_ratio_bounds must satisfy 0 < low <= high <= 1, got {params.keep_ratio_bounds}")
    r = float(map_kept_ratio)
    if not np.isfinite(r) or r <= 0.0 or r > 1.0:
        raise InputError(f"the map's kept ratio must be in (0, 1], got {map_kept_ratio}")
    return min(max(r, lo), hi)


# ------------------------------------------------------------------------------------- views


def view_directions(kind: str = "cube26") -> np.ndarray:
    """Unit view directions (V, 3): cube faces (6), edges (12) and corners (8)."""
    g = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=np.float64)
    nz = np.count_nonzero(g, axis=1)
    if kind == "cube26":
        g = g[nz > 0]
    elif kind == "cube14":
        g = g[(nz == 1) | (nz == 3)]
    else:
        raise InputError(f"unknown view set {kind!r}; choose cube26 or cube14")
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def _view_bases(dirs: np.ndarray) -> np.ndarray:
    """(V, 3, 3) rows (forward, right, down) of each crop camera, in the panorama camera frame."""
    f = dirs
    up = np.where(np.abs(f[:, 2:3]) > 0.99, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]))
    r = np.cross(f, up)
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    d = np.cross(f, r)
    return np.stack([f, r, d], axis=1)


@dataclass(frozen=True)
class _CropSet:
    bases: np.ndarray  # (V, 3, 3) forward, right, down
    size: int  # S: crops are S x S
    focal: float  # pixels
    map1: np.ndarray  # fixed-point remap maps for the stacked (V*S, S) crops
    map2: np.ndarray


def _crop_size(width: int, params: Lines2DParams) -> int:
    return max(16, int(round(params.crop_scale * width * params.fov_deg / 360.0)))


@lru_cache(maxsize=8)
def _crop_set(width: int, height: int, params: Lines2DParams) -> _CropSet:
    """Crop cameras and remap maps for a panorama size (cached).

    The maps (V * S * S entries, 3 million for a 2048-pixel-wide panorama) are computed view by
    view and per coordinate in float32, without (V, S, S, 3) float64 ray arrays, whose fresh
    memory (page faults) costs a new process more than the maps (docs/measurements.md#crop-maps).
    float32 keeps the sample positions within 1e-3 pixel, far below the 1/32 pixel of OpenCV's
    fixed-point maps.
    """
    bases = _view_bases(view_directions(params.views))
    S = _crop_size(width, params)
    focal = (S / 2.0) / np.tan(np.radians(params.fov_deg) / 2.0)
    c = (S - 1) / 2.0
    a = ((np.arange(S, dtype=np.float64) - c) / focal).astype(np.float32)
    col, row = a[None, None, :], a[None, :, None]  # column offset along right, row offset along down
    b = bases.astype(np.float32)
    V = len(b)
    mx = np.empty((V, S, S), dtype=np.float32)
    my = np.empty((V, S, S), dtype=np.float32)
    for v in range(V):  # one view at a time: small temporaries, reused by the allocator
        x, y, z = (b[v, 0, k] + col[0] * b[v, 1, k] + row[0] * b[v, 2, k] for k in range(3))  # (S, S)
        # pixel_from_bearing (ldlmap.core.geometry) in float32; the panorama is padded by one wrapped
        # column on each side, and pixel centres sit at (u - 0.5, v - 0.5):
        # mx = u - 0.5 + 1 with u = W (1 - (atan2(y, x) + pi) / (2 pi)), my = v - 0.5.
        np.arctan2(y, x, out=mx[v])
        mx[v] *= np.float32(-width / (2.0 * np.pi))
        mx[v] += np.float32(width / 2.0 + 0.5)
        np.arctan2(np.hypot(x, y), z, out=my[v])
        my[v] *= np.float32(height / np.pi)
        my[v] -= np.float32(0.5)
    map1, map2 = cv2.convertMaps(mx.reshape(-1, S), my.reshape(-1, S), cv2.CV_16SC2)
    return _CropSet(bases, S, float(focal), map1, map2)


# ------------------------------------------------------------------------------------ detection


def _check_image(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise InputError(f"panorama must be uint8, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (3, 4))):
        raise InputError(f"panorama must have shape (H, W, 3) or (H, W), got {img.shape}")
    h, w = img.shape[:2]
    if h < 16 or abs(w - 2 * h) > 1:
        raise InputError(f"panorama must be equirectangular with W = 2 H (at least 32x16), got {w}x{h}")
    return img


def _gray(image_rgb: np.ndarray, params: Lines2DParams) -> np.ndarray:
    """The grey panorama LSD sees (contrast-stretched when ``params.normalize_contrast``)."""
    img = _check_image(image_rgb)
    gray = img if img.ndim == 2 else cv2.cvtColor(img[..., :3], cv2.COLOR_RGB2GRAY)
    if params.normalize_contrast:
        gray = stretch_contrast(gray)
    return np.ascontiguousarray(gray)


def _crops_of_gray(gray: np.ndarray, params: Lines2DParams) -> np.ndarray:
    h, w = gray.shape
    cs = _crop_set(w, h, params)
    padded = np.concatenate([gray[:, -1:], gray, gray[:, :1]], axis=1)
    out = cv2.remap(padded, cs.map1, cs.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, cs.size, cs.size)


def crops(image_rgb: np.ndarray, params: Lines2DParams = Lines2DParams()) -> np.ndarray:
    """Grey perspective crops (V, S, S) of the panorama (for inspection and tests)."""
    return _crops_of_gray(_gray(image_rgb, params), params)


# ------------------------------------------------------------------------------------ pole masks

_BAND_WIDTH = 512  # band statistics on the panorama resized to this width (resolution-independent)
_BAND_FLAT_GRAD = 2.0  # a pixel is flat when its grey level differs from its right and lower
# neighbours by at most this (at _BAND_WIDTH; 255 levels)
_BAND_ROW_FRACTION = 0.9  # a band row is flat in at least this fraction of its pixels
_BAND_EDGE_DEG = 3.0  # within this many degrees past a band, the flat fraction falls below half


def pole_band_extents(gray: np.ndarray, params: Lines2DParams = Lines2DParams()) -> tuple[float, float]:
    """Angular extents (degrees from the nadir, from the zenith) of flat bands at the image's poles.

    Row statistics of the grey panorama resized to 512 pixels wide (a millisecond): a pixel is
    flat when it differs from its right and lower neighbours by at most 2 grey levels; a row
    belongs to a band when at least 90 % of its pixels are flat, and a band is the run of such
    rows starting at the bottom (top) row. Black or constant padding, a blurred or logo-covered
    nadir and a near-constant dark tripod band are flat. The band counts only when it ends
    sharply (its flat fraction falls below one half within 3 degrees, as it does at a band's
    boundary, which is a row of the image) and within ``params.band_max_deg`` of the pole: an
    untextured floor or ceiling is flat too, but it ends where the walls begin, at rows that
    change around the panorama, and usually farther out. 0 where there is no band.
    """
    g = np.asarray(gray)
    h, w = g.shape[:2]
    ws = min(w, _BAND_WIDTH)
    hs = max(2, ws // 2)
    small = cv2.resize(g, (ws, hs), interpolation=cv2.INTER_AREA).astype(np.int16)
    dx = np.abs(small - np.roll(small, -1, axis=1))  # wraps around: the panorama is periodic in u
    dy = np.zeros_like(small)
    dy[:-1] = np.abs(small[1:] - small[:-1])
    dy[-1] = dy[-2]
    frac = np.mean((dx <= _BAND_FLAT_GRAD) & (dy <= _BAND_FLAT_GRAD), axis=1)  # (hs,)
    deg_per_row = 180.0 / hs
    edge = max(1, int(np.ceil(_BAND_EDGE_DEG / deg_per_row)))
    out = []
    for f in (frac[::-1], frac):  # from the nadir (bottom row), then from the zenith (top row)
        band = f >= _BAND_ROW_FRACTION
        n = len(f) if band.all() else int(np.argmin(band))  # length of the leading run of band rows
        ext = n * deg_per_row
        sharp = n < len(f) and float(f[n:n + edge].min()) < 0.5
        out.append(ext if (n > 0 and sharp and ext <= params.band_max_deg) else 0.0)
    return out[0], out[1]


def pole_caps(gray: np.ndarray, params: Lines2DParams = Lines2DParams()) -> tuple[float, float]:
    """Radii (degrees) of the masked caps around the nadir (camera -z) and the zenith (+z).

    The fixed ``nadir_mask_deg`` / ``zenith_mask_deg``, grown to a detected band plus
    ``band_margin_deg`` (see :class:`Lines2DParams`, :func:`pole_band_extents`).
    """
    caps = [float(params.nadir_mask_deg), float(params.zenith_mask_deg)]
    if params.detect_pole_bands:
        for k, ext in enumerate(pole_band_extents(gray, params)):
            if ext > 0:
                caps[k] = max(caps[k], ext + float(params.band_margin_deg))
    return caps[0], caps[1]


def arc_max_dot(arcs: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``max over x on arc of x . c`` for arcs (N, 2, 3) and a unit direction ``c`` (3,), (N,).

    The arc's closest point to ``c`` is an endpoint or, when it lies between them, the
    normalized projection of ``c`` onto the arc's plane.
    """
    arcs = np.asarray(arcs, dtype=np.float64).reshape(-1, 2, 3)
    c = np.asarray(c, dtype=np.float64)
    s, e = arcs[:, 0], arcs[:, 1]
    best = np.maximum(s @ c, e @ c)
    n = np.cross(s, e)
    nn = np.linalg.norm(n, axis=1)
    ok = nn > 1e-12
    n = n / np.where(ok, nn, 1.0)[:, None]
    p = c[None, :] - (n @ c)[:, None] * n
    pn = np.linalg.norm(p, axis=1)
    p = p / np.maximum(pn, 1e-15)[:, None]
    se = np.sum(s * e, axis=1)
    ps, pe = np.sum(p * s, axis=1), np.sum(p * e, axis=1)
    inside = ok & (pn > 1e-12) & (ps - se * pe > 0) & (pe - se * ps > 0)
    return np.where(inside, np.maximum(best, pn), best)


def _outside_caps(arcs: np.ndarray, nadir_deg: float, zenith_deg: float) -> np.ndarray:
    """Mask (N,) of arcs that stay farther than the cap radii from camera -z and +z."""
    keep = np.ones(len(arcs), dtype=bool)
    for deg, c in ((nadir_deg, (0.0, 0.0, -1.0)), (zenith_deg, (0.0, 0.0, 1.0))):
        if deg > 0:
            keep &= arc_max_dot(arcs, np.array(c)) < np.cos(np.radians(deg))
    return keep


def _lsd_threads(requested: int) -> int:
    if requested > 0:
        return int(requested)
    return max(1, min(4, os.cpu_count() or 1))


@lru_cache(maxsize=4)
def _executor(workers: int):
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="ldl-lsd")


def _detect_all(views: np.ndarray, refine: int, threads: int) -> list:
    """LSD on every crop, (V,) list of (n, 1, 4) arrays or None, split over ``threads`` threads.

    Each thread has its own detector (one crop after another, interleaved so that the threads
    get similar work); OpenCV releases the GIL inside ``detect``.
    """
    def run(k: int) -> list:
        lsd = cv2.createLineSegmentDetector(refine)
        return [lsd.detect(views[v])[0] for v in range(k, len(views), threads)]

    if threads <= 1 or len(views) < 2:
        return _detect_single(views, refine)
    parts = list(_executor(threads).map(run, range(threads)))
    out: list = [None] * len(views)
    for k, part in enumerate(parts):
        out[k::threads] = part
    return out


def _detect_single(views: np.ndarray, refine: int) -> list:
    """LSD on every crop in the calling thread."""
    lsd = cv2.createLineSegmentDetector(refine)
    return [lsd.detect(c)[0] for c in views]


def detect_lines(image_rgb: np.ndarray, params: Lines2DParams = Lines2DParams()) -> np.ndarray:
    """Great-circle arcs (N, 2, 3) of the panorama's line segments (camera-frame unit bearings).

    Accepts uint8 (H, W, 3) RGB (or grey (H, W)) with W = 2 H. An image without lines gives
    an empty (0, 2, 3) array. No arc comes within the pole caps (:func:`pole_caps`: the tripod
    at the nadir, flat bands at the bottom or top rows).
    """
    gray = _gray(image_rgb, params)
    h, w = gray.shape
    views = _crops_of_gray(gray, params)
    cs = _crop_set(w, h, params)
    found = _detect_all(views, int(params.lsd_refine), _lsd_threads(params.lsd_threads))
    segs, owner = [], []
    for v, f in enumerate(found):  # in view order, whatever the threads did
        if f is not None and len(f):
            segs.append(f.reshape(-1, 4))
            owner.append(np.full(len(segs[-1]), v))
    if not segs:
        return np.zeros((0, 2, 3))
    seg = np.concatenate(segs).astype(np.float64)
    own = np.concatenate(owner)
    keep = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) >= params.min_length_px
    seg, own = seg[keep], own[keep]
    c = (cs.size - 1) / 2.0
    pts = (seg.reshape(-1, 2, 2) - c) / cs.focal  # (N, 2 ends, (x, y))
    B = cs.bases[own]  # (N, 3, 3)
    rays = B[:, None, 0, :] + pts[..., 0:1] * B[:, None, 1, :] + pts[..., 1:2] * B[:, None, 2, :]
    arcs = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    # Nothing from the tripod or a band at the poles: segments touching the caps go before the
    # merge, and merged arcs (which may lean a little) are checked once more.
    caps = pole_caps(gray, params)
    arcs = merge_arcs(arcs[_outside_caps(arcs, *caps)], params.merge_angle_deg, params.merge_gap_deg)
    return arcs[_outside_caps(arcs, *caps)]


# ---------------------------------------------------------------------------------------- merge


def _normals_lengths(arcs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s, e = arcs[:, 0], arcs[:, 1]
    n = np.cross(s, e)
    nn = np.linalg.norm(n, axis=1)
    return n / np.maximum(nn, 1e-15)[:, None], np.arctan2(nn, np.sum(s * e, axis=1))


# Plain numpy rather than scipy's k-d tree and sparse graphs: importing scipy.sparse and
# scipy.spatial costs a fresh process more than the whole detection (docs/measurements.md#lines2d-startup).
_HALF_OFFSETS = np.array([o for o in np.ndindex(3, 3, 3) if o > (1, 1, 1)], dtype=np.int64) - 1  # 13


def _close_pairs(p: np.ndarray, radius: float) -> np.ndarray:
    """Index pairs (P, 2), ``i < j``, of points (M, 3) within ``radius`` of each other.

    A hash grid of cell size ``radius``: the points of each occupied cell meet those of their own
    cell and of 13 of its 26 neighbouring cells (the other 13 meet them from their side), so each
    pair comes once. Cells are looked up as sorted keys (a constant offset keeps them sorted).
    """
    M = len(p)
    if M < 2:
        return np.zeros((0, 2), dtype=np.int64)
    cell = np.floor(p / radius).astype(np.int64)
    cell -= cell.min(0) - 1  # >= 1, so that neighbour offsets stay non-negative
    dims = cell.max(0) + 2
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    order = np.argsort(key, kind="stable")
    ukey, start, count = np.unique(key[order], return_index=True, return_counts=True)
    src_all, dst_all = [], []
    for o in np.concatenate([np.zeros((1, 3), dtype=np.int64), _HALF_OFFSETS]):
        nk = ukey + (o[0] * dims[1] + o[1]) * dims[2] + o[2]
        idx = np.minimum(np.searchsorted(ukey, nk), len(ukey) - 1)
        ca = np.nonzero(ukey[idx] == nk)[0]  # occupied cells whose neighbour at o is occupied
        if len(ca) == 0:
            continue
        cb = idx[ca]
        na, nb = count[ca], count[cb]
        tot = na * nb
        pid = np.repeat(np.arange(len(ca)), tot)
        k = np.arange(int(tot.sum())) - np.repeat(np.cumsum(tot) - tot, tot)
        src = order[start[ca][pid] + k // nb[pid]]
        dst = order[start[cb][pid] + k % nb[pid]]
        if not o.any():
            keep = src < dst
            src, dst = src[keep], dst[keep]
        src_all.append(src)
        dst_all.append(dst)
    if not src_all:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = np.concatenate(src_all), np.concatenate(dst_all)
    close = np.sum((p[i] - p[j]) ** 2, axis=1) <= radius * radius
    i, j = i[close], j[close]
    return np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1)


def _components(i: np.ndarray, j: np.ndarray, n: int) -> tuple[int, np.ndarray]:
    """Connected components of the undirected graph with edges ``(i, j)`` on ``n`` nodes.

    Returns ``(count, labels)``, components numbered in the order of their smallest node (as
    scipy's ``connected_components``): each node takes the smallest label among its neighbours,
    with pointer jumping, until nothing changes.
    """
    lab = np.arange(n)
    if len(i) == 0:
        return n, lab
    while True:
        m = np.minimum(lab[i], lab[j])
        new = lab.copy()
        np.minimum.at(new, i, m)
        np.minimum.at(new, j, m)
        new = new[new]
        if np.array_equal(new, lab):
            break
        lab = new
    roots, comp = np.unique(lab, return_inverse=True)
    return len(roots), comp


def merge_arcs(arcs: np.ndarray, angle_deg: float = 1.0, gap_deg: float = 0.5) -> np.ndarray:
    """Join arcs that lie on one great circle and overlap or nearly touch (transitively).

    Each group becomes one arc on the length-weighted mean circle spanning the union of the
    members' extents. Degenerate (zero-length) arcs are dropped.
    """
    arcs = np.asarray(arcs, dtype=np.float64)
    if arcs.ndim != 3 or arcs.shape[1:] != (2, 3):
        raise InputError(f"arcs must have shape (N, 2, 3), got {arcs.shape}")
    n, length = _normals_lengths(arcs)
    ok = length > 1e-9
    arcs, n, length = arcs[ok], n[ok], length[ok]
    N = len(arcs)
    if N < 2:
        return arcs
    sin_tol = np.sin(np.radians(angle_deg))
    gap = np.radians(gap_deg)
    # Candidate pairs: near-parallel normals (same circle up to orientation), from a hash grid
    # over the normals and their antipodes (no N x N matrix).
    pairs = _close_pairs(np.concatenate([n, -n]), 2.0 * np.sin(np.radians(angle_deg) / 2.0))
    i, j = pairs[:, 0] % N, pairs[:, 1] % N
    i, j = np.minimum(i, j), np.maximum(i, j)
    uniq = np.unique(i[i != j] * N + j[i != j])
    i, j = uniq // N, uniq % N
    if len(i):
        # Endpoints of j close to i's circle, and extents overlapping along i's circle.
        pj = arcs[j]  # (P, 2, 3)
        near = np.all(np.abs(np.einsum("pkc,pc->pk", pj, n[i])) < sin_tol, axis=1)
        u = arcs[i, 0]
        w = np.cross(n[i], u)
        th = np.arctan2(np.einsum("pkc,pc->pk", pj, w), np.einsum("pkc,pc->pk", pj, u))  # (P, 2)
        lo, hi = th.min(1), th.max(1)
        no_wrap = (hi - lo) < np.pi
        overlap = (np.maximum(lo, 0.0) <= np.minimum(hi, length[i]) + gap)
        link = near & no_wrap & overlap
        i, j = i[link], j[link]
    ncomp, comp = _components(i, j, N)
    if ncomp == N:
        return arcs
    # Reference arc per component: its longest member.
    order = np.lexsort((-length, comp))
    first = np.ones(N, dtype=bool)
    first[1:] = comp[order][1:] != comp[order][:-1]
    ref = np.empty(ncomp, dtype=np.int64)
    ref[comp[order][first]] = order[first]
    # Length-weighted mean normal, each member's sign aligned to its reference.
    sgn = np.sign(np.sum(n * n[ref[comp]], axis=1))
    sgn[sgn == 0] = 1.0
    nm = np.zeros((ncomp, 3))
    np.add.at(nm, comp, (sgn * length)[:, None] * n)
    nm /= np.linalg.norm(nm, axis=1, keepdims=True)
    s_ref = arcs[ref, 0]
    u = s_ref - np.sum(s_ref * nm, axis=1, keepdims=True) * nm
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(nm, u)
    uc, wc = u[comp], w[comp]
    th = np.arctan2(np.einsum("nkc,nc->nk", arcs, wc), np.einsum("nkc,nc->nk", arcs, uc))  # (N, 2)
    tmin = np.full(ncomp, np.inf)
    tmax = np.full(ncomp, -np.inf)
    np.minimum.at(tmin, comp, th.min(1))
    np.maximum.at(tmax, comp, th.max(1))
    tmax = np.minimum(tmax, tmin + np.pi - 1e-6)  # keep a minor arc
    s = np.cos(tmin)[:, None] * u + np.sin(tmin)[:, None] * w
    e = np.cos(tmax)[:, None] * u + np.sin(tmax)[:, None] * w
    return np.stack([s, e], axis=1)


# --------------------------------------------------------------------------------------- filter


def arc_lengths(arcs: np.ndarray) -> np.ndarray:
    """Arc lengths in radians, (N,)."""
    arcs = np.asarray(arcs, dtype=np.float64).reshape(-1, 2, 3)
    return _normals_lengths(arcs)[1]


def filter_by_length(arcs: np.ndarray, keep_ratio: float) -> np.ndarray:
    """Keep the longest ``keep_ratio`` fraction of arcs (the map's 3D kept ratio), longest first.

    ``ceil(keep_ratio * N)`` arcs are kept (at least one when there are any).
    """
    if not (0.0 < float(keep_ratio) <= 1.0) or not np.isfinite(keep_ratio):
        raise InputError(f"keep_ratio must be in (0, 1], got {keep_ratio}")
    arcs = np.asarray(arcs, dtype=np.float64)
    if arcs.ndim != 3 or arcs.shape[1:] != (2, 3):
        raise InputError(f"arcs must have shape (N, 2, 3), got {arcs.shape}")
    if len(arcs) == 0:
        return arcs
    k = max(1, int(np.ceil(float(keep_ratio) * len(arcs) - 1e-9)))
    order = np.argsort(-arc_lengths(arcs), kind="stable")
    return arcs[order[:k]]
