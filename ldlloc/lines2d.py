"""2D line segments of an equirectangular panorama as great-circle arcs (DESIGN.md 5.5).

LSD (OpenCV) runs on perspective crops that cover the sphere: by default 26 views of 60 degree
field of view looking at the faces, edges and corners of a cube (neighbouring views are 35-45
degrees apart, so every direction lies well inside at least one view). The crops are sampled
from the panorama by one ``cv2.remap`` with fixed-point maps that are computed once per image
size and cached. Segment endpoints become crop rays, then unit bearings in the camera frame of
:mod:`ldlmap.geometry`, i.e. arcs ``(s, e)`` on the sphere.

Overlapping views detect the same line more than once, and a line cut by a crop border is
detected in pieces; both are resolved by merging: arcs whose great circles agree (normals within
``merge_angle_deg`` up to sign, endpoints within the same angle of the other's circle) and whose
extents overlap or are separated by less than ``merge_gap_deg`` are joined (transitively) into
one arc spanning their union on the length-weighted mean circle.

Pixel convention: crop pixel ``(c, r)`` has its centre at crop coordinates ``(c, r)``, which is
the convention of OpenCV's LSD output; the crop's principal point is ``((S-1)/2, (S-1)/2)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ldlmap.errors import InputError


@dataclass(frozen=True)
class Lines2DParams:
    """Parameters of 2D line extraction."""

    fov_deg: float = 60.0  # field of view of each perspective crop (authors: 26 views of 60 deg)
    views: str = "cube26"  # crop directions: cube26 (faces, edges, corners) or cube14 (faces, corners)
    crop_scale: float = 1.0  # crop pixels per panorama pixel at the crop centre
    min_length_px: float = 6.0  # drop LSD segments shorter than this (crop pixels)
    merge_angle_deg: float = 1.0  # great circles closer than this are the same line
    merge_gap_deg: float = 0.5  # arcs on one circle closer than this along it are joined
    lsd_refine: int = 1  # cv2.LSD_REFINE_* (0 none, 1 standard, 2 advanced)
    normalize_contrast: bool = True  # stretch the grey levels (1st-99th percentile) before LSD,
    # so that washed-out or dark panoramas (gamma, exposure changes) keep their gradients
    lsd_threads: int = 0  # threads running LSD over the crops (OpenCV releases the GIL); 0: auto
    # (up to 4, at most the CPU count). The result does not depend on it.


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
    """Crop cameras and remap maps for a panorama size (cached)."""
    import cv2

    from ldlmap.geometry import pixel_from_bearing

    bases = _view_bases(view_directions(params.views))
    S = _crop_size(width, params)
    focal = (S / 2.0) / np.tan(np.radians(params.fov_deg) / 2.0)
    c = (S - 1) / 2.0
    a = (np.arange(S, dtype=np.float64) - c) / focal
    xx, yy = np.meshgrid(a, a)  # (S, S): column offset, row offset
    rays = (bases[:, None, None, 0, :] + xx[None, :, :, None] * bases[:, None, None, 1, :]
            + yy[None, :, :, None] * bases[:, None, None, 2, :])  # (V, S, S, 3)
    uv = pixel_from_bearing(rays, width, height)
    # Panorama is padded by one wrapped column on each side; pixel centres sit at (u - 0.5).
    mx = (uv[..., 0] - 0.5 + 1.0).astype(np.float32).reshape(-1, S)
    my = (uv[..., 1] - 0.5).astype(np.float32).reshape(-1, S)
    map1, map2 = cv2.convertMaps(mx, my, cv2.CV_16SC2)
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


def crops(image_rgb: np.ndarray, params: Lines2DParams = Lines2DParams()) -> np.ndarray:
    """Grey perspective crops (V, S, S) of the panorama (for inspection and tests)."""
    import cv2

    img = _check_image(image_rgb)
    gray = img if img.ndim == 2 else cv2.cvtColor(img[..., :3], cv2.COLOR_RGB2GRAY)
    if params.normalize_contrast:
        from ldlmap.imageproc import stretch_contrast

        gray = stretch_contrast(gray)
    h, w = gray.shape
    cs = _crop_set(w, h, params)
    padded = np.concatenate([gray[:, -1:], gray, gray[:, :1]], axis=1)
    out = cv2.remap(padded, cs.map1, cs.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, cs.size, cs.size)


def _lsd_threads(requested: int) -> int:
    import os

    if requested > 0:
        return int(requested)
    return max(1, min(4, os.cpu_count() or 1))


@lru_cache(maxsize=4)
def _executor(workers: int):
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="ldl-lsd")


def _detect_all(views: np.ndarray, refine: int, threads: int) -> list:
    """LSD on every crop, (V,) list of (n, 1, 4) arrays or None, split over ``threads`` threads.

    Each thread has its own detector (one crop after another, interleaved so that the threads
    get similar work); OpenCV releases the GIL inside ``detect``.
    """
    import cv2

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
    import cv2

    lsd = cv2.createLineSegmentDetector(refine)
    return [lsd.detect(c)[0] for c in views]


def detect_lines(image_rgb: np.ndarray, params: Lines2DParams = Lines2DParams()) -> np.ndarray:
    """Great-circle arcs (N, 2, 3) of the panorama's line segments (camera-frame unit bearings).

    Accepts uint8 (H, W, 3) RGB (or grey (H, W)) with W = 2 H. An image without lines gives
    an empty (0, 2, 3) array.
    """
    views = crops(image_rgb, params)
    h, w = np.asarray(image_rgb).shape[:2]
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
    return merge_arcs(arcs, params.merge_angle_deg, params.merge_gap_deg)


# ---------------------------------------------------------------------------------------- merge


def _normals_lengths(arcs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s, e = arcs[:, 0], arcs[:, 1]
    n = np.cross(s, e)
    nn = np.linalg.norm(n, axis=1)
    return n / np.maximum(nn, 1e-15)[:, None], np.arctan2(nn, np.sum(s * e, axis=1))


def merge_arcs(arcs: np.ndarray, angle_deg: float = 1.0, gap_deg: float = 0.5) -> np.ndarray:
    """Join arcs that lie on one great circle and overlap or nearly touch (transitively).

    Each group becomes one arc on the length-weighted mean circle spanning the union of the
    members' extents. Degenerate (zero-length) arcs are dropped.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

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
    # Candidate pairs: near-parallel normals (same circle up to orientation), from a k-d tree
    # over the normals and their antipodes (no N x N matrix).
    tree = cKDTree(np.concatenate([n, -n]))
    pairs = tree.query_pairs(2.0 * np.sin(np.radians(angle_deg) / 2.0), output_type="ndarray")
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
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(N, N))
    ncomp, comp = connected_components(graph, directed=False)
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
