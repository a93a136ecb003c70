"""Principal 3D directions by voting and line grouping."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import rotation_from_axis_angle
from ldlmap.lines3d import extract_lines, filter_by_length
from ldlmap.lines3d.principal import (FrameParams, assign_line_groups, horizontal_directions, manhattan_frame,
                                      principal_directions_3d, principal_frame)
from ldlmap.map.validate import check_principal
from tests._room_cloud import box_room


def _angle_to_axes(P: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """For each true axis (rows), angle in degrees to the closest estimated direction (sign-free)."""
    c = np.abs(axes @ P.T).max(axis=1)
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def _lines_along(axes, rng, n_per=(40, 25, 15), noise_deg=1.0):
    out = []
    for a, n in zip(axes, n_per):
        d = a + rng.normal(scale=np.radians(noise_deg), size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        s = rng.uniform(-3, 3, size=(n, 3))
        out.append(np.stack([s, s + rng.uniform(0.5, 2.0, (n, 1)) * d], 1))
    return np.concatenate(out)


def test_principal_directions_recover_rotated_frame_with_clutter():
    rng = np.random.default_rng(0)
    R = rotation_from_axis_angle(rng.normal(size=3), 1.1)
    axes = R.T  # rows: the rotated frame's axes
    lines = _lines_along(axes, rng)
    clutter = rng.uniform(-3, 3, size=(30, 2, 3)) * np.array([1, 1, 1])
    clutter[:, 1] = clutter[:, 0] + 0.3 * (clutter[:, 1] - clutter[:, 0]) / np.linalg.norm(clutter[:, 1] - clutter[:, 0], axis=1, keepdims=True)
    P = principal_directions_3d(np.concatenate([lines, clutter]), k=3)
    assert P.shape == (3, 3)
    assert np.allclose(np.linalg.norm(P, axis=1), 1.0)
    assert np.linalg.det(P) > 0
    # Ordered by total length: axis 0 has the most lines.
    assert abs(P[0] @ axes[0]) > np.cos(np.radians(1.0))
    assert np.all(_angle_to_axes(P, axes) < 1.0)


def test_principal_directions_complete_missing_and_bad_input():
    lines = np.array([[[0, 0, 0], [1, 0, 0]], [[0, 1, 0], [0, 2.5, 0]]], dtype=float)
    P = principal_directions_3d(lines)
    assert np.allclose(np.abs(P), np.eye(3)[[1, 0, 2]], atol=1e-9)
    assert np.linalg.det(P) > 0
    with pytest.raises(InputError):
        principal_directions_3d(np.zeros((0, 2, 3)))
    with pytest.raises(InputError):
        principal_directions_3d(np.zeros((4, 3)))


def test_assign_line_groups():
    P = np.eye(3)
    d = np.array([[1, 0.1, 0], [0, -1, 0], [0.7, 0.7, 0], [0, 0.2, -1], [0, 0, 0]], dtype=float)
    g = assign_line_groups(d, P)
    assert g.tolist() == [0, 1, -1, 2, -1]


def test_principal_directions_of_extracted_lines_in_rotated_room():
    yaw = float(np.random.default_rng(7).uniform(0, 360))
    pts, _ = box_room(seed=2, size=(5.0, 4.0, 2.6), n_boxes=2, density=2500.0, yaw_deg=yaw)
    lines = extract_lines(pts)
    kept, _, _ = filter_by_length(lines, pts.min(0), pts.max(0))
    P = principal_directions_3d(kept)
    c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    axes = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
    err = _angle_to_axes(P, axes)
    assert np.all(err < 2.0), err
    assert np.linalg.det(P) > 0


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(a @ b), -1, 1))))


def test_manhattan_frame_is_orthonormal_and_keeps_vertical_and_main_horizontal():
    """Two voted directions 33 deg apart; the frame keeps the vertical and the best
    supported horizontal pair, and reports how far the votes were from it."""
    rng = np.random.default_rng(3)
    R = rotation_from_axis_angle(rng.normal(size=3), 0.8)
    v, h1 = R @ [0, 0, 1.0], R @ [1.0, 0, 0]
    h2 = R @ [np.cos(np.radians(33)), np.sin(np.radians(33)), 0]  # a second wing, 33 deg off h1
    lines = _lines_along(np.stack([v, h1, h2]), rng, n_per=(40, 40, 30))
    P = principal_directions_3d(lines)
    assert min(_angle(P[i], P[j]) for i in range(3) for j in range(i)) < 40  # the votes: not orthogonal
    F, dev = manhattan_frame(lines, P, up=v)
    np.testing.assert_allclose(F @ F.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(F) > 0
    assert min(_angle(f, v) for f in F) < 1.0 and min(_angle(f, h1) for f in F) < 1.0
    assert dev.max() == pytest.approx(57.0, abs=1.5) and np.sort(dev)[1] < 1.0
    assert all(_angle(F[i], P[i]) == pytest.approx(dev[i]) for i in range(3))  # rows follow the votes' order
    # An orthogonal scene: the frame is the voted triplet (within the voting precision).
    lines = _lines_along(R.T, rng)
    P = principal_directions_3d(lines)
    F, dev = manhattan_frame(lines, P, up=v)
    assert dev.max() < 1.0 and all(_angle(F[i], P[i]) < 1.0 for i in range(3))
    with pytest.raises(InputError):
        manhattan_frame(lines, P[:2])


def _room_edges(footprint, height: float, yaw_deg: float) -> np.ndarray:
    """Floor, ceiling and corner edges of a prism room over ``footprint`` (x, y), turned by ``yaw_deg``
    about z and cut into 1 m pieces (as extracted lines come)."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    fp = np.asarray(footprint, float) @ np.array([[c, s], [-s, c]])
    segs = []
    for a, b in zip(fp, np.roll(fp, -1, axis=0)):
        for z in (0.0, height):
            segs.append([[*a, z], [*b, z]])
        segs.append([[*a, 0.0], [*a, height]])
    out = []
    for p, q in np.asarray(segs):
        n = max(1, int(np.ceil(np.linalg.norm(q - p))))
        t = np.linspace(0, 1, n + 1)
        out += [[p + (q - p) * t[i], p + (q - p) * t[i + 1]] for i in range(n)]
    return np.asarray(out)


