"""Confidence of a localization (ldlloc/confidence.py): the rule on constructed poses, and end to
end on the demo dataset (confident poses are right; the fields reach the results and `localize --json`)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.confidence import (MODEL, assess, assess_across, copy_rival, judge, no_surer_than, rotation_kind,
                               verdict_for, why)
from ldlloc.pipeline import Localization

runner = CliRunner()

BOX = np.array([4.0, 6.0, 3.0])  # a box room; the camera at its centre sees it the same turned by 180 degrees
CENTRE = BOX / 2


def _rz(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _box_map():
    """The 12 edges of the box as a map (grouped by direction, no visibility)."""
    corners = np.array([[x, y, z] for x in (0, BOX[0]) for y in (0, BOX[1]) for z in (0, BOX[2])])
    lines, groups = [], []
    for i in range(8):
        for j in range(i + 1, 8):
            d = corners[j] - corners[i]
            if np.count_nonzero(d) == 1:
                lines.append([corners[i], corners[j]])
                groups.append(int(np.flatnonzero(d)[0]))
    return SimpleNamespace(lines=np.array(lines), line_groups=np.array(groups), visibility=None,
                           translations=_lattice(np.zeros(3)))


def _lattice(origin: np.ndarray, spacing: float = 0.3) -> np.ndarray:
    """Candidate translations of the box: a lattice 0.2 m off its walls, 0.3-2.2 m above its floor."""
    axes = [np.arange(0.2, BOX[0] - 0.19, spacing), np.arange(0.2, BOX[1] - 0.19, spacing), np.arange(0.3, 2.21, spacing)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3) + origin


def _shifted(m, shift) -> SimpleNamespace:
    """The map ``m`` moved by ``shift`` (a room alike elsewhere, another floor)."""
    return SimpleNamespace(lines=m.lines + shift, line_groups=m.line_groups, visibility=None,
                           translations=m.translations + shift)


def _arcs(m, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The map's edges as the camera (R, t) sees them: unit start and end directions (N, 2, 3)."""
    d = (m.lines - t) @ R.T
    return d / np.linalg.norm(d, axis=2, keepdims=True)


def _localization(m, R0: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]], losses: list[float],
                  margin: float) -> Localization:
    """A geometric refinement whose final pose is the first of ``poses`` (the search's top K, with
    ``losses``), chosen by ``margin`` over the next distinct refined pose; its image shows the map
    from R0 at the centre."""
    Rs = np.stack([p[0] for p in poses])
    ts = np.stack([p[1] for p in poses])
    return Localization(Rs[0], ts[0], Rs[0], ts[0], Rs, ts, {}, num_rotations=len(poses), num_lines=12,
                        refined=True, arcs=_arcs(m, R0, CENTRE), candidates_loss=np.array(losses, float),
                        refine_method="geometric", selection_margin=margin)


def test_clear_winner_is_confident():
    m = _box_map()
    R0 = _rz(30)
    # the other candidate is 1.5 m away and explains far fewer lines
    loc = _localization(m, R0, [(R0, CENTRE), (R0, CENTRE + [0, 1.5, 0])], [-100.0, -45.0], margin=0.4)
    assess(loc, m)
    assert loc.confidence_signals["gap"] == pytest.approx(0.55)
    assert loc.confidence_signals["support"] > 0.9  # the map's edges lie on the image's lines
    assert loc.verdict == "confident" and loc.confidence >= MODEL.confident_at
    assert loc.competitors == []  # 55 % worse: no competitor


