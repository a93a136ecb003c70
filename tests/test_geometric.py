"""Geometric refinement from lines alone (ldlloc.refine.geometric) on the analytic box room of test_fields."""

from __future__ import annotations

import numpy as np

from ldlmap.core.geometry import cam_from_world, normalize, rotation_error_deg, rotation_from_axis_angle
from ldlloc.refine.geometric import GeometricParams, refine_poses_geometric
from tests.test_fields import HI, LO, _room_lines


def _views(n, seed=3):
    """True poses inside the room, the room's lines seen from them, and starts 0.4 m / 5 deg off."""
    lines, groups = _room_lines()
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        t = rng.uniform(LO + 0.8, HI - 0.8)
        R = rotation_from_axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
        arcs = normalize(cam_from_world(lines, R, t))
        R0 = rotation_from_axis_angle(rng.normal(size=3), np.radians(5.0)) @ R
        d = rng.normal(size=3)
        out.append((arcs, R, t, R0, t + 0.4 * d / np.linalg.norm(d)))
    return lines, groups, out


def test_recovers_a_perturbed_pose():
    """From 0.4 m / 5 deg off with the default parameters (the vanishing-point residuals bring the
    rotation back: 22 of 24 such starts recovered, 20 without them)."""
    lines, groups, views = _views(8)
    ok = 0
    for arcs, R, t, R0, t0 in views:
        res = refine_poses_geometric(arcs, R0[None], t0[None], lines, groups, np.eye(3))
        err_t, err_r = np.linalg.norm(res.centers[0] - t), rotation_error_deg(res.rotations[0], R)
        ok += bool(res.accepted[0] and err_t < 0.02 and err_r < 0.5)
        assert res.residual_deg[0] < 2.0 or not res.accepted[0]
    assert ok >= 7, f"{ok} of 8 recovered to 2 cm / 0.5 deg from 0.4 m / 5 deg off"


def test_batched_poses_equal_one_at_a_time():
    lines, groups, views = _views(3, seed=5)
    arcs, R, t, R0, t0 = views[0]
    starts_R = np.stack([R0, views[1][3], R])
    starts_t = np.stack([t0, views[1][4], t])
    batch = refine_poses_geometric(arcs, starts_R, starts_t, lines, groups, np.eye(3))
    for k in range(3):
        one = refine_poses_geometric(arcs, starts_R[k:k + 1], starts_t[k:k + 1], lines, groups, np.eye(3))
        np.testing.assert_allclose(batch.centers[k], one.centers[0], atol=1e-6)
        np.testing.assert_allclose(batch.rotations[k], one.rotations[0], atol=1e-6)
    assert np.linalg.norm(batch.centers[2] - t) < 1e-6, "a start at the true pose stays there"


def test_poses_that_meet_are_refined_once():
    """Two starts at one pose are refined as one (GeometricParams.merge_m) and end where each
    would alone; a third, different start is unaffected."""
    lines, groups, views = _views(2, seed=5)
    arcs, R, t, R0, t0 = views[0]
    starts_R, starts_t = np.stack([R0, R0, views[1][3]]), np.stack([t0, t0, views[1][4]])
    batch = refine_poses_geometric(arcs, starts_R, starts_t, lines, groups, np.eye(3))
    np.testing.assert_array_equal(batch.centers[0], batch.centers[1])
    np.testing.assert_array_equal(batch.rotations[0], batch.rotations[1])
    alone = refine_poses_geometric(arcs, starts_R, starts_t, lines, groups, np.eye(3), params=GeometricParams(merge_m=0))
    np.testing.assert_allclose(batch.centers, alone.centers, atol=1e-5)
    np.testing.assert_allclose(batch.rotations, alone.rotations, atol=1e-5)


