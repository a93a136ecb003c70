"""A walk changes floors on the stairs (ldlloc.walk.motion: stair_points, FreeSpace.off_stairs).

The scene: two identical floors 3 m apart (a corridor along x), a stair flight at x 10-11.7 m
(its steps' edges: 1.2 m segments rising 0.17 m and running 0.28 m each), a bookshelf (shelves
0.35 m apart, straight above each other) at x 2 m. A walk along the corridor on floor 0 to the
stairs and back along floor 1; each frame's image likes both floors (the floors look the same),
a little more the wrong one on some frames before the stairs.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ldlloc.walk.copies import reachable_pose
from ldlloc.walk.hypotheses import Hypotheses
from ldlloc.walk.motion import FreeSpace, MotionParams, stair_points, transition_costs
from ldlloc.walk.viterbi import best_path

STOREY = 3.0


def _floor_lines(z0: float) -> np.ndarray:
    """(N, 2, 3) a floor's lines: the corridor's edges, a stair flight up from it, a bookshelf."""
    L = [[[0, 0, z0], [14, 0, z0]], [[0, 2, z0], [14, 2, z0]], [[0, 0, z0 + 2.6], [14, 0, z0 + 2.6]],
         [[0, 0, z0], [0, 0, z0 + 2.6]], [[14, 2, z0], [14, 2, z0 + 2.6]]]
    for k in range(1, 8):  # the flight: nosings across the corridor (along y), rising along x
        x, z = 10.0 + 0.28 * k, z0 + 0.17 * k
        L.append([[x, 0.4, z], [x, 1.6, z]])
    for k in range(6):  # a bookshelf's shelves: stacked straight up
        L.append([[2.0, 0.1, z0 + 0.3 + 0.35 * k], [3.0, 0.1, z0 + 0.3 + 0.35 * k]])
    return np.array(L, dtype=float)


def _maps() -> list:
    return [SimpleNamespace(translations=np.array([[x, 1.0, 1.5 + f * STOREY] for x in np.arange(0.5, 14, 0.5)]),
                            config={"translations": {"method": "octree", "num": 28}},
                            lines=_floor_lines(f * STOREY)) for f in range(2)]


def test_stairs_are_found_in_the_lines_not_in_a_bookshelf():
    s = stair_points(_floor_lines(0.0))
    assert len(s) >= 1
    assert np.all((s[:, 0] > 10.5) & (s[:, 0] < 12.0))  # the flight's upper steps, nothing at the shelf (x 2-3)
    assert len(stair_points(_floor_lines(0.0)[:5])) == 0  # a corridor without stairs


def test_octree_candidates_tell_no_walls_but_the_stairs_are_known():
    free = FreeSpace.of_maps(_maps())
    assert free is not None and free.masks is None  # a scan's candidates: no walls from them
    a, b = np.array([[11.0, 1.0, 1.5], [3.0, 1.0, 1.5]]), np.array([[11.0, 1.0, 4.5], [3.0, 1.0, 4.5]])
    off = free.off_stairs(a, np.array([0, 0]), b, np.array([1, 1]))
    assert not off[0, 0] and off[1, 1]  # up at the stairs; up 8 m away from them
    assert not free.blocked(a, np.array([0, 0]), b, np.array([1, 1])).any()
    lattice = _maps()
    for m in lattice:  # the same candidates as a lattice at their spacing (a layout's): walls are known
        m.config = {"translations": {"method": "spacing", "spacing": 0.5}}
    walled = FreeSpace.of_maps(lattice)
    assert walled.masks is not None and walled.reach == [0.5, 0.5]
    out = walled.blocked(a[:1], np.array([0]), np.array([[11.0, 4.0, 1.5]]), np.array([0]))
    assert out[0, 0]  # 3 m off the corridor's candidates: out of its free space


def test_the_walk_changes_floor_at_the_stairs():
    # frames at x 0, 2, ..., 10 on floor 0, then back x 10, 8, ..., 0 on floor 1; each frame's two
    # hypotheses are the same spot on both floors; the first and last frames know their floor (a sign
    # on a wall), frames 1-3 like the wrong floor a little better (identical floors: noise), the others
    # the right one as little. Without stairs known the walk goes up after frame 0 (one floor change
    # either way, and the noise says so); with them it goes up at the stairs only
    xs = [0, 2, 4, 6, 8, 10, 10, 8, 6, 4, 2, 0]
    true_floor = [0] * 6 + [1] * 6
    frames = []
    for k, (x, f) in enumerate(zip(xs, true_floor)):
        worse = -20.0 if k in (0, len(xs) - 1) else -95.0
        loss = [worse, -100.0] if (k in (1, 2, 3)) == (f == 0) else [-100.0, worse]  # loss of floor 0, floor 1
        frames.append(Hypotheses(np.array([0, 1]), np.repeat(np.eye(3)[None], 2, 0),
                                 np.array([[x, 1.0, 1.5], [x, 1.0, 1.5 + STOREY]]), np.array(loss), np.zeros(2, bool)))
    tour = MotionParams()
    em = [h.emission_costs(tour.emission_weight) for h in frames]
    free = FreeSpace.of_maps(_maps())

    def path(known):
        return best_path(em, lambda f: transition_costs(frames[f - 1], frames[f], tour, None, known)).choice

    assert path(free) == true_floor
    assert path(None) != true_floor  # the floors' noise alone decides otherwise


def test_a_floor_the_images_cannot_tell_is_not_sure_from_floor_changes_the_path_did_not_pay():
    """The open-door building's failure (docs/benchmarks.md#walks-synthetic-building): frames 0-2 on
    floor 0 know their floor; frames 3-11 walk to the stairs and back, and their images cannot tell the
    two floors (each image's own pose on floor 0). The path keeps them on floor 0; its margins there
    are the floor changes an alternative would pay (10 nats or more), the walk's margins
    (:func:`walk_margins`) only what the images say."""
    from ldlloc.walk.localize import FrameOutcome, WalkFrame, WalkParams, walk_margins, walk_path
    from ldlloc.walk.viterbi import margin

    xs = [0, 2, 4, 6, 8, 10, 10, 8, 6, 4, 2, 0]
    live = []
    for k, x in enumerate(xs):
        loss = [-100.0, -20.0] if k < 3 else [-100.0, -100.0]  # floor 0, floor 1
        h = Hypotheses(np.array([0, 1]), np.repeat(np.eye(3)[None], 2, 0),
                       np.array([[x, 1.0, 1.5], [x, 1.0, 1.5 + STOREY]]), np.array(loss), np.zeros(2, bool))
        live.append(FrameOutcome(WalkFrame(f"f{k}", lambda: None), hypotheses=h, single_verdict="ambiguous",
                                 single_pose=(np.eye(3), h.center[0])))
    params, free = WalkParams(), FreeSpace.of_maps(_maps())
    path = walk_path(live, params, free=free)
    assert list(path.choice) == [0] * 12
    plain = [margin(m, 0, np.array([False, True])) for m in path.marginals]
    got = walk_margins(live, path, params, free)
    assert min(plain[5:]) >= 10 and max(got[5:]) <= 3  # sure of floor 0 by the floor changes: not any more
    assert min(got[:3]) > 30  # the frames whose images know their floor stay sure


def _poses(*spots) -> Hypotheses:
    """A frame's poses at ``(map index, x)`` spots of the corridor, at one loss (its own first: copies of its room)."""
    k = np.array([s[0] for s in spots])
    return Hypotheses(k, np.repeat(np.eye(3)[None], len(spots), 0),
                      np.array([[x, 1.0, 1.5 + m * STOREY] for m, x in spots]), np.full(len(spots), -80.0),
                      np.zeros(len(spots), bool))


def test_a_relocalized_frame_goes_on_where_the_walk_reaches():
    # a video lost for 7 frames of 0.2 s relocalizes in a room whose copies stand on both floors; the walk's
    # last trusted pose was on floor 0 at x 2
    video = MotionParams(turn_deg=30.0)
    free = FreeSpace.of_maps(_maps())
    last = (0, np.eye(3), [2.0, 1.0, 1.5])
    # away from the stairs: floor 1 is out of reach, the nearer copy on floor 0 is the one the walk took
    assert reachable_pose(_poses((1, 3.0), (0, 3.0), (0, 8.0)), 0, last, 7, video, 0.2, free) == 1
    # on the walk's floor but 9 m away: no walker covers that in 1.4 s
    assert reachable_pose(_poses((0, 11.0), (0, 3.0)), 0, last, 7, video, 0.2, free) == 1
    # ... unless that pose explains the frame's lines and the near one hardly any
    far = _poses((0, 11.0), (0, 3.0))
    far.loss[1] = -10.0
    assert reachable_pose(far, 0, last, 7, video, 0.2, free) is None
    # on the stairs a floor change is a walker's: the image keeps its floor
    assert reachable_pose(_poses((1, 10.8), (0, 10.8)), 0, (0, np.eye(3), [10.5, 1.0, 1.5]), 7, video, 0.2,
                          free) is None
    # the image's own pose on the walk's floor and within reach: kept
    assert reachable_pose(_poses((0, 2.5), (0, 8.0)), 0, last, 7, video, 0.2, free) is None


def test_a_relocalized_frame_goes_on_from_the_walk_unless_its_image_is_sure():
    """ldlloc.walk.localize.reached: a global frame (after 7 lost frames of 0.2 s) whose own pose stands on
    floor 1, away from the stairs, the walk's prediction on floor 0 among its poses: the walk goes on from
    the prediction where the image was not confident (no copies named: a 4045 video's frame lost the walk
    so), and from the image's own pose where it was (a confident image overrules a walk that may be lost)."""
    from ldlloc.walk.localize import FrameOutcome, WalkFrame, WalkParams, reached

    entries = [SimpleNamespace(name="floor 0"), SimpleNamespace(name="floor 1")]
    index = {id(e): i for i, e in enumerate(entries)}
    free = FreeSpace.of_maps(_maps())
    poses = _poses((1, 3.0), (0, 2.4))  # its own pose, the prediction (1.4 m walked in 7 frames)
    params = WalkParams(motion=MotionParams(turn_deg=30.0))
    pred = SimpleNamespace(entry=entries[0], last=(np.eye(3), np.array([1.0, 1.0, 1.5])), frames=7)
    prev = FrameOutcome(WalkFrame("prev", lambda: None, time=0.0))

    def relocalized(verdict: str) -> FrameOutcome:
        o = FrameOutcome(WalkFrame("f", lambda: None, time=1.4), entry=entries[1], single_verdict=verdict,
                         single_pose=(np.eye(3), poses.center[0]), hypotheses=poses)
        return o

    got = reached(relocalized("ambiguous"), pred, prev, index, params, free)
    assert got is not None and got[0] == 0 and np.allclose(got[2], poses.center[1])
    assert reached(relocalized("confident"), pred, prev, index, params, free) is None


def test_an_overruled_track_goes_on_from_the_copy_of_its_global_pose_the_walk_reaches():
    """ldlloc.walk.localize.reached(copies_only=True): a tracked frame a check overruled (its global pose on
    floor 1, a copy of its room on floor 0, where the walk was) goes on from the copy on the walk's floor:
    the copies explain its lines alike and the track had the floor right (a building's identical floors);
    never from another of its poses, nearer the doubted track but explaining fewer lines; without copies,
    from its own pose."""
    from ldlloc.walk.localize import FrameOutcome, WalkFrame, WalkParams, reached

    entries = [SimpleNamespace(name="floor 0"), SimpleNamespace(name="floor 1")]
    index = {id(e): i for i, e in enumerate(entries)}
    free = FreeSpace.of_maps(_maps())
    params = WalkParams(motion=MotionParams(turn_deg=30.0))
    pred = SimpleNamespace(entry=entries[0], last=(np.eye(3), np.array([2.0, 1.0, 1.5])), frames=1)
    prev = FrameOutcome(WalkFrame("prev", lambda: None, time=0.0))
    own = _poses((1, 2.6), (0, 2.0))  # its own pose, and a pose at the doubted track that explains fewer lines
    own.loss[1] = -78.0
    walk = (0, *pred.last)
    both = _poses((0, 2.6), (0, 2.0))
    both.loss[1] = -78.0
    assert reachable_pose(both, 0, walk, 1, params.motion, 0.2, free, 0.0) == 1  # the cheaper of the two for the walk

    def overruled(copies) -> FrameOutcome:
        return FrameOutcome(WalkFrame("f", lambda: None, time=0.2), entry=entries[1], single_verdict="ambiguous",
                            single_pose=(np.eye(3), own.center[0]), hypotheses=own, copies=copies)

    got = reached(overruled(_poses((0, 2.6))), pred, prev, index, params, free, copies_only=True)
    assert got is not None and got[0] == 0 and np.allclose(got[2], [2.6, 1.0, 1.5])
    assert reached(overruled(None), pred, prev, index, params, free, copies_only=True) is None
