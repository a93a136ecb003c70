"""Walks written as they are decided (ldlloc/walk/stream.py): a run killed mid-walk leaves whole
records, ``--resume`` goes on from the last written frame and gives the records of an
uninterrupted run; the window a stream holds stays bounded; bad options are one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.batch.results import load_results, read_results_data
from ldlloc.cli import app
from ldlloc.walk import stream
from ldlloc.walk.hypotheses import Hypotheses
from ldlloc.walk.localize import FrameOutcome, WalkFrame, WalkParams
from tests._hostile import error_line
from tests._results_files import without_timings

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]
LAG, BLOCK = 1, 2  # small: the demo's walks (5 frames) are decided block by block, not as a whole
KILL_AFTER = 4  # records written before the run is killed: two blocks of the first walk, not its last frame

KILLER = """
import os, signal, sys
from ldlloc.batch import results
from ldlloc.walk import stream
stream.BLOCK = {block}
extend, written = results.ResultsWriter.extend, []
def killing(self, records):
    extend(self, records)
    written.extend(records)
    if len(written) >= {n}:
        os.kill(os.getpid(), signal.SIGKILL)  # no cleanup, no finally: as a machine that dies
results.ResultsWriter.extend = killing
from ldlloc.cli import app
app({args!r})
"""


def _walk_args(demo_dataset: Path, out: Path) -> list[str]:
    return ["run", "--root", str(demo_dataset), "--split", "robot", "--walk", "--lag", str(LAG), "--output", str(out)]


@pytest.fixture(scope="module")
def whole_run(demo_dataset, tmp_path_factory) -> Path:
    """The robot split's two walks (one per scene), run without a stop."""
    out = tmp_path_factory.mktemp("whole") / "walks.json"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(stream, "BLOCK", BLOCK)
        res = runner.invoke(app, _walk_args(demo_dataset, out))
    assert res.exit_code == 0, res.output
    return out


@pytest.mark.xdist_group("walk_stream")  # one worker runs ``whole_run``
def test_resume_after_a_kill_goes_on_from_the_last_written_frame(demo_dataset, whole_run, tmp_path, monkeypatch):
    out = tmp_path / "walks.json"
    script = KILLER.format(n=KILL_AFTER, block=BLOCK, args=_walk_args(demo_dataset, out))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    killed = subprocess.run([sys.executable, "-c", script], env=env, cwd=tmp_path, capture_output=True, text=True)
    assert killed.returncode == -9, killed.stderr[-2000:]
    records, meta = load_results(out)  # whole records only: the JSON and its journal read and checked
    assert len(records) == KILL_AFTER and meta["finished"] is False
    assert [r.walk["frame"] for r in records] == list(range(KILL_AFTER))
    before = read_results_data(out)["queries"]
    localized = []
    real = stream.localize_frame
    monkeypatch.setattr(stream, "localize_frame", lambda item, *a: localized.append(item.name) or real(item, *a))
    monkeypatch.setattr(stream, "BLOCK", BLOCK)
    res = runner.invoke(app, [*_walk_args(demo_dataset, out), "--resume"])
    assert res.exit_code == 0, res.output
    whole = without_timings(whole_run)
    names = [q["name"] for q in whole["queries"]]
    first = [q["name"] for q in whole["queries"] if q["walk"]["name"] == whole["queries"][0]["walk"]["name"]]
    # the first walk: the lag frames before the first unwritten one again (its window's past, whole
    # blocks), then the rest
    start = (KILL_AFTER - LAG) // BLOCK * BLOCK
    assert 0 < start < KILL_AFTER and localized == first[start:] + [n for n in names if n not in first], localized
    assert without_timings(out) == whole  # the same records, in the same order
    after = {q["name"]: q for q in json.loads(out.read_text())["queries"]}
    assert all(after[q["name"]] == q for q in before)  # the written frames were not written again


