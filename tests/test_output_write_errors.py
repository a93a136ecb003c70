"""A disk that fills up while an output is written: one line naming the output (`error: no space
left on device writing PATH`), exit 1, no "wrote", the earlier output (or none) left as it was, no
temporary behind. pycolmap reports no write error (a full disk leaves 0-byte files): the model is
read back before it replaces anything. The full disk is simulated: pycolmap's writer truncating its
files as a full disk does, Python's writes raising ``OSError(ENOSPC)``."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from tests._hostile import error_line, snapshot
from tests._results_files import record, write_panorama, write_results

runner = CliRunner()


def _invoke(args: list):
    return runner.invoke(loc_app, [str(a) for a in args])


@pytest.fixture
def results(tmp_path) -> Path:
    shots = [write_panorama(tmp_path / "shots" / f"p{i}.jpg") for i in range(3)]
    return write_results(tmp_path / "r.json", [record(f"p{i}", s, t=(i, 0.0, 1.5)) for i, s in enumerate(shots)])


@pytest.fixture
def pycolmap_on_a_full_disk(monkeypatch):
    """pycolmap's writers as on a full disk: the files are created, their content lost (0 bytes),
    no error raised; ``os.statvfs`` says no block is free."""

    def truncating(write):
        def run(self, path):
            write(self, path)
            for f in Path(path).iterdir():
                f.write_bytes(b"")
        return run

    for name in ("write_binary", "write_text"):
        monkeypatch.setattr(pycolmap.Reconstruction, name, truncating(getattr(pycolmap.Reconstruction, name)))
    real = os.statvfs

    class Full:
        def __init__(self, st):
            self.f_frsize, self.f_bavail = st.f_frsize, 0

    monkeypatch.setattr(os, "statvfs", lambda p: Full(real(p)))


def _no_temporaries(folder: Path) -> bool:
    return not any(".ldltmp." in p.name for p in folder.rglob("*"))


def test_colmap_overwrite_on_a_full_disk_keeps_the_good_model(results, tmp_path, monkeypatch):
    out = tmp_path / "model"
    res = _invoke(["export", results, "--format", "colmap", "-o", out])
    assert res.exit_code == 0, res.output
    good = snapshot(out)
    with monkeypatch.context() as m:
        m.setattr(pycolmap.Reconstruction, "write_binary", _truncated_write)
        res = _invoke(["export", results, "--format", "colmap", "-o", out, "--overwrite"])
    line = error_line(res)
    assert f"could not write the COLMAP model {out}" in line and "missing or empty" in line
    assert "wrote" not in res.output
    assert snapshot(out) == good and len(pycolmap.Reconstruction(str(out)).images) == 3
    assert _no_temporaries(tmp_path)


_REAL_WRITE_BINARY = pycolmap.Reconstruction.write_binary


def _truncated_write(rec, path) -> None:
    """pycolmap's binary write whose files come out empty (what a full disk does)."""
    _REAL_WRITE_BINARY(rec, path)
    for f in Path(path).iterdir():
        f.write_bytes(b"")


@pytest.mark.parametrize("text", [False, True], ids=["binary", "text"])
def test_colmap_on_a_full_disk_names_the_output(results, tmp_path, pycolmap_on_a_full_disk, text):
    out = tmp_path / "new_model"
    before = snapshot(tmp_path)
    res = _invoke(["export", results, "--format", "colmap", "-o", out, *(["--text"] if text else [])])
    assert error_line(res) == f"error: no space left on device writing {out}"
    assert "wrote" not in res.output and not out.exists() and snapshot(tmp_path) == before


def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


# (format, output name, the module and function that writes the file)
PYTHON_WRITERS = [
    ("nerfstudio", "transforms.json", "ldlloc.export.nerfstudio", "write_transforms"),
    ("ply", "cams.ply", "ldlloc.export.ply", "write_cameras_ply"),
]


@pytest.mark.parametrize("fmt, name, module, func", PYTHON_WRITERS, ids=[c[0] for c in PYTHON_WRITERS])
def test_export_files_on_a_full_disk(results, tmp_path, monkeypatch, fmt, name, module, func):
    import importlib

    out = tmp_path / name
    out.write_bytes(b"the earlier export")
    monkeypatch.setattr(importlib.import_module(module), func, _enospc)
    before = snapshot(tmp_path)
    res = _invoke(["export", results, "--format", fmt, "-o", out, "--overwrite"])
    assert error_line(res) == f"error: no space left on device writing {out}"
    assert snapshot(tmp_path) == before


def test_report_html_on_a_full_disk(results, tmp_path, monkeypatch):
    page = tmp_path / "report.html"
    monkeypatch.setattr(Path, "write_text", _enospc)
    res = _invoke(["report", results, "--html", page])  # the tables first, then the error
    assert res.exit_code == 1 and "Traceback" not in res.output and "wrote" not in res.output
    assert res.output.splitlines()[-1] == f"error: no space left on device writing {page}"
    assert not page.exists() and _no_temporaries(tmp_path)


def test_picture_on_a_full_disk_names_the_picture(tmp_path, monkeypatch):
    import builtins

    from ldlmap.core.errors import WriteError
    from ldlmap.core.pictures import write_picture

    real_open = builtins.open

    def full_open(file, mode="r", *args, **kwargs):
        f = real_open(file, mode, *args, **kwargs)
        if "w" in mode and "b" in mode:
            f.write = _enospc
        return f

    monkeypatch.setattr(builtins, "open", full_open)
    with pytest.raises(WriteError, match=f"no space left on device writing {tmp_path / 'p.jpg'}") as caught:
        write_picture(tmp_path / "p.jpg", np.zeros((32, 64, 3), np.uint8))
    assert isinstance(caught.value, OSError) and caught.value.errno == errno.ENOSPC
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []
