"""`ldlloc localize` and `ldlloc run` under hostile inputs: every numeric option bounded,
bad panoramas, pose files and query lists are one error line with nothing written; large
panoramas are resized on reading; inside `run` a bad panorama fails its query only, a picture
that cannot be written is a warning, --resume retries failed queries; outputs never replace
inputs."""

from __future__ import annotations

import json
import os
import shutil
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlloc.pipeline import WORK_WIDTH, load_image
from tests._hostile import assert_clean_failure, error_line, snapshot

runner = CliRunner()
SCENE = "robot_synthroom_1_scene_1"


def _cuda_case() -> tuple[str, str]:
    """``--device cuda`` here: refused without CUDA; with CUDA, an index this machine lacks."""
    import torch

    return ("cuda:99", "CUDA GPU(s)") if torch.cuda.is_available() else ("cuda", "CUDA is not available")


# (case, extra options, words of the error line); each also for `run` unless marked localize-only
OPTIONS = [
    ("threads negative", ["--threads", "-1"], "--threads must be"),
    ("threads 100000", ["--threads", "100000"], "--threads must be"),
    ("threads 1025", ["--threads", "1025"], "--threads must be"),
    ("top-k 0", ["--top-k", "0"], "--top-k must be"),
    ("top-k negative", ["--top-k", "-5"], "--top-k must be"),
    ("top-k 1001", ["--top-k", "1001"], "--top-k must be"),
    ("top-k 10^9", ["--top-k", "1000000000"], "--top-k must be"),
    ("tilt 0", ["--max-tilt", "0"], "--max-tilt must be"),
    ("tilt negative", ["--max-tilt", "-1"], "--max-tilt must be"),
    ("tilt 181", ["--max-tilt", "181"], "--max-tilt must be"),
    ("tilt nan", ["--max-tilt", "nan"], "--max-tilt must be"),
    ("tilt inf", ["--max-tilt", "inf"], "--max-tilt must be"),
    ("loss", ["--loss", "l3"], "unknown loss"),
    ("refine", ["--refine", "magic"], "unknown --refine"),
    ("query frame", ["--query-frame", "sideways"], "unknown --query-frame"),
    ("device gpu", ["--device", "gpu"], "--device must be"),
    ("device cuda:x", ["--device", "cuda:x"], "--device must be"),
    ("device cuda", ["--device", _cuda_case()[0]], _cuda_case()[1]),
]
LOCALIZE_ONLY = [
    ("vis gif", ["--vis", "{tmp}/v.gif"], "cannot write .gif"),
    ("vis over the panorama", ["--vis", "{pano}"], "would replace the input"),
]
RUN_ONLY = [
    ("output csv", ["--output", "{tmp}/r.csv"], "must name a .json"),
    ("output folder", ["--output", "{tmp}/dir.json"], "is a folder"),
    ("any-options alone", ["--resume-any-options"], "goes with --resume"),
    ("map level", ["--map-level", "house"], "--map-level"),
    ("unknown split", ["--split", "nowhere"], "unknown synthetic split"),  # the demo is a dataset of `ldlmap synth`
    ("unknown scene", ["--scene", "nowhere"], "unknown synthetic scene"),
]


@pytest.fixture
def pano(tmp_path, demo_dataset) -> Path:
    """A demo query panorama copied into ``tmp_path`` (with its pose), so that the checks see a
    folder of inputs that nothing may change."""
    src = demo_dataset / "robot_pano" / SCENE / "0000.jpg"
    shutil.copy(src, tmp_path / "q.jpg")
    shutil.copy(demo_dataset / "robot_pose" / SCENE / "0000.txt", tmp_path / "q.txt")
    (tmp_path / "dir.json").mkdir()
    return tmp_path / "q.jpg"


def _fill(args: list[str], tmp: Path, pano: Path) -> list[str]:
    return [a.format(tmp=tmp, pano=pano) for a in args]


@pytest.mark.parametrize("args, words", [c[1:] for c in OPTIONS + LOCALIZE_ONLY],
                         ids=[c[0] for c in OPTIONS + LOCALIZE_ONLY])
