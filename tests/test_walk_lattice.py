"""The walk's lattice near a confident frame (ldlloc/walk/lattice.py): where a map's candidate
translations are too sparse for a frame's true pose to score best among them, a fine lattice of
translations around the walk's confident neighbour finds it, only where the map has free space;
and which frames anchor those searches (ldlloc/walk/localize.py: is_anchor)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ldlmap.core.geometry import cam_from_world, normalize, rotation_from_axis_angle, rotation_error_deg
from ldlmap.map.contents import LdlMap
from ldlloc.confidence import MODEL
from ldlloc.pipeline import LocalizeParams
from ldlloc.search.pose_search import score_on_map
from ldlloc.walk.lattice import LatticeParams, lattice_poses, lattice_translations
from ldlloc.walk.hypotheses import Hypotheses
from ldlloc.walk.localize import FrameOutcome, WalkFrame, WalkParams, emission_costs, is_anchor

LO, HI = np.array([0.0, 0.0, 0.0]), np.array([8.0, 3.0, 2.6])  # a corridor 8 x 3 m
TRUE_T = np.array([4.1, 1.3, 1.6])  # the camera, between the map's candidates (1 m apart)


def _corridor_lines(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The corridor's edges and 16 door and poster rectangles on its walls: (L, 2, 3) and their axis groups."""
    rng = np.random.default_rng(seed)
    c = np.array([[x, y, z] for x in (LO[0], HI[0]) for y in (LO[1], HI[1]) for z in (LO[2], HI[2])])
    lines = [[c[i], c[j]] for i in range(8) for j in range(i + 1, 8) if np.sum(c[i] != c[j]) == 1]
    for _ in range(16):
        y = (LO[1], HI[1])[rng.integers(0, 2)]
        x0, w = rng.uniform(0.3, 7.0), rng.uniform(0.4, 1.0)
        z0, h = rng.uniform(0.0, 1.2), rng.uniform(0.5, 1.2)
        q = np.array([[x0, y, z0], [x0 + w, y, z0], [x0 + w, y, z0 + h], [x0, y, z0 + h]])
        lines += [[q[k], q[(k + 1) % 4]] for k in range(4)]
    L = np.array(lines, dtype=np.float64)
    return L, np.argmax(np.abs(L[:, 1] - L[:, 0]), axis=1)


def _map(lines: np.ndarray, groups: np.ndarray) -> LdlMap:
    """The corridor's map with sparse candidates: 1 m apart in xy at two heights of the camera band."""
    g = np.meshgrid(np.arange(0.5, 8.0, 1.0), np.arange(0.5, 3.0, 1.0), (0.9, 2.0), indexing="ij")
    T = np.stack(g, -1).reshape(-1, 3)
    return LdlMap(name="corridor", bounds_min=LO, bounds_max=HI, lines_raw=lines, lines=lines, line_groups=groups,
                  length_threshold=0.0, kept_ratio=1.0, principal_directions=np.eye(3), translations=T)


def _query(lines: np.ndarray, R: np.ndarray, t: np.ndarray, seed: int = 4) -> np.ndarray:
    """The arcs (N, 2, 3) the camera at (R, t) sees of the lines, a little noisy."""
    rng = np.random.default_rng(seed)
    arcs = cam_from_world(lines, R, t)
    return normalize(arcs + rng.normal(scale=0.003, size=arcs.shape))


def test_lattice_finds_the_pose_the_sparse_candidates_miss():
    lines, groups = _corridor_lines()
    m = _map(lines, groups)
    loz = SimpleNamespace(map=m, params=LocalizeParams(), device="cpu")
    R = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(30.0))
    arcs = _query(lines, R, TRUE_T)
    sp, tol = loz.params.search, loz.params.principal.group_tol
    # at its true rotation, the map's best candidate is 0.5 m or more from the camera: the true pose is not among them
    cand = score_on_map(arcs, np.repeat(R[None], len(m.translations), 0), m.translations, m, sp, "cpu", tol)
    assert np.linalg.norm(m.translations[np.argmin(cand)] - TRUE_T) > 0.3
    # the walk's confident neighbour stands 1.1 m away at the camera's height; the search's rotations: the true one,
    # a degree off, and its 180-degree twin
    anchor = TRUE_T + np.array([1.1, -0.3, 0.0])
    twin = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.pi) @ R
    rots = np.stack([rotation_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(1.0)) @ R, twin])
    Rk, tk, lk = lattice_poses(arcs, loz, anchor, 2.0, rots, LatticeParams(spacing_m=0.2))
    assert len(lk) > 1 and np.all(np.diff(lk) >= 0)
    assert np.linalg.norm(tk[0] - TRUE_T) < 0.15 and rotation_error_deg(Rk[0], R) < 2.0
    assert lk[0] < np.min(cand)  # it explains more lines than any candidate of the map


