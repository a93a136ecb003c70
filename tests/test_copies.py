"""Identical rooms found from the maps' lines (ldlloc/refine/copies.py, ldlloc/confidence.py): a
pose in one of two identical rooms is ambiguous and names the other copy, on its own map (next
door) and on another map (the same room a floor up); a room of its own stays confident."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ldlloc.confidence import MODEL, add_copies, assess
from ldlloc.pipeline import Localization
from ldlloc.refine.copies import find_copies, line_samples, turn

ROOM = np.array([4.0, 6.0, 3.0])
NEXT_DOOR = np.array([4.2, 0.0, 0.0])  # the copy beyond a 0.2 m wall
UP = np.array([0.0, 0.0, 3.3])  # the same room a floor up


def _segments(points: list) -> list:
    return [[np.array(a, float), np.array(b, float)] for a, b in points]


def _room(door_y: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A room's lines and groups (0, 1, 2: x, y, z): the box's 12 edges, a door on the wall x = 0 at
    ``door_y`` and a window on the wall y = 6 (what breaks its symmetry)."""
    X, Y, Z = ROOM
    corners = np.array([[x, y, z] for x in (0, X) for y in (0, Y) for z in (0, Z)])
    lines = [[corners[i], corners[j]] for i in range(8) for j in range(i + 1, 8)
             if np.count_nonzero(corners[j] - corners[i]) == 1]
    lines += _segments([([0, door_y, 0], [0, door_y, 2.1]), ([0, door_y + 0.9, 0], [0, door_y + 0.9, 2.1]),
                        ([0, door_y, 2.1], [0, door_y + 0.9, 2.1]),
                        ([1.0, Y, 0.9], [2.5, Y, 0.9]), ([1.0, Y, 2.1], [2.5, Y, 2.1]),
                        ([1.0, Y, 0.9], [1.0, Y, 2.1]), ([2.5, Y, 0.9], [2.5, Y, 2.1])])
    L = np.array(lines, float)
    d = np.abs(L[:, 1] - L[:, 0])
    return L, np.argmax(d, axis=1)


def _lattice(origin: np.ndarray, spacing: float = 0.3) -> np.ndarray:
    axes = [np.arange(0.2, ROOM[0] - 0.19, spacing), np.arange(0.2, ROOM[1] - 0.19, spacing), np.arange(0.3, 2.21, spacing)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3) + origin


def _map(rooms: list[tuple[np.ndarray, np.ndarray, np.ndarray]], name: str = "floor") -> SimpleNamespace:
    """A map of rooms ``(origin, lines, groups)`` whose candidates each see their own room's lines."""
    lines = np.concatenate([L + o for o, L, _ in rooms])
    groups = np.concatenate([g for _, _, g in rooms])
    owner = np.concatenate([np.full(len(L), k) for k, (_, L, _) in enumerate(rooms)])
    T = [_lattice(o) for o, _, _ in rooms]
    room_of = np.concatenate([np.full(len(t), k) for k, t in enumerate(T)])
    T = np.concatenate(T)

    def nearest(c):
        return np.argmin(np.linalg.norm(T[None] - np.asarray(c, float).reshape(-1, 1, 3), axis=2), axis=1)
    return SimpleNamespace(lines=lines, line_groups=groups, translations=T, visibility=room_of[:, None] == owner[None],
                           nearest_translation=nearest, name=name)


def _localization(m, R: np.ndarray, t: np.ndarray) -> Localization:
    """A clear geometric winner at ``(R, t)`` whose image shows the lines its candidate sees."""
    seen = m.lines[m.visibility[m.nearest_translation(t[None])[0]]]
    d = (seen - t) @ R.T
    arcs = d / np.linalg.norm(d, axis=2, keepdims=True)
    far = t + [0.0, 1.5, 0.0]
    return Localization(R, t, R, t, np.stack([R, R]), np.stack([t, far]), {}, num_rotations=2, num_lines=len(arcs),
                        refined=True, arcs=arcs, candidates_loss=np.array([-100.0, -60.0]),
                        refine_method="geometric", selection_margin=0.4)