def test_near_equal_twin_is_ambiguous_and_named():
    m = _box_map()
    R0 = _rz(30)
    twin = R0 @ _rz(180)  # the same camera turned half a turn about the up axis: the box looks the same
    loc = _localization(m, R0, [(R0, CENTRE), (twin, CENTRE), (R0, CENTRE + [0, 1.5, 0])], [-100.0, -99.0, -45.0],
                        margin=0.01)  # the twin, refined, scores the same
    assess(loc, m)
    assert loc.confidence_signals["gap"] == pytest.approx(0.01)
    assert abs(loc.confidence_signals["support_gap"]) < 0.05  # both explain the box
    assert loc.verdict == "ambiguous" and loc.confidence < MODEL.confident_at
    assert [c["why"] for c in loc.competitors] == ["180-degree twin"]
    assert np.allclose(loc.competitors[0]["R"], twin) and loc.competitors[0]["loss"] == -99.0


def _clear_winner(m, R0, t):
    loc = _localization(m, R0, [(R0, t), (R0, t + [0, 1.5, 0])], [-100.0, -80.0], margin=0.4)
    assess(loc, m)
    assert loc.verdict == "confident"
    return loc


def test_maps_judged_together():
    """Several maps (`run --images --maps DIR`): each map's pose is confident within its map; a
    distinct pose of another map that scores as well takes the confidence away and is named; a
    pose that another map confirms (maps sharing a frame) stays confident; a map whose loss is far
    behind cannot be confident."""
    m = _box_map()
    R0 = _rz(30)
    here, there = CENTRE, CENTRE + [5.0, 0.0, 0.0]
    twin = R0 @ _rz(180)  # another room like this one, whose map puts the camera turned by half a turn
    a = _clear_winner(m, R0, here)
    b = _localization(m, R0, [(twin, here), (twin, there)], [-99.0, -80.0], margin=0.4)
    assess(b, m)
    assess_across([a, b], [-100.0, -99.0], ["room_a", "room_b"])
    for loc, other in ((a, "room_b"), (b, "room_a")):
        assert abs(loc.confidence_signals["map_margin"]) < 0.05
        assert loc.verdict == "ambiguous" and loc.confidence < MODEL.confident_at
        assert [c["map"] for c in loc.competitors] == [other]  # the twin scores within the noise: named as such
        assert loc.competitors[0]["why"] == f"map {other}, 180-degree twin scoring within 0.010"
    assert np.allclose(a.competitors[0]["R"], twin) and a.competitors[0]["loss"] == -99.0

    a, b = _clear_winner(m, R0, here), _clear_winner(m, R0, here + [0.05, 0, 0])  # the same pose twice
    assess_across([a, b], [-100.0, -99.0], ["room_a", "room_b"])
    assert a.verdict == b.verdict == "confident" and a.competitors == b.competitors == []

    a, b = _clear_winner(m, R0, here), _clear_winner(_shifted(m, [5.0, 0.0, 0.0]), R0, there)
    assess_across([a, b], [-100.0, -60.0], ["room_a", "room_b"])  # room_b explains 40 % fewer lines
    assert a.verdict == "confident" and a.confidence_signals["map_margin"] == 0.5
    assert b.confidence_signals["map_margin"] == -1.0 and b.verdict != "confident"

    a = _clear_winner(m, R0, here)  # judged again on a subset: as alone
    b = _localization(m, R0, [(twin, here), (twin, there)], [-99.0, -80.0], margin=0.4)
    assess(b, m)
    assess_across([a, b], [-100.0, -99.0], ["room_a", "room_b"])
    assert a.verdict == "ambiguous"
    assess_across([a], [-100.0], ["room_a"])
    assert a.verdict == "confident" and a.competitors == []


def _feature_pose(m, R0, t, inliers: int, rival: tuple[np.ndarray, int] | None = None) -> Localization:
    """A PnP pose at (R0, t) with ``inliers``; ``rival``: a distinct PnP pose (centre, inliers)."""
    loc = _localization(m, R0, [(R0, t), (R0, t + [0, 1.5, 0])], [-100.0, -95.0], margin=0.0)
    loc.refine_method, loc.selection_margin, loc.num_inliers = "features", None, inliers
    if rival is not None:
        loc.pnp_rival = {"R": R0, "t": rival[0], "inliers": rival[1], "candidate": 1}
    return loc


