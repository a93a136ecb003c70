"""Line distance functions (ldlloc.search.ldf) against brute force and closed forms."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import cam_from_world, icosphere_points, normalize, rotation_from_axis_angle
from ldlloc.search import ldf


def _random_unit(rng, n):
    return normalize(rng.normal(size=(n, 3)))


def _random_arcs(rng, n, min_deg=0.5, max_deg=179.0):
    """Arcs with lengths uniform in [min_deg, max_deg] (as start, end)."""
    s = _random_unit(rng, n)
    axis = normalize(np.cross(s, rng.normal(size=(n, 3))))
    ang = np.radians(rng.uniform(min_deg, max_deg, n))
    e = s * np.cos(ang)[:, None] + np.cross(axis, s) * np.sin(ang)[:, None]
    return s, normalize(e)


def _geodesic(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _slerp(s, e, ts):
    ang = _geodesic(s, e)
    w = np.sin((1 - ts)[:, None] * ang) / np.sin(ang) * s + np.sin(ts[:, None] * ang) / np.sin(ang) * e
    return normalize(w)


def _brute_distance(x, s, e, n=20000):
    """Min geodesic distance from x (Q, 3) to the densely sampled arc, refined locally."""
    ts = np.linspace(0.0, 1.0, n)
    pts = _slerp(s, e, ts)
    d = _geodesic(x[:, None, :], pts[None])  # (Q, n)
    best = d.argmin(1)
    out = np.empty(len(x))
    for i, b in enumerate(best):  # local refinement around the best sample (test only)
        lo, hi = ts[max(b - 1, 0)], ts[min(b + 1, n - 1)]
        fine = _slerp(s, e, np.linspace(lo, hi, 4001))
        out[i] = _geodesic(x[i][None], fine).min()
    return out


def _points_for_arc(rng, s, e, k=6):
    """Random points plus points near the ends, the poles and the antipodes of the arc."""
    n = normalize(np.cross(s, e))
    mid = normalize(s + e)
    near = [s, e, -s, -e, n, -n, -mid]
    out = [_random_unit(rng, k)]
    for p in near:
        out.append(normalize(p + rng.normal(scale=0.01, size=(2, 3))))
    # Just beyond/before each end along the circle, and just off the circle near the ends.
    ang = _geodesic(s, e)
    ts = np.array([-1e-3, 1e-3, 1.0 - 1e-3, 1.0 + 1e-3]) * 1.0
    along = np.array([np.cos(t * ang) * s + np.sin(t * ang) * np.cross(n, s) for t in ts])
    out.append(normalize(along + 0.003 * n))
    return np.concatenate(out)


def test_point_arc_distance_matches_brute_force_float64():
    rng = np.random.default_rng(0)
    s_all, e_all = _random_arcs(rng, 12, 0.5, 179.0)
    # Force a few long arcs (> 90 degrees, up to 179).
    s_long, e_long = _random_arcs(rng, 4, 100.0, 179.0)
    s_all, e_all = np.concatenate([s_all, s_long]), np.concatenate([e_all, e_long])
    for s, e in zip(s_all, e_all):
        x = _points_for_arc(rng, s, e)
        got = ldf.point_arc_distance(torch.tensor(x), torch.tensor(s[None]), torch.tensor(e[None]))
        ref = _brute_distance(x, s, e)
        np.testing.assert_allclose(got.numpy()[:, 0], ref, atol=1e-5)


def test_point_arc_distance_float32_and_batching():
    rng = np.random.default_rng(1)
    s, e = _random_arcs(rng, 50)
    x = _random_unit(rng, 40)
    d64 = ldf.point_arc_distance(torch.tensor(x), torch.tensor(s), torch.tensor(e))
    d32 = ldf.point_arc_distance(x, s, e)  # numpy -> float32
    assert d32.dtype == torch.float32 and d32.shape == (40, 50)
    np.testing.assert_allclose(d32.numpy(), d64.numpy(), atol=1e-3)
    # Leading batch dims broadcast.
    xb = torch.tensor(np.stack([x, x[::-1].copy()]))
    db = ldf.point_arc_distance(xb, torch.tensor(s), torch.tensor(e))
    np.testing.assert_allclose(db[1].numpy(), d64.numpy()[::-1], atol=1e-12)


def test_degenerate_and_closed_forms():
    s = np.array([[1.0, 0, 0]])
    x = normalize(np.array([[1.0, 1.0, 0.0], [0, 0, 1.0], [-1.0, 0, 0]]))
    d = ldf.point_arc_distance(torch.tensor(x), torch.tensor(s), torch.tensor(s)).numpy()[:, 0]
    np.testing.assert_allclose(d, [np.pi / 4, np.pi / 2, np.pi], atol=1e-12)
    # Quarter arc along the equator from +x to +y: a point above the middle is at its latitude.
    e = np.array([[0.0, 1.0, 0.0]])
    lat = 0.3
    p = np.array([[np.cos(lat) / np.sqrt(2), np.cos(lat) / np.sqrt(2), np.sin(lat)]])
    got = ldf.point_arc_distance(torch.tensor(p), torch.tensor(s), torch.tensor(e)).item()
    assert got == pytest.approx(lat, abs=1e-12)
    # Pole of the arc: pi/2 from everywhere on it.
    got = ldf.point_arc_distance(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64),
                                 torch.tensor(s), torch.tensor(e)).item()
    assert got == pytest.approx(np.pi / 2, abs=1e-12)


def test_distance_function_min_mask_and_empty():
    rng = np.random.default_rng(2)
    s, e = _random_arcs(rng, 30)
    arcs = torch.tensor(np.stack([s, e], 1))
    x = torch.tensor(_random_unit(rng, 20))
    d = ldf.point_arc_distance(x, arcs[:, 0], arcs[:, 1])
    np.testing.assert_allclose(ldf.distance_function(x, arcs).numpy(), d.min(1).values.numpy())
    mask = torch.zeros(30, dtype=torch.bool)
    mask[:5] = True
    np.testing.assert_allclose(ldf.distance_function(x, arcs, mask).numpy(), d[:, :5].min(1).values.numpy())
    assert torch.all(ldf.distance_function(x, arcs, torch.zeros(30, dtype=torch.bool)) == ldf.EMPTY_DISTANCE)
    assert torch.all(ldf.distance_function(x, arcs[:0]) == ldf.EMPTY_DISTANCE)
    labels = torch.tensor(rng.integers(-1, 3, 30))
    f = ldf.decomposed_distance_2d(x, arcs, labels)
    for g in range(3):
        np.testing.assert_allclose(f[g].numpy(), ldf.distance_function(x, arcs, labels == g).numpy())
    # Per-rotation labels give per-rotation functions.
    lab2 = torch.stack([labels, torch.flip(labels, [0])])
    f2 = ldf.decomposed_distance_2d(x, arcs, lab2)
    assert f2.shape == (2, 3, 20)
    np.testing.assert_allclose(f2[0].numpy(), f.numpy())


def test_rotation_invariance():
    rng = np.random.default_rng(3)
    s, e = _random_arcs(rng, 40)
    x = _random_unit(rng, 30)
    R = rotation_from_axis_angle(rng.normal(size=3), 1.234)
    a = ldf.point_arc_distance(torch.tensor(x), torch.tensor(s), torch.tensor(e))
    b = ldf.point_arc_distance(torch.tensor(x @ R.T), torch.tensor(s @ R.T), torch.tensor(e @ R.T))
    np.testing.assert_allclose(a.numpy(), b.numpy(), atol=1e-9)


def _random_rotations(rng, n):
    return np.stack([rotation_from_axis_angle(rng.normal(size=3), rng.uniform(0, np.pi)) for _ in range(n)])


def test_ldf_3d_equals_2d_function_of_projected_lines():
    rng = np.random.default_rng(4)
    lines = rng.uniform(-3, 3, size=(25, 2, 3))
    groups = rng.integers(-1, 3, 25)
    groups[0] = 2
    R = _random_rotations(rng, 4)
    T = rng.uniform(-1, 1, size=(5, 3))
    x = np.array(icosphere_points(1))
    f = ldf.ldf_3d(torch.tensor(x), torch.tensor(R), torch.tensor(T), torch.tensor(lines),
                   torch.tensor(groups), chunk=2)
    assert f.shape == (5, 4, 3, 42) and f.dtype == torch.float64
    f32 = ldf.ldf_3d(x, R, T, lines, groups, chunk=3)  # numpy -> float32, other chunking
    np.testing.assert_allclose(f32.numpy(), f.numpy(), atol=2e-3)
    for i in range(5):
        for r in range(4):
            arcs = normalize(cam_from_world(lines, R[r], T[i]))  # project the lines at the pose
            ref = ldf.decomposed_distance_2d(torch.tensor(x), torch.tensor(arcs), torch.tensor(groups))
            np.testing.assert_allclose(f[i, r].numpy(), ref.numpy(), atol=1e-9)


def test_ldf_3d_bad_input():
    x = icosphere_points(1)
    with pytest.raises(InputError):
        ldf.ldf_3d(x, np.eye(3)[None], np.zeros((1, 3)), np.zeros((4, 3)), np.zeros(4, int))
    lines = np.ones((2, 2, 3))
    lines[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        ldf.ldf_3d(x, np.eye(3)[None], np.zeros((1, 3)), lines, np.zeros(2, int))
    with pytest.raises(InputError, match="unknown loss"):
        ldf.pose_loss(torch.zeros(3, 42), torch.zeros(1, 1, 3, 42), kind="l3")


def test_pose_loss_kinds_closed_form():
    f2d = torch.zeros(1, 3, 4, dtype=torch.float64)
    f3d = torch.tensor([0.0, 0.05, 0.2, 1.0], dtype=torch.float64).repeat(2, 1, 3, 1)  # (2, 1, 3, 4)
    f3d[1] = 0.0
    assert ldf.pose_loss(f2d, f3d, "inlier").tolist() == [[-6.0], [-12.0]]
    assert ldf.pose_loss(f2d, f3d, "l1")[0, 0].item() == pytest.approx(3 * 1.25)
    assert ldf.pose_loss(f2d, f3d, "l2")[0, 0].item() == pytest.approx(3 * (0.0025 + 0.04 + 1.0))
    hub = 3 * (0.5 * 0.05 ** 2 + 0.1 * (0.2 - 0.05) + 0.1 * (1.0 - 0.05))
    assert ldf.pose_loss(f2d, f3d, "huber", tau=0.1)[0, 0].item() == pytest.approx(hub)
    assert ldf.pose_loss(f2d, f3d, "median")[1, 0].item() == 0.0
    # Without decomposition each side is the min over groups: 4 points only.
    assert ldf.pose_loss(f2d, f3d, "inlier", decompose=False)[0, 0].item() == -2.0


def _box_room_lines(rng):
    """A 6 x 4 x 3 m box room's 12 edges plus axis-aligned segments on the walls."""
    lo, hi = np.array([-3.0, -2.0, 0.0]), np.array([3.0, 2.0, 3.0])
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    edges = []
    for i in range(8):
        for j in range(i + 1, 8):
            if np.sum(c[i] != c[j]) == 1:
                edges.append([c[i], c[j]])
    lines = list(edges)
    for _ in range(40):  # frames/posters: axis-aligned segments on random walls
        axis = rng.integers(0, 3)
        wall = rng.integers(0, 2)
        p = rng.uniform(lo, hi)
        normal_axis = (axis + 1 + rng.integers(0, 2)) % 3
        p[normal_axis] = (lo, hi)[wall][normal_axis]
        q = p.copy()
        q[axis] = np.clip(p[axis] + rng.uniform(0.4, 1.5), lo[axis], hi[axis])
        lines.append([p, q])
    lines = np.array(lines)
    groups = np.argmax(np.abs(lines[:, 1] - lines[:, 0]), axis=1)
    return lines, groups