def test_localize_refuses_bad_options(demo_dataset, tmp_path, pano, args, words):
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(pano),
                                  *_fill(args, tmp_path, pano)])
    assert words in assert_clean_failure(res, tmp_path, before)


@pytest.mark.parametrize("args, words", [c[1:] for c in OPTIONS + RUN_ONLY], ids=[c[0] for c in OPTIONS + RUN_ONLY])
def test_run_refuses_bad_options(demo_dataset, tmp_path, pano, args, words):
    before, data = snapshot(tmp_path), snapshot(demo_dataset)
    res = runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "robot",
                                  "--output", str(tmp_path / "r.json"), *_fill(args, tmp_path, pano)])
    assert words in assert_clean_failure(res, tmp_path, before)
    assert snapshot(demo_dataset) == data


# ----------------------------------------------------------------------------- panoramas


def _png_with_size(w: int, h: int) -> bytes:
    """A small PNG whose header claims ``w`` x ``h`` pixels."""
    ok, buf = cv2.imencode(".png", np.zeros((4, 8, 3), np.uint8))
    data = buf.tobytes()
    return data[:16] + struct.pack(">II", w, h) + data[24:]


def _jpeg(shape: tuple, value: int = 90) -> bytes:
    return cv2.imencode(".jpg", np.random.default_rng(0).integers(0, 255, shape, np.uint8))[1].tobytes()


BAD_PANORAMAS = [
    ("missing", None, "image not found"),
    ("folder", "folder", "image is not a file"),
    ("empty", b"", "image file is empty"),
    ("garbage", b"not an image at all", "cannot decode"),
    ("truncated jpeg", _jpeg((64, 128, 3))[:400], "truncated JPEG"),
    ("truncated png", cv2.imencode(".png", np.full((64, 128, 3), 7, np.uint8))[1].tobytes()[:60], "cannot decode"),
    ("huge header", _png_with_size(100000, 50000), "panorama too large"),
    ("1x1", cv2.imencode(".png", np.zeros((1, 1, 3), np.uint8))[1].tobytes(), "width must be 2 x height"),
    ("2x1", cv2.imencode(".png", np.zeros((1, 2, 3), np.uint8))[1].tobytes(), "panorama too small"),
    ("not 2:1", _jpeg((200, 300, 3)), "width must be 2 x height"),
    ("flat grey", cv2.imencode(".png", np.full((256, 512), 128, np.uint8))[1].tobytes(), "too few lines"),
]


@pytest.mark.parametrize("content, words", [c[1:] for c in BAD_PANORAMAS], ids=[c[0] for c in BAD_PANORAMAS])
def test_localize_refuses_bad_panoramas(demo_dataset, tmp_path, content, words):
    img = tmp_path / "p.png"
    if content == "folder":
        img.mkdir()
    elif content is not None:
        img.write_bytes(content)
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(img),
                                  "--vis", str(tmp_path / "v.jpg")])
    assert words in assert_clean_failure(res, tmp_path, before)


# (case, image written by cv2) -> read as uint8 RGB (H, 2H, 3), at most WORK_WIDTH wide
CONVERTED = [
    ("grayscale", np.full((64, 128), 200, np.uint8)),
    ("16-bit", np.full((64, 128, 3), 40000, np.uint16)),
    ("RGBA", np.full((64, 128, 4), 90, np.uint8)),
    ("wider than the working width", np.full((1200, 2400, 3), 90, np.uint8)),
]


