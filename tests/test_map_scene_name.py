"""A map's scene has one name: `ldlmap build ... -o maps/room.h5` stores "room" (the output's
stem, what `ldlloc run --maps` calls it), `ldlmap info` shows it, and a file renamed since shows
the name `run` uses with the stored one beside it."""

from __future__ import annotations

import shutil

import numpy as np
from typer.testing import CliRunner

from ldlloc.batch.which_map import MapSet
from ldlloc.pipeline import LocalizeParams
from ldlmap.cli import app as map_app
from ldlmap.io.linefiles import write_lines_txt
from ldlmap.map.mapfile import read_map

runner = CliRunner()


def _room_lines() -> np.ndarray:
    """The 12 edges of a 4 x 3 x 2.5 m box and a door frame."""
    c = np.array([[x, y, z] for x in (0, 4) for y in (0, 3) for z in (0, 2.5)], float)
    edges = [[c[a], c[b]] for a in range(8) for b in range(a + 1, 8) if np.sum(c[a] != c[b]) == 1]
    edges += [[[1, 0, 0], [1, 0, 2]], [[2, 0, 0], [2, 0, 2]], [[1, 0, 2], [2, 0, 2]]]
    return np.array(edges, float)


def _scene_row(output: str) -> str:
    row = next(line for line in output.splitlines() if line.strip(" │|").startswith("scene"))
    return row.strip(" │|").removeprefix("scene").strip(" │|")


def test_build_names_the_scene_after_its_output_and_info_and_run_agree(tmp_path):
    scan = tmp_path / "scan.txt"  # the input's stem ("scan") must not become the scene's name
    write_lines_txt(scan, _room_lines())
    maps = tmp_path / "maps"
    r = runner.invoke(map_app, ["build", str(scan), "-o", str(maps / "room.h5"), "--features", "none",
                                "--num-trans", "30", "--up", "z"])
    assert r.exit_code == 0, r.output
    assert read_map(maps / "room.h5", load_cloud=False).name == "room"
    info = runner.invoke(map_app, ["info", str(maps / "room.h5")])
    assert info.exit_code == 0, info.output
    assert _scene_row(info.output) == "room"
    (entry,) = MapSet.load(maps, LocalizeParams()).entries
    assert entry.scene == "room"

    shutil.move(maps / "room.h5", maps / "kitchen.h5")  # renamed: run calls it kitchen, and so does info first
    info = runner.invoke(map_app, ["info", str(maps / "kitchen.h5")])
    assert _scene_row(info.output).startswith("kitchen (stored as 'room'")
    assert MapSet.load(maps, LocalizeParams()).entries[0].scene == "kitchen"


def test_build_without_output_names_the_scene_after_the_input(tmp_path):
    lines = tmp_path / "hall.txt"
    write_lines_txt(lines, _room_lines())
    r = runner.invoke(map_app, ["build", str(lines), "--features", "none", "--num-trans", "30", "--up", "z"])
    assert r.exit_code == 0, r.output
    assert read_map(tmp_path / "hall.h5", load_cloud=False).name == "hall"