# Walls at 0 and 45 degrees (and one short one at 90): the footprint of no box.
ANGLED = ((0.0, 0.0), (6.0, 0.0), (8.8, 2.8), (3.5, 2.8), (3.5, 3.5))


def test_angled_room_gets_an_atlanta_frame_with_its_wall_directions():
    """Walls at 45 degrees keep their own direction (the Manhattan frame would fold them
    onto a perpendicular pair)."""
    yaw = 17.0
    lines = _room_edges(ANGLED, 2.6, yaw)
    P = principal_directions_3d(lines)
    F, dev, kind = principal_frame(lines, P)
    walls = [np.array([np.cos(np.radians(a + yaw)), np.sin(np.radians(a + yaw)), 0.0]) for a in (0.0, 45.0)]
    assert kind == "atlanta"
    for true in (np.array([0, 0, 1.0]), *walls):
        assert min(_angle(f, true) for f in F) < 2.0
    assert np.linalg.det(F) > 0 and np.allclose(np.linalg.norm(F, axis=1), 1.0)
    H, between = horizontal_directions(lines, np.array([0, 0, 1.0]))
    assert between == pytest.approx(45.0, abs=1.0)
    # Forced onto the Manhattan pair the 45-degree walls are lost: one frame axis is 45 deg off them.
    M, _ = manhattan_frame(lines, P)
    assert max(min(_angle(f, w) for f in M) for w in walls) > 40.0


def test_sloped_ceilings_add_their_inclined_directions():
    """A shed ceiling's slope edges are not horizontal: they do not vote for the horizontals, the
    vertical stays the vertical, and the slope becomes a direction of its own (a gable: two)."""
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.spec import CeilingSpec, SceneSpec

    rect = ((0.0, 0.0), (5.0, 0.0), (5.0, 4.0), (0.0, 4.0))
    for ceiling, slopes in ((CeilingSpec("shed", 0.0, 40.0), [40.0]), (CeilingSpec("shed", 0.0, 15.0), [15.0]),
                            (CeilingSpec("gable", 0.0, 30.0), [30.0, 30.0])):
        lines = mesh_edges(build_scene(SceneSpec("t", rect, 2.4, ceiling=ceiling)))
        F, _, kind = principal_frame(lines, principal_directions_3d(lines))
        assert kind == "sloped" and len(F) == 3 + len(slopes)
        np.testing.assert_allclose(F[:3] @ F[:3].T, np.eye(3), atol=1e-9)  # the box's Manhattan frame first
        for true in np.eye(3):
            assert min(_angle(f, true) for f in F[:3]) < 1.0
        rise = np.degrees(np.arcsin(np.abs(F[3:, 2])))
        np.testing.assert_allclose(np.sort(rise), slopes, atol=0.5)
        assert np.all(np.abs(F[3:, 1]) < 1e-3)  # slopes run along x (direction_deg 0)
        check_principal(F, orthonormal=False)  # a 15-deg slope is still a distinct map direction
    # Walls at 45 degrees under a sloped ceiling keep their Atlanta frame, and the slope is added.
    rhomb = ((0.0, 0.0), (6.0, 0.0), (8.5, 2.5), (2.5, 2.5))  # convex, as sloped ceilings need
    for ceiling, frame in ((CeilingSpec("shed", 0.0, 30.0), "sloped"), (CeilingSpec(), "atlanta")):
        lines = mesh_edges(build_scene(SceneSpec("t", rhomb, 2.4, ceiling=ceiling)))
        F, _, kind = principal_frame(lines, principal_directions_3d(lines))
        assert kind == frame
        horizontal = F[np.abs(F[:, 2]) < 1e-3]
        assert min(_angle(h, np.array([0.7071, 0.7071, 0.0])) for h in horizontal) < 1.0
    assert principal_frame(lines, principal_directions_3d(lines), params=FrameParams(max_inclined=0))[2] == "atlanta"


def test_line_groups_keep_to_their_elevation():
    """With the up axis, a sloped edge 15 deg off a wall direction joins no horizontal group (its
    arc misses that direction's vanishing point in a panorama), while level lines do."""
    P = np.array([[0, 0, 1.0], [1, 0, 0], [0, 1, 0]])
    s15 = [np.cos(np.radians(15)), 0, np.sin(np.radians(15))]
    d = np.array([[1, 0.02, 0], s15, [0.05, 0, 1], [0.2, 1, 0.02]])
    assert assign_line_groups(d, P).tolist() == [1, 1, 0, 2]
    assert assign_line_groups(d, P, up=(0, 0, 1)).tolist() == [1, -1, 0, 2]
    assert assign_line_groups(d, np.vstack([P, s15]), up=(0, 0, 1)).tolist() == [1, 3, 0, 2]
