"""Several videos in one run (``ldlloc run --video A --video B``, a folder or a glob of videos): which
videos are taken, and one-line errors for bad input before any work (the runs themselves, plain and
on Ray, killed and resumed: tests/test_ray.py)."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from ldlloc.cli import app
from ldlloc.walk.video import find_videos, write_video
from tests._hostile import error_line

runner = CliRunner()


def _video(path):
    return write_video(path, (np.zeros((32, 64, 3), np.uint8) for _ in range(3)), fps=5)


def test_folders_globs_and_repeats_give_each_video_once_in_name_order(tmp_path):
    (tmp_path / "d").mkdir()
    for name in ("walk10.mp4", "walk2.MOV", ".hidden.mp4"):
        _video(tmp_path / "d" / name)
    (tmp_path / "d" / "notes.txt").write_text("not a video")
    said = []
    got = find_videos([str(tmp_path / "d"), str(tmp_path / "d" / "walk2.MOV")], warn=said.append)
    assert [p.name for p in got] == ["walk2.MOV", "walk10.mp4"]  # natural order, the repeated one once
    assert said == [f"warning: 1 file(s) in the folder {tmp_path / 'd'} left out (not "
                    ".mp4/.mov/.m4v/.mkv/.avi/.webm)"]
    assert [p.name for p in find_videos([str(tmp_path / "d" / "walk*")])] == ["walk2.MOV", "walk10.mp4"]


def test_bad_video_inputs_are_one_line(demo_dataset, tmp_path):
    for d in ("x", "y", "empty"):
        (tmp_path / d).mkdir()
    _video(tmp_path / "x" / "walk.mp4")
    _video(tmp_path / "y" / "walk.mp4")
    (tmp_path / "empty" / "notes.txt").write_text("not a video")
    (tmp_path / "y" / "broken.mp4").write_bytes(b"\0" * 1000)
    out = tmp_path / "o.json"
    for args, why in [
        ([str(tmp_path / "nothing")], "--video not found"),
        ([str(tmp_path / "empty")], f"no video (mp4, mov, m4v, mkv, avi, webm) in the folder {tmp_path / 'empty'}"),
        ([str(tmp_path / "*.webm")], "no video (mp4, mov, m4v, mkv, avi, webm) matching"),
        ([str(tmp_path / "x"), "--video", str(tmp_path / "y" / "walk.mp4")], "two videos named walk"),
        ([str(tmp_path / "x" / "walk.mp4"), "--video", str(tmp_path / "y" / "broken.mp4")], "cannot decode video"),
        ([str(tmp_path / "x" / "walk.mp4"), "--video", str(tmp_path / "x" / "walk.mp4"), "--images", "p"],
         "--video runs alone: drop --images"),
    ]:
        res = runner.invoke(app, ["run", "--video", *args, "--maps", str(demo_dataset / "maps"), "--output", str(out)])
        assert res.exit_code != 0 and why in error_line(res), (args, res.output)
        assert not out.exists()