@pytest.mark.parametrize("kind", ["inlier", "l1", "huber", "median"])
def test_pose_loss_ranks_true_pose_first(kind):
    rng = np.random.default_rng(5)
    lines, groups = _box_room_lines(rng)
    R_true = rotation_from_axis_angle(rng.normal(size=3), 2.0)
    t_true = np.array([0.7, -0.4, 1.4])
    # Query arcs: the true projection, a few lines dropped (misdetections), small noise.
    keep = rng.random(len(lines)) > 0.15
    arcs = normalize(cam_from_world(lines[keep], R_true, t_true) + rng.normal(scale=0.003, size=(keep.sum(), 2, 3)))
    x = torch.tensor(np.array(icosphere_points(1)))
    f2d = ldf.decomposed_distance_2d(x, torch.tensor(arcs), torch.tensor(groups[keep]))
    # Candidate poses: perturbed translations (>= 0.4 m) and rotations (>= 8 deg) plus the truth.
    T = [t_true + rng.normal(size=3) * 0 + d for d in
         [np.zeros(3)] + [normalize(rng.normal(size=3)) * rng.uniform(0.4, 1.0) for _ in range(15)]]
    Rs = [R_true] + [rotation_from_axis_angle(rng.normal(size=3), np.radians(rng.uniform(8, 40))) @ R_true
                     for _ in range(9)]
    perm_t, perm_r = rng.permutation(16), rng.permutation(10)
    T, Rs = np.array(T)[perm_t], np.array(Rs)[perm_r]
    f3d = ldf.ldf_3d(x, torch.tensor(Rs), torch.tensor(T), torch.tensor(lines), torch.tensor(groups))
    loss = ldf.pose_loss(f2d, f3d, kind=kind)
    ti, ri, _ = ldf.top_k_poses(loss, 3)
    assert perm_t[ti[0]] == 0 and perm_r[ri[0]] == 0
    true_loss = loss[np.argmin(perm_t), np.argmin(perm_r)]
    others = loss.clone()
    others[np.argmin(perm_t), np.argmin(perm_r)] = float("inf")
    assert true_loss < others.min()


