"""Rooms under sloped ceilings keep the frame of their walls (Manhattan or Atlanta), add
the slopes' inclined directions, group lines by elevation, and localize."""

from __future__ import annotations

import numpy as np

from ldlmap.core.geometry import rotation_error_deg, rotation_from_axis_angle
from ldlmap.synth.spec import CeilingSpec, ObjectSpec, OpeningSpec, SceneSpec
from tests._localize import localize_rendered
from tests.test_atlanta_many import HEXAGON, _room_arcs


def test_inclined_directions_pair_with_vanishing_points_but_seed_no_rotation():
    """The vertical, two horizontals and a 15-deg slope along the first: with the inclined row
    left out of the seeds the candidates are fewer, still hold the truth, and the slope's
    vanishing point is paired with its row."""
    from ldlloc import rotation

    s15 = np.radians(15.0)
    P = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0], [np.cos(s15), 0, np.sin(s15)]])
    seed = rotation.frame_rows(P)
    assert seed.tolist() == [True, True, True, False]
    R = rotation_from_axis_angle(np.array([0.3, 0.1, 1.0]), 1.2)
    arcs = _room_arcs(P, R, np.random.default_rng(3))
    vps = rotation.vanishing_points(arcs, k=20)
    every, seeded = rotation.candidate_rotations(vps, P), rotation.candidate_rotations(vps, P, seed=seed)
    assert 0 < len(seeded) < len(every)
    best = int(np.argmin([rotation_error_deg(Rc, R) for Rc in seeded.rotations]))
    assert rotation_error_deg(seeded.rotations[best], R) < 1.0
    assert np.all(seeded.triplets[best] >= 0)  # the slope's direction found among the vanishing points
    labels = rotation.rotation_labels(arcs, vps, seeded, P)
    assert np.mean(labels[best] == np.repeat(np.arange(4), 25)) > 0.9


def test_angled_room_under_a_gable_keeps_its_atlanta_frame_and_localizes(tmp_path):
    """Walls at 0, 60 and 120 deg under a 15-deg gable: the walls' directions are kept (the
    nearest Manhattan frame would fold the 60/120-deg walls onto a perpendicular pair), the
    slope's edges join no wall direction's group, and rendered panoramas localize."""
    from ldlloc.pipeline import Localizer, LocalizeParams
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene

    room = SceneSpec(
        "hexagon_gable", HEXAGON, 2.4, ceiling=CeilingSpec("gable", 0.0, 15.0),
        objects=(ObjectSpec("cabinet", (1.0, 3.6), (1.2, 0.5, 1.0), 0.0, "wood"),
                 ObjectSpec("table", (4.5, 1.5), (1.2, 0.8, 0.75), 0.0, "dark_wood")),
        openings=(OpeningSpec("door", 0, 1.0, 0.9, 2.0, 0.0), OpeningSpec("window", 3, 1.5, 1.2, 1.0, 0.9)))
    mesh = build_scene(room)
    lines = mesh_edges(mesh)
    params = BuildParams().replaced(features="none", up="z", trans_spacing=0.4, camera_height=(1.2, 1.8))
    build_lines_map(lines, tmp_path / "m.h5", params)
    m = read_map(tmp_path / "m.h5")
    P = m.principal_directions
    assert m.config["principal_frame"] in ("atlanta", "sloped")
    for azimuth in (0.0, 60.0, 120.0):
        wall = np.array([np.cos(np.radians(azimuth)), np.sin(np.radians(azimuth)), 0.0])
        assert np.abs(P @ wall).max() > np.cos(np.radians(1.5))
    d = m.lines[:, 1] - m.lines[:, 0]
    rise = np.degrees(np.arcsin(np.abs(d[:, 2]) / np.linalg.norm(d, axis=1)))
    level = np.abs(P[:, 2]) < 0.05
    assert not np.any(level[m.line_groups[(rise > 10.0) & (m.line_groups >= 0)]])  # no slope edge in a wall's group
    localize_rendered(Localizer(m, LocalizeParams()), mesh,
                      (((3.0, 1.5, 1.5), 20.0, 3.0), ((4.5, 3.0, 1.6), 250.0, 0.0), ((1.5, 2.5, 1.3), 140.0, 20.0)))