@pytest.mark.xdist_group("walk_stream")  # one worker runs ``whole_run``
def test_a_walk_written_whole_is_not_run_again(whole_run, demo_dataset, tmp_path, monkeypatch):
    out = tmp_path / "again.json"
    out.write_bytes(whole_run.read_bytes())
    monkeypatch.setattr(stream, "localize_frame", lambda *a: pytest.fail("a frame was localized again"))
    monkeypatch.setattr(stream, "BLOCK", BLOCK)
    res = runner.invoke(app, [*_walk_args(demo_dataset, out), "--resume"])
    assert res.exit_code == 0, res.output
    assert without_timings(out)["queries"] == without_timings(whole_run)["queries"]


def test_a_resumed_video_goes_on_from_its_last_written_frames(demo_dataset, tmp_path, monkeypatch):
    """A video's frames are decoded again up to the resume point, localized again from there (the
    lag before the first unwritten block), and its records equal an uninterrupted run's."""
    import cv2
    from ldlloc.walk.video import write_video

    shots = sorted((demo_dataset / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[:4]
    video = write_video(tmp_path / "v.mp4", (cv2.imread(str(p))[:, :, ::-1] for p in shots for _ in range(2)), fps=5)
    monkeypatch.setattr(stream, "BLOCK", BLOCK)
    args = ["run", "--video", str(video), "--maps", str(demo_dataset / "maps"), "--lag", str(LAG)]
    whole, out = tmp_path / "whole.json", tmp_path / "v.json"
    res = runner.invoke(app, [*args, "--output", str(whole)])
    assert res.exit_code == 0, res.output
    data = json.loads(whole.read_text())
    data["meta"]["finished"] = False  # as a run killed after its first blocks leaves it
    data["queries"] = data["queries"][:KILL_AFTER]
    out.write_text(json.dumps(data))
    localized = []
    real = stream.localize_frame
    monkeypatch.setattr(stream, "localize_frame", lambda item, *a: localized.append(item[0].name) or real(item, *a))
    res = runner.invoke(app, [*args, "--output", str(out), "--resume"])
    assert res.exit_code == 0, res.output
    names = [q["name"] for q in without_timings(whole)["queries"]]
    assert len(names) == 8 and localized == names[(KILL_AFTER - LAG) // BLOCK * BLOCK:], localized
    assert without_timings(out) == without_timings(whole)


@pytest.mark.parametrize("args, why", [
    (["--lag", "0", "--walk"], "--lag must be a whole number of frames >= 1, got 0"),
    (["--lag", "3"], "--lag goes with --walk or --video"),
])
def test_bad_lag_is_one_line(demo_dataset, tmp_path, args, why):
    res = runner.invoke(app, ["run", "--root", str(demo_dataset), "--split", "robot", "--output",
                              str(tmp_path / "r.json"), *args])
    assert res.exit_code != 0 and why in error_line(res)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("args, why", [
    (["--images", "{demo}/robot", "--walk"], "--images --walk is one walk, localized in this process: drop --ray"),
])
def test_one_walk_on_ray_is_one_line(demo_dataset, tmp_path, args, why):
    args = [a.replace("{demo}", str(demo_dataset)) for a in args]
    res = runner.invoke(app, ["run", *args, "--maps", str(demo_dataset / "maps"), "--ray", "local", "--output",
                              str(tmp_path / "r.json")])
    assert res.exit_code != 0 and why in error_line(res)


# ----------------------------------------------------------------- the stream alone, on made-up frames


def _fake_frames(n: int, copies: int = 2) -> tuple[list, dict]:
    """``n`` frames of a walk down a corridor whose images cannot tell two copies of it apart (the
    copies 30 m apart; frame 0 sees which): each frame's hypotheses, the own pose in copy 0."""
    rng = np.random.default_rng(0)
    hyps = {}
    for i in range(n):
        c = np.array([0.5 * i, 0.0, 1.5])
        centers = np.array([c + [0, 30.0 * k, 0] for k in range(copies)] + [c + rng.normal(0, 2, 3) for _ in range(6)])
        loss = np.r_[[-50.0] * copies, rng.uniform(-40, -10, 6)]
        if i == 0:
            loss[1:copies] = -20.0
        hyps[f"f{i:04d}"] = Hypotheses(np.zeros(len(loss), np.int64), np.repeat(np.eye(3)[None], len(loss), 0),
                                       centers, loss, np.r_[[True], np.zeros(len(loss) - 1, bool)])
    return [WalkFrame(name, lambda: None) for name in hyps], hyps


class _Loc:
    def __init__(self, h: Hypotheses):
        self.rot_cam_from_world, self.center, self.refined = h.rot_cam_from_world[0], h.center[0], True
        self.confidence, self.verdict, self.competitors, self.message = 0.5, "ambiguous", [], ""


def _fake_localize(hyps: dict, held: list, streams: list):
    def localize_frame(item, prev, maps, params, ref_loss, trackers, index, threads=None, free=None):
        if threads is not None:  # as the tracker does: one thread for a line refinement, back before a search
            threads.one()
            threads.restore()
        h = hyps[item.name]
        loc = _Loc(h)
        out = FrameOutcome(item, loc=loc, entry=_ENTRY, hypotheses=h, single_confidence=0.5,
                           single_verdict="ambiguous", single_pose=(loc.rot_cam_from_world, loc.center))
        held.append(max(len(s.slots) for s in streams) if streams else 0)
        return out, None
    return localize_frame


class _Entry:
    path, scene = Path("m.h5"), "m"


_ENTRY = _Entry()


class _Maps:
    entries = [_ENTRY]


def _streamed(monkeypatch, n: int, lag: int) -> tuple[list, list]:
    frames, hyps = _fake_frames(n)
    held, streams = [], []
    monkeypatch.setattr(stream, "localize_frame", _fake_localize(hyps, held, streams))
    real = stream.WalkStream

    def keep(*a, **k):
        s = real(*a, **k)
        streams.append(s)
        return s
    monkeypatch.setattr(stream, "WalkStream", keep)
    got = [(s.index, s.out.walk_margin, s.out.single_pose[1][1]) for block in
           stream.stream_walk(frames, _Maps(), WalkParams(), lag) for s in block]
    return got, held


def test_a_long_walk_holds_a_bounded_window(monkeypatch):
    got, held = _streamed(monkeypatch, 400, 10)
    assert [g[0] for g in got] == list(range(400))  # every frame, in order, once
    assert max(held) < 2 * (10 + stream.BLOCK)  # the window: lag frames before the block decided, lag after


def test_a_walk_shorter_than_the_lag_is_decided_as_a_whole(monkeypatch):
    """Frame 0 alone tells the copies apart: with the whole walk in view every frame is decided
    with the same margin as the offline walk's (the path's cost of the other copy)."""
    from ldlloc.walk.localize import walk_margins, walk_path

    got, _ = _streamed(monkeypatch, 12, 20)
    frames, hyps = _fake_frames(12)
    live = [FrameOutcome(f, hypotheses=hyps[f.name], single_pose=(np.eye(3), hyps[f.name].center[0]),
                         single_verdict="ambiguous") for f in frames]
    path = walk_path(live, WalkParams())
    assert all(j == 0 for j in path.choice)
    margins = walk_margins(live, path, WalkParams())  # the offline walk's (its second path too)
    assert np.allclose([g[1] for g in got], margins) and min(margins) > 0


def test_torch_threads_are_switched_once_per_walk(monkeypatch):
    """The walk runs torch on one thread, switched at its start and given back at its end: not twice a
    frame (about 11 ms a frame with a caller's 2 threads)."""
    import torch
    from ldlloc.walk import track

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    calls = []
    real = torch.set_num_threads
    track.torch.get_num_threads  # noqa: B018 - loaded: the module's names copied in, then one replaced
    monkeypatch.setattr(track.torch, "set_num_threads", lambda n: calls.append(n) or real(n))
    try:
        got, _ = _streamed(monkeypatch, 60, 10)
        assert len(got) == 60 and calls == [1, 2] and torch.get_num_threads() == 2
    finally:
        real(before)
