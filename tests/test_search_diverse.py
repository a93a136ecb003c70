"""Diverse top-K poses: the search keeps distinct poses (a pose and its twin), not near-copies."""

from __future__ import annotations

import numpy as np

from ldlmap.core.geometry import rotation_from_axis_angle
from ldlloc.search.pose_search import SearchParams, diverse_subset, search_poses
from tests.test_fields import _query_searches, room  # noqa: F401  (module fixture)


def test_diverse_subset_suppresses_only_near_copies():
    Rz = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(90))
    small = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(2))
    C = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0, 0], [1.0, 0, 0], [0.05, 0.05, 0]], dtype=float)
    R = np.stack([np.eye(3), small, Rz, np.eye(3), Rz])
    # 1: 0.1 m and 2 deg from 0 (a near-copy); 2: other rotation; 3: 1 m away; 4: near-copy of 2.
    assert diverse_subset(C, R, 10, 0.3, 5.0).tolist() == [0, 2, 3]
    assert diverse_subset(C, R, 2, 0.3, 5.0).tolist() == [0, 2]
    assert diverse_subset(C, R, 10, 0.05, 1.0).tolist() == [0, 1, 2, 3, 4], "tight bounds keep everything"


def test_search_with_diversity_keeps_the_best_pose_and_spreads_the_rest(room):  # noqa: F811
    fields = room[3]
    div = SearchParams(diverse_translation=0.6, diverse_rotation_deg=5.0, rescore_query_level=None)
    for args, exact in _query_searches(room, n=10):
        T = args[5]
        res = search_poses(*args, div, fields=fields)
        plain = search_poses(*args, SearchParams(diverse_translation=0.0, rescore_query_level=None), fields=fields)
        assert res.losses[0] == plain.losses[0], "the best pose is never suppressed"
        assert np.all(np.diff(res.losses) >= 0)
        d = np.linalg.norm(res.centers[:, None] - res.centers[None], axis=-1)
        tr = np.einsum("aij,bij->ab", res.rotations, res.rotations)
        close = (d < 0.6) & ((tr - 1) / 2 > np.cos(np.radians(5.0)))
        np.fill_diagonal(close, False)
        assert not close.any(), "no two returned poses are near-copies"
        assert len(res.losses) == min(20, len(T) * len(args[2]))


def test_denser_rescoring_finds_the_true_pose(room):  # noqa: F811
    """The default search (re-scoring on 162 query points, diversity) puts a pose at the nearest
    candidate translation and within 2 degrees of the truth first, as the exact path does."""
    from ldlmap.core.geometry import rotation_error_deg
    from ldlloc.rotation import assign_arcs_to_principal
    from tests.test_fields import _manhattan_candidates, _synthetic_query

    lines, groups, T, fields, *_ = room
    rng = np.random.default_rng(11)
    hits = exact_hits = 0
    for _ in range(12):
        arcs, R_true, t_true = _synthetic_query(rng, lines)
        rots = _manhattan_candidates(rng, R_true)
        labels = np.stack([assign_arcs_to_principal(arcs, r.T) for r in rots])
        nearest = int(np.argmin(np.linalg.norm(T - t_true, axis=1)))
        for params, f in ((SearchParams(), fields), (SearchParams(use_fields=False), None)):
            res = search_poses(arcs, labels, rots, lines, groups, T, params, fields=f)
            ok = res.translation_index[0] == nearest and rotation_error_deg(res.rotations[0], R_true) < 2.0
            if f is None:
                exact_hits += ok
            else:
                hits += ok
    assert hits >= exact_hits - 1 and hits >= 10, (hits, exact_hits)