def test_identical_copy_takes_the_feature_confidence_away():
    """A PnP pose is confident when no distinct PnP pose comes near its inliers; a copy of the room
    (in its map or another map) that explains as many features makes it ambiguous and is named."""
    m = _box_map()
    R0 = _rz(30)
    alone = _feature_pose(m, R0, CENTRE, 120, (CENTRE + [0, 2.0, 0], 20))  # a stray PnP pose of 20 inliers
    assess(alone, m)
    assert alone.verdict == "confident" and alone.confidence_signals["pnp_rival"] == pytest.approx(20 / 120, abs=1e-6)

    copy = _feature_pose(m, R0, CENTRE, 120, (CENTRE + [6.0, 0, 0], 118))
    assess(copy, m)
    assert copy.verdict == "ambiguous" and copy.confidence < MODEL.confident_at
    assert copy.competitors[0]["why"] == "other position (6.0 m), PnP 118 inliers against 120"
    assert np.allclose(copy.competitors[0]["t"], CENTRE + [6.0, 0, 0])

    above = _shifted(m, [0, 0, 3.0])  # the floor above
    a, b = _feature_pose(m, R0, CENTRE, 120), _feature_pose(above, R0, CENTRE + [0, 0, 3.0], 115)
    for loc, on in ((a, m), (b, above)):
        assess(loc, on)
        assert loc.verdict == "confident"
    assess_across([a, b], [-100.0, -100.0], ["floor_0", "floor_1"])
    assert a.confidence_signals["map_rival"] == pytest.approx(115 / 120, abs=1e-6)
    assert a.verdict == b.verdict == "ambiguous"  # b is judged unlikely on its lines, but a copy explains its features
    assert [c["map"] for c in a.competitors if "map" in c] == ["floor_1"]
    c = _feature_pose(above, R0, CENTRE + [0, 0, 3.0], 10)  # another floor's pose, few inliers (not verified): no rival
    assess(c, above)
    assess_across([a, c], [-100.0, -100.0], ["floor_0", "floor_1"])
    assert a.verdict == "confident" and a.confidence_signals["map_twin"] == 0.0
    # 30 inliers: far fewer, but verified (PnP and lines back it) and as good on the lines: the copy on the floor
    # above in poor light (the building's extreme_intensity office query was once confident in a wrong copy)
    c = _feature_pose(above, R0, CENTRE + [0, 0, 3.0], 30)
    assess(c, above)
    assess_across([a, c], [-100.0, -100.0], ["floor_0", "floor_1"])
    assert a.confidence_signals["map_twin"] == 1.0 and a.verdict == "ambiguous"
    assert [x["map"] for x in a.competitors if "map" in x] == ["floor_1"]
    assess_across([a, c], [-100.0, -80.0], ["floor_0", "floor_1"])  # the copy explains 20 % fewer lines: no twin
    assert a.verdict == "confident"


def _options(pairs):
    """``choose_map``'s options of (map name, localization, exact loss of its final pose)."""
    from ldlloc.batch.which_map import MapEntry, MapOption

    return [MapOption(MapEntry(Path(f"{name}.h5"), name, None), loss, loc, loss) for name, loc, loss in pairs]


