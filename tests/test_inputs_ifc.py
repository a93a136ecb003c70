"""IFC (BIM) models: lines-only maps per storey, units honoured, and a 3-storey building whose
panoramas are localized against the folder of its storey maps, the storey not given."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlmap.synth.spec import ObjectSpec, OpeningSpec, SceneSpec

pytest.importorskip("ifcopenshell")  # the `bim` extra (make install adds it)

runner = CliRunner()

ANGLED = SceneSpec("angled", ((0.0, 0.0), (6.0, 0.0), (8.8, 2.8), (3.5, 2.8), (3.5, 3.5)), 2.6,
                   objects=(ObjectSpec("table", (5.5, 1.0), (1.2, 0.8, 0.75), 0.0, "dark_wood"),),
                   openings=(OpeningSpec("door", 0, 1.0, 0.9, 2.0, 0.0), OpeningSpec("window", 2, 1.5, 1.2, 1.0, 0.9)))
L_ROOM = SceneSpec("lroom", ((0.0, 0.0), (7.0, 0.0), (7.0, 3.0), (3.0, 3.0), (3.0, 5.0), (0.0, 5.0)), 2.7,
                   openings=(OpeningSpec("door", 0, 4.5, 0.9, 2.0, 0.0), OpeningSpec("window", 5, 1.0, 1.6, 1.1, 0.9),
                             OpeningSpec("window", 1, 0.8, 1.2, 1.0, 1.0)))
OFFICE = SceneSpec("office", ((0.0, 0.0), (6.0, 0.0), (6.0, 4.0), (0.0, 4.0)), 2.9,
                   openings=(OpeningSpec("door", 3, 0.4, 0.9, 2.1, 0.0), OpeningSpec("window", 0, 0.6, 1.0, 1.2, 0.9),
                             OpeningSpec("window", 0, 2.4, 2.2, 1.2, 0.9)))
# storey name, elevation (m), room, and query poses (centre in the room, yaw, tilt in degrees)
BUILDING = (("ground", 0.0, ANGLED, (((4.0, 1.6, 1.5), 30.0, 3.0),)),
            ("first", 3.0, L_ROOM, (((1.5, 3.6, 1.4), 60.0, 2.0),)),
            ("second", 6.2, OFFICE, (((2.0, 2.2, 1.3), 200.0, 1.0),)))


def _write(path, units="metre"):
    from ldlmap.synth.ifc import StoreyToWrite, write_ifc

    return write_ifc(path, [StoreyToWrite(n, z, [room]) for n, z, room, _ in BUILDING], units=units)


def test_ifc_in_feet_gives_the_same_lines_in_metres(tmp_path):
    from ldlmap.io.ifc import read_ifc
    from ldlmap.map.ifc_maps import storey_lines

    metre, note_m = read_ifc(_write(tmp_path / "m.ifc"), "first")
    feet, note_f = read_ifc(_write(tmp_path / "f.ifc", "foot"), "first")
    assert "length unit metres" in note_m and "length unit feet" in note_f
    a, b = storey_lines(metre[0]), storey_lines(feet[0])
    assert len(a) == len(b) > 20
    np.testing.assert_allclose(np.sort(a.reshape(len(a), -1), axis=0), np.sort(b.reshape(len(b), -1), axis=0), atol=1e-4)
    assert feet[0].elevation == pytest.approx(3.0, abs=1e-6)
    # lines stand on the storey's floor and under its ceiling (2.7 m): z-up, metres
    assert a[..., 2].min() == pytest.approx(3.0, abs=1e-6) and a[..., 2].max() == pytest.approx(5.7, abs=1e-6)
    assert metre[0].classes == {"IfcCovering": 1, "IfcDoor": 1, "IfcSlab": 1, "IfcWall": 6, "IfcWindow": 2}


def test_furniture_only_with_include(tmp_path):
    from ldlmap.io.ifc import read_ifc

    path = _write(tmp_path / "b.ifc")
    plain, _ = read_ifc(path, "ground")
    more, _ = read_ifc(path, "ground", ("IfcFurnishingElement",))
    assert "IfcFurnishingElement" not in plain[0].classes and more[0].classes["IfcFurnishingElement"] == 1
    assert len(more[0].triangles) > len(plain[0].triangles)


@pytest.mark.xdist_group("inputs_ifc")
def test_building_storey_maps_localize_its_panoramas_storey_not_given(tmp_path):
    from ldlloc.batch.which_map import MapSet, localize_on_maps
    from ldlloc.pipeline import LocalizeParams
    from ldlmap.cli import app
    from ldlmap.core.geometry import rotation_error_deg, rotation_from_axis_angle
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.render import Renderer
    from ldlmap.synth.scene import build_scene

    model = _write(tmp_path / "house.ifc", "foot")
    r = runner.invoke(app, ["build", str(model), "-o", str(tmp_path / "storeys"), "--trans-spacing", "0.4"])
    assert r.exit_code == 0, r.output
    assert "length unit feet" in r.output
    files = sorted(p.name for p in (tmp_path / "storeys").glob("*.h5"))
    assert files == ["first.h5", "ground.h5", "second.h5"]
    m = read_map(tmp_path / "storeys" / "first.h5")
    assert m.config["features"] == "none" and np.all((m.translations[:, 2] >= 3.8) & (m.translations[:, 2] <= 4.8))
    maps = MapSet.load(tmp_path / "storeys", LocalizeParams(), "cpu")
    for name, z, room, poses in BUILDING:
        render = Renderer(build_scene(room))  # the room at its own floor; the storey lifts it by z
        for center, yaw, tilt in poses:
            R = rotation_from_axis_angle(np.array([1.0, 0, 0]), np.radians(tilt)) @ \
                rotation_from_axis_angle(np.array([0, 0, 1.0]), np.radians(yaw))
            loc, choice = localize_on_maps(render.render(R, np.array(center), 512).rgb, maps, None)
            truth = np.array(center) + [0.0, 0.0, z]
            t_err, r_err = np.linalg.norm(loc.center - truth), rotation_error_deg(loc.rot_cam_from_world, R)
            assert choice.chosen.entry.scene == name, (name, choice.record())
            assert t_err < 0.1 and r_err < 5.0, (name, t_err, r_err, loc.message)
