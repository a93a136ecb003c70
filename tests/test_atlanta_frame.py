"""A room whose walls are not at right angles gets an Atlanta frame, and localizes."""

from __future__ import annotations

import numpy as np

from ldlmap.synth.spec import ObjectSpec, OpeningSpec, SceneSpec
from tests._localize import localize_rendered

# Walls at 0 and 45 degrees (one short one at 90), furnished: no 180-degree symmetry.
ROOM = SceneSpec(
    "angled", ((0.0, 0.0), (6.0, 0.0), (8.8, 2.8), (3.5, 2.8), (3.5, 3.5)), 2.6,
    objects=(ObjectSpec("cabinet", (2.4, 1.5), (1.2, 0.5, 1.0), 45.0, "wood"),
             ObjectSpec("table", (5.5, 1.0), (1.2, 0.8, 0.75), 0.0, "dark_wood")),
    openings=(OpeningSpec("door", 0, 1.0, 0.9, 2.0, 0.0), OpeningSpec("window", 2, 1.5, 1.2, 1.0, 0.9)))


def test_atlanta_map_of_an_angled_room_localizes_its_panoramas(tmp_path):
    from ldlloc.pipeline import Localizer, LocalizeParams
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene

    mesh = build_scene(ROOM)
    params = BuildParams().replaced(features="none", up="z", trans_spacing=0.4, camera_height=(1.2, 1.8), distance_fields=False)
    report = build_lines_map(mesh_edges(mesh), tmp_path / "angled.h5", params)
    assert any("Atlanta frame" in n for n in report.notes)
    m = read_map(tmp_path / "angled.h5")
    assert m.config["principal_frame"] == "atlanta"
    walls = np.array([[1.0, 0, 0], [np.sqrt(0.5), np.sqrt(0.5), 0], [0, 0, 1.0]])
    assert np.all(np.abs(walls @ m.principal_directions.T).max(axis=1) > np.cos(np.radians(2.0)))
    localize_rendered(Localizer(m, LocalizeParams()), mesh, (((4.0, 1.6, 1.5), 30.0, 3.0), ((6.3, 1.7, 1.4), 200.0, 5.0)))