@pytest.mark.parametrize("pixels", [c[1] for c in CONVERTED], ids=[c[0] for c in CONVERTED])
def test_panoramas_of_other_kinds_are_read_as_rgb(tmp_path, pixels):
    cv2.imwrite(str(tmp_path / "p.png"), pixels)
    img = load_image(tmp_path / "p.png")
    w = min(pixels.shape[1], WORK_WIDTH)
    assert img.dtype == np.uint8 and img.shape == (w // 2, w, 3)


def test_an_8192_panorama_localizes(demo_dataset, tmp_path):
    """8192 x 4096 crashed OpenCV's remap: it is resized to the working width when read. A --vis
    picture that cannot be written does not take the result with it."""
    src = demo_dataset / "robot_pano" / SCENE / "0000.jpg"
    big = cv2.resize(cv2.imread(str(src)), (8192, 4096), interpolation=cv2.INTER_LINEAR)
    cv2.imwrite(str(tmp_path / "big.jpg"), big)
    (tmp_path / "blocked").write_text("a file where the picture's folder should be")
    res = runner.invoke(loc_app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(tmp_path / "big.jpg"),
                                  "--json", "--gt", str(demo_dataset / "robot_pose" / SCENE / "0000.txt"),
                                  "--vis", str(tmp_path / "blocked" / "v.jpg")])
    assert res.exit_code == 0, res.output  # the picture cannot be written: a warning beside the result
    out = json.loads(res.output)
    assert out["t_error_m"] < 0.1 and out["r_error_deg"] < 5 and "blocked" in out["picture_error"]


# ----------------------------------------------------------------------------- pose files

BAD_POSES = [
    ("empty", "q.txt", "", "got empty"),
    ("binary", "q.txt", "\x00\xff\xfe", "cannot read pose file"),
    ("2x2", "q.txt", "1 0\n0 1\n", "got 2x2"),
    ("ragged", "q.txt", "1 0 0 0\n0 1 0\n0 0 1 0\n", "expected a 3x4 matrix"),
    ("NaN", "q.txt", "1 0 0 nan\n0 1 0 0\n0 0 1 0\n", "non-finite"),
    ("1e999", "q.txt", "1 0 0 1e999\n0 1 0 0\n0 0 1 0\n", "non-finite"),
    ("not a rotation", "q.txt", "2 0 0 0\n0 1 0 0\n0 0 1 0\n", "not a proper rotation"),
    ("mirror", "q.txt", "-1 0 0 0\n0 1 0 0\n0 0 1 0\n", "not a proper rotation"),
    ("huge", "q.txt", "1 0 0 0\n" * 300_000, "not a pose file"),
    ("json list", "q_pose.json", "[1, 2, 3]", "must be an object"),
    ("json deep", "q_pose.json", "[" * 50_000 + "]" * 50_000, "nested too deeply"),
    ("json keys", "q_pose.json", '{"camera_location": [0, 0, 0]}', "lacks a numeric"),
    ("json 2 values", "q_pose.json", '{"camera_location": [0, 0], "final_camera_rotation": [0, 0, 0]}',
     "3 values each"),
    ("other format", "q.yaml", "R: []", "unsupported pose file"),
    ("folder", "posedir.txt", None, "pose file is a folder"),
]


@pytest.mark.parametrize("name, text, words", [c[1:] for c in BAD_POSES], ids=[c[0] for c in BAD_POSES])
def test_localize_refuses_bad_pose_files(demo_dataset, tmp_path, pano, name, text, words):
    gt = tmp_path / name
    if text is None:
        gt.mkdir()
    else:
        gt.write_bytes(text.encode("latin-1"))
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(pano),
                                  "--gt", str(gt), "--vis", str(tmp_path / "v.jpg")])
    assert words in assert_clean_failure(res, tmp_path, before)


# ----------------------------------------------------------------------------- query lists (run)


def _tiny_root(tmp_path: Path, demo: Path, images: dict[str, bytes | None] | None = None) -> Path:
    """An OmniScenes-like root with the robot split of synthroom_1 (``images``: name -> bytes to
    write instead, None to copy the demo's 0000.jpg) and the demo's maps."""
    root = tmp_path / "data"
    for kind in ("pano", "pose"):
        (root / f"robot_{kind}" / SCENE).mkdir(parents=True)
    src = demo / "robot_pano" / SCENE / "0000.jpg"
    for name, content in (images or {"0000": None}).items():
        (root / "robot_pano" / SCENE / f"{name}.jpg").write_bytes(src.read_bytes() if content is None else content)
        shutil.copy(demo / "robot_pose" / SCENE / "0000.txt", root / "robot_pose" / SCENE / f"{name}.txt")
    (root / "maps").mkdir()
    return root


