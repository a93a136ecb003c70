"""Reading panoramas (``ldlmap.io.imagefile``, ``ldlloc.pipeline.load_image``): a JPEG whose data
was cut short (its end marker kept) is a corrupt image, a ``failed`` record in a run, and libjpeg's
warning never reaches the terminal; a file name that is not UTF-8 is read (OpenCV never sees the
path: it crashed with SIGSEGV), and a run over such a folder finishes, and resumes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ldlloc.cli import app
from ldlloc.pipeline import load_image
from ldlmap.core.errors import InputError
from ldlmap.io.imagefile import read_image

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]


def a_panorama(demo_dataset) -> Path:
    return sorted((demo_dataset / "robot_pano").rglob("*.jpg"))[0]


def truncated(src: Path, dst: Path) -> Path:
    """``src`` with two thirds of its data cut and its end marker kept."""
    data = src.read_bytes()
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_bytes(data[: len(data) // 3] + b"\xff\xd9")
    return dst


def test_a_truncated_jpeg_is_corrupt_and_says_nothing_on_stderr(demo_dataset, tmp_path, capfd):
    bad = truncated(a_panorama(demo_dataset), tmp_path / "cut.jpg")
    with pytest.raises(InputError, match=r"corrupt image data \(Corrupt JPEG data: premature end of data segment\)"):
        load_image(bad)
    assert load_image(a_panorama(demo_dataset)).shape[1] == 2 * load_image(a_panorama(demo_dataset)).shape[0]
    assert "Corrupt JPEG" not in capfd.readouterr().err


def test_a_truncated_jpeg_is_a_failed_record(demo_dataset, tmp_path, capfd):
    truncated(a_panorama(demo_dataset), tmp_path / "shots" / "cut.jpg")
    out = tmp_path / "r.json"
    runner.invoke(app, ["run", "--images", str(tmp_path / "shots"), "--maps",
                        str(demo_dataset / "maps" / "synthroom_1.h5"), "-o", str(out)])
    (rec,) = json.loads(out.read_text())["queries"]
    assert rec["status"] == "failed" and "corrupt image data" in rec["message"]
    assert "Corrupt JPEG" not in capfd.readouterr().err


def test_other_decoder_output_is_passed_on(tmp_path, capfd):
    """Only libjpeg's damage warnings are taken; an image that decodes cleanly says nothing."""
    import cv2
    import numpy as np

    ok, buf = cv2.imencode(".png", np.zeros((8, 16, 3), np.uint8))
    (tmp_path / "a.png").write_bytes(buf.tobytes())
    assert read_image(tmp_path / "a.png").shape == (8, 16, 3)
    assert read_image(tmp_path / "a.png", cv2.IMREAD_GRAYSCALE).shape == (8, 16)
    assert capfd.readouterr().err == ""


def test_a_file_name_that_is_not_utf8_is_read_and_the_run_finishes(demo_dataset, tmp_path):
    """In a child process: before, OpenCV crashed on the name (SIGSEGV, exit -11), again on --resume."""
    shots = tmp_path / "shots"
    shots.mkdir()
    name = os.fsdecode(b"z\xff.jpg")
    (shots / name).write_bytes(a_panorama(demo_dataset).read_bytes())
    out = tmp_path / "r.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
           "COLUMNS": "200"}
    cmd = [sys.executable, "-m", "ldlloc.cli", "run", "--images", str(shots), "--maps",
           str(demo_dataset / "maps" / "synthroom_1.h5"), "-o", str(out)]
    first = subprocess.run([*cmd, "--save-vis", str(tmp_path / "vis")], env=env, capture_output=True, timeout=600)
    assert first.returncode == 0, first.stdout[-2000:] + first.stderr[-2000:]
    assert (tmp_path / "vis" / os.fsdecode(b"z\xff.jpg")).stat().st_size > 0  # its picture too
    (rec,) = json.loads(out.read_text())["queries"]
    assert rec["name"] == os.fsdecode(b"z\xff") and rec["status"] != "failed", rec["message"]
    assert b"z\xff" in out.with_suffix(".csv").read_bytes()  # the CSV holds the name's own bytes
    again = subprocess.run([*cmd, "--save-vis", str(tmp_path / "vis"), "--resume"], env=env, capture_output=True,
                           timeout=600)
    assert again.returncode == 0 and b"1 of 1 queries done" in again.stdout, again.stderr[-2000:]