def test_point_arc_distance_shared_with_the_map_side():
    from ldlmap.core import sphere_distance

    assert ldf.point_arc_distance is sphere_distance.point_arc_distance
    assert ldf.EMPTY_DISTANCE == sphere_distance.EMPTY_DISTANCE == np.pi


def test_grouped_min_distance_equals_per_group_brute_force():
    """The kernel behind ldf_3d and the map's distance fields, on many points and chunks."""
    from ldlmap.core.sphere_distance import grouped_min_distance, project_lines, sort_by_group

    rng = np.random.default_rng(11)
    lines = rng.uniform(-3, 3, size=(30, 2, 3))
    groups = rng.integers(-1, 4, 30)  # -1 and 3 are outside the 3 groups: ignored
    groups[:3] = [0, 1, 1]  # group 2 may be empty or not; groups 0 and 1 are not
    T = rng.uniform(-1, 1, size=(3, 3))
    x = _random_unit(rng, 500)
    L, bounds = sort_by_group(torch.tensor(lines), torch.tensor(groups), 3)
    assert bounds[0] == 0 and bounds[-1] == int(np.sum((groups >= 0) & (groups < 3)))
    s, e = project_lines(L, torch.tensor(T))
    got = grouped_min_distance(torch.tensor(x), s, e, bounds).numpy()  # (3, G, P)
    for i, t in enumerate(T):
        arcs = normalize(cam_from_world(lines, np.eye(3), t))
        d = ldf.point_arc_distance(torch.tensor(x), torch.tensor(arcs[:, 0]), torch.tensor(arcs[:, 1])).numpy()
        for g in range(3):
            ref = d[:, groups == g].min(1) if np.any(groups == g) else np.full(len(x), np.pi)
            np.testing.assert_allclose(got[i, g], ref, atol=1e-9)


def test_ldf_3d_is_invariant_to_chunking():
    rng = np.random.default_rng(12)
    lines = rng.uniform(-3, 3, size=(40, 2, 3))
    groups = rng.integers(0, 3, 40)
    R = _random_rotations(rng, 3)
    T = rng.uniform(-1, 1, size=(9, 3))
    x = np.array(icosphere_points(1))
    a = ldf.ldf_3d(torch.tensor(x), torch.tensor(R), torch.tensor(T), torch.tensor(lines), torch.tensor(groups), chunk=1)
    b = ldf.ldf_3d(torch.tensor(x), torch.tensor(R), torch.tensor(T), torch.tensor(lines), torch.tensor(groups), chunk=64)
    np.testing.assert_array_equal(a.numpy(), b.numpy())
