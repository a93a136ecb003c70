"""Candidate translations: inside the room, clear of the scan, near the requested count, covering."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from ldlmap.errors import InputError
from ldlmap.translations import candidate_translations
from tests._room_cloud import box_room

SIZE = (6.0, 4.5, 2.8)
YAW = 30.0


@pytest.fixture(scope="module")
def room():
    pts, edges = box_room(seed=0, size=SIZE, n_boxes=3, density=1500.0, yaw_deg=YAW)
    c, s = np.cos(np.radians(YAW)), np.sin(np.radians(YAW))
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    centre = np.array([SIZE[0] / 2, SIZE[1] / 2, 0.0])

    def to_room(X):  # undo the yaw: room frame [0, W] x [0, D] x [0, H]
        return (X - centre) @ R + centre

    E = to_room(edges)
    boxes = [(E[12 + 12 * k: 24 + 12 * k].reshape(-1, 3).min(0), E[12 + 12 * k: 24 + 12 * k].reshape(-1, 3).max(0))
             for k in range((len(E) - 12) // 12)]
    return pts, to_room, boxes


@pytest.mark.parametrize("method,num", [("octree", 800), ("grid", 1700), ("octree", 60)])
def test_candidates_inside_free_space(room, method, num):
    pts, to_room, boxes = room
    C = candidate_translations(pts, num=num, method=method, clearance=0.25)
    assert abs(len(C) - num) <= 0.15 * num
    X = to_room(C)
    assert np.all((X > 0) & (X < np.array(SIZE))), "all candidates inside the room"
    for lo, hi in boxes:
        assert not np.any(np.all((X > lo) & (X < hi), axis=1)), "no candidate inside furniture"
    d, _ = cKDTree(pts).query(C)
    assert d.min() >= 0.25
    # Coverage: free positions of the room have a candidate nearby.
    rng = np.random.default_rng(1)
    Q = rng.uniform([0.6, 0.6, 0.6], np.array(SIZE) - 0.6, size=(400, 3))
    for lo, hi in boxes:
        Q = Q[~np.all((Q > lo - 0.5) & (Q < hi + 0.5), axis=1)]
    dq, _ = cKDTree(X).query(Q)
    spacing = (np.prod(SIZE) / num) ** (1 / 3)
    assert np.max(dq) < 2.0 * spacing, (np.max(dq), spacing)


def test_prior_centers_and_bad_input(room):
    pts, _, _ = room
    prior = np.array([[1.0, 1.0, 1.5], [2.0, 2.0, 1.5]])
    C = candidate_translations(pts, num=50, method="grid", prior_centers=prior)
    assert np.allclose(C[-2:], prior)
    with pytest.raises(InputError):
        candidate_translations(pts, num=10, method="voronoi")
    with pytest.raises(InputError):
        candidate_translations(np.zeros((0, 3)), num=10)
    bad = pts[:100].copy()
    bad[3, 2] = np.nan
    with pytest.raises(InputError):
        candidate_translations(bad, num=10)
