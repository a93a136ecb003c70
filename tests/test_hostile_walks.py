"""Hostile walks and videos (``ldlloc run --walk``, ``run --video``, ``export --format tum``): a bad
input or a results file of another kind of run is one line ``error: ...``, exit 1, nothing written;
a corrupt photo fails its own frame, not the walk; an export says what its poses are (not a walk,
a run that did not finish). The videos are tiny (128 x 64 frames, written with PyAV); the map and
panoramas are the demo dataset's (conftest)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app
from tests._hostile import assert_clean_failure, snapshot

pytestmark = pytest.mark.xdist_group("hostile_walks")  # one worker makes ``work``
runner = CliRunner()


def _mpegts(path: Path, img: np.ndarray, n: int) -> bytes:
    """``n`` frames of ``img`` as an H.264 MPEG-TS stream (segments of such streams concatenate)."""
    import av

    with av.open(str(path), "w", format="mpegts") as c:
        s = c.add_stream("libx264", rate=5)
        s.width, s.height, s.pix_fmt = img.shape[1], img.shape[0], "yuv420p"
        for _ in range(n):
            for packet in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")):
                c.mux(packet)
        for packet in s.encode():
            c.mux(packet)
    return path.read_bytes()


@pytest.fixture(scope="module")
def work(demo_dataset, tmp_path_factory):
    """``map.h5`` (demo room 1), ``walk/`` (3 of its panoramas), ``v.mp4`` (4 tiny frames), and the
    results of a walk (``walk.json``), a plain run of the same photos (``plain.json``) and the video
    (``video.json``): written once, copied into each test's folder."""
    from ldlloc.walk.video import write_video

    root = tmp_path_factory.mktemp("hostile_walks")
    shutil.copy(demo_dataset / "maps" / "synthroom_1.h5", root / "map.h5")
    (root / "walk").mkdir()
    panos = sorted((demo_dataset / "robot_pano").rglob("*.jpg"))[:3]
    for i, p in enumerate(panos):
        shutil.copy(p, root / "walk" / f"p{i}.jpg")
    small = cv2.resize(cv2.imread(str(panos[0]))[:, :, ::-1], (128, 64), interpolation=cv2.INTER_AREA)
    write_video(root / "v.mp4", (small for _ in range(4)), fps=5)
    cwd = os.getcwd()
    os.chdir(root)
    try:
        for args, out in ((["--images", "walk", "--walk"], "walk.json"), (["--images", "walk"], "plain.json"),
                          (["--video", "v.mp4"], "video.json")):
            res = runner.invoke(app, ["run", *args, "--maps", "map.h5", "-o", out])
            assert res.exit_code == 0, res.output
    finally:
        os.chdir(cwd)
    return root


@pytest.fixture
def here(work, tmp_path, monkeypatch):
    """A copy of :func:`work` as the working folder."""
    d = tmp_path / "w"
    shutil.copytree(work, d)
    monkeypatch.chdir(d)
    return d


def _square_midway(d: Path) -> None:
    img = np.full((64, 128, 3), 90, np.uint8)
    (d / "sq.ts").write_bytes(_mpegts(d / "a.ts", img, 3) + _mpegts(d / "b.ts", img[:, :64], 3))
    (d / "a.ts").unlink(), (d / "b.ts").unlink()


def _unfinished_video(d: Path) -> None:
    data = json.loads((d / "video.json").read_text())
    data["meta"]["finished"] = False  # as a run killed (or stopped by a full disk) leaves it
    (d / "video.json").write_text(json.dumps(data))


def _two_walks(d: Path) -> None:
    """``two.json``: the walk's records and a copy of them as a second walk (a dataset run's, one per scene)."""
    data = json.loads((d / "walk.json").read_text())
    copies = [{**q, "name": f"b/{q['name']}", "walk": {**q["walk"], "name": "other"}} for q in data["queries"]]
    data["queries"] += copies
    (d / "two.json").write_text(json.dumps(data))


