"""``ldlmap synth`` through Typer's CliRunner: determinism, seeds, and one-line errors."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ldlmap.cli import app
from tests.conftest import TINY

runner = CliRunner()
SMALL = TINY  # --width 64 --per-split 1 --quiet: files and seeds, not images

L_ROOM = """
name = "lroom"
footprint = [[0.0, 0.0], [6.0, 0.0], [6.0, 3.0], [3.0, 3.0], [3.0, 5.0], [0.0, 5.0]]
ceiling_height = 2.7

[[objects]]
kind = "table"
center = [1.5, 1.5]
size = [1.2, 0.8, 0.75]
"""


def hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def synth(*args: str):
    return runner.invoke(app, ["synth", *map(str, args)])


def test_same_seed_identical_files_other_seed_other_rooms(tiny_synth, tmp_path):
    h1 = hashes(tiny_synth)  # `synth --preset demo --seed 1` with SMALL's options (conftest)
    r1b = synth(tmp_path / "s1b", "--seed", "1", *SMALL)  # --preset demo is the default
    assert r1b.exit_code == 0, r1b.output
    assert "synthroom_1" in r1b.output and "extreme_gamma" in r1b.output
    r2 = synth(tmp_path / "s2", "--preset", "demo", "--seed", "2", *SMALL)
    assert r2.exit_code == 0, r2.output
    h1b, h2 = hashes(tmp_path / "s1b"), hashes(tmp_path / "s2")
    assert h1 == h1b
    assert set(h1) == set(h2)
    for f in ("specs/synthroom_1.toml", "specs/synthroom_2.toml", "pcd/synthroom_1.txt", "mesh/synthroom_1.obj"):
        assert h1[f] != h2[f], f
    # An existing non-empty folder needs --overwrite, and stays untouched without it.
    r = synth(tmp_path / "s1b", "--seed", "1", *SMALL)
    assert r.exit_code == 1 and "--overwrite" in r.output
    assert hashes(tmp_path / "s1b") == h1
    r = synth(tmp_path / "s1b", "--seed", "2", "--overwrite", *SMALL)
    assert r.exit_code == 0 and hashes(tmp_path / "s1b") == h2


def test_spec_file_and_no_illumination(tmp_path):
    spec = tmp_path / "l.toml"
    spec.write_text(L_ROOM)
    r = synth(tmp_path / "out", "--spec", spec, "--no-illumination", *SMALL)
    assert r.exit_code == 0, r.output
    assert (tmp_path / "out" / "pcd" / "lroom_1.ply").is_file()
    assert (tmp_path / "out" / "robot_pano" / "robot_lroom_1_scene_1" / "0000.jpg").is_file()
    assert not list((tmp_path / "out").glob("extreme_*_pano"))


BAD_SPECS = {
    "self-intersecting footprint": ("footprint = [[0.0, 0.0], [4.0, 4.0], [4.0, 0.0], [0.0, 4.0]]\n"
                                    "ceiling_height = 2.5\nname = \"bow\"\n", "footprint"),
    "object outside the room": (L_ROOM.replace("center = [1.5, 1.5]", "center = [5.0, 4.5]"), "not inside"),
    "missing field": ("name = \"x\"\nfootprint = [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]]\n", "ceiling_height"),
}


@pytest.mark.parametrize("case", sorted(BAD_SPECS))
def test_bad_spec_one_line_error_nothing_written(tmp_path, case):
    text, needle = BAD_SPECS[case]
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    out = tmp_path / "out"
    r = synth(out, "--spec", spec, *SMALL)
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], r.output
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_unwritable_output_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    r = synth(blocker / "out", *SMALL)
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]
    r = synth(tmp_path / "o", "--preset", "nosuch", *SMALL)
    assert r.exit_code == 1 and "unknown preset" in r.output and not (tmp_path / "o").exists()