def test_verified_pnp_pose_is_not_outvoted_by_lines_alone_on_another_map():
    """Two floor maps: on the query's floor the features give a PnP pose (35 inliers, its lines near
    its search's best: verified); on the other floor they give none, and the geometric pose there
    explains 28 % more of the image's lines in a room that looks alike (a handheld query of the
    building once missed). The lines-only pose used to win the choice; now the verified PnP pose
    is kept, confident, and the other cannot win (margin -1, the PnP pose named). A PnP pose of 12
    inliers is not verified: the lines judge it as before."""
    from ldlloc.batch.which_map import choose_map
    from ldlloc.confidence import verified

    m = _box_map()
    R0 = _rz(30)
    shift = np.array([5.0, 0.0, 0.0])
    m2 = _shifted(m, shift)  # a room alike, 5 m on

    def pair(inliers: int):
        a = _feature_pose(m, R0, CENTRE, inliers)  # its search's best loss -100
        assess(a, m)
        b = _localization(m2, R0, [(R0, CENTRE + shift), (R0, CENTRE + shift + [0, 1.5, 0])], [-100.0, -80.0], 0.4)
        b.arcs = a.arcs  # the same panorama
        assess(b, m2)
        assert a.verdict == b.verdict == "confident"  # each within its own map
        return a, b

    a, b = pair(35)
    assert verified(a, -98.0) and not verified(b, -125.0) and not verified(a, -60.0)
    chosen = choose_map(_options([("floor_2", a, -98.0), ("floor_1", b, -125.0)]))
    assert chosen.loc is a and a.verdict == "confident" and a.confidence_signals["map_margin"] == 0.5
    assert b.confidence_signals["map_margin"] == -1.0 and b.verdict != "confident"
    assert [c["map"] for c in b.competitors if "map" in c] == ["floor_2"]

    a, b = pair(12)
    assert not verified(a, -98.0)
    chosen = choose_map(_options([("floor_2", a, -98.0), ("floor_1", b, -125.0)]))
    assert chosen.loc is b and a.confidence_signals["map_margin"] < 0

    # two verified PnP poses in different places, as good on the lines (twins: neither confident); the one of
    # most inliers is kept even where the other's search gap makes it the more confident (a wrong floor's
    # retrieved pose of 16 inliers beside the right floor's 44)
    a = _feature_pose(m, R0, CENTRE, 44)
    b = _feature_pose(m2, R0, CENTRE + shift, 16)
    b.candidates_loss = np.array([-100.0, -40.0])
    b.arcs = a.arcs
    assess(a, m)
    assess(b, m2)
    chosen = choose_map(_options([("floor_0", a, -98.0), ("floor_1", b, -95.0)]))
    assert a.confidence_signals["map_twin"] == b.confidence_signals["map_twin"] == 1.0
    assert b.confidence > a.confidence and a.verdict == b.verdict == "ambiguous"
    assert chosen.loc is a


def test_no_pose_is_failed():
    from ldlloc.batch.run import failed_result
    from ldlloc.pipeline import LocalizeParams

    model = MODEL
    assert verdict_for(None, [], model) == "failed"
    q = SimpleNamespace(image="p.jpg", scene="s", split="robot", name="p", upright=False)
    r = failed_result(q, LocalizeParams(), "too few lines")
    assert (r.verdict, r.confidence, r.competitors) == ("failed", 0.0, [])
    # a doubtful pose is failed without a competitor, or when it is too unlikely; else ambiguous
    doubtful = (model.failed_below + model.confident_at) / 2
    assert verdict_for(doubtful, [], model) == "failed"
    assert verdict_for(0.0, [{"why": "other position"}], model) == "failed"
    assert verdict_for(doubtful, [{"why": "other position"}], model) == "ambiguous"
    # a pose the model gives little chance, but whose PnP rival (a copy) explains the features as well
    assert verdict_for(0.0, [{"why": "other position (6.0 m), PnP 90 inliers against 100"}], model,
                       rival=True) == "ambiguous"