def test_lattice_stays_in_the_free_space_at_the_anchors_height_and_is_bounded():
    lines, groups = _corridor_lines()
    m = _map(lines, groups)
    T2 = m.translations[:, :2]
    anchor = np.array([7.5, 1.5, 1.62])
    p = LatticeParams(spacing_m=0.2, reach_m=0.6)
    P = lattice_translations(m.translations, anchor, 3.0, p)
    assert len(P) > 100 and np.all(P[:, 2] == anchor[2])
    assert np.all(np.linalg.norm(P[:, :2] - anchor[:2], axis=1) <= 3.0 + 1e-9)
    d = np.linalg.norm(P[:, None, :2] - T2[None], axis=2).min(1)
    assert np.all(d <= 0.6 + 1e-9)  # beyond the corridor's end (x > 8.1): no candidate near, no lattice point
    assert P[:, 0].max() <= 8.1
    few = lattice_translations(m.translations, anchor, 3.0, LatticeParams(spacing_m=0.2, max_points=50))
    assert 0 < len(few) <= 53  # a coarser lattice, its cost bounded
    other_floor = lattice_translations(m.translations + [0, 0, 3.0], anchor, 3.0, p)
    assert len(other_floor) == 0  # the candidates of the floor above tell nothing here
    assert len(lattice_translations(m.translations, anchor, 3.0, LatticeParams())) == 0  # off by default


def test_a_frame_confident_but_for_copies_of_its_room_anchors_the_walks_searches():
    # a building's floors are copies of each other: every corridor frame names them and is ambiguous, yet its pose is
    # right up to which copy (the walk chooses it), so it anchors the searches (and lattices) of the frames near it
    def frame(verdict: str, conf: float, copies: float) -> FrameOutcome:
        loc = SimpleNamespace(confidence_signals={"copies": copies})
        return FrameOutcome(WalkFrame("f", None), loc=loc, single_verdict=verdict, single_confidence=conf)

    sure = MODEL.confident_at + 0.01
    assert is_anchor(frame("confident", sure, 0.0))
    assert is_anchor(frame("ambiguous", sure, 2.0))
    assert not is_anchor(frame("ambiguous", sure, 0.0))  # a twin or a rival, not a copy: no anchor
    assert not is_anchor(frame("ambiguous", MODEL.confident_at - 0.05, 2.0))  # doubtful even without its copies
    assert not is_anchor(frame("failed", 0.0, 2.0))


def test_a_frame_confident_but_for_copies_leaves_the_walk_its_copies_only():
    # its own pose and the copies it named cost next to nothing; any other pose costs the anchor cost, as beside a
    # confident frame (without it, a building walk stayed on the floor below: no corridor frame held it)
    R = np.eye(3)
    own, copy, other = np.array([20.4, 5.4, 7.6]), np.array([20.4, 5.4, 4.6]), np.array([20.9, 0.9, 4.6])
    h = Hypotheses(map_index=np.array([2, 1, 1]), rot_cam_from_world=np.stack([R, R, R]),
                   center=np.stack([own, copy, other]), loss=np.array([-200.0, -200.0, -200.0]),
                   final=np.array([True, True, True]))
    named = [{"R": R.tolist(), "t": copy.tolist(), "loss": None, "why": "copy of this room", "copy": {"map": "f1"}}]
    loc = SimpleNamespace(confidence_signals={"copies": 2.0})
    o = FrameOutcome(WalkFrame("f", None), loc=loc, single_verdict="ambiguous",
                     single_confidence=MODEL.confident_at + 0.01, single_pose=(R, own), competitors=named, hypotheses=h)
    params = WalkParams()
    cost = emission_costs(o, params)
    assert cost[0] == 0.0 and cost[1] < 0.1
    assert cost[2] >= params.motion.anchor_cost