def test_divergence_and_too_little_evidence_are_flagged():
    lines, groups, views = _views(1, seed=7)
    arcs, R, t, R0, t0 = views[0]
    # Too few line points to trust: rejected, the coarse pose comes back unchanged.
    res = refine_poses_geometric(arcs, R0[None], t0[None], lines, groups, np.eye(3),
                                 params=GeometricParams(min_points=10_000))
    assert not res.accepted[0]
    np.testing.assert_array_equal(res.centers[0], t0)
    np.testing.assert_array_equal(res.rotations[0], R0)
    # A refinement allowed to move only 1 cm from a start 0.4 m off is flagged as diverged.
    res = refine_poses_geometric(arcs, R0[None], t0[None], lines, groups, np.eye(3), params=GeometricParams(max_move_m=0.01))
    assert not res.accepted[0] and np.array_equal(res.centers[0], t0)


def test_line_jacobian_matches_finite_differences():
    """The per-line operators give each point's residual ``n . x`` and its exact derivatives ``D x``
    by the pose update; the normal equations summed per line equal the sum over points."""
    import torch

    from ldlloc.refine.geometric import _apply, _line_operators

    rng = np.random.default_rng(1)
    R = torch.as_tensor(rotation_from_axis_angle(rng.normal(size=3), 0.4)[None])
    t = torch.as_tensor(rng.normal(size=(1, 3)) * 0.3)
    L = torch.as_tensor(rng.normal(size=(1, 5, 2, 3)) * 2)
    X = torch.as_tensor(normalize(rng.normal(size=(5, 3))))  # point i on line i
    n, D = _line_operators(R, t, L)
    r = (n[0] * X).sum(-1)
    J = torch.einsum("lai,li->la", D[0], X)  # (5, 6)
    eps = 1e-6
    for i in range(6):
        v = torch.zeros((1, 6), dtype=torch.float64)
        v[0, i] = eps
        rp = (_line_operators(*_apply(R, t, v), L)[0][0] * X).sum(-1)
        v[0, i] = -eps
        rm = (_line_operators(*_apply(R, t, v), L)[0][0] * X).sum(-1)
        assert torch.allclose((rp - rm) / (2 * eps), J[:, i], atol=1e-6)
    S = X[:, :, None] * X[:, None, :]  # one point per line: S_l = x x^T
    H_lines = torch.einsum("lai,lij,lbj->ab", D[0], S, D[0])
    assert torch.allclose(H_lines, J.T @ J) and torch.allclose(torch.einsum("lai,lij,lj->a", D[0], S, n[0]), J.T @ r)


def test_vanishing_point_jacobian_matches_finite_differences():
    import torch

    from ldlloc.refine.geometric import _apply, _vp_residuals

    rng = np.random.default_rng(0)
    R = torch.as_tensor(rotation_from_axis_angle(rng.normal(size=3), 0.7)[None])
    n2 = torch.as_tensor(normalize(rng.normal(size=(6, 3))))
    groups = torch.as_tensor([[0, 1, 2, -1, 0, 2]])
    r, J = _vp_residuals(R, n2, torch.eye(3, dtype=torch.float64), groups)
    eps = 1e-6
    for i in range(3):
        v = torch.zeros((1, 6), dtype=torch.float64)
        v[0, i] = eps
        rp = _vp_residuals(_apply(R, torch.zeros((1, 3), dtype=torch.float64), v)[0], n2, torch.eye(3, dtype=torch.float64), groups)[0]
        v[0, i] = -eps
        rm = _vp_residuals(_apply(R, torch.zeros((1, 3), dtype=torch.float64), v)[0], n2, torch.eye(3, dtype=torch.float64), groups)[0]
        assert torch.allclose((rp - rm) / (2 * eps), J[..., i], atol=1e-6)
    assert r[0, 3] == 0 and torch.all(J[0, 3] == 0)  # an arc of no group adds nothing


def test_map_line_support_prefers_the_true_pose():
    """The map's lines seen from the true pose lie on the query's arcs; from a pose 0.3 m and
    10 deg off they mostly do not."""
    from ldlloc.refine.geometric import map_line_support

    lines, groups, views = _views(2, seed=11)
    arcs, R, t, _, _ = views[0]
    off = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(10.0)) @ R
    s = map_line_support(arcs, np.stack([R, off, R]), np.stack([t, t, t + [0.3, 0.0, 0.0]]), lines, groups)
    assert s[0] > 0.9 and s[1] < 0.5 and s[2] < 0.7 * s[0], s


