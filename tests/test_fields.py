"""Precomputed 3D distance fields (ldlmap.map.fields3d) and the fast pose search (ldlloc.search.fields).

The scene is an analytic box room (walls, posters, a table-sized box): lines, their principal
groups and candidate translations are known in closed form, so the tests need neither the
scene generator nor images.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ldlmap.core.errors import InputError
from ldlmap.map.fields3d import FieldParams, compute_fields, field_bytes, grid_directions
from ldlmap.core.geometry import cam_from_world, normalize, rotation_from_axis_angle
from ldlmap.map.contents import LdlMap
from ldlmap.map.mapfile import DISTANCE_QUANTUM, read_map, write_map
from ldlloc.search import ldf
from ldlloc.search.fields import DistanceFields, inlier_loss_from_fields
from ldlloc.rotation import assign_arcs_to_principal
from ldlloc.search.pose_search import SearchParams, rescored_poses, search_poses

pytestmark = pytest.mark.xdist_group("fields")  # one worker makes ``room``

LO, HI = np.array([-3.0, -2.0, 0.0]), np.array([3.0, 2.0, 3.0])


def _box_edges(lo, hi):
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return [[c[i], c[j]] for i in range(8) for j in range(i + 1, 8) if np.sum(c[i] != c[j]) == 1]


def _room_lines(seed=0):
    """Box room edges, 12 wall rectangles and a box: (L, 2, 3) lines and their axis groups."""
    rng = np.random.default_rng(seed)
    lines = _box_edges(LO, HI) + _box_edges(np.array([0.5, -1.2, 0.0]), np.array([1.7, -0.4, 0.8]))
    for _ in range(12):
        ax = rng.integers(0, 2)  # a wall normal to x or y
        side = rng.integers(0, 2)
        a, b = [k for k in range(3) if k != ax]
        half = rng.uniform(0.2, 0.6, 2)
        c = rng.uniform(LO + 0.7, HI - 0.7)
        corner = np.zeros((4, 3))
        corner[:, ax] = (LO, HI)[side][ax]
        corner[:, a] = c[a] + half[0] * np.array([-1, 1, 1, -1])
        corner[:, b] = c[b] + half[1] * np.array([-1, -1, 1, 1])
        lines += [[corner[k], corner[(k + 1) % 4]] for k in range(4)]
    lines = np.array(lines, dtype=np.float64)
    groups = np.argmax(np.abs(lines[:, 1] - lines[:, 0]), axis=1)
    return lines, groups


def _translations():
    g = np.meshgrid(np.linspace(-2.4, 2.4, 7), np.linspace(-1.5, 1.5, 5), np.linspace(0.6, 2.2, 3), indexing="ij")
    return np.stack(g, -1).reshape(-1, 3)


@pytest.fixture(scope="module")
def room():
    lines, groups = _room_lines()
    T = _translations()
    dist, attrs = compute_fields(lines, groups, T)
    return lines, groups, T, DistanceFields.from_arrays(dist, attrs), dist, attrs


def _random_rotations(rng, n):
    return np.stack([rotation_from_axis_angle(rng.normal(size=3), rng.uniform(0, np.pi)) for _ in range(n)])


def test_grid_directions_and_sizes():
    d = grid_directions(8)
    assert d.shape == (9, 16, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d[0], np.broadcast_to([0, 0, 1], (16, 3)), atol=1e-12)  # north pole row
    np.testing.assert_allclose(d[-1], np.broadcast_to([0, 0, -1], (16, 3)), atol=1e-12)
    np.testing.assert_allclose(d[4, 0], [-1, 0, 0], atol=1e-12)  # equator, phi = -pi
    assert field_bytes(800) == 800 * 3 * 65 * 128 * 2 and field_bytes(1700) / 1e6 < 90
    with pytest.raises(InputError):
        grid_directions(1)


def test_fields_equal_exact_function_at_nodes(room):
    lines, groups, T, _, dist, attrs = room
    assert dist.shape == (len(T), 3, 65, 128) and dist.dtype == np.float16
    assert attrs == {"kind": "equirect_nodes", "rows": 64, "num_groups": 3, "version": 1}
    x = grid_directions(64).reshape(-1, 3)
    for i in (0, 17, len(T) - 1):  # the world-aligned frame: identity rotation at T[i]
        arcs = normalize(cam_from_world(lines, np.eye(3), T[i]))
        ref = ldf.decomposed_distance_2d(torch.tensor(x), torch.tensor(arcs), torch.tensor(groups)).numpy()
        np.testing.assert_allclose(dist[i].reshape(3, -1).astype(np.float64), ref, atol=2e-3)  # float16


def test_interpolation_error_against_exact(room):
    lines, groups, T, fields, _, _ = room
    rng = np.random.default_rng(1)
    R = _random_rotations(rng, 12)
    x = ldf.query_points(1, dtype=torch.float64)
    exact = ldf.ldf_3d(x, torch.tensor(R), torch.tensor(T), torch.tensor(lines), torch.tensor(groups)).numpy()
    fast = fields.ldf_3d(x, R).permute(3, 0, 2, 1).double().numpy()
    assert fast.shape == exact.shape
    err = np.abs(fast - exact)
    assert err.mean() < 0.005 and np.percentile(err, 95) < 0.01
    # f is 1-Lipschitz: a convex combination of the 4 corner values is within the cell
    # diagonal (sqrt(2) pi / G at the equator) of the true value, plus float16 rounding.
    assert err.max() < np.sqrt(2) * np.pi / 64 + 2e-3


def test_lookup_continuous_across_seam_and_poles(room):
    *_, fields, _, _ = room
    eps = 1e-6
    a = normalize(np.array([[-1.0, eps, 0.3], [-1.0, -eps, 0.3], [eps, 0.0, 1.0], [0.0, eps, 1.0],
                            [-eps, -eps, -1.0], [eps, -eps, -1.0]]))
    v = fields.lookup(torch.tensor(a, dtype=torch.float32)).float().numpy()  # (6, 3, N_t)
    np.testing.assert_allclose(v[0], v[1], atol=2e-3)  # phi = +pi and -pi
    np.testing.assert_allclose(v[2], v[3], atol=2e-3)  # north pole from two azimuths
    np.testing.assert_allclose(v[4], v[5], atol=2e-3)  # south pole
    idx, w = fields.corners(torch.tensor(a, dtype=torch.float32))
    assert int(idx.min()) >= 0 and int(idx.max()) < 65 * 128
    np.testing.assert_allclose(w.sum(1).numpy(), 1.0, atol=1e-6)


def test_inlier_loss_layout_matches_pose_loss(room):
    *_, fields, _, _ = room
    rng = np.random.default_rng(2)
    R = _random_rotations(rng, 5)
    x = ldf.query_points(1)
    f3d = fields.ldf_3d(x, R).float()  # (N_r, Q, G, N_t)
    f2d = torch.rand(5, 3, 42) * 1.5
    ref = ldf.pose_loss(f2d, f3d.permute(3, 0, 2, 1), kind="inlier", tau=0.1)
    np.testing.assert_array_equal(inlier_loss_from_fields(f2d, f3d, 0.1).numpy(), ref.numpy())
    np.testing.assert_array_equal(inlier_loss_from_fields(f2d[0], f3d, 0.1).numpy(),
                                  ldf.pose_loss(f2d[0], f3d.permute(3, 0, 2, 1)).numpy())


def _synthetic_query(rng, lines, num_spurious=8):
    """2D arcs of the room seen at a random pose: partial, noisy, some missed, some spurious."""
    t = rng.uniform(LO + [0.8, 0.8, 0.8], HI - [0.8, 0.8, 0.8])
    R = rotation_from_axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
    keep = rng.random(len(lines)) > 0.2
    a = rng.uniform(0.0, 0.2, (len(lines), 1))
    b = rng.uniform(0.8, 1.0, (len(lines), 1))
    seg = np.stack([lines[:, 0] + a * (lines[:, 1] - lines[:, 0]), lines[:, 0] + b * (lines[:, 1] - lines[:, 0])], 1)
    arcs = normalize(cam_from_world(seg[keep], R, t) + rng.normal(scale=0.005, size=(keep.sum(), 2, 3)))
    s = normalize(rng.normal(size=(num_spurious, 3)))
    e = normalize(s + 0.15 * normalize(rng.normal(size=(num_spurious, 3))))
    return np.concatenate([arcs, np.stack([s, e], 1)]), R, t


def _manhattan_candidates(rng, R):
    """The 24 rotations mapping the world axes onto the true camera-frame axes (up to labels),
    each perturbed by ~1 degree, as the vanishing-point stage would produce them."""
    out = []
    for perm in ((0, 1, 2), (1, 2, 0), (2, 0, 1), (0, 2, 1), (2, 1, 0), (1, 0, 2)):
        for sx in (1, -1):
            for sy in (1, -1):
                P = np.eye(3)[list(perm)] * np.array([sx, sy, 1.0])[:, None]
                P[2] *= np.linalg.det(P)  # proper
                noise = rotation_from_axis_angle(rng.normal(size=3), np.radians(rng.uniform(0, 1.0)))
                out.append(noise @ R @ P)
    return np.stack(out)


def _query_searches(room, seed=5, n=40):
    """(search arguments, exact SearchResult) of n synthetic queries of the room, 24 rotations each."""
    lines, groups, T, *_ = room
    rng = np.random.default_rng(seed)
    for _ in range(n):
        arcs, R_true, _ = _synthetic_query(rng, lines)
        rots = _manhattan_candidates(rng, R_true)
        # Under rotation r, 2D group j holds the arcs through R_r e_j (3D group j = axis j).
        labels = np.stack([assign_arcs_to_principal(arcs, r.T) for r in rots])
        args = (arcs, labels, rots, lines, groups, T)
        yield args, search_poses(*args, SearchParams(use_fields=False))


# The exact re-scoring on the search's own 42 query points and no top-K diversity: then the fast
# path's losses are the exact path's (the defaults re-score on 162 points, see test_search_diverse).
LEVEL1 = dict(rescore_query_level=None, diverse_translation=0.0)


def _pairs(res):
    return list(zip(res.translation_index.tolist(), res.rotation_index.tolist()))


def test_fast_search_with_rescoring_returns_the_exact_ranking(room):
    fields = room[3]
    for args, exact in _query_searches(room):
        fast = search_poses(*args, SearchParams(**LEVEL1), fields=fields)  # rescore = 64 by default
        # Measured on these 40 queries: the exact best pose is the fast path's first every time and
        # the returned top-20 losses are the exact path's top-20 losses (the poses may differ
        # where inlier counts tie).
        assert _pairs(fast)[0] == _pairs(exact)[0]
        np.testing.assert_array_equal(fast.losses, exact.losses)
        # Without re-scoring the field ranking alone keeps the exact best pose in its top 20
        # (first in 39 / 40, second once), with field losses within 3 inliers of the exact ones.
        plain = search_poses(*args, SearchParams(rescore=0, **LEVEL1), fields=fields)
        assert _pairs(exact)[0] in _pairs(plain)[:2]
        assert abs(plain.losses[0] - exact.losses[0]) <= 3  # inlier counts of 126 terms


def test_maps_of_many_lines_rescore_fewer_poses(room):
    """The exact re-scoring costs poses x lines: a map of more than ``rescore_lines`` lines
    re-scores proportionally fewer poses, never fewer than top_k; the ranking's best stays exact."""
    p = SearchParams()
    assert rescored_poses(p, 300) == rescored_poses(p, p.rescore_lines) == 64
    assert rescored_poses(p, 1573) == 64 * 700 // 1573 == 28  # a building floor's map
    assert rescored_poses(p, 100_000) == p.top_k
    assert rescored_poses(SearchParams(rescore_lines=0), 100_000) == 64
    lines, fields = room[0], room[3]
    half = SearchParams(rescore_lines=len(lines) // 2, **LEVEL1)  # 32 poses re-scored on this room
    assert rescored_poses(half, len(lines)) == 32
    for args, exact in _query_searches(room):
        fast = search_poses(*args, half, fields=fields)
        assert _pairs(fast)[0] == _pairs(exact)[0] and fast.losses[0] == exact.losses[0]


@pytest.mark.parametrize("loss", ["inlier", "l1"])
def test_rescored_losses_equal_exact_losses_at_the_same_poses(room, loss):
    T, fields = room[2], room[3]
    for args, _ in _query_searches(room, seed=8, n=6):
        rots = args[2]
        full = search_poses(*args, SearchParams(use_fields=False, loss=loss, top_k=len(T) * len(rots)))
        grid = np.full((len(T), len(rots)), np.nan)
        grid[full.translation_index, full.rotation_index] = full.losses  # every pose's exact loss
        for rescore in (1, 64, 200):  # at least top_k candidates are re-scored
            fast = search_poses(*args, SearchParams(loss=loss, rescore=rescore, **LEVEL1), fields=fields)
            assert len(fast.losses) == 20 and np.all(np.diff(fast.losses) >= 0)
            np.testing.assert_allclose(fast.losses, grid[fast.translation_index, fast.rotation_index],
                                       rtol=1e-6, atol=1e-6)


def test_ldf_3d_at_equals_ldf_3d_at_those_poses(room):
    lines, groups, T, *_ = room
    rng = np.random.default_rng(3)
    R = _random_rotations(rng, 6)
    x = ldf.query_points(1)
    ti, ri = rng.integers(0, len(T), 30), rng.integers(0, len(R), 30)
    ti[:5] = 7  # repeated translations share one projection
    ref = ldf.ldf_3d(x, R, T, lines, groups)[ti, ri]
    got = ldf.ldf_3d_at(x, R, T, lines, groups, ti, ri)
    assert got.shape == (30, 3, 42)
    np.testing.assert_allclose(got.numpy(), ref.numpy(), atol=1e-6)
    assert ldf.ldf_3d_at(x, R, T, lines, groups, ti[:0], ri[:0]).shape == (0, 3, 42)
    empty = ldf.ldf_3d_at(x, R, T, lines, np.full(len(lines), -1), ti, ri)  # no grouped line
    assert bool((empty == ldf.EMPTY_DISTANCE).all())
    with pytest.raises(InputError, match="indices"):
        ldf.ldf_3d_at(x, R, T, lines, groups, ti, ri[:-1])


@pytest.mark.parametrize("poses_per_batch", [1, 4, 7])
@pytest.mark.parametrize("seen", [0.7, 0.05])
def test_ldf_3d_at_in_batches_equals_one_batch(room, monkeypatch, poses_per_batch, seen):
    """The poses go through batches of AT_BATCH_VALUES dot products, each on the lines its poses see:
    any batch size, same values; a group all of whose lines are hidden is pi away (5 % seen: a floor)."""
    lines, groups, T, *_ = room
    rng = np.random.default_rng(5)
    R = _random_rotations(rng, 6)
    x = ldf.query_points(1)
    ti, ri = rng.integers(0, len(T), 30), rng.integers(0, len(R), 30)
    vis = rng.random((len(T), len(lines))) < seen
    whole = ldf.ldf_3d_at(x, R, T, lines, groups, ti, ri, visibility=vis)
    monkeypatch.setattr(ldf, "AT_BATCH_VALUES", poses_per_batch * 5 * len(lines) * len(x))
    got = ldf.ldf_3d_at(x, R, T, lines, groups, ti, ri, visibility=vis)
    ref = ldf.ldf_3d(x, R, T, lines, groups, visibility=vis)[ti, ri]
    np.testing.assert_allclose(got.numpy(), whole.numpy(), atol=1e-6)
    np.testing.assert_allclose(got.numpy(), ref.numpy(), atol=1e-6)


def test_search_path_selection(room):
    lines, groups, T, fields, _, _ = room
    rng = np.random.default_rng(6)
    arcs, R_true, _ = _synthetic_query(rng, lines)
    rots = _manhattan_candidates(rng, R_true)[:4]
    labels = np.stack([assign_arcs_to_principal(arcs, r.T) for r in rots])
    args = (arcs, labels, rots, lines, groups, T)
    with pytest.raises(InputError, match="no distance fields"):
        search_poses(*args, SearchParams(use_fields=True))
    with pytest.raises(InputError, match="undecomposed"):
        search_poses(*args, SearchParams(use_fields=True, decompose=False), fields=fields)
    with pytest.raises(InputError, match="translations"):
        search_poses(*args[:-1], T[:-1], SearchParams(use_fields=True), fields=fields)
    # decompose=False with fields present silently runs the exact path: same as use_fields=False.
    a = search_poses(*args, SearchParams(decompose=False), fields=fields)
    b = search_poses(*args, SearchParams(decompose=False, use_fields=False))
    np.testing.assert_array_equal(a.losses, b.losses)
    # Other losses go through ldf.pose_loss on the looked-up values.
    c = search_poses(*args, SearchParams(loss="l1", **LEVEL1), fields=fields)
    d = search_poses(*args, SearchParams(loss="l1", use_fields=False))
    assert c.losses[0] == pytest.approx(d.losses[0], rel=0.05)


def test_fields_round_trip_through_the_map_file(room, tmp_path):
    lines, groups, T, _, dist, attrs = room
    m = LdlMap(name="box", bounds_min=LO, bounds_max=HI, lines_raw=lines, lines=lines, line_groups=groups,
               length_threshold=0.5, kept_ratio=1.0, principal_directions=np.eye(3), translations=T,
               fields={"distances": dist}, fields_attrs=attrs)
    write_map(tmp_path / "box.h5", m)
    back = read_map(tmp_path / "box.h5")
    f = DistanceFields.from_map(back)
    assert f.num_translations == len(T) and f.rows == 64 and f.nbytes == dist.nbytes
    # stored as uint8 codes of DISTANCE_QUANTUM * q**2: within half a step (plus float16 rounding) of the computed
    # fields, the step 2 sqrt(d DISTANCE_QUANTUM) finest where the lines are near
    assert back.fields["distances"].dtype == np.float16
    d = dist.astype(np.float32)
    err = np.abs(back.fields["distances"].astype(np.float32) - d)
    step = 2 * np.sqrt(d * DISTANCE_QUANTUM) + DISTANCE_QUANTUM
    assert np.all(err <= step / 2 + 2e-3) and np.all(err[d < 0.1] <= 0.003)
    back.translations = T[:-1]
    with pytest.raises(InputError, match="rebuild"):
        DistanceFields.from_map(back)
    back.fields = {}
    assert DistanceFields.from_map(back) is None
    with pytest.raises(InputError, match="kind"):
        DistanceFields.from_arrays(dist, {**attrs, "kind": "cubemap"})
    with pytest.raises(InputError, match="shape"):
        DistanceFields.from_arrays(dist[:, :, :, :-1], attrs)


def test_compute_fields_bad_input_and_empty_groups():
    with pytest.raises(InputError, match="NaN"):
        compute_fields(np.full((1, 2, 3), np.nan), np.zeros(1, int), np.zeros((1, 3)))
    with pytest.raises(InputError, match="groups"):
        compute_fields(np.ones((2, 2, 3)), np.zeros(3, int), np.zeros((1, 3)))
    lines = np.array([[[1.0, -1.0, 0.0], [1.0, 1.0, 0.0]]])
    d, _ = compute_fields(lines, np.array([1]), np.zeros((2, 3)), FieldParams(rows=8))
    assert d.shape == (2, 3, 9, 16)
    assert np.all(d[:, [0, 2]] == np.float16(np.pi))  # empty groups: pi everywhere
    assert d[0, 1, 4, 8] == 0.0  # equator, phi = 0 looks at the line's midpoint (1, 0, 0)
