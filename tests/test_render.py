"""Point splatting renderer: projection, z-buffer, hole-free surfaces, coordinate image."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core import geometry as geo
from ldlmap.core.errors import InputError
from ldlmap.map.render import (PointRenderer, RenderParams, estimate_point_spacing, local_point_spacing,
                               render_points_panorama, render_views)

W, H = 256, 128


def _index_colors(n: int) -> np.ndarray:
    """Colors that encode the point index (base 256), to read back which point won a pixel."""
    i = np.arange(n, dtype=np.int64) + 1
    return np.stack([i % 256, (i // 256) % 256, i // 65536], axis=1).astype(np.uint8)


def _decode(rgb: np.ndarray) -> np.ndarray:
    rgb = rgb.astype(np.int64)
    return rgb[..., 0] + 256 * rgb[..., 1] + 65536 * rgb[..., 2] - 1


def _sparse(points, colors, R=np.eye(3), t=np.zeros(3)):
    """Single-pixel footprints, no hole filling."""
    return render_points_panorama(points, colors, R, t, W, H, point_spacing_m=1e-6, fill_iterations=0, depth_tolerance=0.0)


def test_few_points_land_on_projected_pixels():
    rng = np.random.default_rng(0)
    R = geo.rotation_from_axis_angle([0.3, -0.5, 0.8], 0.7)
    t = np.array([0.5, -1.0, 1.2])
    dirs = geo.normalize(rng.normal(size=(12, 3)))
    pts = t + dirs * rng.uniform(1.0, 5.0, (12, 1))
    cols = _index_colors(12)
    rgb, xyz, depth = _sparse(pts, cols, R, t)
    uv = geo.project_to_pixels(pts, R, t, W, H)
    c = np.mod(np.floor(uv[:, 0]).astype(int), W)
    r = np.clip(np.floor(uv[:, 1]).astype(int), 0, H - 1)
    assert np.array_equal(_decode(rgb[r, c]), np.arange(12))
    np.testing.assert_allclose(xyz[r, c], pts, atol=1e-5)
    np.testing.assert_allclose(depth[r, c], np.linalg.norm(pts - t, axis=1), rtol=1e-6)
    assert np.isfinite(depth).sum() == 12 and (rgb.any(axis=2)).sum() == 12


def test_zbuffer_keeps_nearer_point_in_either_order():
    d = geo.normalize(np.array([1.0, 2.0, 0.5]))
    near, far = 1.5 * d, 4.0 * d
    for pts in (np.stack([near, far]), np.stack([far, near])):
        cols = np.where(np.linalg.norm(pts, axis=1, keepdims=True) < 2, [255, 0, 0], [0, 0, 255]).astype(np.uint8)
        rgb, xyz, depth = _sparse(pts, cols)
        r, c = geo.pixel_index_from_bearing(d, W, H)
        assert tuple(rgb[r, c]) == (255, 0, 0)
        np.testing.assert_allclose(xyz[r, c], near, atol=1e-6)
        assert depth[r, c] == pytest.approx(1.5, rel=1e-6)
        assert np.isfinite(depth).sum() == 1


def test_zbuffer_matches_brute_force_min_range():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-3, 3, (20000, 3))
    rgb, xyz, depth = _sparse(pts, _index_colors(len(pts)))
    r, c = geo.pixel_index_from_bearing(pts, W, H)
    rngs = np.linalg.norm(pts, axis=1)
    best = np.full(H * W, np.inf)
    np.minimum.at(best, r * W + c, rngs)
    best = best.reshape(H, W)
    np.testing.assert_allclose(np.nan_to_num(depth, nan=np.inf), best, rtol=1e-6)
    # The coordinate image holds exactly the point splatted there (read back from its color).
    ok = np.isfinite(depth)
    idx = _decode(rgb[ok])
    np.testing.assert_allclose(xyz[ok], pts[idx], atol=1e-5)
    np.testing.assert_allclose(depth[ok], rngs[idx], rtol=1e-6)


@pytest.mark.parametrize("width", [W, 16])  # 16: narrower than the largest footprint (the other wrap)
def test_footprint_wraps_around_u(width):
    # A point straight behind the camera sits on the u = 0 / W seam; a wide footprint covers both sides.
    pts = np.array([[-2.0, 1e-4, 0.0]])
    rgb, xyz, depth = render_points_panorama(pts, np.full((1, 3), 200, np.uint8), np.eye(3), np.zeros(3), width,
                                             width // 2, point_radius_px=2, fill_iterations=0)
    cols = np.nonzero(np.isfinite(depth).any(axis=0))[0]
    assert {0, 1, width - 1, width - 2} <= set(cols.tolist())
    assert len(cols) in (5, 6)  # a 5-pixel-wide square touches 5 or 6 columns


def test_dense_plane_renders_without_holes():
    rng = np.random.default_rng(2)
    n = 150_000
    pts = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), np.full(n, -1.0)])
    cols = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    center = np.array([0.1, -0.2, 0.0])
    rgb, xyz, depth = render_points_panorama(pts, cols, np.eye(3), center, W, H)
    # Pixels whose ray hits the plane well inside its border must be filled and see the plane.
    b = geo.bearing_from_pixel(geo.pixel_centers(W, H), W, H)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -1.0 / b[..., 2]
    hit = center + s[..., None] * b
    inner = (b[..., 2] < -0.05) & (np.abs(hit[..., 0]) < 1.8) & (np.abs(hit[..., 1]) < 1.8)
    assert inner.sum() > 0.2 * W * H
    assert np.isfinite(depth[inner]).all()
    np.testing.assert_allclose(xyz[inner][:, 2], -1.0, atol=1e-5)
    # Each pixel shows a point near its own ray hit (footprint of a couple of pixels at most).
    err = np.linalg.norm(xyz[inner] - hit[inner], axis=1) / np.linalg.norm(hit[inner] - center, axis=1)
    assert np.degrees(np.median(err)) < 180.0 / H and np.degrees(np.max(err)) < 8 * 180.0 / H
    # Nothing above the horizon.
    assert not np.isfinite(depth[b[..., 2] > 0.05]).any()


def test_point_spacing_estimate_on_a_grid_and_random_plane():
    g = np.stack(np.meshgrid(np.arange(200) * 0.01, np.arange(200) * 0.01), -1).reshape(-1, 2)
    grid = np.column_stack([g, np.zeros(len(g))])
    # Random samples of density rho: mean spacing 1 / sqrt(rho) = 1 cm.
    rnd = np.column_stack([np.random.default_rng(3).uniform(0, 2, (40000, 2)), np.zeros(40000)])
    assert estimate_point_spacing(rnd) == pytest.approx(0.01, rel=0.1)
    assert 0.01 <= estimate_point_spacing(grid) <= 0.025


def test_render_views_and_bad_input():
    rng = np.random.default_rng(4)
    pts = rng.uniform(-3, 3, (5000, 3))
    cols = rng.integers(0, 256, (5000, 3), dtype=np.uint8)
    centers = np.array([[0.0, 0, 0], [0.5, 0.5, 0.5]])
    views = list(render_views(pts, cols, centers, RenderParams(width=W, height=H)))
    assert len(views) == 2 and views[1].rgb.shape == (H, W, 3) and views[1].xyz.dtype == np.float32
    np.testing.assert_allclose(views[1].center, centers[1])
    with pytest.raises(InputError, match="empty"):
        render_points_panorama(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.eye(3), np.zeros(3), W, H)
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        render_points_panorama(bad, cols, np.eye(3), np.zeros(3), W, H)
    with pytest.raises(InputError, match="colors"):
        render_points_panorama(pts, cols[:10], np.eye(3), np.zeros(3), W, H)
    with pytest.raises(InputError, match="W = 2 H"):
        render_points_panorama(pts, cols, np.eye(3), np.zeros(3), 100, 100)
    with pytest.raises(InputError, match="centers"):
        list(render_views(pts, cols, np.zeros(3)))
    with pytest.raises(InputError, match="device"):
        PointRenderer(pts, cols, device="nonsense")


def test_local_spacing_follows_density():
    rng = np.random.default_rng(6)
    dense = np.column_stack([rng.uniform(0, 1, (40000, 2)), np.zeros(40000)])  # 0.5 cm spacing
    sparse = np.column_stack([rng.uniform(2, 3, (2500, 2)), np.zeros(2500)])  # 2 cm spacing
    pts = np.concatenate([dense, sparse])
    loc = local_point_spacing(pts, 0.01, clip=(0.1, 10.0))
    assert np.median(loc[:40000]) == pytest.approx(0.005, rel=0.25)
    assert np.median(loc[40000:]) == pytest.approx(0.02, rel=0.25)
