"""Tracking a dense walk (ldlloc/walk/track.py): where the walk predicts its next frame, and which
frames it is tracked from. The end-to-end run on a rendered video is in tests/test_walk.py."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ldlloc.walk.track import TrackParams, height_band, next_basis, predict, trusted
from ldlmap.core.geometry import rotation_error_deg, rotation_from_axis_angle

UP = np.array([0.0, 0.0, 1.0])


def _frame(k: int, entry, verdict: str = "confident", tracked: bool = True):
    """A frame of a walk 0.2 m a frame along x, turning 3 degrees a frame."""
    R = rotation_from_axis_angle(UP, np.radians(3.0 * k))
    loc = SimpleNamespace(rot_cam_from_world=R, center=np.array([0.2 * k, 0.0, 1.5]), verdict=verdict,
                          confidence=0.99 if verdict == "confident" else 0.1)
    return SimpleNamespace(loc=loc, entry=entry, tracked=tracked, single_verdict=verdict, track_basis=None)


def _walk(frames: list, p: TrackParams = TrackParams()) -> list:
    """The frames with the bases they hand on, in walk order (as the walk's first pass sets them)."""
    prev = None
    for f in frames:
        f.track_basis = next_basis(prev, f, p)
        prev = f
    return frames


def test_prediction_goes_on_at_the_walks_velocity():
    entry = object()
    walk = _walk([_frame(k, entry) for k in range(4)])
    pred = predict(walk[-1], TrackParams())
    assert pred.entry is entry and pred.frames == 1
    assert np.allclose(pred.center, [0.8, 0.0, 1.5])
    assert rotation_error_deg(pred.rot_cam_from_world, rotation_from_axis_angle(UP, np.radians(12.0))) < 1e-6
    assert np.allclose(pred.last[1], walk[-1].loc.center)  # the last pose: the refinement's second start


def test_a_failed_frame_is_not_tracked_from():
    entry = object()
    walk = [_frame(k, entry) for k in range(3)] + [_frame(3, entry, "failed", tracked=False)]
    walk[3].loc.center = np.array([5.0, 5.0, 1.5])  # a global localization that failed: a wrong pose
    _walk(walk)
    assert not trusted(walk[3]) and trusted(walk[2])
    pred = predict(walk[3], TrackParams())
    assert pred.frames == 2 and np.allclose(pred.center, [0.8, 0.0, 1.5])  # from frame 2, two steps on
    gap = _walk([_frame(0, entry)] + [_frame(k, entry, "failed", tracked=False) for k in range(1, 7)],
                TrackParams(lookback=5))
    assert predict(gap[-1], TrackParams(lookback=5)) is None  # nothing trusted within 5 frames: a global search


@pytest.mark.parametrize("step, moved", [(0.2, True), (1.5, False)])
def test_a_step_too_long_for_a_video_is_not_extrapolated(step, moved):
    entry = object()
    walk = [_frame(0, entry), _frame(1, entry)]
    walk[1].loc.center = np.array([step, 0.0, 1.5])
    pred = predict(_walk(walk, TrackParams(max_step_m=0.75))[-1], TrackParams(max_step_m=0.75))
    assert np.allclose(pred.center, [2 * step if moved else step, 0.0, 1.5])


def test_frames_on_another_map_give_no_velocity():
    walk = _walk([_frame(0, object()), _frame(1, object())])
    pred = predict(walk[-1], TrackParams())
    assert np.allclose(pred.center, walk[1].loc.center)


def test_a_resumed_walk_tracks_from_the_written_pose():
    # a frame read back from a results file: its own pose and map, no basis: the prediction is that pose
    entry = object()
    back = SimpleNamespace(loc=SimpleNamespace(rot_cam_from_world=np.eye(3), center=np.array([1.0, 2.0, 1.5])),
                           entry=entry)
    pred = predict(back, TrackParams())
    assert pred.entry is entry and pred.frames == 1 and np.allclose(pred.center, [1.0, 2.0, 1.5])


def test_a_track_carries_its_global_frames_confidence():
    """What a tracked frame may be sure of at most (ldlloc.confidence.no_surer_than): the image's own
    confidence at the global frame its track started from, handed on through tracked and lost frames."""
    entry = object()
    walk = [_frame(0, entry, tracked=False)] + [_frame(k, entry) for k in (1, 2)]
    walk[0].single_confidence, walk[0].single_verdict = 0.3, "ambiguous"
    for f in walk[1:]:
        f.single_confidence = 0.99  # a tracked pose's own judgement: no contender was searched
    lost = _frame(3, entry, "failed", tracked=False)
    again = _frame(4, entry, tracked=False)
    again.single_confidence, again.single_verdict = 0.95, "confident"
    _walk(walk + [lost, again])
    assert [f.track_basis.sure for f in walk + [lost, again]] == [0.3, 0.3, 0.3, 0.3, 0.95]
    assert [f.track_basis.sure_verdict for f in walk + [lost, again]] == ["ambiguous"] * 4 + ["confident"]


def test_a_tracked_camera_keeps_its_height():
    """A walker's camera rises or sinks at most ``climb_m`` a frame (a stair's rise): the lines of the room
    it entered once drew a tracked camera in the corridor down 1 m in four frames."""
    entry = object()
    walk = _walk([_frame(0, entry, tracked=False), _frame(1, entry)])
    p = TrackParams(climb_m=0.15)
    pred = predict(walk[-1], p)
    assert height_band(pred, p, (0.4, 2.3)) == pytest.approx((1.35, 1.65))
    assert height_band(pred, p, (1.6, 2.3)) == pytest.approx((1.6, 1.65))  # inside the map's band
    assert height_band(pred, p, (3.4, 5.3)) == pytest.approx((1.35, 1.65))  # a band it does not meet: its own
    lost = _frame(2, entry, "failed", tracked=False)
    lost.loc = None
    _walk(walk + [lost])
    assert height_band(predict(lost, p), p, None) == pytest.approx((1.2, 1.8))  # two frames since



def test_a_tracks_unsure_frames_are_counted_until_a_check():
    """TrackBasis.age (what TrackParams.check_every counts): the tracked frames that are not confident (their
    own verdict, no surer than the global frame the track started from) since the last global frame or check;
    a confident frame adds nothing, a lost one adds one, a checked frame or a global one starts again."""
    entry = object()
    sure = [_frame(0, entry, tracked=False)] + [_frame(k, entry) for k in range(1, 3)] + \
        [_frame(k, entry, "ambiguous") for k in range(3, 6)]
    assert [f.track_basis.age for f in _walk(sure)] == [0, 0, 0, 1, 2, 3]
    unsure = [_frame(0, entry, "ambiguous", tracked=False)] + [_frame(k, entry) for k in range(1, 4)]
    unsure[0].single_confidence = 0.3  # the track's start was not confident: neither is any frame tracked from it
    assert [f.track_basis.age for f in _walk(unsure)] == [0, 1, 2, 3]
    checked = [_frame(k, entry, "ambiguous") for k in range(4)]
    checked[2].checked = True
    lost = SimpleNamespace(loc=None, entry=None, tracked=False, single_verdict="failed", track_basis=None)
    assert [f.track_basis.age for f in _walk(checked + [lost])] == [0, 1, 0, 1, 2]
