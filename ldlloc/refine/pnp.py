"""Spherical PnP-RANSAC through pycolmap's ``EQUIRECTANGULAR`` camera.

A panorama sees in every direction, so a pinhole PnP on ``x / z`` cannot use points behind the
camera. pycolmap's absolute pose solver works on camera rays, and its equirectangular model maps
pixels exactly as our convention does up to the fixed rotation ``geometry.COLMAP_FROM_OURS``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.geometry import pose_from_colmap
from ldlmap.core.signals import import_pycolmap


@dataclass(frozen=True)
class PnPParams:
    """RANSAC settings of the spherical PnP."""

    max_error_px: float = 6.0
    """RANSAC inlier threshold in panorama pixels (at the query width)."""
    min_inliers: int = 12
    """Fewer inliers: the refinement failed."""
    seed: int = 0
    """RANSAC seed, for reproducible results."""


@dataclass
class PnPResult:
    rot_cam_from_world: np.ndarray
    center: np.ndarray
    inliers: np.ndarray  # (M,) bool


def estimate_pose_spherical(keypoints_uv: np.ndarray, points_world: np.ndarray, width: int, height: int,
                            params: PnPParams = PnPParams()) -> PnPResult | None:
    """Pose ``(R, t)`` from 2D-3D matches on an equirectangular image, or None when it fails.

    ``keypoints_uv`` (M, 2) are continuous image coordinates (pixel centre at +0.5), as everywhere
    in this toolkit; ``points_world`` (M, 3) the matched 3D points.
    """
    pycolmap = import_pycolmap()
    uv = np.ascontiguousarray(keypoints_uv, dtype=np.float64)
    X = np.ascontiguousarray(points_world, dtype=np.float64)
    if len(uv) < max(4, params.min_inliers):
        return None
    cam = pycolmap.Camera(model="EQUIRECTANGULAR", width=int(width), height=int(height),
                          params=[float(width), float(height)])
    opts = pycolmap.AbsolutePoseEstimationOptions()
    opts.ransac.max_error = float(params.max_error_px)
    opts.ransac.random_seed = int(params.seed)
    res = pycolmap.estimate_and_refine_absolute_pose(uv, X, cam, opts)
    if res is None or int(res["num_inliers"]) < params.min_inliers:
        return None
    cfw = res["cam_from_world"]
    R, t = pose_from_colmap(cfw.rotation.matrix(), np.asarray(cfw.translation))
    return PnPResult(R, t, np.asarray(res["inlier_mask"], dtype=bool))
