"""Back-projection of 2D keypoints of rendered views to 3D, and per-view map features.

The paper (sec. 3.1) renders synthetic views of the colored cloud, detects local features and
looks up each keypoint's 3D point. The coordinate image of :mod:`ldlmap.map.render` stores the
visible world point per pixel, so the lookup is an image read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.map.render import PointRenderer, RenderParams

cv2 = lazy_module("cv2")


@dataclass(frozen=True)
class ViewFeatures:
    """Features of one rendered view with their 3D positions (only back-projected ones)."""

    xyz: np.ndarray  # (K, 3) float32 world coordinates of the keypoints
    descriptors: np.ndarray  # (K, D) backend storage dtype
    scores: np.ndarray  # (K,) float32
    keypoints: np.ndarray  # (K, 2) float32 continuous pixel coordinates in the rendered view
    center: np.ndarray  # (3,) float64 translation the view was rendered at
    backend: str  # feature backend name


def backproject_keypoints(keypoints: np.ndarray, xyz_image: np.ndarray, search_radius: int = 1,
                          ) -> tuple[np.ndarray, np.ndarray]:
    """3D points of keypoints from a world-coordinate image.

    Each keypoint (continuous pixel coordinates, pixel centre = +0.5) reads the pixel that
    contains it; when that pixel is empty (NaN), the nearest valid pixel within
    ``search_radius`` (max norm, wrapping in u) is used. Keypoints with no valid pixel nearby
    are invalid.

    Returns:
        ``xyz`` (K, 3) float32 (NaN where invalid) and ``valid`` (K,) bool.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    img = np.asarray(xyz_image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"coordinate image must have shape (H, W, 3), got {img.shape}")
    if kp.ndim != 2 or kp.shape[1] != 2:
        raise InputError(f"keypoints must have shape (K, 2), got {kp.shape}")
    H, W = img.shape[:2]
    if len(kp) == 0:
        return np.zeros((0, 3), np.float32), np.zeros(0, bool)
    if not np.isfinite(kp).all():
        raise InputError("keypoints contain NaN or infinite coordinates")
    col = np.floor(kp[:, 0]).astype(np.int64)
    row = np.floor(kp[:, 1]).astype(np.int64)
    r = max(int(search_radius), 0)
    off = np.arange(-r, r + 1)
    dr, dc = (a.ravel() for a in np.meshgrid(off, off, indexing="ij"))
    # Candidates (K, O), the centre first so that ties favour it; sorted by distance to the keypoint.
    rr = row[:, None] + dr[None]
    cc = np.mod(col[:, None] + dc[None], W)
    inside = (rr >= 0) & (rr < H)
    rr_c = np.clip(rr, 0, H - 1)
    cand = img[rr_c, cc].astype(np.float32)  # (K, O, 3)
    ok = inside & np.isfinite(cand).all(axis=2)
    # Distance from the keypoint to each candidate pixel centre (unwrapped offsets).
    du = (col[:, None] + dc[None] + 0.5) - kp[:, :1]
    dv = (rr + 0.5) - kp[:, 1:]
    dist = np.where(ok, du * du + dv * dv, np.inf)
    best = np.argmin(dist, axis=1)
    valid = np.isfinite(dist[np.arange(len(kp)), best])
    xyz = cand[np.arange(len(kp)), best]
    xyz[~valid] = np.nan
    return xyz, valid


def view_features(points: np.ndarray, colors: np.ndarray, center: np.ndarray, backend, width: int = 1024,
                  height: int = 512, *, mask: np.ndarray | None = None, max_keypoints: int | None = None,
                  renderer=None, device: str = "cpu", mask_erosion_px: int = 3) -> ViewFeatures:
    """Render the cloud at translation ``center`` (identity rotation), extract features, lift to 3D.

    ``backend`` is a :class:`~ldlmap.features.FeatureBackend`. Pass a prepared
    :class:`~ldlmap.map.render.PointRenderer` as ``renderer`` when rendering many views of one cloud
    (``points`` and ``colors`` are then ignored). Keypoints within ``mask_erosion_px`` pixels of
    empty pixels, or on them, are dropped.
    """
    if renderer is None:
        renderer = PointRenderer(points, colors, RenderParams(width=int(width), height=int(height)), device=device)
    view = renderer.render(np.eye(3), center)
    # Keypoints only well inside rendered content: not on the rim of holes (unscanned areas).
    valid_px = cv2.erode(np.isfinite(view.depth).astype(np.uint8), np.ones((3, 3), np.uint8),
                         iterations=int(mask_erosion_px)).astype(bool) if mask_erosion_px > 0 else np.isfinite(view.depth)
    m = valid_px if mask is None else (valid_px & np.asarray(mask, bool))
    feats = backend.extract(view.rgb, mask=m, max_keypoints=max_keypoints)
    xyz, valid = backproject_keypoints(feats.keypoints, view.xyz)
    f = feats.subset(valid)
    return ViewFeatures(xyz=xyz[valid], descriptors=f.descriptors, scores=f.scores, keypoints=f.keypoints,
                        center=np.asarray(center, dtype=np.float64).reshape(3), backend=backend.name)