def test_copies_by_the_lines_yield_to_features_that_single_the_pose_out():
    """A room whose lines repeat on another floor (the same walls, other textures) is told apart by a
    strong PnP with no rival anywhere; an identical room's copy (a PnP rival of half the inliers or more
    on another map) or a weak PnP leaves it ambiguous. Signals of single images of a synthetic building."""
    room = {"gap": 0.1, "support": 0.123, "support_gap": 0.05, "margin": 0.0, "features": 1.0, "refined": 1.0,
            "inliers": 60.0, "pnp_rival": 0.0, "retrieved": 0.0, "physical": 1.0, "tie": 0.0, "map_margin": 0.5,
            "map_rival": 0.0, "map_twin": 0.0}
    copy = [{"why": "copy of this room on floor_2, 4.8 m away", "copy": {"map": "floor_2", "t": [0, 0, 0]}}]
    assert judge(room, [])[1] == "confident"
    assert judge({**room, "copies": 2.0}, copy)[1] == "confident"  # other textures: the features tell
    assert judge({**room, "copies": 2.0, "map_rival": 0.6}, copy)[1] != "confident"  # the copy looks the same
    assert judge({**room, "copies": 2.0, "pnp_rival": 0.55}, copy)[1] != "confident"
    weak = {**room, "features": 0.6, "retrieved": 1.0, "inliers": 36.0, "support": 0.5, "margin": 0.3}
    assert judge(weak, [])[1] == "confident"
    assert judge({**weak, "copies": 2.0}, copy)[1] == "ambiguous"  # a weak PnP does not decide


def test_features_single_a_copy_out_only_on_the_same_footing():
    """PnP at each copy of the room (its map's views nearest it) against PnP at the pose itself with its own
    map's views no nearer than the copy's: a pose whose map happened to render a view where the camera
    stood, and whose copies' maps did not, is not singled out by the features (an identical stairwell a
    floor down, session 17); a copy whose views see nothing of the image on an equal footing is."""
    sig = {"gap": 0.1, "support": 0.3, "support_gap": 0.05, "margin": 0.0, "features": 1.0, "refined": 1.0,
           "inliers": 60.0, "pnp_rival": 0.0, "retrieved": 1.0, "physical": 1.0, "tie": 0.0, "map_margin": 0.5,
           "map_rival": 0.0, "map_twin": 0.0, "copies": 2.0}
    loc = SimpleNamespace(confidence_signals=sig, num_inliers=60, rot_cam_from_world=np.eye(3), center=np.zeros(3))
    found = [{"map": "floor_1", "R": np.eye(3), "t": np.array([0.0, 0.0, 3.0])},
             {"map": "floor_2", "R": np.eye(3), "t": np.array([0.0, 0.0, 6.0])}]
    copies = [{"why": "copy of this room on floor_1, 3.0 m away", "copy": {"map": "floor_1", "t": [0, 0, 3]}}]
    asked = []

    def views(copy_n: int, copy_view_m: float, own_n: int, own_view_m: float):
        def inliers_at(name, R, t, beyond=0.0):
            asked.append((name, beyond))
            if name is not None:
                return copy_n, copy_view_m
            return (own_n, own_view_m) if own_view_m >= beyond else (0, float("inf"))
        return inliers_at

    # the copies' maps hold no view within 1.8 m, the pose's own views beyond that see nothing: cannot tell
    got = copy_rival(loc, found, views(0, 1.8, 60, 0.5))
    assert got == {"copy_rival": 1.0} and asked[:2] == [("floor_1", 0.0), (None, 1.8)] and len(asked) == 2
    assert judge({**sig, **got}, copies)[1] == "ambiguous"
    # on the same footing the pose keeps 50 inliers, its copies 5: the features tell them apart
    got = copy_rival(loc, found, views(5, 0.6, 50, 0.7))
    assert got == {"copy_rival": 0.1} and judge({**sig, **got}, copies)[1] == "confident"
    # an identical room's copy: 45 inliers against 50
    assert judge({**sig, **copy_rival(loc, found, views(45, 0.6, 50, 0.7))}, copies)[1] == "ambiguous"
    # a pose the features do not single out (a PnP rival already) runs no PnP at its copies
    asked.clear()
    assert copy_rival(SimpleNamespace(**{**vars(loc), "confidence_signals": {**sig, "map_rival": 0.6}}), found,
                      views(0, 0.6, 60, 0.5)) == {} and not asked


