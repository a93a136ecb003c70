"""COLMAP image names an export writes are read back by pycolmap exactly as written, or refused in
one line before anything is written: a text model (`--text`) cannot hold white space or control
characters in a name (COLMAP reads `my pano 1.jpg` as `my`), no model a name that is not UTF-8."""

from __future__ import annotations

import os
from pathlib import Path

import pycolmap
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from tests._hostile import error_line, snapshot
from tests._results_files import record, write_panorama, write_results

runner = CliRunner()

# (case, file name, binary model: read back identically, text model: read back identically)
NAMES = [
    ("space", "my pano 1.jpg", True, False),
    ("tab", "tab\tpano.jpg", True, False),
    ("newline", "new\nline.jpg", True, False),
    ("leading space", " lead.jpg", True, False),
    ("comma", "a,b.jpg", True, True),
    ("double quote", 'q"x.jpg', True, True),
    ("single quote", "q'x.jpg", True, True),
    ("hash", "#1.jpg", True, True),
    ("accents", "salle à manger.jpg", True, False),
    ("accents, no space", "séjour.jpg", True, True),
    ("not UTF-8", os.fsdecode(b"z\xff.jpg"), False, False),
]


@pytest.mark.parametrize("name, binary_ok, text_ok", [c[1:] for c in NAMES], ids=[c[0] for c in NAMES])
@pytest.mark.parametrize("text", [False, True], ids=["binary", "text"])
def test_names_read_back_identically_or_are_refused(tmp_path, name, binary_ok, text_ok, text):
    shots = [write_panorama(tmp_path / "shots" / name), write_panorama(tmp_path / "shots" / "plain.jpg")]
    results = write_results(tmp_path / "r.json", [record(f"q{i}", s) for i, s in enumerate(shots)])
    out = tmp_path / "model"
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["export", str(results), "--format", "colmap", "-o", str(out),
                                  *(["--text"] if text else [])])
    if text_ok if text else binary_ok:
        assert res.exit_code == 0, res.output
        back = sorted(im.name for im in pycolmap.Reconstruction(str(out)).images.values())
        assert back == sorted([name, "plain.jpg"])
    else:
        line = error_line(res)
        assert repr(name) in line and ("--text" in line or "UTF-8" in line), line
        assert snapshot(tmp_path) == before  # nothing written


def test_the_written_model_is_checked_against_what_was_meant(tmp_path, monkeypatch):
    """A writer that drops a name's end (as COLMAP's text reader does at a space) is caught by the
    read-back, whatever the cause."""
    from ldlloc.export.colmap import check_written_model
    from ldlmap.core.errors import LdlError

    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_id(1, pycolmap.CameraModelId.EQUIRECTANGULAR, 0.0, 64, 32)
    rec.add_camera_with_trivial_rig(cam)
    rec.add_image_with_trivial_frame(pycolmap.Image(name="a b.jpg", camera_id=1, image_id=1), pycolmap.Rigid3d())
    folder = tmp_path / "m"
    folder.mkdir()
    rec.write_text(str(folder))
    with pytest.raises(LdlError, match="reads back other than written"):
        check_written_model(folder, rec, True, Path("OUT"))