# (case id, prepare the folder, ldlloc arguments, words the error line must hold)
CASES = [
    ("video-frames-turn-square", _square_midway, ["run", "--video", "sq.ts", "--maps", "map.h5", "-o", "r.json"],
     "from frame 3 on"),
    ("images-resume-of-video-results", None, ["run", "--images", "walk", "--maps", "map.h5", "--resume",
                                              "-o", "video.json"], "holds the results of a --video run"),
    ("walk-resume-of-video-results", None, ["run", "--images", "walk", "--maps", "map.h5", "--walk", "--resume",
                                            "-o", "video.json"], "this is an --images --walk run"),
    ("walk-resume-of-plain-results", None, ["run", "--images", "walk", "--maps", "map.h5", "--walk", "--resume",
                                            "-o", "plain.json"], "holds the results of an --images run and this "
                                                                 "is an --images --walk run"),
    ("plain-resume-of-walk-results", None, ["run", "--images", "walk", "--maps", "map.h5", "--resume",
                                            "-o", "walk.json"], "holds the results of an --images --walk run"),
    ("video-over-unfinished-video", _unfinished_video, ["run", "--video", "v.mp4", "--maps", "map.h5",
                                                        "-o", "video.json"], "continue it with --resume, or replace it with --overwrite"),
    ("colmap-of-a-video", None, ["export", "video.json", "--format", "colmap", "-o", "model"], "frames of a video"),
    ("nerfstudio-of-a-video", None, ["export", "video.json", "--format", "nerfstudio", "-o", "t.json"],
     "frames of a video"),
    ("video-with-dataset-options", None, ["run", "--video", "v.mp4", "--maps", "map.h5", "--split", "robot",
                                          "--scene-unknown"], "--video runs alone: drop --split, --scene-unknown"),
    ("tum-of-two-walks", _two_walks, ["export", "two.json", "--format", "tum", "--all", "-o", "t.txt"],
     "holds 2 walks (other, walk)"),
]


@pytest.mark.parametrize("case, prepare, args, words", CASES, ids=[c[0] for c in CASES])
def test_bad_walk_and_video_inputs_fail_in_one_line(here, case, prepare, args, words):
    if prepare is not None:
        prepare(here)
    before = snapshot(here)
    line = assert_clean_failure(runner.invoke(app, args), here, before)
    assert words in line, line


def test_a_corrupt_photo_fails_its_frame_not_the_walk(here):
    data = (here / "walk" / "p1.jpg").read_bytes()
    (here / "walk" / "p1.jpg").write_bytes(data[: len(data) // 3])  # no end marker
    res = runner.invoke(app, ["run", "--images", "walk", "--maps", "map.h5", "--walk", "-o", "r.json"])
    assert res.exit_code == 0 and "Traceback" not in res.output, res.output
    status = {q["name"]: q["status"] for q in json.loads((here / "r.json").read_text())["queries"]}
    assert status["p1"] == "failed" and len(status) == 3 and status["p0"] != "failed", status


@pytest.mark.parametrize("results, prepare, words", [
    ("plain.json", None, "not of a walk"),
    ("video.json", _unfinished_video, "did not finish"),
    ("walk.json", None, None),
])
def test_tum_export_says_what_its_poses_are(here, results, prepare, words):
    if prepare is not None:
        prepare(here)
    res = runner.invoke(app, ["export", results, "--format", "tum", "--all", "-o", "t.txt"])
    assert res.exit_code == 0 and (here / "t.txt").is_file(), res.output
    if words is None:
        assert "not of a walk" not in res.output and "did not finish" not in res.output, res.output
    else:
        assert words in res.output, res.output
    if words == "did not finish":
        assert "--resume` continues it" in res.output, res.output


def test_html_report_of_a_video_shows_its_frames(here):
    res = runner.invoke(app, ["report", "video.json", "--html", "r.html"])
    assert res.exit_code == 0, res.output
    page = (here / "r.html").read_text()
    n = len(json.loads((here / "video.json").read_text())["queries"])
    assert "cannot decode" not in page and page.count('class="thumb" alt="v/') == n, page[:2000]
    assert page.count("data:image/jpeg;base64,") >= n
