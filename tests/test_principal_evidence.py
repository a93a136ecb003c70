"""A map's principal directions need evidence: when the up axis is known (the user, the cameras,
a layout) the vertical is that axis, not the lines' most vertical direction; an inclined
direction needs a surface's edges (lines long and many enough), so a flat room's scan artefacts
add none while the generator's sloped ceilings keep theirs."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core.pictures import group_legend
from ldlmap.lines3d.principal import (FrameParams, inclined_peaks, longest_crease, principal_directions_3d,
                                      principal_frame)

SMALL_ROOM = """
name = "synthroom"
seed = 3
ceiling_height = 2.6
footprint = [[0.0, 0.0], [4.0, 0.0], [4.0, 2.0], [2.5, 2.0], [2.5, 3.5], [0.0, 3.5]]
[scan]
density = 600.0
[[objects]]
kind = "table"
center = [1.5, 1.5]
size = [1.2, 0.7, 0.75]
[[openings]]
kind = "door"
wall = 5
offset = 1.0
width = 0.9
height = 2.1
[[openings]]
kind = "window"
wall = 0
offset = 1.0
width = 1.2
height = 1.0
"""  # docs/commands.md's working-folder room (its scan: the one `ldlmap build scan.ply` reads there)


def _rise_deg(P: np.ndarray) -> np.ndarray:
    return np.degrees(np.arcsin(np.minimum(np.abs(P[:, 2]), 1.0)))


def _segments(direction, starts, length: float) -> np.ndarray:
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    s = np.asarray(starts, float)
    return np.stack([s, s + length * d], axis=1)


def _box_room_lines(rng: np.random.Generator) -> np.ndarray:
    """A 5 x 4 x 2.6 m room's creases as noisy pieces: long horizontals, vertical corners."""
    corners = [(0, 0), (5, 0), (5, 4), (0, 4)]
    segs = []
    for z in (0.0, 2.6):
        segs += [_segments([1, 0, 0], [(0, y, z) for y in (0, 4)], 5.0), _segments([0, 1, 0], [(x, 0, z) for x in (0, 5)], 4.0)]
    segs.append(_segments([0, 0, 1], [(x, y, 0) for x, y in corners], 2.6))
    segs.append(_segments([1, 0, 0], rng.uniform([0, 0, 0.3], [3, 4, 2.2], (20, 3)), 1.5))  # furniture, frames
    segs.append(_segments([0, 1, 0], rng.uniform([0, 0, 0.3], [5, 2, 2.2], (20, 3)), 1.5))
    segs.append(_segments([0, 0, 1], rng.uniform([0, 0, 0], [5, 4, 0.5], (10, 3)), 1.0))
    return np.concatenate(segs) + rng.normal(0, 0.002, (sum(len(s) for s in segs), 2, 3))


def test_short_zigzags_make_no_inclined_direction_but_a_slopes_edges_do():
    """Eight 0.25-0.39 m pieces at 45 deg (enough of the length, as a sparse scan's plane outlines
    give) are no sloped ceiling; two 1.6 m creases at 30 deg, each in two pieces, are one; lines steeper than a ceiling
    slopes (65 deg, the docs' room's false direction) are never one."""
    rng = np.random.default_rng(4)
    room = _box_room_lines(rng)
    tilt45 = [np.cos(np.radians(45)), 0, np.sin(np.radians(45))]
    zigzag = np.concatenate([_segments(tilt45, [(rng.uniform(0, 5), y, rng.uniform(0, 2))], rng.uniform(0.25, 0.39))
                             for y in (0, 4) for _ in range(4)])
    lines = np.concatenate([room, zigzag])
    length = np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1)
    assert length[len(room):].sum() / length.sum() > FrameParams().inclined_share  # enough length to pass before
    F, _, kind = principal_frame(lines, principal_directions_3d(lines))
    assert len(F) == 3 and not np.any((_rise_deg(F) > 10) & (_rise_deg(F) < 80)), _rise_deg(F)
    assert len(inclined_peaks(lines, F, (0, 0, 1), FrameParams(inclined_chain_m=0.0, inclined_min_lines=1))) == 1
    tilt65 = np.array([np.cos(np.radians(65)), 0, np.sin(np.radians(65))])
    steep = np.concatenate([room, _segments(tilt65, [(1, 0, 0.2), (3, 4, 0.2)], 1.6)])
    assert len(inclined_peaks(steep, F, (0, 0, 1))) == 0

    tilt30 = np.array([np.cos(np.radians(30)), 0, np.sin(np.radians(30))])
    slope = np.concatenate([_segments(tilt30, [(0, 0, 1.2), (0, 4, 1.2)], 0.8),  # each crease in two pieces
                            _segments(tilt30, [(0, 0, 1.2) + 0.85 * tilt30, (0, 4, 1.2) + 0.85 * tilt30], 0.8)])
    lines = np.concatenate([room, zigzag, slope])
    F, _, kind = principal_frame(lines, principal_directions_3d(lines))
    inclined = _rise_deg(F)[(_rise_deg(F) > 10) & (_rise_deg(F) < 80)]
    assert kind == "sloped" and np.allclose(inclined, [30.0], atol=1.0), _rise_deg(F)


