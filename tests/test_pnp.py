"""Spherical PnP recovers poses from matches all around the panorama, with outliers."""

from __future__ import annotations

import numpy as np

from ldlmap.core import geometry as g
from ldlloc.refine.pnp import PnPParams, estimate_pose_spherical
from tests.test_geometry import random_rotation

W, H = 1024, 512


def test_pnp_recovers_pose_with_outliers():
    rng = np.random.default_rng(0)
    for _ in range(5):
        R, t = random_rotation(rng), rng.normal(size=3)
        X = t + g.normalize(rng.normal(size=(300, 3))) * rng.uniform(1, 5, size=(300, 1))
        uv = g.project_to_pixels(X, R, t, W, H) + rng.normal(size=(300, 2)) * 0.5
        uv[:, 0] = np.mod(uv[:, 0], W)
        uv[:120] = rng.uniform(0, 1, size=(120, 2)) * [W, H]  # 40 % outliers
        res = estimate_pose_spherical(uv, X, W, H, PnPParams(max_error_px=4.0))
        assert res is not None
        assert g.rotation_error_deg(res.rot_cam_from_world, R) < 0.2
        assert g.translation_error(res.center, t) < 0.01
        assert res.inliers[120:].mean() > 0.95 and res.inliers[:120].mean() < 0.1


def test_pnp_fails_cleanly_on_garbage():
    rng = np.random.default_rng(1)
    uv = rng.uniform(0, 1, size=(40, 2)) * [W, H]
    X = rng.normal(size=(40, 3))
    assert estimate_pose_spherical(uv, X, W, H, PnPParams(max_error_px=2.0, min_inliers=20)) is None
    assert estimate_pose_spherical(uv[:3], X[:3], W, H) is None
