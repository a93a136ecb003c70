"""Checks of a pose that need no fitting (ldlloc/refine/geometric.py, ldlloc/confidence.py): a camera
stands where the map's candidate translations are (never under the floor, in a wall, outside the
room), and a refined twin that scores as well makes the verdict ambiguous, named."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ldlloc.confidence import assess, refined_rivals
from ldlloc.refine.geometric import GeometricParams, physical_poses, selection_scores
from tests.test_confidence import BOX, CENTRE, _box_map, _localization, _rz


def test_physical_poses_follow_the_candidates():
    """Inside the box's band every centre is physical (the lattice's corners and mid-cells too);
    under the floor, above the band, a metre into or beyond a wall, or in another room is not. The
    tolerance follows the map's own spacing: the same room sampled twice as coarsely tolerates
    twice the distance."""
    m = _box_map()
    inside = np.array([CENTRE, [0.35, 0.35, 0.45], [3.8, 5.8, 2.2], [2.05, 3.05, 1.65], [0.05, 3.0, 1.4]])
    assert physical_poses(inside, m).all()
    outside = np.array([CENTRE - [0, 0, 3.9],  # 3.9 m under the floor (issue's layout miss)
                        CENTRE + [0, 0, 4.6],  # above the ceiling
                        [-1.0, 3.0, 1.5],  # a metre beyond the wall
                        [2.0, 7.2, 1.5],  # outside the far wall
                        [9.0, 3.0, 1.5],  # in another room
                        [2.0, 3.0, -0.6]])  # under the floor
    assert not physical_poses(outside, m).any()
    T = m.translations
    sparse = SimpleNamespace(translations=T[(np.round((T[:, 0] - 0.2) / 0.3) % 2 == 0)
                                            & (np.round((T[:, 1] - 0.2) / 0.3) % 2 == 0)
                                            & (np.round((T[:, 2] - 0.3) / 0.3) % 2 == 0)])
    off = np.array([[2.0, 3.0, 2.2 + 0.9]])  # 0.9 m above the band: 3 spacings of 0.3, 1.5 of 0.6
    assert not physical_poses(off, m)[0] and physical_poses(off, sparse)[0]


def test_selection_drops_an_unphysical_best_pose():
    """The refinement's best-scoring pose stands under the floor: the selection picks the best
    physical pose instead; when no refined pose is physical, every pose competes (the verdict then
    says failed)."""
    m = _box_map()
    centers = np.array([CENTRE - [0, 0, 2.0], CENTRE + [0.1, 0, 0], CENTRE + [0, 1.5, 0]])
    loss = np.array([-120.0, -100.0, -60.0])  # the unphysical pose explains the most lines
    params = GeometricParams()
    support = lambda idx: np.zeros(len(idx))  # noqa: E731
    allowed = physical_poses(centers, m)
    assert allowed.tolist() == [False, True, True]
    score = selection_scores(loss, params, support, allowed)
    assert int(np.argmax(score)) == 1 and score[0] == -np.inf
    assert int(np.argmax(selection_scores(loss, params, support))) == 0  # without the rule it would win
    none = selection_scores(loss, params, support, np.zeros(3, bool))
    assert int(np.argmax(none)) == 0


def test_unphysical_final_pose_is_failed():
    """A final pose (a PnP pose far from every candidate) 1 m under the floor is failed with
    confidence 0, whatever its other signals say."""
    m = _box_map()
    R0 = _rz(30)
    loc = _localization(m, R0, [(R0, CENTRE - [0, 0, 2.5]), (R0, CENTRE + [0, 1.5, 0])], [-100.0, -50.0], margin=0.5)
    loc.refine_method, loc.selection_margin, loc.num_inliers = "features", None, 150
    assess(loc, m)
    assert loc.confidence_signals["physical"] == 0.0
    assert loc.verdict == "failed" and loc.confidence == 0.0
    ok = _localization(m, R0, [(R0, CENTRE), (R0, CENTRE + [0, 1.5, 0])], [-100.0, -50.0], margin=0.5)
    ok.refine_method, ok.selection_margin, ok.num_inliers = "features", None, 150
    assess(ok, m)
    assert ok.confidence_signals["physical"] == 1.0 and ok.verdict == "confident"


def test_symmetric_room_twin_is_named_and_ambiguous():
    """A box seen from off its centre: the 180-degree twin about the box's centre sees the same
    lines. The search ranked the twin far down (its loss 40 % worse: no search competitor), but
    refined it scores within the noise of the final pose: the verdict is ambiguous (``tie``: never
    confident, whatever the fitted model says) and the twin is named, refined. A rival that scores
    clearly worse leaves the pose confident."""
    m = _box_map()
    R0 = _rz(30)
    t = CENTRE + [0.6, 0.9, 0.0]
    twin_R, twin_t = R0 @ _rz(180), BOX * [1, 1, 0] - t * [1, 1, -1]  # turned half a turn about the box's centre
    poses = [(R0, t), (R0, t + [0, 1.5, 0]), (twin_R, twin_t)]
    for gap, verdict in ((0.01, "ambiguous"), (0.3, "confident")):
        loc = _localization(m, R0, poses, [-100.0, -60.0, -60.0], margin=gap)
        rots, centers = np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses])
        score = np.array([1.0, -np.inf, 1.0 - gap])  # the second never came within reach
        loc.selection_margin, loc.refined_rivals = refined_rivals(0, rots, centers, np.array([-100.0, -60.0, -99.5]),
                                                                  score)
        assert loc.selection_margin == pytest.approx(gap)
        assess(loc, m)
        assert loc.confidence_signals["physical"] == 1.0
        assert loc.verdict == verdict
        if verdict == "ambiguous":
            assert loc.confidence_signals["tie"] == 1.0
            assert loc.competitors[0]["why"].startswith("other position (2.2 m), 180-degree twin, refined")
            assert np.allclose(loc.competitors[0]["t"], twin_t)
        else:
            assert loc.confidence_signals["tie"] == 0.0 and loc.competitors == []
