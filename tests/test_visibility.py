"""Line visibility behind walls (ldlmap.map.visibility) and its use in the 3D distance functions."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ldlmap.map.visibility import line_visibility

H = 2.5


def _wall(p, q, z0=0.0, z1=H):
    return np.array([[p[0], p[1], z0], [q[0], q[1], z0], [q[0], q[1], z1], [p[0], p[1], z1]], dtype=float)


def _two_rooms():
    """Rooms A = [0, 4] x [0, 3] and B = [4, 8] x [0, 3] sharing the wall x = 4, with a door
    y in [1, 2], z < 2 in it (the lintel above the door is wall)."""
    walls = [_wall((0, 0), (8, 0)), _wall((8, 0), (8, 3)), _wall((8, 3), (0, 3)), _wall((0, 3), (0, 0)),
             _wall((4, 0), (4, 1)), _wall((4, 2), (4, 3)), _wall((4, 1), (4, 2), 2.0, H)]
    lines = np.array([
        [[0, 0, 0], [0, 0, H]],  # 0: corner of A (on two walls)
        [[8, 3, 0], [8, 3, H]],  # 1: far corner of B, hidden behind the shared wall from A's left
        [[8, 1.5, 0.2], [8, 1.5, 1.8]],  # 2: on B's far wall, straight through the door
        [[4, 1, 0], [4, 1, 2.0]],  # 3: the door's frame
        [[5, 0, 0], [7, 0, 0]],  # 4: B's floor edge along y = 0
    ], dtype=float)
    return np.array(walls), lines


def test_walls_hide_lines_and_doors_let_them_through():
    walls, lines = _two_rooms()
    T = np.array([[1.0, 1.5, 1.4],   # in A, looking at the door
                  [1.0, 2.8, 1.4],   # in A, near its back-left corner
                  [6.0, 1.5, 1.4]])  # in B
    vis = line_visibility(lines, T, walls)
    assert vis[0].tolist() == [True, False, True, True, False]
    assert vis[1, 0] and not vis[1, 1] and vis[1, 3]
    assert vis[2].tolist() == [False, True, True, True, True]
    assert line_visibility(lines, T, np.zeros((0, 4, 3))).all(), "no walls: every line is seen"


def test_hidden_lines_leave_the_distance_functions():
    from ldlloc.search import ldf
    from ldlmap.map.fields3d import compute_fields
    from ldlmap.core.geometry import rotation_from_axis_angle

    walls, lines = _two_rooms()
    groups = np.argmax(np.abs(lines[:, 1] - lines[:, 0]), axis=1)
    T = np.array([[1.0, 1.5, 1.4], [6.0, 1.5, 1.4], [2.0, 0.7, 1.2]])
    vis = line_visibility(lines, T, walls)
    rng = np.random.default_rng(0)
    R = np.stack([rotation_from_axis_angle(rng.normal(size=3), rng.uniform(0, np.pi)) for _ in range(3)])
    Q = ldf.query_points(1, dtype=torch.float64)
    full = ldf.ldf_3d(Q, R, T, lines, groups, dtype=torch.float64, visibility=vis)
    fields, _ = compute_fields(lines, groups, T, visibility=vis)
    for i in range(len(T)):  # each translation equals the functions of its visible lines alone
        alone = ldf.ldf_3d(Q, R, T[i:i + 1], lines[vis[i]], groups[vis[i]], dtype=torch.float64)
        torch.testing.assert_close(full[i:i + 1], alone)
        f_alone, _ = compute_fields(lines[vis[i]], groups[vis[i]], T[i:i + 1])
        np.testing.assert_array_equal(fields[i:i + 1], f_alone)
    at = ldf.ldf_3d_at(Q, R, T, lines, groups, [2, 0, 1], [1, 2, 0], dtype=torch.float64, visibility=vis)
    torch.testing.assert_close(at, full[[2, 0, 1], [1, 2, 0]])
    everything = ldf.ldf_3d(Q, R, T, lines, groups, dtype=torch.float64)
    torch.testing.assert_close(ldf.ldf_3d(Q, R, T, lines, groups, dtype=torch.float64,
                                          visibility=np.ones_like(vis)), everything)
    assert not torch.allclose(full, everything), "hiding lines changes the functions"


def test_map_stores_visibility_and_rejects_a_wrong_shape(tmp_path):
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.core.errors import InputError
    from ldlmap.map.mapfile import read_map, write_map
    from ldlmap.map.translations import Walkable

    walls, lines = _two_rooms()
    edges = [[[x0, y0, z], [x1, y1, z]] for (x0, y0), (x1, y1) in
             [((0, 0), (8, 0)), ((8, 0), (8, 3)), ((8, 3), (0, 3)), ((0, 3), (0, 0)), ((4, 0), (4, 3))] for z in (0, H)]
    lines = np.concatenate([lines, np.array(edges, float)])
    polys = (np.array([[0, 0], [4, 0], [4, 3], [0, 3]], float), np.array([[4, 0], [8, 0], [8, 3], [4, 3]], float))
    rep = build_lines_map(lines, tmp_path / "two.h5", BuildParams().replaced(features="none", trans_spacing=0.5),
                          walkable=Walkable(polys, None, (1.4, 1.4), walls))
    m = read_map(rep.path)
    assert m.visibility is not None and m.visibility.shape == (len(m.translations), len(m.lines))
    assert 0 < m.visibility.mean() < 1, "some lines hidden from some translations"
    np.testing.assert_array_equal(m.visibility, line_visibility(m.lines, m.translations, walls))
    m.visibility = m.visibility[:, :-1]
    with pytest.raises(InputError):
        write_map(tmp_path / "bad.h5", m)


def test_coverage_of_a_closed_room_and_of_a_doorway():
    from ldlmap.map.visibility import coverage_at, coverage_fields, room_surfaces

    walls, _ = _two_rooms()
    polys = (np.array([[0, 0], [4, 0], [4, 3], [0, 3]], float), np.array([[4, 0], [8, 0], [8, 3], [4, 3]], float))
    both = room_surfaces(walls, polys, (H, H))
    T = np.array([[2.0, 1.5, 1.4], [3.9, 1.5, 1.4]])
    cov = coverage_fields(T, *both, rows=16)
    assert cov.shape == (2, 17, 32) and cov.all(), "both rooms mapped: every direction meets a surface"
    # Room A alone (its walls, floor and ceiling): from near the door, the directions through it leave the map.
    a_walls = np.array([w for w in walls if w[:, 0].max() <= 4.0 + 1e-9])
    cov_a = coverage_fields(T, *room_surfaces(a_walls, polys[:1], (H,)), rows=16)
    assert cov_a[0].mean() > cov_a[1].mean() > 0.5
    through_door = coverage_at(cov_a, np.array([1]), np.array([[[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]]))
    assert through_door.tolist() == [[False, True]]


def test_covered_inlier_loss_equals_the_inlier_loss_on_a_covered_map():
    from ldlloc.search import ldf
    from ldlloc.search.pose_search import covered_inlier_loss

    Q = ldf.query_points(1)
    f2d = torch.rand(5, 3, len(Q))
    f3d = f2d + 0.2 * (torch.rand(5, 3, len(Q)) - 0.5)
    R = np.stack([np.eye(3)] * 5)
    full = np.ones((2, 9, 16), bool)
    plain = ldf.pose_loss(f2d, f3d.unsqueeze(0), kind="inlier", tau=0.1)[0]
    got = covered_inlier_loss(f2d, f3d, Q, R, np.zeros(5, int), full, 0.1, 2.0)
    torch.testing.assert_close(got, plain)
    half = full.copy()
    half[:, :, :8] = False  # directions with phi < 0 (y < 0) leave the map
    got = covered_inlier_loss(f2d, f3d, Q, R, np.zeros(5, int), half, 0.1, 2.0)
    from ldlmap.map.visibility import coverage_at

    cov = torch.as_tensor(coverage_at(half, np.zeros(1, int), Q.numpy()[None].astype(float))[0])
    assert 0.4 < cov.float().mean() < 0.65 and bool(cov[Q[:, 1] < -0.2].logical_not().all())
    expect = -((f2d - f3d).abs() < 0.1)[:, :, cov].sum((1, 2)).float() / cov.float().mean().clamp(min=0.5)
    torch.testing.assert_close(got, expect)  # inliers on covered directions, scaled by their share
