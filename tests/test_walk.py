"""Walks localized as sequences (ldlloc/walk/): the path over each frame's hypotheses, the walk's
verdicts, photo order, and a walk through identical rooms end to end.

End to end (``demo_dataset``): the SIFT map of one demo room written twice, shifted, as two
identical rooms beside the other room's map (all in one frame): a walk that starts in the other
room and goes into the near copy. Alone, a panorama in the copy is never ``confident`` and names
the other copy; the walk puts it in the near copy, within 0.1 m / 5 deg, and says that it decided.
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app
from ldlloc.confidence import MODEL, WALK_MARGIN, walk_confidence, walk_judgement
from ldlloc.walk.hypotheses import Hypotheses
from ldlloc.walk.motion import MotionParams, transition_costs
from ldlloc.walk.order import capture_time, natural_key, ordered
from ldlloc.walk.viterbi import best_path, margin
from ldlmap.core.geometry import rotation_error_deg, translation_error
from tests._hostile import error_line

pytestmark = pytest.mark.xdist_group("walk")
runner = CliRunner()
NEAR, FAR = np.array([5.5, 0.0, 0.0]), np.array([40.0, 0.0, 0.0])  # where the two copies of room 1 stand


def _hyps(centers: list, losses: list, maps: list | None = None) -> Hypotheses:
    n = len(centers)
    return Hypotheses(np.array(maps or [0] * n), np.repeat(np.eye(3)[None], n, 0), np.array(centers, float),
                      np.array(losses, float), np.zeros(n, bool))


def _path(frames: list[Hypotheses], params: MotionParams = MotionParams()):
    em = [h.emission_costs(params.emission_weight) for h in frames]
    return best_path(em, lambda f: transition_costs(frames[f - 1], frames[f], params))


def test_path_keeps_to_the_copy_the_walk_came_into():
    # a corridor at x = 0..6, then two identical rooms (x = 9 and x = 40): inside, each frame scores both
    # copies the same (the far one even a little better); the walk came from the corridor: the near copy
    corridor = [_hyps([[x, 0, 1.5]], [-100]) for x in (0.0, 2.0, 4.0, 6.0)]
    rooms = [_hyps([[9 + d, 1, 1.5], [40 + d, 1, 1.5]], [-100, -101]) for d in (0.0, 1.0, 2.0)]
    p = _path(corridor + rooms)
    assert p.choice[4:] == [0, 0, 0]
    m = [margin(p.marginals[f], 0, np.array([False, True])) for f in (4, 5, 6)]
    assert all(v > 2.0 for v in m), m  # the far copy needs a jump: it costs more than the loss it gains
    alone = _path(rooms)  # without the corridor nothing tells them apart: the better loss wins, by a hair
    assert alone.choice == [1, 1, 1] and margin(alone.marginals[0], 1, np.array([True, False])) < 1.0


def _outcome(h: Hypotheses, verdict: str = "ambiguous", copies: Hypotheses | None = None):
    from ldlloc.walk.localize import FrameOutcome, WalkFrame

    return FrameOutcome(WalkFrame("frame", None), hypotheses=h, single_pose=(h.rot_cam_from_world[0], h.center[0]),
                        single_verdict=verdict, copies=copies)


def test_a_copy_its_image_cannot_tell_keeps_the_walks_margin_small():
    """Two frames in a room after a corridor: each image's own pose refined in the room (x = 3.5), the
    identical room next door (3.8 m over) only as a coarse pose 0.6 m off that explains fewer lines.
    The path keeps the room, but only the refinement made it surer: with every copy the images found
    at their own pose's cost (``copies``), the margin is what the walk itself knows (a step 0.7 m
    longer than a free one), under a walk's margin; a copy 40 m away, reached by a jump only, leaves
    the walk sure."""
    from ldlloc.walk.localize import WalkParams, walk_margins, walk_path

    params = WalkParams()
    corridor = [_outcome(_hyps([[x, 0, 1.5]], [-100]), "confident") for x in (0.0, 2.0)]
    rooms = [_hyps([[3.5, 2 + d, 1.5], [7.9, 2 + d, 1.5]], [-100, -80]) for d in (0.0, 1.0)]
    plain = corridor + [_outcome(h) for h in rooms]
    path = walk_path(plain, params)
    assert path.choice == [0, 0, 0, 0]
    assert all(m > WALK_MARGIN for m in walk_margins(plain, path, params)[2:])
    beside = corridor + [_outcome(h, copies=_hyps([[7.3, 2 + d, 1.5]], [-100])) for h, d in zip(rooms, (0.0, 1.0))]
    assert walk_path(beside, params).choice == path.choice  # the poses stay as the path chose them
    m = walk_margins(beside, path, params)
    assert m[:2] == walk_margins(plain, path, params)[:2] and all(v < 1.0 for v in m[2:]), m
    far = corridor + [_outcome(h, copies=_hyps([[40.0, 2 + d, 1.5]], [-100])) for h, d in zip(rooms, (0.0, 1.0))]
    assert all(v > WALK_MARGIN for v in walk_margins(far, path, params)[2:])


def test_a_jump_between_shots_does_not_break_the_path():
    # shots 1-3 m apart, then a 10 m jump (a room skipped), each frame sure of its pose; a wrong
    # candidate near the previous shot that explains far fewer lines does not win
    a = [_hyps([[x, 0, 1.5], [x + 0.5, 3, 1.5]], [-100, -60]) for x in (0.0, 2.0, 4.0)]
    b = [_hyps([[x, 0, 1.5], [5.0, 1, 1.5]], [-100, -55]) for x in (14.0, 16.0)]
    assert _path(a + b).choice == [0] * 5


def test_floor_changes_cost_more_than_a_jump():
    p = MotionParams()
    h0, h1 = _hyps([[0, 0, 1.5]], [-100]), _hyps([[12, 0, 1.5], [0.5, 0, 4.5]], [-100, -100])
    c = transition_costs(h0, h1, p)[0]
    assert c[0] == pytest.approx(p.jump_cost) and c[1] == pytest.approx(p.floor_cost) and p.floor_cost > p.jump_cost
    near = transition_costs(h0, _hyps([[3.0, 0, 1.5]], [-1]), p)[0, 0]
    assert near == 0.0  # a tour's step
    video = transition_costs(h0, _hyps([[3.0, 0, 1.5]], [-1]), p, dt=0.2)[0, 0]
    assert video > 1.0  # 3 m in 0.2 s is no step


def test_a_pose_the_walk_moved_is_sound_only_where_its_image_agrees():
    from types import SimpleNamespace

    from ldlloc.confidence import sound_where_moved

    assert sound_where_moved(SimpleNamespace(confidence=0.997))  # its image, refined there, would be confident
    assert not sound_where_moved(SimpleNamespace(confidence=0.484))  # a corridor frame the walk moved 1.3 m off
    assert not sound_where_moved(SimpleNamespace(confidence=None)) and not sound_where_moved(None)


def test_walk_judgement():
    assert walk_confidence(WALK_MARGIN) == pytest.approx(MODEL.confident_at)
    assert walk_judgement(0.9, "confident", 0.1, changed=False, pose_ok=True) == (0.9, "confident", False)
    conf, verdict, decided = walk_judgement(0.3, "ambiguous", WALK_MARGIN + 2, changed=False, pose_ok=True)
    assert verdict == "confident" and decided and conf > MODEL.confident_at
    assert walk_judgement(0.3, "ambiguous", 0.5, changed=False, pose_ok=True) == (0.3, "ambiguous", False)
    assert walk_judgement(0.9, "confident", WALK_MARGIN + 2, changed=True, pose_ok=True)[1:] == ("confident", True)
    assert walk_judgement(0.9, "confident", 0.5, changed=True, pose_ok=True)[1:] == ("ambiguous", True)
    assert walk_judgement(0.1, "failed", WALK_MARGIN + 2, changed=True, pose_ok=False)[1:] == ("ambiguous", True)


def _jpeg_with_time(path: Path, stamp: str, sub: str = "") -> None:
    """A 64 x 32 JPEG whose EXIF holds DateTimeOriginal (and SubSecTimeOriginal)."""
    ok, data = cv2.imencode(".jpg", np.full((32, 64, 3), 128, np.uint8))
    entries = [(0x9003, stamp.encode() + b"\0")] + ([(0x9291, sub.encode() + b"\0")] if sub else [])
    exif_at = 8 + 2 + 12 + 4  # IFD0 with one entry (the EXIF pointer)
    data_at = exif_at + 2 + 12 * len(entries) + 4
    ifd, blob = b"", b""
    for tag, raw in entries:
        value = raw.ljust(4, b"\0") if len(raw) <= 4 else struct.pack("<I", data_at + len(blob))
        if len(raw) > 4:
            blob += raw
        ifd += struct.pack("<HHI", tag, 2, len(raw)) + value
    tiff = (b"II*\0" + struct.pack("<I", 8) + struct.pack("<H", 1) + struct.pack("<HHII", 0x8769, 4, 1, exif_at)
            + b"\0\0\0\0" + struct.pack("<H", len(entries)) + ifd + b"\0\0\0\0" + blob)
    app1 = b"\xff\xe1" + struct.pack(">H", len(tiff) + 8) + b"Exif\0\0" + tiff
    path.write_bytes(data.tobytes()[:2] + app1 + data.tobytes()[2:])


def test_photo_order_by_name_and_by_capture_time(tmp_path):
    names = ["pano_10", "pano_2", "pano_1"]
    assert sorted(names, key=natural_key) == ["pano_1", "pano_2", "pano_10"]
    for name, stamp in zip(names, ["2024:05:01 10:00:00", "2024:05:01 10:00:05", "2024:05:01 09:59:59"]):
        _jpeg_with_time(tmp_path / f"{name}.jpg", stamp, "25" if name == "pano_2" else "")
    assert capture_time(tmp_path / "pano_2.jpg") == pytest.approx(capture_time(tmp_path / "pano_10.jpg") + 5.25)
    items, times = ordered(names, "time", lambda n: n, lambda n: tmp_path / f"{n}.jpg")
    assert items == ["pano_1", "pano_10", "pano_2"] and times[0] < times[1] < times[2]
    cv2.imwrite(str(tmp_path / "plain.jpg"), np.zeros((32, 64, 3), np.uint8))
    assert capture_time(tmp_path / "plain.jpg") is None


def _shifted(src: Path, dst: Path, offset: np.ndarray) -> None:
    """Map ``src`` moved by ``offset`` (its lines, translations, bounds, feature points and views)."""
    from ldlmap.map.mapfile import read_map, write_map

    m = read_map(src, load_cloud=False)
    f = m.features
    f = replace(f, xyz=f.xyz + offset, view_centers=f.view_centers + offset)
    write_map(dst, replace(m, lines_raw=m.lines_raw + offset, lines=m.lines + offset, features=f,
                           translations=m.translations + offset, bounds_min=m.bounds_min + offset,
                           bounds_max=m.bounds_max + offset))


@pytest.fixture(scope="module")
def copies(demo_dataset, tmp_path_factory):
    """``maps/``: room 2 where it is, room 1 twice (near at NEAR, far at FAR); ``walk/``: a
    panorama of room 2, then two of room 1 (linked, named in walk order); the truth by name."""
    from ldlmap.datasets import open_dataset

    root = tmp_path_factory.mktemp("walk")
    maps, walk = root / "maps", root / "walk"
    maps.mkdir(), walk.mkdir()
    os.symlink(demo_dataset / "maps" / "synthroom_2.h5", maps / "room2.h5")
    _shifted(demo_dataset / "maps" / "synthroom_1.h5", maps / "room1_near.h5", NEAR)
    _shifted(demo_dataset / "maps" / "synthroom_1.h5", maps / "room1_far.h5", FAR)
    qs = {s: [q for q in open_dataset(demo_dataset, "omniscenes").queries(["robot"]) if q.scene == s]
          for s in ("synthroom_1", "synthroom_2")}
    truth = {}
    shots = [(q, np.zeros(3)) for q in qs["synthroom_2"][1:2]] + [(q, NEAR) for q in qs["synthroom_1"][:2]]
    for i, (q, off) in enumerate(shots):
        name = f"frame_{i:02d}"
        os.symlink(q.image, walk / f"{name}{Path(q.image).suffix}")
        truth[name] = (q.rot_cam_from_world, q.center + off)
    return root, truth


@pytest.fixture(scope="module")
def walk_run(copies):
    root, truth = copies
    out = root / "res.json"
    res = runner.invoke(app, ["run", "--images", str(root / "walk"), "--maps", str(root / "maps"), "--walk",
                              "--output", str(out)])
    assert res.exit_code == 0, res.output
    return {r["name"]: r for r in json.loads(out.read_text())["queries"]}, truth


def test_walk_puts_the_frames_in_the_copy_it_walked_into(walk_run):
    recs, truth = walk_run
    assert sorted(recs) == sorted(truth)
    for name, r in recs.items():
        R, t = truth[name]
        assert translation_error(np.array(r["t"]), t) < 0.1 and rotation_error_deg(np.array(r["R"]), R) < 5, name
        assert r["walk"]["frame"] == int(name[-2:]) and r["walk"]["name"] == "walk"
    for name in ("frame_01", "frame_02"):  # in a copy: the image alone cannot tell which
        r = recs[name]
        assert Path(r["map"]).stem == "room1_near"
        assert r["walk"]["single_verdict"] != "confident" and r["walk"]["walk_decided"], r["walk"]
        assert r["verdict"] == "confident"


def test_walk_with_a_tilt_bound_searches_near_its_confident_frames(copies):
    """With --max-tilt (as for upright tours), the frames whose image was not confident are searched
    again near the confident one (a search restricted to a radius around it) and still end in the
    copy the walk came into."""
    root, truth = copies
    out = root / "res_tilt.json"
    res = runner.invoke(app, ["run", "--images", str(root / "walk"), "--maps", str(root / "maps"), "--walk",
                              "--max-tilt", "10", "--output", str(out)])
    assert res.exit_code == 0, res.output
    recs = {r["name"]: r for r in json.loads(out.read_text())["queries"]}
    for name in ("frame_01", "frame_02"):
        R, t = truth[name]
        r = recs[name]
        assert Path(r["map"]).stem == "room1_near" and r["walk"]["walk_decided"], r["walk"]
        assert translation_error(np.array(r["t"]), t) < 0.1 and rotation_error_deg(np.array(r["R"]), R) < 5, name


def test_single_image_in_a_copy_is_ambiguous_and_names_it(copies):
    root, truth = copies
    out = root / "single.json"
    res = runner.invoke(app, ["run", "--images", str(root / "walk" / "frame_02.jpg"), "--maps", str(root / "maps"),
                              "--output", str(out)])
    assert res.exit_code == 0, res.output
    r = json.loads(out.read_text())["queries"][0]
    assert r["verdict"] == "ambiguous"
    assert any(Path(c.get("map", "")).stem.startswith("room1_") and Path(c["map"]).stem != Path(r["map"]).stem
               for c in r["competitors"]), r["competitors"]


@pytest.mark.parametrize("args, why", [
    (["--order", "time"], "--order goes with --walk"),
    (["--walk", "--order", "size"], "--order must be name or time"),
    (["--walk", "--order", "time"], "carry no capture time"),
    (["--walk", "--ray", "auto"], "drop --ray"),
])
def test_bad_walk_options_are_one_line_errors(copies, tmp_path, args, why):
    root, _ = copies
    res = runner.invoke(app, ["run", "--images", str(root / "walk"), "--maps", str(root / "maps"),
                              "--output", str(tmp_path / "r.json"), *args])
    assert res.exit_code != 0 and why in error_line(res)


def test_walk_of_one_photo_and_of_mixed_sizes_are_errors(copies, tmp_path):
    root, _ = copies
    one = runner.invoke(app, ["run", "--images", str(root / "walk" / "frame_00.jpg"), "--maps", str(root / "maps"),
                              "--walk", "--output", str(tmp_path / "a.json")])
    assert one.exit_code != 0 and "at least 2 photos" in error_line(one)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for i, w in enumerate((512, 256)):
        cv2.imwrite(str(mixed / f"p{i}.jpg"), np.zeros((w // 2, w, 3), np.uint8))
    res = runner.invoke(app, ["run", "--images", str(mixed), "--maps", str(root / "maps"), "--walk",
                              "--output", str(tmp_path / "b.json")])
    assert res.exit_code != 0 and "must be of one size" in error_line(res)


def test_quaternions_of_rotations():
    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlloc.export.tum import quaternion_xyzw

    rng = np.random.default_rng(0)
    for angle in (0.0, 0.5, np.pi - 1e-9, np.pi, 2.5):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        q = quaternion_xyzw(rotation_from_axis_angle(axis, angle))
        assert q[3] == pytest.approx(np.cos(angle / 2), abs=1e-6)
        assert np.allclose(np.abs(q[:3]), np.abs(axis * np.sin(angle / 2)), atol=1e-6)


def test_walk_exports_as_tum_trajectory(walk_run, copies, tmp_path):
    from ldlloc.export.tum import quaternion_xyzw

    recs, _ = walk_run
    root, _ = copies
    out = tmp_path / "walk.txt"
    res = runner.invoke(app, ["export", str(root / "res.json"), "--format", "tum", "--all", "-o", str(out)])
    assert res.exit_code == 0, res.output
    rows = [line.split() for line in out.read_text().splitlines() if not line.startswith("#")]
    by_frame = {r["walk"]["frame"]: r for r in recs.values()}
    assert [float(r[0]) for r in rows] == sorted(float(f) for f in by_frame)  # no times: the frame index
    for row in rows:
        r = by_frame[int(float(row[0]))]
        assert np.allclose([float(v) for v in row[1:4]], r["t"], atol=1e-5)
        assert np.allclose([float(v) for v in row[4:]], quaternion_xyzw(np.array(r["R"]).T), atol=1e-5)


@pytest.fixture(scope="module")
def video(demo_dataset, tmp_path_factory):
    """A 5 fps mp4 of 6 frames (512 x 256) walking 0.15 m a frame towards room 1's middle, turning
    4 degrees a frame; the truth per frame."""
    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.render import Renderer
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.spec import load_spec
    from ldlloc.walk.video import write_video

    q = [q for q in open_dataset(demo_dataset, "omniscenes").queries(["robot"]) if q.scene == "synthroom_1"][0]
    middle = read_map(demo_dataset / "maps" / "synthroom_1.h5", load_cloud=False).translations.mean(0)
    step = (middle - q.center) * [1, 1, 0]
    step = 0.15 * step / np.linalg.norm(step)
    render = Renderer(build_scene(load_spec(demo_dataset / "specs" / "synthroom_1.toml")))
    truth = []
    for k in range(6):
        R = q.rot_cam_from_world @ rotation_from_axis_angle(np.array([0, 0, 1.0]), np.radians(4 * k))
        truth.append((R, q.center + k * step))
    path = tmp_path_factory.mktemp("video") / "walk.mp4"
    write_video(path, (render.render(R, t, 512, supersample=1).rgb for R, t in truth), fps=5)
    return path, truth


def test_video_is_tracked_frame_by_frame(video, demo_dataset, tmp_path):
    path, truth = video
    out = tmp_path / "v.json"
    res = runner.invoke(app, ["run", "--video", str(path), "--maps", str(demo_dataset / "maps" / "synthroom_1.h5"),
                              "--output", str(out)])
    assert res.exit_code == 0, res.output
    recs = sorted(json.loads(out.read_text())["queries"], key=lambda r: r["walk"]["frame"])
    assert [r["name"] for r in recs] == [f"walk/{k:06d}" for k in range(6)]
    assert [r["walk"]["time"] for r in recs] == pytest.approx([k / 5 for k in range(6)], abs=1e-3)
    assert all(r["image"] == str(path) for r in recs)
    assert sum(r["walk"]["tracked"] for r in recs) >= 4  # found near the previous frame, not by a global search
    assert sum("refined from lines" in r["message"] for r in recs) >= 3  # the prediction refined: no search
    for r, (R, t) in zip(recs, truth):
        assert translation_error(np.array(r["t"]), t) < 0.1 and rotation_error_deg(np.array(r["R"]), R) < 5, r["name"]
    half = tmp_path / "h.json"
    res = runner.invoke(app, ["run", "--video", str(path), "--maps", str(demo_dataset / "maps" / "synthroom_1.h5"),
                              "--every", "2", "--output", str(half)])
    assert res.exit_code == 0, res.output
    assert sorted(r["walk"]["time"] for r in json.loads(half.read_text())["queries"]) == pytest.approx([0, 0.4, 0.8],
                                                                                                    abs=1e-3)


def test_a_video_in_one_of_two_identical_rooms_is_never_confident(video, copies, tmp_path):
    """The test video against room 1 written twice (and room 2): each frame in one of the copies within
    0.1 m / 5 deg, and none `confident`: nothing in a walk that stays in the room tells the copies apart,
    and the frames tracked from an ambiguous one are no surer than it, however long their chain."""
    path, truth = video
    root, _ = copies
    out = tmp_path / "v.json"
    res = runner.invoke(app, ["run", "--video", str(path), "--maps", str(root / "maps"), "--output", str(out)])
    assert res.exit_code == 0, res.output
    recs = sorted(json.loads(out.read_text())["queries"], key=lambda r: r["walk"]["frame"])
    assert sum(r["walk"]["tracked"] for r in recs) >= 4
    for r, (R, t) in zip(recs, truth):
        assert min(translation_error(np.array(r["t"]), t + shift) for shift in (NEAR, FAR)) < 0.1, r["name"]
        assert rotation_error_deg(np.array(r["R"]), R) < 5 and r["verdict"] != "confident", r["name"]


def test_a_frame_tracked_from_a_step_off_finds_its_pose(video, demo_dataset):
    """Step 1 of tracking from the previous frame's true pose (0.15 m and 4 degrees off, as a prediction
    without a velocity is): every frame within 0.05 m / 2 deg. From that start alone the lines' refinement
    stalls 0.1-0.2 m off on some frames of this walk; the starts around the prediction reach the truth."""
    from ldlloc.batch.which_map import MapSet
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.walk.track import Prediction, TrackParams, frame_arcs, track_by_lines
    from ldlloc.walk.video import decoded_frames, video_info

    path, truth = video
    entry = MapSet.load(demo_dataset / "maps" / "synthroom_1.h5", LocalizeParams()).entries[0]
    frames = [img for _, img in decoded_frames(video_info(path))]
    for k in range(1, len(frames)):
        R0, t0 = truth[k - 1]
        arcs, secs = frame_arcs(frames[k], entry, TrackParams())
        loc, _ = track_by_lines(arcs, secs, Prediction(entry, R0, t0, 1, (R0, t0)), TrackParams(), ref_loss=-1.0)
        R, t = truth[k]
        assert translation_error(loc.center, t) < 0.05 and rotation_error_deg(loc.rot_cam_from_world, R) < 2, k


def test_bad_videos_are_one_line_errors(video, demo_dataset, tmp_path):
    from ldlloc.walk.video import write_video

    path, _ = video
    maps = str(demo_dataset / "maps" / "synthroom_1.h5")
    square = write_video(tmp_path / "square.mp4", (np.zeros((64, 64, 3), np.uint8) for _ in range(3)), fps=5)
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"\0" * 1000)
    for args, why in [([str(square)], "not an equirectangular video"), ([str(broken)], "cannot decode video"),
                      ([str(path), "--fps", "30"], "--fps must be in (0, 5]"),
                      ([str(path), "--fps", "2", "--every", "2"], "give one"),
                      ([str(path), "--every", "6"], "a walk needs at least 2")]:
        res = runner.invoke(app, ["run", "--video", *args, "--maps", maps, "--output", str(tmp_path / "o.json")])
        assert res.exit_code != 0 and why in error_line(res), (args, res.output)
    res = runner.invoke(app, ["run", "--fps", "2", "--maps", maps])
    assert "--fps goes with --video" in error_line(res)


def test_report_draws_the_walk_coloured_by_verdict(walk_run, copies, tmp_path):
    root, _ = copies
    html = tmp_path / "r.html"
    res = runner.invoke(app, ["report", str(root / "res.json"), "--html", str(html)])
    assert res.exit_code == 0, res.output
    page = html.read_text()
    assert "top view of the walk" in page and page.count("decided by the walk") >= 3
    assert page.count("<circle") >= len(walk_run[0])


def test_dataset_run_as_walks_with_ground_truth(demo_dataset, tmp_path):
    out = tmp_path / "d.json"
    args = ["run", "--root", str(demo_dataset), "--split", "robot", "--scene", "synthroom_1", "--walk",
            "--output", str(out)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    recs = json.loads(out.read_text())["queries"]
    assert len(recs) == 5 and sorted(r["walk"]["frame"] for r in recs) == list(range(5))
    assert all(r["walk"]["name"] == "synthroom_1" for r in recs)
    assert all(r["t_error_m"] < 0.1 and r["r_error_deg"] < 5 for r in recs), [r["t_error_m"] for r in recs]
    again = runner.invoke(app, [*args, "--resume"])  # every frame of the walk done: nothing runs again
    assert again.exit_code == 0, again.output
    assert json.loads(out.read_text())["queries"] == recs


def test_search_near_a_pose_stays_there_and_finds_it(demo_dataset):
    from ldlmap.core.errors import InputError
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map
    from ldlloc.pipeline import Localizer, SearchNear, load_image

    q = [q for q in open_dataset(demo_dataset, "omniscenes").queries(["robot"]) if q.scene == "synthroom_1"][0]
    loz = Localizer(read_map(demo_dataset / "maps" / "synthroom_1.h5", load_cloud=False))
    img = load_image(q.image)
    near = loz.search(img, near=SearchNear(q.center, q.rot_cam_from_world, 0.75, 15.0))
    c = near.out
    assert np.all(np.linalg.norm(c.candidates_center - q.center, axis=1) <= 0.75 + 1e-9)
    assert all(rotation_error_deg(R, q.rot_cam_from_world) <= 15.0 for R in c.candidates_rot)
    T = loz.map.translations[near.res.translation_index]  # indices into the whole map's translations
    assert np.allclose(T, c.candidates_center)
    assert translation_error(c.candidates_center[0], q.center) < 0.5
    whole = loz.search(img).out  # the restricted search scores its poses as the whole search does
    same = np.flatnonzero(np.linalg.norm(whole.candidates_center - c.candidates_center[0], axis=1) < 1e-6)
    for i in same:
        if rotation_error_deg(whole.candidates_rot[i], c.candidates_rot[0]) < 1e-3:
            assert whole.candidates_loss[i] == pytest.approx(c.candidates_loss[0], rel=1e-4)
    with pytest.raises(InputError, match="no candidate translation within"):
        loz.search(img, near=SearchNear(q.center + [100.0, 0, 0], None, 0.5))


def test_distance_fields_of_a_subset_are_its_columns():
    import torch

    from ldlloc.search.fields import DistanceFields

    d = np.random.default_rng(0).random((5, 3, 9, 16)).astype(np.float32)
    full = DistanceFields.from_arrays(d, {"rows": 8})
    sub = full.subset(np.array([4, 1]))
    pts = torch.nn.functional.normalize(torch.randn(7, 3), dim=1)
    assert sub.num_translations == 2
    assert torch.allclose(sub.lookup(pts), full.lookup(pts)[:, :, [4, 1]])


def test_a_track_resumed_at_the_rooms_twin_gives_way_to_its_confident_image(demo_dataset, monkeypatch):
    """The checks of tracking (ldlloc.walk.track.check_due, overruled): a frame tracked again after lost frames at
    the demo room's 180-degree twin of its true pose is localized globally and takes its image's confident pose,
    within 0.1 m / 5 deg; a tracked pose that is the image's own stands, and a frame tracked without a loss of
    two frames or more before it is not checked. An unsure track is checked every ``check_every`` frames and
    gives way to a global pose its image is not confident of only where that pose explains ``check_gain`` times
    the tracked pose's lines (the twin: yes; the true pose: no)."""
    from dataclasses import replace
    from types import SimpleNamespace

    import ldlloc.walk.track as track
    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlmap.datasets import open_dataset
    from ldlloc.batch.which_map import TOP_MAPS, MapSet
    from ldlloc.pipeline import LocalizeParams, load_image
    from ldlloc.walk.track import Prediction, TorchThreads, TrackParams, check_due, overruled

    q = [q for q in open_dataset(demo_dataset, "omniscenes").queries(["robot"]) if q.scene == "synthroom_1"][0]
    maps = MapSet.load(demo_dataset / "maps" / "synthroom_1.h5", LocalizeParams())
    entry = maps.entries[0]
    img = load_image(q.image)
    middle = entry.localizer.map.translations.mean(0)
    half = rotation_from_axis_angle(np.array([0, 0, 1.0]), np.pi)  # the room turned half a turn about its middle
    R2, t2 = q.rot_cam_from_world @ half, middle + half @ (q.center - middle)
    t2[2] = q.center[2]

    def tracked(R, t, verdict: str = "confident"):
        loc = SimpleNamespace(rot_cam_from_world=R, center=t, refined=True, confidence=0.9, verdict=verdict)
        return loc, SimpleNamespace(chosen=SimpleNamespace(entry=entry))

    def check(got, frames: int = 3, p: TrackParams = TrackParams(), age: int = 0):
        due = check_due(got, Prediction(entry, R2, t2, frames, (R2, t2), age), p)
        return due and overruled(img, got, maps, None, TOP_MAPS, p, TorchThreads())

    assert translation_error(t2, q.center) > 1.0
    found = check(tracked(R2, t2))
    assert found and found[0].verdict == "confident"
    assert translation_error(found[0].center, q.center) < 0.1
    assert rotation_error_deg(found[0].rot_cam_from_world, q.rot_cam_from_world) < 5
    assert check(tracked(found[0].rot_cam_from_world, found[0].center)) is None  # the image's own pose stands
    assert not check(tracked(R2, t2), frames=2)  # tracked after one lost frame: not checked
    assert not check(tracked(R2, t2), p=TrackParams(check_after_lost=0))
    # an unsure track, checked at its 25th unsure frame, against an image that is not confident either
    unsure = TrackParams(check_every=25)
    assert not check(tracked(R2, t2, "ambiguous"), frames=1, p=unsure, age=23)
    assert not check(tracked(R2, t2), frames=1, p=unsure, age=24)  # a confident frame: not checked
    # confident, but its track started from an image that was not
    assert check_due(tracked(R2, t2), Prediction(entry, R2, t2, 1, (R2, t2), 24, 0.4, "ambiguous"), unsure)
    own = track.localize_on_maps
    monkeypatch.setattr(track, "localize_on_maps", lambda *a: (lambda lc: (replace(lc[0], verdict="ambiguous"),
                                                                            lc[1]))(own(*a)))
    found = check(tracked(R2, t2, "ambiguous"), frames=1, p=unsure, age=24)
    assert found and translation_error(found[0].center, q.center) < 0.1
    assert check(tracked(R2, t2, "ambiguous"), frames=3, p=TrackParams(check_every=0))  # resumed: the same rule
    right = tracked(found[0].rot_cam_from_world, found[0].center, "ambiguous")
    assert not check(right, frames=1, p=unsure, age=24)