R0 = turn(0) @ np.array([[np.cos(0.5), -np.sin(0.5), 0], [np.sin(0.5), np.cos(0.5), 0], [0, 0, 1]])
T0 = np.array([1.7, 2.6, 1.4])


def test_line_samples_cover_each_line():
    pts, owner = line_samples(np.array([[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [0, 0, 0.01]]], float), 0.1)
    assert owner.tolist() == [0] * 11 + [1] * 2
    assert np.allclose(pts[:11, 0], np.linspace(0, 1, 11)) and np.allclose(pts[11:, 2], [0, 0.01])


def test_room_next_door_is_a_copy():
    """Two identical rooms side by side on one map: the pose in the first is ambiguous, the copy named
    4.2 m away (where the same camera stands in the other room); a unique room stays confident."""
    L, g = _room()
    twins = _map([(np.zeros(3), L, g), (NEXT_DOOR, L, g)])
    loc = _localization(twins, R0, T0)
    assess(loc, twins)
    assert loc.verdict == "ambiguous" and loc.confidence_signals["copies"] == 1
    copy = [c for c in loc.competitors if "copy" in c]
    assert len(copy) == 1 and np.allclose(copy[0]["t"], T0 + NEXT_DOOR, atol=0.05)
    assert np.allclose(copy[0]["R"], R0, atol=1e-6) and "4.2 m away" in copy[0]["why"]

    L2, g2 = _room(door_y=3.5)  # the room next door has its door elsewhere: nothing repeats
    unique = _map([(np.zeros(3), L, g), (NEXT_DOOR, L2, g2)])
    loc = _localization(unique, R0, T0)
    assess(loc, unique)
    assert loc.verdict == "confident" and loc.confidence >= MODEL.confident_at
    assert "copies" not in loc.confidence_signals and not loc.competitors


def test_turned_copy_on_another_floor():
    """The same room a floor up, turned by 90 degrees, on another map: named with that map, the copy's
    camera turned with it; the room's own 180-degree symmetry is never a copy."""
    L, g = _room()
    ground = _map([(np.zeros(3), L, g)], "floor_0")
    Q = turn(1)
    up = UP + [10.0, 0.0, 0.0]
    upper = _map([(up, L @ Q.T, np.array([1, 0, 2])[g])], "floor_1")
    upper.translations = _lattice(np.zeros(3)) @ Q.T + up
    loc = _localization(ground, R0, T0)
    assess(loc, ground)
    assert loc.verdict == "confident"
    add_copies(loc, ground, [("floor_1", upper)])
    assert loc.verdict == "ambiguous" and loc.confidence_signals["copies"] == 1
    c = loc.competitors[0]
    assert c["map"] == "floor_1" and c["copy"]["map"] == "floor_1" and "turned 90 deg" in c["why"]
    assert np.allclose(c["t"], Q @ T0 + up, atol=0.05) and np.allclose(c["R"], R0 @ Q.T, atol=1e-6)


def test_image_that_tells_the_copies_apart():
    """Identical walls, but the image shows a wall of shelves only the first room has (map lines the
    copy lacks): the copy explains the image less well, and is not named."""
    L, g = _room()
    shelves = [[[3.99, 1.5, z], [3.99, 4.5, z]] for z in np.arange(0.3, 2.6, 0.2)]
    shelves += [[[3.99, y, 0.3], [3.99, y, 2.5]] for y in np.arange(1.5, 4.6, 0.4)]
    first = np.concatenate([L, np.array(shelves, float)])
    groups = np.concatenate([g, [1] * 12, [2] * (len(shelves) - 12)])
    m = _map([(np.zeros(3), first, groups), (NEXT_DOOR, L, g)])
    loc = _localization(m, R0, T0)
    assert find_copies(loc.arcs, R0, T0, m, [(None, m)], 1.0) == []
    assess(loc, m)
    assert loc.verdict == "confident"
