"""Write paths of the ldlmap commands: an output never replaces an input (nor a file
written beside it, nor a folder holding one), an existing file of another kind is replaced only
with --overwrite, and the temporaries of killed runs are removed by the next run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ldlmap.cli import app
from ldlmap.core.errors import LdlError, atomic_dir, atomic_file, refuse_overwriting_inputs, remove_stale_temporaries
from tests._hostile import assert_clean_failure, snapshot

runner = CliRunner()
CLOUD = "0 0 0\n1 0 0\n0 1 0\n0 0 1\n"  # refused before it is read: any content would do
LINE_FILE = "# ldl lines v1\n0 0 0 1 0 0\n0 0 0 0 1 0\n"


def _files(root: Path) -> None:
    """The inputs the cases name: a scan as .txt (OmniScenes keeps them so), .ply and mesh .obj, a
    line file, a spec, links to them, and a synthetic dataset holding a spec."""
    (root / "pcd").mkdir()
    (root / "pcd" / "scan.txt").write_text(CLOUD)
    (root / "scan.ply").write_text(CLOUD)
    (root / "mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (root / "lines.txt").write_text(LINE_FILE)
    os.symlink(root / "pcd" / "scan.txt", root / "alias.txt")
    os.link(root / "scan.ply", root / "hard.ply")
    (root / "ds").mkdir()
    (root / "ds" / "dataset.json").write_text(json.dumps({"generator": "ldlmap.synth"}))
    (root / "ds" / "room.toml").write_text((Path(__file__).parents[1] / "datasets/synthetic/l_room.toml").read_text())
    (root / "notes.txt").write_text("my notes\n")
    (root / "folder").mkdir()


# (arguments with {r} for the folder, what the error says)
REPLACING_INPUTS = [
    (["lines", "{r}/pcd/scan.txt", "-o", "{r}/pcd/scan.obj"], "would replace the input"),  # the .txt beside
    (["lines", "{r}/pcd/scan.txt", "-o", "{r}/pcd/scan"], "would replace the input"),
    (["lines", "{r}/mesh.obj", "-o", "{r}/mesh.obj"], "would replace the input"),
    (["lines", "{r}/pcd/scan.txt", "-o", "{r}/alias.obj"], "would replace the input"),  # symlink to the scan
    (["lines", "{r}/scan.ply", "-o", "{r}/out.obj", "--png", "{r}/scan.ply"], "cannot write .ply pictures"),
    (["build", "{r}/scan.ply", "-o", "{r}/scan.ply"], "would replace the input"),
    (["build", "{r}/scan.ply", "-o", "{r}/hard.ply"], "would replace the input"),  # hard link
    (["build", "{r}/scan.ply", "-o", "{r}/./pcd/../scan.ply"], "would replace the input"),
    (["build", "{r}/scan.ply", "--lines", "{r}/lines.txt", "-o", "{r}/lines.txt"], "would replace the input"),
    (["build", "{r}/lines.txt", "-o", "{r}/lines.txt"], "would replace the input"),
    (["build", "{r}/pcd/scan.txt", "-o", "{r}/pcd"], "would replace the folder"),
    (["synth", "{r}/ds", "--spec", "{r}/ds/room.toml", "--overwrite"], "would replace the folder"),
    (["synth", "{r}", "--spec", "{r}/ds/room.toml", "--overwrite"], "would replace the folder"),
    # An existing file of another kind is replaced only with --overwrite; a folder never.
    (["lines", "{r}/scan.ply", "-o", "{r}/notes.obj"], "notes.txt exists and is not a 3D line file"),
    (["build", "{r}/scan.ply", "-o", "{r}/notes.txt"], "exists and is not an LDL map"),
    (["build", "{r}/scan.ply", "-o", "{r}/folder"], "is a folder"),
    (["synth", "{r}", "--overwrite"], "is not a dataset written by `ldlmap synth`"),
    (["synth", "{r}/folder/..", "--overwrite"], "is not a dataset written by `ldlmap synth`"),
    (["synth", "{r}/ds"], "output folder is not empty"),
    (["synth", "{r}/notes.txt", "--overwrite"], "is not a folder"),
    # A failed run leaves an existing output as it was (lines.txt: a line file it may replace).
    (["lines", "{r}/scan.ply", "-o", "{r}/lines.obj"], "scan.ply"),
]


@pytest.mark.parametrize("args,says", REPLACING_INPUTS, ids=[" ".join(a[:1] + a[-2:]) for a, _ in REPLACING_INPUTS])
def test_an_output_never_replaces_an_input(tmp_path, args, says):
    _files(tmp_path)
    before = snapshot(tmp_path)
    res = runner.invoke(app, [a.format(r=tmp_path) for a in args])
    assert says in assert_clean_failure(res, tmp_path, before)


def test_prepare_refuses_a_map_path_that_is_a_scan(tmp_path):
    """A scene whose map would replace its own scan (here through a link) fails, the scan intact."""
    (tmp_path / "pcd").mkdir()
    (tmp_path / "pcd" / "room_1.txt").write_text(CLOUD)
    (tmp_path / "maps").mkdir()
    os.symlink(tmp_path / "pcd" / "room_1.txt", tmp_path / "maps" / "room_1.h5")
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["prepare", str(tmp_path), "--dataset", "omniscenes"])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "would replace the input" in res.output
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("inputs,outputs,refused", [
    (["a.txt"], ["a.obj", "a.txt"], True),
    (["a.txt"], ["b.txt"], False),
    (["a.txt"], ["."], True),  # a folder replaced whole that holds the input
    (["sub/a.txt"], ["sub"], True),
    (["sub"], ["sub/map.h5"], False),  # writing into an input folder replaces nothing
    ([None, "a.txt"], [None, "c.txt"], False),
])
def test_refuse_overwriting_inputs(tmp_path, monkeypatch, inputs, outputs, refused):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    if refused:
        with pytest.raises(LdlError, match="would replace"):
            refuse_overwriting_inputs(inputs, outputs)
    else:
        refuse_overwriting_inputs(inputs, outputs)


# ----------------------------------------------------------------- temporaries of killed runs

_WRITER = textwrap.dedent("""
    import sys, time
    from ldlmap.core.errors import atomic_dir, atomic_file
    target, kind = sys.argv[1], sys.argv[2]
    with (atomic_file(target) if kind == "file" else atomic_dir(target)) as tmp:
        if kind == "file":
            tmp.write_bytes(b"half" * 1000)
        else:
            (tmp / "part.txt").write_text("half")
        print(tmp, flush=True)
        time.sleep(60)
