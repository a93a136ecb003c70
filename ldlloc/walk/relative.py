"""The motion between two panoramas of a walk, from what both images show.

Two frames a metre apart see the same cabinets, the same pantry shelves: surfaces a layout map
lacks, so the map cannot place a frame by them, but the frames' own images match each other there.
:func:`relative_pose` matches SIFT features (:class:`ldlmap.features.sift.SiftBackend`) between the
two panoramas (on a cube's faces) and fits the essential matrix on their unit bearings (a
spherical camera: every direction, no pinhole model) for two upright cameras (tilted ones levelled
first by a rotation whose vertical is right): RANSAC over the turn about the vertical and samples of
two matches, all hypotheses scored at once, the turn refitted finely on its inliers. The rotation
between the frames and the direction of the step follow (its sign from the points in front of both
cameras), and the step's length in camera heights from the matched points on the floor
(:func:`floor_scale`). :func:`poses_along` turns it into the poses a frame may stand at, given its
neighbour's pose and the floor under it (:func:`floor_under`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.geometry import bearing_from_pixel
from ldlmap.core.lazy import lazy_module
from ldlmap.features.sift import SiftBackend, SiftConfig
from ldlmap.features.sphere import CubeFaces

cv2 = lazy_module("cv2")


@dataclass(frozen=True)
class RelativeParams:
    """How two panoramas' motion is fitted."""

    width: int = 1536  # the panoramas are resized to this width before SIFT (speed; 0.23 deg a pixel)
    max_keypoints: int = 8000  # per panorama ...
    contrast_threshold: float = 0.01  # ... SIFT's low: white walls, cabinets, a pantry's shelves show little texture
    ratio: float = 0.9  # Lowe's ratio test of the mutual nearest-neighbour matches (loose: RANSAC sorts them)
    pairs: int = 128  # RANSAC samples of two matches per turn (drawn with ``seed``: results do not depend on the CPU)
    turn_step_deg: float = 1.0  # the upright stage's grid of turns about the vertical ...
    upright_threshold_deg: float = 2.0  # ... and its inlier threshold (the grid's step, a camera's small tilt)
    threshold_deg: float = 0.6  # a match is an inlier when each bearing lies within this of its epipolar plane
    refits: int = 3  # refits on the inliers ...
    refine_span_deg: float = 2.0  # ... of the turn within this of the last one ...
    refine_step_deg: float = 0.05  # ... on a grid this fine
    min_inliers: int = 40  # fewer: the two frames share too little to tell their motion
    min_baseline_deg: float = 1.0  # a fit whose inliers' parallax is below this (median): a turn on the spot,
    # the step's direction unknown
    floor_below_deg: float = 20.0  # the step's length from the points this far below the horizon or more ...
    floor_bin: float = 0.03  # ... on the floor (the most common length, in bins of 3 %) ...
    min_floor_points: int = 12  # ... when this many agree
    seed: int = 0


