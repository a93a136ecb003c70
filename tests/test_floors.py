"""Where a camera can stand in height: floors found from the lines, the camera-height band above
each (ldlmap/map/floors.py), layouts kept z-up (ldlmap/sfm/gravity.py), candidates only in the band."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlmap.cli import app
from ldlmap.io.linefiles import write_lines
from ldlmap.map.build import BuildParams, build_lines_map
from ldlmap.map.floors import DEFAULT_CAMERA_HEIGHT, find_floors, height_above_floor
from ldlmap.map.mapfile import read_map
from ldlmap.sfm.gravity import estimate_up, map_rotation
from ldlmap.synth.edges import mesh_edges
from ldlmap.synth.furnished import furnished_spec, layout_spec
from ldlmap.synth.scene import build_scene

runner = CliRunner()


def box_shell(x: float, y: float, z0: float, h: float) -> np.ndarray:
    """The 12 creases of an empty x-by-y room whose floor is at ``z0``, ``h`` tall."""
    c = np.array([[0, 0], [x, 0], [x, y], [0, y]], float)
    out = []
    for i in range(4):
        a, b = c[i], c[(i + 1) % 4]
        for z in (z0, z0 + h):
            out.append([[*a, z], [*b, z]])
        out.append([[*a, z0], [*a, z0 + h]])
    return np.asarray(out)


def cabinets(z0: float) -> np.ndarray:
    """Upper kitchen cabinets: vertical sides that start 1.4 m above the floor at ``z0``."""
    return np.asarray([[[x, 0.3, z0 + 1.4], [x, 0.3, z0 + 2.2]] for x in np.linspace(0.5, 3.5, 8)])


def test_floors_are_where_vertical_lines_begin():
    """One floor at any height (a layout in a building's frame at z = -3.5), cabinets do not make a
    floor, two storeys make two, and heights are measured from the floor under each point."""
    assert np.allclose(find_floors(box_shell(4, 3, -3.5, 2.6)), [-3.5])
    assert np.allclose(find_floors(np.concatenate([box_shell(4, 3, 0.0, 2.6), cabinets(0.0)])), [0.0])
    two = np.concatenate([box_shell(6, 5, 0.0, 2.8), box_shell(6, 5, 3.0, 2.8), cabinets(3.0)])
    floors = find_floors(two)
    assert np.allclose(floors, [0.0, 3.0])
    assert np.allclose(height_above_floor(np.array([1.5, 4.5, 2.9, -0.5]), floors), [1.5, 1.5, 2.9, -0.5])
    horizontal_only = box_shell(4, 3, 1.0, 2.6)[[0, 1, 3, 4]]  # no vertical line: the lowest ends
    assert np.allclose(find_floors(horizontal_only), [1.0])


def test_a_layout_below_zero_gets_its_band_above_its_own_floor(tmp_path):
    """``ldlmap build`` of a line file whose floor is at z = -3.5: the default band and a given one
    are measured from that floor (today's z = 0 would leave no candidate)."""
    write_lines(tmp_path / "room.obj", box_shell(4, 3, -3.5, 2.6))
    for band, (lo, hi) in ((None, DEFAULT_CAMERA_HEIGHT), ("1.2:1.6", (1.2, 1.6))):
        out = tmp_path / f"room_{band is None}.h5"
        res = runner.invoke(app, ["build", str(tmp_path / "room.obj"), "-o", str(out), "--trans-spacing", "0.5",
                                  *(["--camera-height", band] if band else [])], terminal_width=200)
        assert res.exit_code == 0, res.output
        m = read_map(out)
        z = m.translations[:, 2] + 3.5
        assert len(z) > 20 and z.min() >= lo - 1e-6 and z.max() <= hi + 1e-6, (z.min(), z.max())
        assert m.config["translations"]["floors"] == [-3.5]
        assert m.camera_height_band == pytest.approx((-3.5 + lo, -3.5 + hi))
    res = runner.invoke(app, ["build", str(tmp_path / "room.obj"), "-o", str(tmp_path / "high.h5"),
                              "--camera-height", "3:4"])
    assert res.exit_code == 1 and "lies above the ceiling" in res.output and not (tmp_path / "high.h5").exists()


def test_two_storey_lines_get_candidates_above_each_floor_only(tmp_path):
    """A two-storey line map: candidates 0.3-2.2 m above floor 0 or floor 3, none in the slab between."""
    lines = np.concatenate([box_shell(6, 5, 0.0, 2.8), box_shell(6, 5, 3.0, 2.8)])
    rep = build_lines_map(lines, tmp_path / "two.h5", BuildParams().replaced(features="none", trans_spacing=0.5,
                                                                              distance_fields=False))
    z = read_map(rep.path).translations[:, 2]
    h = height_above_floor(z, np.array([0.0, 3.0]))
    assert (h >= 0.3 - 1e-6).all() and (h <= 2.2 + 1e-6).all()
    assert (z < 3.0).sum() > 20 and (z > 3.0).sum() > 20


@pytest.mark.parametrize("index", range(1, 25))
def test_furnished_layouts_stay_z_up(index):
    """The layout line files of seed 39's 24 furnished rooms (bare shells: sloped, stepped, arched,
    curved ceilings) keep their z axis as up; the last rule turned 6 of them on their side (the
    lines' proportions cannot tell a narrow tall room's up axis)."""
    lines = mesh_edges(build_scene(layout_spec(furnished_spec(39, index))))
    est, principal = estimate_up(lines)
    assert est.kept_z and np.allclose(map_rotation(est, principal), np.eye(3)), est.note