""")


def _start_writer(target: Path, kind: str) -> tuple[subprocess.Popen, Path]:
    """A process stopped inside an atomic write of ``target``, and its temporary."""
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(target), kind], stdout=subprocess.PIPE, text=True)
    return proc, Path(proc.stdout.readline().strip())


@pytest.mark.parametrize("kind", ["file", "dir"])
def test_temporaries_of_a_killed_run_are_removed_by_the_next(tmp_path, kind):
    target = tmp_path / ("map.h5" if kind == "file" else "dataset")
    killed, killed_tmp = _start_writer(target, kind)
    live, live_tmp = _start_writer(target, kind)
    try:
        killed.send_signal(signal.SIGKILL)
        killed.wait()
        assert killed_tmp.exists() and not target.exists()  # SIGKILL: no clean-up, no half output
        writer = atomic_file(target) if kind == "file" else atomic_dir(target)
        with writer as tmp:
            assert not killed_tmp.exists()  # the dead run's temporary is gone ...
            assert live_tmp.exists()  # ... a live run's is not touched
            tmp.write_text("new") if kind == "file" else (tmp / "x").write_text("new")
        assert target.exists() and live_tmp.exists()
    finally:
        live.kill()
        live.wait()


def test_only_temporaries_of_this_host_and_target_are_removed(tmp_path):
    from ldlmap.core.errors import _host

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    names = {f".map.ldltmp.{_host()}.{dead}.abc123.tmp.h5": True,  # ours, process gone
             f".map.ldltmp.otherhost.{dead}.abc123.tmp.h5": False,  # another machine's (shared folder)
             f".map.ldltmp.{_host()}.{os.getpid()}.abc123.tmp.h5": False,  # a live process
             f".other.ldltmp.{_host()}.{dead}.abc123.tmp.h5": False,  # another output's
             ".map.abc123.tmp.h5": False,  # not named by us
             "map.h5": False}
    for name in names:
        (tmp_path / name).write_text("x")
    removed = remove_stale_temporaries(tmp_path / "map.h5", ".h5")
    assert sorted(p.name for p in removed) == sorted(n for n, gone in names.items() if gone)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(n for n, gone in names.items() if not gone)


def test_lines_replaces_its_own_outputs_and_the_stale_temporaries(tmp_path):
    """A second `ldlmap lines` replaces the line files of the first (no --overwrite needed) and
    removes what a killed run left."""
    import numpy as np

    from ldlmap.core.errors import _host
    from tests._room_cloud import box_room

    pts, _ = box_room(seed=1, size=(3.0, 2.5, 2.4), n_boxes=1, density=600.0)
    np.savetxt(tmp_path / "room.xyz.txt", pts, fmt="%.4f")
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = tmp_path / f".lines.ldltmp.{_host()}.{dead}.zz.tmp.obj"
    stale.write_text("half")
    args = ["lines", str(tmp_path / "room.xyz.txt"), "-o", str(tmp_path / "lines.obj")]
    assert runner.invoke(app, args).exit_code == 0
    first = (tmp_path / "lines.txt").read_text()
    time.sleep(0.01)
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "lines.txt").read_text() == first and not stale.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lines.obj", "lines.txt", "room.xyz.txt"]