def test_height_band_holds_an_unobservable_height():
    """Vertical lines alone say nothing of the camera's height: without a band the height stays as
    wrong as its start, with the map's camera-height band it comes back within the margin while the
    rest of the pose is recovered."""
    lines, groups = _room_lines()
    vertical = groups == 2
    lines, groups = lines[vertical], groups[vertical]
    rng = np.random.default_rng(11)
    for _ in range(3):
        t = np.r_[rng.uniform(LO[:2] + 0.8, HI[:2] - 0.8), 1.5]
        R = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), rng.uniform(0, 2 * np.pi))
        arcs = normalize(cam_from_world(lines, R, t))
        t0 = t + np.array([0.2, -0.15, 0.4])
        free = refine_poses_geometric(arcs, R[None], t0[None], lines, groups, np.eye(3))
        assert abs(free.centers[0, 2] - t[2]) > 0.3
        band = refine_poses_geometric(arcs, R[None], t0[None], lines, groups, np.eye(3), height_band=(1.5, 1.5))
        p = GeometricParams()
        assert band.accepted[0] and abs(band.centers[0, 2] - t[2]) <= p.height_margin_m + 1e-6
        assert np.linalg.norm(band.centers[0, :2] - t[:2]) < 0.02
        assert rotation_error_deg(band.rotations[0], R) < 0.5


def test_per_pose_association_angles_batch_like_one_at_a_time():
    """Poses refined with their own first association angles (the pipeline's wide second
    refinement of the best poses) end where each would alone with that angle."""
    lines, groups, views = _views(2, seed=9)
    arcs, R, t, R0, t0 = views[0]
    starts_R, starts_t = np.stack([R0, R0, views[1][3]]), np.stack([t0, t0, views[1][4]])
    angles = np.array([12.0, 20.0, 20.0])
    batch = refine_poses_geometric(arcs, starts_R, starts_t, lines, groups, np.eye(3), assoc_deg=angles)
    for k in range(3):
        one = refine_poses_geometric(arcs, starts_R[k:k + 1], starts_t[k:k + 1], lines, groups, np.eye(3),
                                     params=GeometricParams(assoc_deg=float(angles[k])))
        np.testing.assert_allclose(batch.centers[k], one.centers[0], atol=1e-5)
        np.testing.assert_allclose(batch.rotations[k], one.rotations[0], atol=1e-5)


def test_fit_counts_points_by_how_near_their_lines_they_lie():
    """`GeometricResult.fit` (each matched point 1 - (angle / final association angle)^2): ten points 1 deg
    off fit worse than nine 0.2 deg off, though they are more; a refined pose on its own lines fits nearly
    one a point, one 0.3 m off fits less; the tracker keeps the start of the higher fit (`best_fit`)."""
    import torch

    from ldlloc.refine.geometric import GeometricResult, residual_stats
    from ldlloc.walk.track import best_fit

    r = torch.full((2, 10), float("nan"))
    r[0] = np.sin(np.radians(1.0))
    r[1, :9] = np.sin(np.radians(0.2))
    med, fit = residual_stats(r, 1.5)
    assert np.allclose(med, [1.0, 0.2], atol=1e-4)
    assert fit[1] > fit[0] and np.isclose(fit[1], 9 * (1 - (np.sin(np.radians(0.2)) / np.sin(np.radians(1.5))) ** 2))
    g = GeometricResult(np.stack([np.eye(3)] * 2), np.zeros((2, 3)), np.ones(2, bool), np.array([10, 9]), med, fit)
    assert best_fit(np.ones(2, bool), g) == 1 and best_fit(np.array([True, False]), g) == 0
    lines, groups, views = _views(1)
    arcs, R, t, _, _ = views[0]
    res = refine_poses_geometric(arcs, np.stack([R, R]), np.stack([t, t + [0.3, 0.0, 0.0]]), lines, groups, np.eye(3),
                                 params=GeometricParams(rounds=1, assoc_deg=1.5, final_assoc_deg=1.5))
    assert res.fit[0] > 0.9 * res.matched[0] and res.fit[0] > res.fit[1]
