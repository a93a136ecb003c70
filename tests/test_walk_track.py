"""Tracking a dense walk (ldlloc/walk/track.py): where the walk predicts its next frame, and which
frames it is tracked from. The end-to-end run on a rendered video is in tests/test_walk.py."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ldlloc.walk.track import TrackParams, predict, trusted
from ldlmap.core.geometry import rotation_error_deg, rotation_from_axis_angle

UP = np.array([0.0, 0.0, 1.0])


def _frame(k: int, entry, verdict: str = "confident", tracked: bool = True):
    """A frame of a walk 0.2 m a frame along x, turning 3 degrees a frame."""
    R = rotation_from_axis_angle(UP, np.radians(3.0 * k))
    loc = SimpleNamespace(rot_cam_from_world=R, center=np.array([0.2 * k, 0.0, 1.5]))
    return SimpleNamespace(loc=loc, entry=entry, tracked=tracked, single_verdict=verdict)


def test_prediction_goes_on_at_the_walks_velocity():
    entry = object()
    walk = [_frame(k, entry) for k in range(4)]
    pred = predict(walk, TrackParams())
    assert pred.entry is entry and pred.frames == 1
    assert np.allclose(pred.center, [0.8, 0.0, 1.5])
    assert rotation_error_deg(pred.rot_cam_from_world, rotation_from_axis_angle(UP, np.radians(12.0))) < 1e-6
    assert np.allclose(pred.last[1], walk[-1].loc.center)  # the last pose: the refinement's second start


def test_a_failed_frame_is_not_tracked_from():
    entry = object()
    walk = [_frame(k, entry) for k in range(3)] + [_frame(3, entry, "failed", tracked=False)]
    walk[3].loc.center = np.array([5.0, 5.0, 1.5])  # a global localization that failed: a wrong pose
    assert not trusted(walk[3]) and trusted(walk[2])
    pred = predict(walk, TrackParams())
    assert pred.frames == 2 and np.allclose(pred.center, [0.8, 0.0, 1.5])  # from frame 2, two steps on
    gap = [_frame(0, entry)] + [_frame(k, entry, "failed", tracked=False) for k in range(1, 7)]
    assert predict(gap, TrackParams(lookback=5)) is None  # nothing trusted within 5 frames: a global search


@pytest.mark.parametrize("step, moved", [(0.2, True), (1.5, False)])
def test_a_step_too_long_for_a_video_is_not_extrapolated(step, moved):
    entry = object()
    walk = [_frame(0, entry), _frame(1, entry)]
    walk[1].loc.center = np.array([step, 0.0, 1.5])
    pred = predict(walk, TrackParams(max_step_m=0.75))
    assert np.allclose(pred.center, [2 * step if moved else step, 0.0, 1.5])


def test_frames_on_another_map_give_no_velocity():
    walk = [_frame(0, object()), _frame(1, object())]
    pred = predict(walk, TrackParams())
    assert np.allclose(pred.center, walk[1].loc.center)


def test_line_reference_is_the_median_of_recent_trusted_frames():
    from ldlloc.walk.track import LineReference

    ref = LineReference(5)
    assert ref.loss is None
    for v in (-300, -290, -310, -120, -305, -295):  # one weak frame (a few lines) among good ones
        ref.add(v)
    assert ref.loss == pytest.approx(-295.0)  # the last 5: -290, -310, -120, -305, -295
    ref.add(float("nan"))
    assert len(ref.recent) == 5