def test_competitor_reasons():
    R = _rz(10)
    assert rotation_kind(R, R @ _rz(180)) == "180-degree twin"
    assert rotation_kind(R, R @ _rz(-90)) == "90-degree rotation"
    flip = np.diag([1.0, -1.0, -1.0])  # upside down: a half turn about x
    assert rotation_kind(R, R @ flip) == "other up axis"
    assert why(R, CENTRE, R, CENTRE + [0.0, 2.0, 0.0]) == "other position (2.0 m)"
    assert why(R, CENTRE, R @ _rz(180), CENTRE + [1.0, 0.0, 0.0]) == "other position (1.0 m), 180-degree twin"


def test_results_without_confidence_still_load():
    from ldlloc.batch.accuracy import summarize, verdict_line
    from ldlloc.batch.results import validate_results
    from ldlmap.core.errors import InputError

    old = {"format_version": 1, "queries": [{"image": "a.jpg", "scene": "s", "split": "robot", "name": "a",
                                             "status": "ok", "t_error_m": 0.01, "r_error_deg": 0.1}]}
    rs, _ = validate_results(old)
    assert rs[0].verdict is None and rs[0].confidence is None and rs[0].competitors == []
    assert "verdicts" not in summarize(rs) and verdict_line(rs) is None
    bad = {"queries": [{**old["queries"][0], "verdict": "sure"}]}
    with pytest.raises(InputError, match="verdict"):
        validate_results(bad)


@pytest.mark.xdist_group("end_to_end")
def test_confident_poses_are_right_and_reach_the_outputs(demo_dataset, tmp_path):
    from ldlloc.cli import app as loc_app

    out = tmp_path / "r.json"
    res = runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "extreme", "--scene", "synthroom_1",
                                  "-o", str(out)])
    assert res.exit_code == 0, res.output
    queries = json.loads(out.read_text())["queries"]
    assert len(queries) == 5
    confident = [q for q in queries if q["verdict"] == "confident"]
    assert confident, [(q["confidence"], q["t_error_m"]) for q in queries]
    assert all(q["t_error_m"] < 0.25 and q["r_error_deg"] < 5 for q in confident)
    assert all(0 <= q["confidence"] <= 1 and set(q["confidence_signals"]) >= {"gap", "support"} for q in queries)
    line = next(x for x in res.output.splitlines() if x.startswith("verdicts:"))
    assert f"{len(confident)} confident" in line and f"({len(confident)} / {len(confident)})" in line
    report = runner.invoke(loc_app, ["report", str(out)])
    assert line in report.output
    # one panorama with --json: the same fields
    img = Path(queries[0]["image"])
    res = runner.invoke(loc_app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(img), "--json"])
    assert res.exit_code == 0, res.output
    one = json.loads(res.stdout)
    assert one["verdict"] == queries[0]["verdict"] and one["confidence"] == pytest.approx(queries[0]["confidence"])
    assert isinstance(one["competitors"], list)


def test_a_tracked_frame_is_no_surer_than_where_its_track_started():
    sure, unsure = MODEL.confident_at + 0.01, MODEL.confident_at - 0.2
    assert no_surer_than(0.999, "confident", None) == (0.999, "confident")  # not known: as judged
    assert no_surer_than(0.999, "confident", sure) == (round(sure, 6), "confident")
    assert no_surer_than(0.999, "confident", unsure) == (round(unsure, 6), "ambiguous")
    assert no_surer_than(0.1, "ambiguous", sure) == (0.1, "ambiguous")  # never raised
    assert no_surer_than(0.0, "failed", unsure) == (0.0, "failed")
    # a start whose image named copies of its room (ambiguous, however sure of the room): never confident
    assert no_surer_than(0.999, "confident", 0.999, "ambiguous") == (0.999, "ambiguous")
    assert no_surer_than(0.999, "confident", sure, "confident") == (round(sure, 6), "confident")