@dataclass(frozen=True)
class RelativePose:
    """Frame b's motion from frame a: ``rot`` = R_b R_a^T (camera-from-world rotations: R_b = rot @ R_a)
    and ``direction`` the unit step c_b - c_a in a's camera frame (its length unknown)."""

    rot: np.ndarray  # (3, 3)
    direction: np.ndarray  # (3,)
    inliers: int
    matches: int
    parallax_deg: float  # the inliers' median angle between their two bearings, once rotated alike
    per_height: float | None = None  # the step's length in a's camera heights above the floor (None: unknown)

    def in_world(self, rot_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frame b's rotation and the step's world direction, given frame a's rotation ``rot_a``."""
        rot_a = np.asarray(rot_a, float)
        return self.rot @ rot_a, rot_a.T @ self.direction


def panorama_features(image: np.ndarray, params: RelativeParams = RelativeParams()) -> tuple[np.ndarray, np.ndarray]:
    """Bearings (N, 3) and SIFT descriptors (N, 128) of an RGB panorama, resized to ``params.width``."""
    H, W = image.shape[:2]
    w = min(int(params.width), W)
    img = image if w == W else cv2.resize(image, (w, w // 2), interpolation=cv2.INTER_AREA)
    f = CubeFaces(backend(params)).extract(img)  # a cube's faces: the same surface looks alike from two places
    return bearing_from_pixel(f.keypoints, img.shape[1], img.shape[0]), f.descriptors


def backend(params: RelativeParams) -> SiftBackend:
    """The SIFT backend of these params."""
    return SiftBackend(SiftConfig(max_keypoints=params.max_keypoints, contrast_threshold=params.contrast_threshold))


def relative_pose(feats_a: tuple[np.ndarray, np.ndarray], feats_b: tuple[np.ndarray, np.ndarray],
                  params: RelativeParams = RelativeParams(), level_a: np.ndarray | None = None,
                  level_b: np.ndarray | None = None) -> RelativePose | None:
    """Frame b's motion from frame a (:class:`RelativePose`) from their :func:`panorama_features`;
    None when fewer than ``min_inliers`` matches agree or the frames barely moved. The fit takes the
    cameras upright: ``level_a``, ``level_b`` (camera-from-world rotations whose vertical is right,
    e.g. each frame's own pose; None: upright as taken) level tilted ones first."""
    La, Lb = (np.eye(3) if L is None else np.asarray(L, float) for L in (level_a, level_b))
    (xa, da), (xb, db) = (feats_a[0] @ La, feats_a[1]), (feats_b[0] @ Lb, feats_b[1])  # bearings R^T x
    if len(xa) < 8 or len(xb) < 8:
        return None
    m = backend(params).match(da, db, ratio=params.ratio)
    if len(m) < max(8, params.min_inliers):
        return None
    xa, xb = xa[m[:, 0]], xb[m[:, 1]]
    E, inl = ransac_upright(xa, xb, params)
    if E is None or inl.sum() < params.min_inliers:
        return None
    for _ in range(params.refits):  # refit on the inliers (turns about the vertical), which may then grow
        E = refine_upright(E, xa[inl], xb[inl], params)
        inl = epipolar_error(E[None], xa, xb)[0] < np.sin(np.radians(params.threshold_deg))
    R, d = decompose(E, xa[inl], xb[inl])
    par = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", xb[inl], xa[inl] @ R.T), -1.0, 1.0)))
    if inl.sum() < params.min_inliers or float(np.median(par)) < params.min_baseline_deg:
        return None
    return RelativePose(Lb @ R @ La.T, La @ d, int(inl.sum()), len(m), float(np.median(par)),
                        floor_scale(R, d, xa[inl], xb[inl], params))


def ransac_upright(xa: np.ndarray, xb: np.ndarray, params: RelativeParams) -> tuple[np.ndarray | None, np.ndarray]:
    """The essential matrix (3, 3) with ``xb^T E xa = 0`` for most of the bearing pairs ``xa``, ``xb``
    (N, 3), and its inliers (N,) bool, for two upright cameras: the turn about the vertical on a grid
    (``turn_step_deg``), for each turn the step's direction from ``pairs`` random pairs of matches
    (perpendicular to both their epipolar normals), every hypothesis scored at once (within
    ``upright_threshold_deg``: a camera tilted a little); the one with most inliers kept. A minimal
    sample of two matches, not eight: a few hundred samples find a motion that a quarter of the
    matches agree with (eight-point RANSAC would need ~10^5)."""
    n = len(xa)
    rng = np.random.default_rng(params.seed)
    k = rng.integers(0, n, (2, params.pairs))
    k = k[:, k[0] != k[1]]
    th = np.radians(np.arange(0.0, 360.0, params.turn_step_deg))
    Rz = turns(th)
    thr = np.sin(np.radians(params.upright_threshold_deg))
    best = (-1.0, None, None)
    step = max(1, CHUNK // max(1, n * k.shape[1]))
    for lo in range(0, len(th), step):
        R = Rz[lo:lo + step]
        ra = np.einsum("tij,nj->tni", R, xa)  # (T, N, 3) a's bearings turned into b's frame
        nrm = np.cross(ra, xb[None])  # the step t is perpendicular to each: t . (R xa x xb) = 0
        t = np.cross(nrm[:, k[0]], nrm[:, k[1]])  # (T, P, 3)
        t /= np.maximum(np.linalg.norm(t, axis=2, keepdims=True), 1e-12)
        tt = np.swapaxes(t, 1, 2)
        # the sine of xb's angle to the plane through t and R xa: |xb . (t x R xa)| / |t x R xa|
        err = np.abs(nrm @ tt) / np.sqrt(np.maximum(1.0 - (ra @ tt) ** 2, 1e-12))  # (T, N, P)
        inl = err < thr
        score = inl.sum(1) - np.where(inl, err, thr).sum(1) / thr / (n + 1)  # (T, P): count, then smaller errors
        ti, pj = np.unravel_index(int(np.argmax(score)), score.shape)
        if score[ti, pj] > best[0]:
            best = (float(score[ti, pj]), skew(t[ti, pj]) @ R[ti], inl[ti, :, pj])
    _, E, inl = best
    return (E, inl) if E is not None and inl.sum() >= 8 else (None, np.zeros(n, dtype=bool))


CHUNK = 2_000_000  # hypotheses x matches scored at once (memory bounded)


def skew(t: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the cross-product matrices of vectors ``t`` (..., 3)."""
    z = np.zeros(t.shape[:-1])
    return np.stack([np.stack([z, -t[..., 2], t[..., 1]], -1), np.stack([t[..., 2], z, -t[..., 0]], -1),
                     np.stack([-t[..., 1], t[..., 0], z], -1)], -2)


def refine_upright(E: np.ndarray, xa: np.ndarray, xb: np.ndarray, params: RelativeParams) -> np.ndarray:
    """``E`` refitted on its inlier bearings: the turn about the vertical on a fine grid around its own
    (``refine_span_deg``, ``refine_step_deg``), the step for each turn the direction most perpendicular
    to the inliers' epipolar normals (least squares), the turn of least squared error kept."""
    R0, _ = decompose(E, xa, xb)
    th = np.arctan2(R0[1, 0], R0[0, 0]) + np.radians(np.arange(-params.refine_span_deg, params.refine_span_deg
                                                               + 1e-9, params.refine_step_deg))
    R = turns(th)
    nrm = np.cross(np.einsum("tij,nj->tni", R, xa), xb[None])  # (T, N, 3)
    w, v = np.linalg.eigh(np.einsum("tni,tnj->tij", nrm, nrm))  # the smallest eigenvector: the step
    j = int(np.argmin(w[:, 0]))
    return skew(v[j, :, 0]) @ R[j]


def turns(th: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations about the vertical (z) by the angles ``th`` (T,) radians."""
    c, s = np.cos(th), np.sin(th)
    R = np.zeros((len(th), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def epipolar_error(E: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(M, N) the larger sine of the angles between each bearing and its epipolar plane in the other image."""
    la = np.einsum("mij,nj->mni", E, xa)  # planes in b of a's bearings
    lb = np.einsum("mji,nj->mni", E, xb)  # planes in a of b's bearings
    alg = np.abs(np.einsum("ni,mni->mn", xb, la))
    return alg / np.maximum(np.minimum(np.linalg.norm(la, axis=2), np.linalg.norm(lb, axis=2)), 1e-12)


def decompose(E: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, d) of an essential matrix ``E = [t]x R``: of its four motions, the one that puts most of
    the inlier points (bearings ``xa``, ``xb``) in front of both cameras; ``d`` the unit step c_b - c_a
    in a's frame (``-R^T t``)."""
    u, _, vt = np.linalg.svd(E)
    u, vt = u * np.sign(np.linalg.det(u)), vt * np.sign(np.linalg.det(vt))
    w = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    best, out = -1, None
    for R in (u @ w @ vt, u @ w.T @ vt):
        for t in (u[:, 2], -u[:, 2]):
            front = int(in_front(R, t, xa, xb).sum())
            if front > best:
                best, out = front, (R, -R.T @ t)
    return out


def in_front(R: np.ndarray, t: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(N,) whether each point seen along ``xa`` and ``xb`` lies ahead on both rays under the motion
    ``X_b = R X_a + t``: the depths of ``la R xa - lb xb = -t`` in least squares, both positive."""
    ra = xa @ R.T
    g = np.einsum("ni,ni->n", ra, xb)  # the normal equations of [ra, -xb] (la, lb) = -t
    pa, pb = -ra @ t, xb @ t
    det = 1.0 - g * g
    la = (pa + g * pb) / np.maximum(det, 1e-12)
    lb = (g * pa + pb) / np.maximum(det, 1e-12)
    return (la > 0) & (lb > 0) & (det > 1e-9)


def floor_scale(R: np.ndarray, d: np.ndarray, xa: np.ndarray, xb: np.ndarray, params: RelativeParams) -> float | None:
    """The step's length in camera heights above the floor, from the inliers seen below the horizon
    (levelled bearings ``xa``, ``xb``; motion ``R``, unit step ``d`` in a's frame): triangulated with a
    unit step, a point on the floor a camera height below says the step's length; the most common
    such length (bins ``floor_bin`` wide in its logarithm: furniture points, higher, scatter above
    it), when ``min_floor_points`` agree; else None."""
    t = -R @ d
    ra = xa @ R.T
    g = np.einsum("ni,ni->n", ra, xb)
    la = (-ra @ t + g * (xb @ t)) / np.maximum(1.0 - g * g, 1e-12)  # depth along xa for a unit step (in_front)
    low = (xa[:, 2] < -np.sin(np.radians(params.floor_below_deg))) & (la > 0)
    if low.sum() < params.min_floor_points:
        return None
    r = np.log(-1.0 / (la[low] * xa[low, 2]))  # log(step / camera height) that puts each point on the floor
    bins = np.floor(r / params.floor_bin).astype(int)
    vals, counts = np.unique(bins, return_counts=True)
    near = counts + np.r_[0, counts[:-1]] * (np.diff(vals, prepend=vals[0] - 2) == 1) \
        + np.r_[counts[1:], 0] * (np.diff(vals, append=vals[-1] + 2) == 1)  # a bin and its neighbours
    j = int(np.argmax(near))
    if near[j] < params.min_floor_points:
        return None
    at = np.abs(bins - vals[j]) <= 1
    return float(np.exp(np.median(r[at])))


def inverse(rel: RelativePose) -> RelativePose:
    """Frame a's motion from frame b, given b's from a (its length in b's camera heights: the same
    floor, the same camera height)."""
    return RelativePose(rel.rot.T, -rel.rot @ rel.direction, rel.inliers, rel.matches, rel.parallax_deg,
                        rel.per_height)


def poses_along(rel: RelativePose, rot_a: np.ndarray, center_a: np.ndarray, length_m: float,
                spread: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Frame b's poses (3, 3, 3), (3, 3) given frame a's: its rotation from ``rel`` and its centre
    along the step's direction, ``length_m`` from a's and ``spread`` of it shorter and longer."""
    R, d = rel.in_world(rot_a)
    s = float(length_m) * np.array([1.0 - spread, 1.0, 1.0 + spread])
    return np.repeat(R[None], len(s), axis=0), np.asarray(center_a, float)[None] + s[:, None] * d[None]


def floor_under(lines: np.ndarray, center: np.ndarray, reach_m: float = 3.0, band_m: tuple = (0.3, 2.5),
                bin_m: float = 0.05) -> float | None:
    """The height (world z) of the floor under a camera at ``center`` from a map's 3D segments
    ``lines`` (N, 2, 3): of the horizontal segments within ``reach_m`` (xy) and ``band_m`` below it, the
    height (bins of ``bin_m``) that holds most of their length (the floor's edges along the walls);
    None when there are none."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    c = np.asarray(center, dtype=np.float64)
    d = L[:, 1] - L[:, 0]
    n = np.linalg.norm(d, axis=1)
    z = L[:, :, 2].mean(1)
    mid = L.mean(1)
    ok = ((np.abs(d[:, 2]) < 0.05 * np.maximum(n, 1e-9)) & (np.linalg.norm(mid[:, :2] - c[:2], axis=1) <= reach_m)
          & (z <= c[2] - band_m[0]) & (z >= c[2] - band_m[1]))
    if not ok.any():
        return None
    bins = np.floor(z[ok] / bin_m).astype(int)
    vals, inv = np.unique(bins, return_inverse=True)
    weight = np.bincount(inv, weights=n[ok])
    return float(np.median(z[ok][inv == int(np.argmax(weight))]))


def disagreement(rel: RelativePose, rot_a: np.ndarray, center_a: np.ndarray, rot_b: np.ndarray,
                 center_b: np.ndarray, min_step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(P, Q) degrees between each pose pair's relative rotation (poses ``rot_a`` (P, 3, 3), ``rot_b``
    (Q, 3, 3)) and ``rel``'s, and between their step (``center_b - center_a``, in a's frame) and
    ``rel``'s direction (0 where the step is shorter than ``min_step_m``: its direction unknown)."""
    rb_ra = np.einsum("qij,pkj->pqik", rot_b, rot_a)  # R_b R_a^T
    tr = np.einsum("ij,pqij->pq", rel.rot, rb_ra)  # trace(rel^T R_b R_a^T)
    rot = np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))
    step = np.einsum("pij,pqj->pqi", rot_a, center_b[None] - center_a[:, None])
    n = np.linalg.norm(step, axis=2)
    cos = np.einsum("pqi,i->pq", step, rel.direction) / np.maximum(n, 1e-12)
    ang = np.where(n >= min_step_m, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), 0.0)
    return rot, ang
