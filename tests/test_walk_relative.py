"""The motion between two panoramas of a walk (ldlloc/walk/relative.py) and what a walk does with it.

On the demo dataset's rendered rooms: the rotation and step direction between two panoramas of a
room against their true poses (one pair upright, one pair tilted 8-9 degrees, levelled by its
true rotation as a walk levels it by its own); the step's length from the floor; and a walk of two
frames whose second image lost its pose among wrong ones (its hypotheses near the truth removed):
only the motion from its confident neighbour brings it back, within 0.1 m / 5 deg.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from ldlloc.batch.which_map import MapSet
from ldlloc.pipeline import LocalizeParams, load_image
from ldlloc.walk.hypotheses import Hypotheses
from ldlloc.walk.localize import WalkFrame, WalkParams, decide, localize_frame, relate, relative_costs
from ldlloc.walk.relative import inverse, panorama_features, relative_pose
from ldlloc.walk.run import relative_record
from ldlmap.core.geometry import rotation_error_deg, translation_error

pytestmark = pytest.mark.xdist_group("walk")


def _queries(demo_dataset, split: str, scene: str = "synthroom_1") -> list:
    from ldlmap.datasets import open_dataset

    return [q for q in open_dataset(demo_dataset, "omniscenes").queries([split]) if q.scene == scene]


def _truth(a, b) -> tuple[np.ndarray, np.ndarray, float]:
    """b's rotation from a's, the unit step in a's frame and its length."""
    Ra, Rb = np.asarray(a.rot_cam_from_world), np.asarray(b.rot_cam_from_world)
    step = Ra @ (np.asarray(b.center) - np.asarray(a.center))
    return Rb @ Ra.T, step / np.linalg.norm(step), float(np.linalg.norm(step))


@pytest.mark.parametrize("split, pair", [("robot", (1, 2)), ("handheld", (2, 3))])
def test_relative_pose_of_two_panoramas(demo_dataset, split, pair):
    qs = _queries(demo_dataset, split)
    a, b = qs[pair[0]], qs[pair[1]]
    fa, fb = (panorama_features(load_image(q.image)) for q in (a, b))
    Ra, Rb = np.asarray(a.rot_cam_from_world), np.asarray(b.rot_cam_from_world)
    rel = relative_pose(fa, fb, level_a=Ra, level_b=Rb)
    assert rel is not None
    R, d, length = _truth(a, b)
    assert rotation_error_deg(rel.rot, R) < 1.0
    assert np.degrees(np.arccos(np.clip(rel.direction @ d, -1, 1))) < 5.0
    height = float(np.asarray(a.center)[2])  # the rooms' floor is at z = 0
    assert rel.per_height is not None and abs(rel.per_height * height - length) < 0.1 * length
    back = inverse(rel)  # a's motion from b
    assert rotation_error_deg(back.rot, R.T) < 1.0
    assert np.degrees(np.arccos(np.clip(back.direction @ (Rb @ (np.asarray(a.center) - np.asarray(b.center)))
                                        / length, -1, 1))) < 5.0


def test_panoramas_of_two_rooms_share_no_motion(demo_dataset):
    a = _queries(demo_dataset, "robot")[1]
    b = _queries(demo_dataset, "robot", "synthroom_2")[1]
    fa, fb = (panorama_features(load_image(q.image)) for q in (a, b))
    assert relative_pose(fa, fb) is None


def _lost(o, truth_center: np.ndarray):
    """Frame ``o`` as if its image had lost its pose among distractors: its hypotheses within 1 m of
    the truth removed, its own pose the best of the rest, not confident."""
    h = o.hypotheses
    far = np.linalg.norm(h.center - truth_center, axis=1) > 1.0
    o.hypotheses = Hypotheses(h.map_index[far], h.rot_cam_from_world[far], h.center[far], h.loss[far], h.final[far])
    j = int(np.argmin(o.hypotheses.loss))
    R, t = o.hypotheses.rot_cam_from_world[j], o.hypotheses.center[j]
    o.single_pose, o.single_verdict, o.competitors = (R, t), "ambiguous", []
    o.loc.rot_cam_from_world, o.loc.center, o.loc.verdict = R, t, "ambiguous"
    return o


def test_a_frame_is_recovered_only_by_the_motion_from_its_neighbour(demo_dataset):
    maps = MapSet.load(demo_dataset / "maps" / "synthroom_1.h5", LocalizeParams())
    index = {id(e): i for i, e in enumerate(maps.entries)}
    qs = _queries(demo_dataset, "robot")
    a, b = qs[1], qs[2]
    params = WalkParams()
    frames = [WalkFrame(q.name, (lambda p=q.image: load_image(p))) for q in (a, b)]
    oa, _ = localize_frame(frames[0], None, maps, params, None, {}, index)
    ob, _ = localize_frame(frames[1], oa, maps, params, None, {}, index)
    assert oa.single_verdict == "confident"
    ob = _lost(ob, np.asarray(b.center))
    got = {}
    for relative in (False, True):
        p = WalkParams(relative=relative)
        pa, pb = copy.copy(oa), copy.copy(ob)  # the same maps, their own localizations
        pa.loc, pb.loc = copy.copy(oa.loc), copy.copy(ob.loc)
        relate(pa, pb, maps, index, p, {})
        assert (pb.relative is not None) == relative
        if relative:  # the steps that disagree with the motion cost more; the record says the motion
            c = relative_costs(pa, pb, p)
            assert c.shape == (len(pa.hypotheses), len(pb.hypotheses)) and c.max() > 0
            rec = relative_record(pb)
            step = float(np.linalg.norm(np.asarray(b.center) - np.asarray(a.center)))
            assert rec["from"] == a.name and rec["inliers"] >= 40 and abs(rec["length_m"] - step) < 0.1 * step
        decide([pa, pb], maps, p)
        got[relative] = (translation_error(pb.loc.center, b.center),
                         rotation_error_deg(pb.loc.rot_cam_from_world, b.rot_cam_from_world))
    assert not (got[False][0] < 0.1 and got[False][1] < 5), got  # without it the frame stays lost ...
    assert got[True][0] < 0.1 and got[True][1] < 5, got  # ... with it the walk brings it back