BAD_LISTS = [
    ("pose missing", lambda r: (r / "robot_pose" / SCENE / "0000.txt").unlink(), "no pose file for query"),
    ("pose malformed", lambda r: (r / "robot_pose" / SCENE / "0000.txt").write_text("1 2"), "malformed pose file"),
    ("odd scene folder", lambda r: (r / "robot_pano" / "robot_weird").mkdir(), "unrecognised OmniScenes scene"),
    ("pose a folder", lambda r: ((r / "robot_pose" / SCENE / "0000.txt").unlink(),
                                 (r / "robot_pose" / SCENE / "0000.txt").mkdir()), "no pose file for query"),
]


@pytest.mark.parametrize("spoil, words", [c[1:] for c in BAD_LISTS], ids=[c[0] for c in BAD_LISTS])
def test_run_refuses_bad_query_lists(demo_dataset, tmp_path, spoil, words):
    root = _tiny_root(tmp_path, demo_dataset)
    spoil(root)
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["run", "--root", str(root), "--output", str(tmp_path / "r.json")])
    assert words in assert_clean_failure(res, tmp_path, before)


def test_run_outputs_never_replace_inputs(demo_dataset, tmp_path):
    """A picture that would land on a query's panorama (through a linked folder) is refused: query
    ``robot/synthroom_1_scene_1/a``'s picture ``vis/robot/synthroom_1_scene_1/a.jpg`` is its panorama."""
    root = _tiny_root(tmp_path, demo_dataset, {"a": None, "synthroom_1_a": None})
    (tmp_path / "vis" / "robot").mkdir(parents=True)
    os.symlink(root / "robot_pano" / SCENE, tmp_path / "vis" / "robot" / "synthroom_1_scene_1")
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["run", "--root", str(root), "--output", str(tmp_path / "r.json"),
                                  "--save-vis", str(tmp_path / "vis")])
    assert "would replace the input" in assert_clean_failure(res, tmp_path, before)


def test_run_keeps_results_through_bad_inputs_and_resumes(demo_dataset, tmp_path):
    """One run: a good, an 8192-wide and a corrupt panorama, a picture folder that cannot be made and
    a missing map. Without any map nothing runs (one line says how to build them); once the map is
    there the corrupt one fails alone, the pictures are warnings, the results stay, and --resume
    retries the failed query (and says so)."""
    good = (demo_dataset / "robot_pano" / SCENE / "0000.jpg").read_bytes()
    big = cv2.imencode(".jpg", cv2.resize(cv2.imdecode(np.frombuffer(good, np.uint8), cv2.IMREAD_COLOR),
                                          (8192, 4096)))[1].tobytes()
    root = _tiny_root(tmp_path, demo_dataset, {"0000": good, "0001": big, "0002": b"\xff\xd8 corrupt"})
    (tmp_path / "vis").write_text("a file where the picture folder should be")
    out = tmp_path / "r.json"
    run = ["run", "--root", str(root), "--output", str(out), "--save-vis", str(tmp_path / "vis")]
    assert "no maps for the queries' 1 scene(s)" in error_line(runner.invoke(loc_app, run))
    assert not out.exists()
    shutil.copy(demo_dataset / "maps" / "synthroom_1.h5", root / "maps" / "synthroom_1.h5")
    res = runner.invoke(loc_app, run)
    assert res.exit_code == 0, res.output
    assert res.output.count("warning: picture of") == 1 and "2 pictures not written" in res.output
    res = runner.invoke(loc_app, [*run, "--resume"])
    assert res.exit_code == 0, res.output
    assert "2 of 3 queries done, 0 to run, 1 failed ones retried" in res.output
    qs = {q["name"].rsplit("/", 1)[1]: q for q in json.loads(out.read_text())["queries"]}
    assert qs["0002"]["status"] == "failed" and "truncated JPEG" in qs["0002"]["message"]
    for name in ("0000", "0001"):
        assert qs[name]["status"] == "ok" and qs[name]["t_error_m"] < 0.1, qs[name]
        assert "Not a directory" in qs[name]["picture_error"] or "folder" in qs[name]["picture_error"]
    assert out.with_suffix(".csv").read_text().count("\n") == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "r.csv", "r.json", "vis"]
