"""The walk's motion model: no step through a wall (ldlloc.walk.motion.FreeSpace).

The map: a scan of two 4 x 4 m rooms side by side, a 0.2 m wall between them with a 1 m door
(y 1.5-2.5 m); its candidate translations are the scan's (``candidate_translations``: free space
kept 0.25 m clear of every point), so the wall leaves a 0.7 m band without candidates, the door
none.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ldlloc.walk.hypotheses import Hypotheses
from ldlloc.walk.doors import lived_in, with_doors
from ldlloc.walk.motion import FreeSpace, MotionParams, transition_costs
from ldlloc.walk.viterbi import best_path
from ldlmap.map.translations import TranslationParams, candidate_translations, translations_and_footprint

WALL = (4.0, 4.2)  # x of the wall's faces
DOOR = (1.5, 2.5)  # y of the door's jambs
VIDEO = MotionParams(turn_deg=30.0)


def _plane(u: np.ndarray, v: np.ndarray, fix: int, value: float) -> np.ndarray:
    """Points of an axis-aligned rectangle: coordinate ``fix`` = ``value``, the other two over ``u`` x ``v``."""
    U, V = np.meshgrid(u, v, indexing="ij")
    cols = [U.ravel(), V.ravel()]
    cols.insert(fix, np.full(U.size, value))
    return np.stack(cols, 1)


@pytest.fixture(scope="module")
def two_rooms() -> np.ndarray:
    """Candidate translations (N_t, 3) of the scan of two rooms with a door between them."""
    s = 0.05
    x, y, z = np.arange(0, 8.2 + s, s), np.arange(0, 4 + s, s), np.arange(0, 2.6 + s, s)
    parts = [_plane(x, y, 2, 0.0), _plane(x, y, 2, 2.6),  # floor, ceiling
             _plane(y, z, 0, 0.0), _plane(y, z, 0, 8.2), _plane(x, z, 1, 0.0), _plane(x, z, 1, 4.0)]  # outer walls
    for face in WALL:  # the wall between the rooms, both faces, the door cut out below 2.1 m
        p = _plane(y, z, 0, face)
        parts.append(p[~((p[:, 1] > DOOR[0]) & (p[:, 1] < DOOR[1]) & (p[:, 2] < 2.1))])
    T = candidate_translations(np.concatenate(parts), num=600, method="grid", clearance=0.25)
    assert len(T) > 100
    return T


def _hyps(centers: list, losses: list) -> Hypotheses:
    n = len(centers)
    return Hypotheses(np.zeros(n, dtype=np.int64), np.repeat(np.eye(3)[None], n, 0), np.array(centers, float),
                      np.array(losses, float), np.zeros(n, bool))


def test_steps_through_the_wall_leave_the_free_space(two_rooms):
    free = FreeSpace([two_rooms])
    z = float(np.median(two_rooms[:, 2]))
    a = np.array([[3.2, 0.8, z], [3.2, 2.0, z], [1.0, 1.0, z]])
    b = np.array([[5.0, 0.8, z], [5.0, 2.0, z], [3.0, 3.0, z]])
    blocked = free.blocked(a, np.zeros(3, int), b, np.zeros(3, int))
    assert blocked[0, 0]  # straight through the wall
    assert not blocked[1, 1]  # through the door
    assert not blocked[2, 2]  # across room A
    assert blocked[2, 0] and not blocked[2, 1]  # from room A's far corner: into room B only by the door
    outside = free.blocked(a[:1], np.zeros(1, int), np.array([[3.2, 6.0, z]]), np.zeros(1, int))
    assert outside[0, 0]  # out of the building


def test_a_video_does_not_step_through_a_wall(two_rooms):
    # frames 1 s apart walking along room A towards the wall (0.8 m a frame); the last frame's image
    # likes a pose in room B behind the wall (2.2 m away: a walker covers 1.4 m in a second) better
    # than its pose in room A: the walls keep the walk in room A, without them it goes through
    z = float(np.median(two_rooms[:, 2]))
    frames = [_hyps([[1.0 + 0.8 * k, 0.8, z]], [-100]) for k in range(3)]
    frames.append(_hyps([[3.3, 0.8, z], [4.8, 0.8, z]], [-90, -100]))
    em = [h.emission_costs(VIDEO.emission_weight) for h in frames]
    free = FreeSpace([two_rooms])

    def path(walls):
        return best_path(em, lambda f: transition_costs(frames[f - 1], frames[f], VIDEO, 1.0, walls)).choice

    assert path(None)[-1] == 1
    assert path(free)[-1] == 0
    through = transition_costs(frames[2], frames[3], VIDEO, 1.0, free)[0]
    assert through[1] >= VIDEO.blocked_cost and through[0] == 0.0


def test_a_tour_step_through_a_wall_costs_a_jump(two_rooms):
    z = float(np.median(two_rooms[:, 2]))
    tour = MotionParams()
    a, b = _hyps([[3.0, 0.8, z]], [-100]), _hyps([[5.0, 0.8, z], [3.5, 3.2, z]], [-100, -100])
    free = FreeSpace([two_rooms])
    c = transition_costs(a, b, tour, None, free)[0]
    assert c[0] == pytest.approx(tour.jump_cost)  # 2 m (free), but through the wall: round by the door, a detour
    assert c[1] == 0.0  # 2.4 m within room A
    assert transition_costs(a, b, tour, None, None)[0, 0] == 0.0  # no walls known: a short step
    assert transition_costs(a, b, tour, 60.0, free)[0, 0] == pytest.approx(tour.jump_cost)  # a minute apart


def test_free_space_of_each_map_and_of_maps_side_by_side(two_rooms):
    # each room as its own map (room maps of one floor): a step from one to the other through the door
    # is free (both maps' free space), through the wall it is not
    room_a, room_b = two_rooms[two_rooms[:, 0] < 4.1], two_rooms[two_rooms[:, 0] >= 4.1]
    free = FreeSpace([room_a, room_b])
    z = float(np.median(two_rooms[:, 2]))
    a, b = np.array([[3.2, 2.0, z], [3.2, 0.8, z]]), np.array([[5.0, 2.0, z], [5.0, 0.8, z]])
    blocked = free.blocked(a, np.array([0, 0]), b, np.array([1, 1]))
    assert not blocked[0, 0] and blocked[1, 1]
    assert free.blocked(a[:1], np.array([0]), b[:1], np.array([0]))[0, 0]  # room A's map alone ends at the door


def test_frames_close_in_time_skip_no_room():
    # a tour may skip a room (a jump of 12 m costs the jump cost); a video's frames 0.2 s apart cannot:
    # a run of frames (few lines) whose images prefer a pose 3 m away does not outweigh the motion there and back
    a, b = _hyps([[0.0, 0, 1.5]], [-100]), _hyps([[12.0, 0, 1.5]], [-100])
    assert transition_costs(a, b, MotionParams(), None)[0, 0] == pytest.approx(MotionParams().jump_cost)
    assert transition_costs(a, b, VIDEO, 0.2)[0, 0] > 5 * VIDEO.jump_cost  # 12 m in 0.2 s
    walk = [_hyps([[0.2 * k, 0, 1.5]], [-100]) for k in range(3)]
    walk += [_hyps([[0.2 * k, 0, 1.5], [0.2 * k, 3.0, 1.5]], [-80, -100]) for k in range(3, 6)]
    walk += [_hyps([[0.2 * k, 0, 1.5]], [-100]) for k in range(6, 9)]
    em = [h.emission_costs(VIDEO.emission_weight) for h in walk]
    assert best_path(em, lambda f: transition_costs(walk[f - 1], walk[f], VIDEO, 0.2)).choice == [0] * 9


TWIN_DOORS = ((1.5, 2.5), (5.7, 6.7))  # x of the jambs of room A's and room B's doors


def _twin_scan(closed: bool) -> tuple[np.ndarray, list]:
    """The scan of two identical 4 x 4 m rooms side by side (x 0-4 and 4.2-8.2 m: a 0.2 m wall between
    them), each with a 1 m door 2.1 m high (:data:`TWIN_DOORS`) onto a 2 m corridor south of both
    (y -2-0), the doors open (holes in the wall) or ``closed`` (the wall whole, as the synthetic
    building's scans see them), and a cabinet (0.5 x 0.8 x 2 m) against the wall between the rooms;
    its points and its lines: the doors' jambs on both sides, the rooms' corners, the cabinet's edges."""
    s = 0.05
    x, y, z = np.arange(0, 8.2 + s, s), np.arange(-2.0, 4.2 + s, s), np.arange(0, 2.6 + s, s)
    parts = [_plane(x, y, 2, 0.0), _plane(x, y, 2, 2.6), _plane(y, z, 0, 0.0), _plane(y, z, 0, 8.2),
             _plane(x, z, 1, -2.0), _plane(x, z, 1, 4.2)]
    for face in (0.0, 0.2):  # the rooms' wall onto the corridor, both faces
        p = _plane(x, z, 1, face)
        door = np.any([(p[:, 0] > a) & (p[:, 0] < b) for a, b in TWIN_DOORS], axis=0) & (p[:, 2] < 2.1)
        parts.append(p if closed else p[~door])
    parts += [_plane(y[y >= 0.2], z, 0, face) for face in (4.0, 4.2)]  # the wall between the rooms
    cx, cy, cz = np.arange(3.5, 4.0 + s, s), np.arange(2.0, 2.8 + s, s), np.arange(0, 2.0 + s, s)
    parts += [_plane(cy, cz, 0, 3.5), _plane(cx, cz, 1, 2.0), _plane(cx, cz, 1, 2.8), _plane(cx, cy, 2, 2.0)]
    up = lambda px, py, top: [[px, py, 0.0], [px, py, top]]  # noqa: E731
    lines = [up(j, face, 2.1) for pair in TWIN_DOORS for j in pair for face in (0.0, 0.2)]
    lines += [up(cx_, cy_, 2.6) for cx_ in (0.0, 4.0, 4.2, 8.2) for cy_ in (0.2, 4.2)]
    lines += [up(3.5, 2.0, 2.0), up(3.5, 2.8, 2.0), up(4.0, 2.0, 2.0), up(4.0, 2.8, 2.0)]
    return np.concatenate(parts), lines


@pytest.fixture(scope="module", params=[False, True], ids=["open doors", "closed doors"])
def twin_rooms(request):
    """:func:`_twin_scan`'s candidate translations at ``prepare``'s camera band (0.3-2.2 m), its
    footprint and the map a walk sees (a scan's: octree candidates, the footprint, its lines)."""
    points, lines = _twin_scan(request.param)
    band = TranslationParams(band_above_floor=(0.3, 2.2), floors=(0.0,))
    T, footprint = translations_and_footprint(points, num=600, clearance=0.25, params=band)
    scan = SimpleNamespace(translations=T, config={"translations": {"method": "octree", "num": 600, "floors": [0.0]}},
                           lines=np.array(lines, float), footprint=footprint)
    return T, footprint, scan


def test_a_scans_footprint_has_its_walls_and_doors(twin_rooms):
    _, fp, scan = twin_rooms
    doors = np.array([[2.0, 0.05], [6.2, 0.05]])
    assert fp.free_at(np.array([[2.0, 2.0], [6.0, -1.0]])).all()  # a room, the corridor
    assert not fp.free_at(np.array([[4.02, 1.0], [3.5, 0.05], [4.0, 5.0], [-1.0, 1.0]])).any()  # walls, the outside
    closed = not fp.free_at(doors).any()
    assert closed or fp.free_at(doors).all()
    opened = with_doors(lived_in(fp, scan.translations), scan.lines, np.array([0.0]))  # a closed door's jambs open it
    assert opened.free_at(doors).all()
    assert not opened.free_at(np.array([[4.02, 1.0], [4.02, 2.4], [3.5, 0.05], [4.1, 0.05]])).any()  # no other wall
    row = np.column_stack([np.arange(0.5, 3.5, 0.01), np.full(300, 0.05)])
    assert 0.8 <= opened.free_at(row).sum() * 0.01 <= 1.1  # the 1 m door, as wide in the mask


def test_a_walk_does_not_enter_the_copy_of_a_room_through_its_wall(twin_rooms):
    # from the corridor in front of room A's door the walker goes in and across room A; each frame's image
    # sees room A and its copy B alike (B 4.2 m east), the noise a little in favour of B. The corridor
    # frame to B is a free 4.7 m step without walls; the footprint says it goes through the wall
    T, fp, scan = twin_rooms
    z = float(np.median(T[:, 2]))
    frames = [_hyps([[2.0, -1.0, z]], [-100])]
    frames += [_hyps([[x, y, z], [x + 4.2, y, z]], [-95, -100]) for x, y in ((2.0, 1.0), (3.0, 2.5), (3.5, 3.0))]
    tour = MotionParams()
    em = [h.emission_costs(tour.emission_weight) for h in frames]

    def path(footprint, read: bool = True):
        free = FreeSpace.of_maps([SimpleNamespace(**{**vars(scan), "footprint": footprint})], read)
        return best_path(em, lambda f: transition_costs(frames[f - 1], frames[f], tour, None, free)).choice

    assert path(None) == [0, 1, 1, 1]  # walls unknown (a map without a footprint): the copy next door
    assert path(fp, read=False) == [0, 1, 1, 1]  # a footprint the walk does not read (WalkParams.scan_walls off)
    assert path(fp) == [0, 0, 0, 0]  # the room the door leads to
