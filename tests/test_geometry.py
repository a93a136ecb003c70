"""Conventions module: round trips, known values, icosphere counts, COLMAP frame."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core import geometry as g

W, H = 1024, 512


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def test_known_bearings():
    # Image centre looks along +x, top row along +z, bottom along -z.
    np.testing.assert_allclose(g.bearing_from_pixel([W / 2, H / 2], W, H), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(g.bearing_from_pixel([W / 2, 0], W, H), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(g.bearing_from_pixel([W / 2, H], W, H), [0, 0, -1], atol=1e-12)
    # A quarter turn to the right of centre (u = 3W/4) is atan2(y, x) = -pi/2: the -y axis.
    np.testing.assert_allclose(g.bearing_from_pixel([3 * W / 4, H / 2], W, H), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(g.bearing_from_pixel([W / 4, H / 2], W, H), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(g.pixel_from_bearing([1.0, 0, 0], W, H), [W / 2, H / 2])
    np.testing.assert_allclose(g.pixel_from_bearing([0, 1.0, 0], W, H), [W / 4, H / 2])


def test_pixel_bearing_round_trip():
    uv = g.pixel_centers(W, H).reshape(-1, 2)
    b = g.bearing_from_pixel(uv, W, H)
    np.testing.assert_allclose(np.linalg.norm(b, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(g.pixel_from_bearing(b, W, H), uv, atol=1e-8)
    row, col = g.pixel_index_from_bearing(b, W, H)
    np.testing.assert_array_equal(col, np.floor(uv[:, 0]).astype(int))
    np.testing.assert_array_equal(row, np.floor(uv[:, 1]).astype(int))


def test_bearing_pixel_round_trip_random_directions():
    rng = np.random.default_rng(0)
    d = g.normalize(rng.normal(size=(1000, 3)))
    np.testing.assert_allclose(g.bearing_from_pixel(g.pixel_from_bearing(d, W, H), W, H), d, atol=1e-12)


def test_pixel_centers_layout():
    c = g.pixel_centers(8, 4)
    assert c.shape == (4, 8, 2)
    np.testing.assert_allclose(c[0, 0], [0.5, 0.5])
    np.testing.assert_allclose(c[3, 7], [7.5, 3.5])


def test_world_camera_round_trip_and_definition():
    rng = np.random.default_rng(1)
    R, t = random_rotation(rng), rng.normal(size=3)
    X = rng.normal(size=(50, 3))
    p = g.cam_from_world(X, R, t)
    np.testing.assert_allclose(p, (R @ (X - t).T).T, atol=1e-12)
    np.testing.assert_allclose(g.world_from_cam(p, R, t), X, atol=1e-12)
    # A point straight ahead of an identity-rotation camera lands on the image centre.
    np.testing.assert_allclose(g.project_to_pixels(t + [2.0, 0, 0], np.eye(3), t, W, H), [W / 2, H / 2])


def test_errors():
    R = g.rotation_from_axis_angle([0, 0, 1], np.radians(7.0))
    assert g.rotation_error_deg(R, np.eye(3)) == pytest.approx(7.0)
    assert g.rotation_error_deg(np.eye(3), np.eye(3)) == pytest.approx(0.0, abs=1e-6)
    flip = g.rotation_from_axis_angle([1, 1, 0], np.pi)
    assert g.rotation_error_deg(flip, np.eye(3)) == pytest.approx(180.0)
    assert g.translation_error([1, 2, 3], [1, 2, 5]) == pytest.approx(2.0)


def test_rotation_helpers():
    rng = np.random.default_rng(2)
    R = random_rotation(rng)
    assert g.is_rotation(R)
    assert not g.is_rotation(-R)
    Rz = g.rotation_from_axis_angle([0, 0, 2.0], np.pi / 2)
    np.testing.assert_allclose(Rz @ [1, 0, 0], [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("level,count", [(0, 12), (1, 42), (2, 162), (3, 642), (4, 2562), (5, 10242)])
def test_icosphere_counts(level, count):
    V, F = g.icosphere(level)
    assert V.shape == (count, 3)
    assert F.shape == (20 * 4 ** level, 3)
    np.testing.assert_allclose(np.linalg.norm(V, axis=1), 1.0, atol=1e-12)
    # Euler characteristic of a sphere: V - E + F = 2 with E = 3F/2.
    assert count - 3 * len(F) // 2 + len(F) == 2
    # No duplicated vertices.
    assert len(np.unique(np.round(V, 9), axis=0)) == count


def test_icosphere_is_uniform():
    V = g.icosphere_points(3)
    # Nearest-neighbour angles vary little on an icosphere.
    dots = V @ V.T
    np.fill_diagonal(dots, -1)
    nn = np.degrees(np.arccos(dots.max(axis=1)))
    assert nn.max() / nn.min() < 1.3
    assert np.linalg.norm(V.mean(axis=0)) < 1e-9


def test_half_icosphere():
    V = g.half_icosphere_points(5)
    assert len(V) == 10242 // 2
    full = g.icosphere_points(5)
    # Every full-sphere vertex is +-one of the half-sphere vertices.
    best = np.abs(full @ V.T).max(axis=1)
    np.testing.assert_allclose(best, 1.0, atol=1e-12)


def test_colmap_conversion_round_trip():
    rng = np.random.default_rng(3)
    R, t = random_rotation(rng), rng.normal(size=3)
    R_c, t_c = g.colmap_cam_from_world(R, t)
    assert g.is_rotation(R_c)
    R2, t2 = g.pose_from_colmap(R_c, t_c)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)


def test_colmap_equirectangular_camera_agrees_with_ours():
    pycolmap = pytest.importorskip("pycolmap")
    cam = pycolmap.Camera(model="EQUIRECTANGULAR", width=W, height=H, params=[W, H])
    rng = np.random.default_rng(4)
    R, t = random_rotation(rng), rng.normal(size=3)
    X = t + rng.normal(size=(200, 3)) * 3
    ours = g.project_to_pixels(X, R, t, W, H)
    R_c, t_c = g.colmap_cam_from_world(R, t)
    theirs = cam.img_from_cam(X @ R_c.T + t_c)
    du = np.abs(ours[:, 0] - theirs[:, 0])
    du = np.minimum(du, W - du)  # the seam at u = 0 / W
    assert du.max() < 1e-6
    np.testing.assert_allclose(ours[:, 1], theirs[:, 1], atol=1e-6)
