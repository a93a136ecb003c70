"""Vanishing points, candidate rotations and rotation groups (ldlloc.rotation)."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import cam_from_world, normalize, rotation_error_deg, rotation_from_axis_angle
from ldlloc import rotation


def _manhattan_lines(rng, n=60):
    """Axis-aligned segments on the walls, floor and ceiling of a 6 x 4 x 3 m box room."""
    lo, hi = np.array([-3.0, -2.0, 0.0]), np.array([3.0, 2.0, 3.0])
    axis = rng.integers(0, 3, n)
    p = rng.uniform(lo, hi, size=(n, 3))
    other = (axis + 1 + rng.integers(0, 2, n)) % 3
    side = rng.integers(0, 2, n)
    p[np.arange(n), other] = np.where(side == 0, lo[other], hi[other])
    q = p.copy()
    q[np.arange(n), axis] = np.clip(p[np.arange(n), axis] + rng.uniform(0.5, 2.5, n), lo[axis], hi[axis])
    return np.stack([p, q], 1), axis


def _scene(seed, noise_arcs=40):
    rng = np.random.default_rng(seed)
    lines, axis = _manhattan_lines(rng)
    R = rotation_from_axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
    t = rng.uniform([-2, -1.5, 0.5], [2, 1.5, 2.5])
    arcs = normalize(cam_from_world(lines, R, t) + rng.normal(scale=0.002, size=(len(lines), 2, 3)))
    # Clutter: short arcs in random directions.
    s = normalize(rng.normal(size=(noise_arcs, 3)))
    e = normalize(s + 0.08 * normalize(rng.normal(size=(noise_arcs, 3))))
    arcs = np.concatenate([arcs, np.stack([s, e], 1)])
    return arcs, axis, R


def _line_angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.abs(a @ b), 0, 1)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_vanishing_points_recover_manhattan_directions(seed):
    arcs, _, R = _scene(seed)
    vps, votes = rotation.vanishing_points(arcs, k=20, return_counts=True)
    assert 3 <= len(vps) <= 20
    assert np.allclose(np.linalg.norm(vps, axis=1), 1.0)
    assert np.all(np.diff(votes) <= 1e-6 + 1e-6 * votes[:-1])  # greedy order
    for j in range(3):
        true_dir = R[:, j]  # camera-frame image of world axis j
        assert min(_line_angle_deg(v, true_dir) for v in vps[:3]) < 1.0


@pytest.mark.parametrize("seed", [3, 4, 5, 6, 7])
def test_candidate_rotations_contain_truth(seed):
    arcs, _, R = _scene(seed)
    vps = rotation.vanishing_points(arcs, k=20)
    # 3D rotation directions: the room axes, in some order and signs.
    P = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    cands = rotation.candidate_rotations(vps, P)
    assert len(cands) >= 24  # all relabelings of the Manhattan frame
    assert len(cands) <= 150
    errs = [rotation_error_deg(Rc, R) for Rc in cands.rotations]
    assert min(errs) < 1.0
    # The bookkeeping: R p3d_j ~ s_j vp2d[triplets[j]].
    for Rc, trip, sg in zip(cands.rotations, cands.triplets, cands.signs):
        assert np.linalg.det(Rc) == pytest.approx(1.0)
        pred = (Rc @ P.T).T
        assert np.all(np.sum(pred * (sg[:, None] * vps[trip]), axis=1) > np.cos(np.radians(8)))
    # No two candidates are near-duplicates.
    tr = np.einsum("aij,bij->ab", cands.rotations, cands.rotations)
    ang = np.degrees(np.arccos(np.clip((tr - 1) / 2, -1, 1)))
    np.fill_diagonal(ang, 180)
    assert ang.min() >= 2.5
    assert np.all(np.diff(cands.residuals) >= 0)


def test_candidate_rotations_of_an_atlanta_frame_contain_truth():
    """The map's directions are the vertical and two horizontals 45 deg apart (an Atlanta
    frame); triplets of vanishing points are matched by those angles, not by right angles."""
    rng = np.random.default_rng(11)
    s = np.sqrt(0.5)
    P = np.array([[0, 0, 1.0], [1.0, 0, 0], [s, s, 0]])
    dirs = np.concatenate([P, [[0, 1.0, 0]]])  # and a weaker wall direction the frame leaves out
    segs = []
    for d, n in zip(dirs, (30, 30, 30, 10)):
        a = rng.uniform([-3, -2, 0], [3, 2, 3], (n, 3))
        segs.append(np.stack([a, a + rng.uniform(0.6, 2.0, (n, 1)) * d], 1))
    R = rotation_from_axis_angle(rng.normal(size=3), 1.3)
    arcs = normalize(cam_from_world(np.concatenate(segs), R, np.array([0.3, -0.2, 1.4])))
    vps = rotation.vanishing_points(arcs, k=20)
    cands = rotation.candidate_rotations(vps, P)
    assert min(rotation_error_deg(Rc, R) for Rc in cands.rotations) < 1.0
    for Rc in cands.rotations:  # every candidate maps the frame onto 3 vanishing points at its angles
        assert np.all(np.abs(vps @ (Rc @ P.T)).max(axis=0) > np.cos(np.radians(6.0)))


def test_candidate_rotations_exact_kabsch_and_empty():
    rng = np.random.default_rng(9)
    R = rotation_from_axis_angle(rng.normal(size=3), 0.7)
    P = normalize(np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.2, 0.0, 1.0]]))  # non-orthogonal
    vps = np.concatenate([(R @ P.T).T * np.array([[1.0], [-1.0], [1.0]]), normalize(rng.normal(size=(2, 3)))])
    c = rotation.candidate_rotations(vps, P)
    best = int(np.argmin([rotation_error_deg(Rc, R) for Rc in c.rotations]))
    np.testing.assert_allclose(c.rotations[best], R, atol=1e-9)
    assert c.residuals[best] < 1e-12
    assert list(c.triplets[best]) == [0, 1, 2] and list(c.signs[best]) == [1, -1, 1]
    assert len(rotation.candidate_rotations(vps[:2], P)) == 0
    with pytest.raises(InputError):
        rotation.candidate_rotations(vps, P[:2])


def test_assign_groups_and_labels_for_rotations():
    arcs, axis, R = _scene(10, noise_arcs=0)
    g = rotation.assign_arcs_to_principal(arcs, R.T)  # rows: camera-frame rotation dirs
    assert np.mean(g == axis) > 0.9
    # A tiny arc's circle is ill-defined only by noise; an arc not through any direction -> -1.
    off = normalize(np.array([[[1.0, 1.0, 1.0], [1.0, -1.0, 0.3]]]))
    off_n = normalize(np.cross(off[0, 0], off[0, 1]))
    if np.min(np.abs(R.T @ off_n)) > 0.05:
        assert rotation.assign_arcs_to_principal(off, R.T)[0] == -1
    vps = rotation.vanishing_points(arcs, k=20)
    P = np.eye(3)
    cands = rotation.candidate_rotations(vps, P)
    best = int(np.argmin([rotation_error_deg(Rc, R) for Rc in cands.rotations]))
    labels = rotation.labels_for_rotations(arcs, vps, cands.triplets)
    assert labels.shape == (len(cands), len(arcs))
    assert np.mean(labels[best] == axis) > 0.9  # group j pairs with 3D direction j
    with pytest.raises(InputError):
        rotation.vanishing_points(np.zeros((3, 3)))


def test_pairs_are_the_fallback_of_a_three_direction_map():
    """A view of the vertical and one horizontal only (a corridor seen along its length): no
    triplet matches a Manhattan map, the perpendicular pairs give the rotation, and the arcs of
    the two seen directions are grouped (the unseen one has no vanishing point: -1)."""
    from ldlmap.core.geometry import rotation_error_deg, rotation_from_axis_angle
    from tests.test_atlanta_many import _room_arcs

    P = np.eye(3)
    R = rotation_from_axis_angle(np.array([0.1, 0.2, 1.0]), 0.7)
    arcs = _room_arcs(P[[2, 0]], R, np.random.default_rng(4))
    vps = rotation.vanishing_points(arcs, k=20)
    assert len(rotation.candidate_rotations(vps, P)) == 0
    pairs = rotation.pair_candidates(vps, P)
    best = int(np.argmin([rotation_error_deg(Rc, R) for Rc in pairs.rotations]))
    assert rotation_error_deg(pairs.rotations[best], R) < 1.0
    assert pairs.triplets[best, 1] == -1 and np.all(pairs.triplets[best, [0, 2]] >= 0)
    labels = rotation.rotation_labels(arcs, vps, pairs, P)
    truth = np.repeat([2, 0], 25)
    assert np.mean(labels[best] == truth) > 0.9