def test_longest_crease_sums_pieces_end_to_end_not_side_by_side():
    p = np.array([1.0, 0, 1.0]) / np.sqrt(2)
    end_to_end = _segments(p, [(0, 0, 0), 0.5 * p, 1.0 * p], 0.45)
    side_by_side = _segments(p, [(0, 0, 0), (0, 0.3, 0), (0, 0.6, 0)], 0.45)
    assert longest_crease(end_to_end, p, 0.15) == pytest.approx(1.35)
    assert longest_crease(side_by_side, p, 0.15) == pytest.approx(0.45)
    assert longest_crease(side_by_side[::-1], p, 0.15) == pytest.approx(0.45)  # whatever the order
    assert longest_crease(end_to_end[:1], p, 0.15) == pytest.approx(0.45)


def test_known_up_is_the_vertical_of_an_sfm_like_line_set():
    """SfM lines whose most vertical voted direction leans 15 deg (a few true verticals, more
    length in an oblique structure): with the up axis known, the vertical is +z exactly."""
    rng = np.random.default_rng(7)
    room = _box_room_lines(rng)[:-10]  # fewer true verticals than an oblique set
    lean = [np.sin(np.radians(15)), 0, np.cos(np.radians(15))]
    oblique = _segments(lean, rng.uniform([0, 0, 0], [5, 4, 0.3], (14, 3)), 1.8)
    lines = np.concatenate([room, oblique])
    E = principal_directions_3d(lines)
    assert 12.0 < 90.0 - _rise_deg(E).max() < 18.0  # the votes' vertical leans
    F, dev, _ = principal_frame(lines, E, up=(0, 0, 1), up_known=True)
    assert len(F) == 3 and np.isclose(_rise_deg(F).max(), 90.0, atol=1e-9)  # no leaning "inclined" rows either
    assert dev.max() > 10.0  # and the build warns how far the votes were from the frame it uses
    F_lines, _, _ = principal_frame(lines, E)  # up from the lines alone: their vertical stays
    assert np.any(np.abs(90.0 - _rise_deg(F_lines) - 15.0) < 3.0)


def test_known_up_reaches_the_map(tmp_path):
    """`--up z` (the user's word, as the cameras' would be) on SfM-like lines: the map's vertical is +z."""
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.map.mapfile import read_map

    rng = np.random.default_rng(7)
    lean = [np.sin(np.radians(15)), 0, np.cos(np.radians(15))]
    lines = np.concatenate([_box_room_lines(rng)[:-10], _segments(lean, rng.uniform([0, 0, 0], [5, 4, 0.3], (14, 3)), 1.8)])
    build_lines_map(lines, tmp_path / "sfm.h5", BuildParams().replaced(features="none", up="z", trans_spacing=0.8))
    m = read_map(tmp_path / "sfm.h5", load_cloud=False)
    assert len(m.principal_directions) == 3 and np.isclose(_rise_deg(m.principal_directions).max(), 90.0, atol=1e-6)


def _scan_map(tmp_path, spec, density: float | None = None):
    """The map (lines only) of a simulated scan of ``spec``, built as `ldlmap build scan.ply` does."""
    from dataclasses import replace

    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.capture import stream_rng
    from ldlmap.synth.scan import sample_scan, write_ply
    from ldlmap.synth.scene import build_scene

    if density is not None:
        spec = replace(spec, scan=replace(spec.scan, density=density))
    pts, cols = sample_scan(build_scene(spec), spec.scan, stream_rng(0, spec, 1, "scan"))
    write_ply(tmp_path / "scan.ply", pts, cols)
    report = build_map(tmp_path / "scan.ply", tmp_path / "scan.h5",
                       params=BuildParams().replaced(features="none", num_translations=50))
    return read_map(tmp_path / "scan.h5", load_cloud=False), report


def test_the_docs_flat_room_gets_no_inclined_direction(tmp_path):
    """The working folder's room (flat ceiling, sparse scan): before, 6 wall pieces of 0.21-0.39 m
    made "1 inclined at 65 deg: a sloped ceiling"."""
    from ldlmap.synth.spec import spec_from_dict
    import tomllib

    m, report = _scan_map(tmp_path, spec_from_dict(tomllib.loads(SMALL_ROOM)))
    rise = _rise_deg(m.principal_directions)
    assert len(rise) == 3 and not np.any((rise > 10) & (rise < 80)), rise
    assert not any("sloped ceiling)" in n for n in report.notes), report.notes


def test_a_sloped_room_from_a_sparse_scan_keeps_its_slope(tmp_path):
    """The generator's gable room (42.5 deg) scanned as sparsely as the docs' room: its slopes'
    creases are evidence enough."""
    from ldlmap.synth.presets import random_spec

    spec = random_spec("sloped", 23, 1)
    m, report = _scan_map(tmp_path, spec, density=600.0)
    rise = _rise_deg(m.principal_directions)
    inclined = rise[(rise > 10) & (rise < 80)]
    assert m.config["principal_frame"] == "sloped" and len(inclined) >= 1, rise
    assert np.all(np.abs(inclined - spec.ceiling.slope_deg) < 5.0), (inclined, spec.ceiling.slope_deg)
    assert any("sloped ceiling)" in n for n in report.notes)


def test_legend_names_inclined_directions_by_their_elevation():
    s65 = [np.cos(np.radians(65)), 0, np.sin(np.radians(65))]
    P = np.array([[0, 0, 1.0], [1, 0, 0], [0, 1, 0], s65])
    labels = [label for _, label in group_legend(P)]
    assert labels[:4] == ["d0 vertical", "d1 horizontal", "d2 horizontal", "d3 inclined 65 deg"]
