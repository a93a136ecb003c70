"""Rooms whose walls run in more than two horizontal directions get an Atlanta frame of
the vertical and all of them (K > 3 principal directions), and localize; boxes keep Manhattan."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import cam_from_world, normalize, rotation_error_deg, rotation_from_axis_angle
from ldlmap.synth.spec import ObjectSpec, OpeningSpec, SceneSpec
from tests._localize import localize_rendered

# An irregular hexagon: walls at 0, 60 and 120 degrees (11, 5 and 5 m of them), no two
# perpendicular and no rotational symmetry; furnished. The Atlanta frame of the main two
# horizontals (0 and 60 deg) would leave the 120-deg walls in no group.
HEXAGON = ((0.0, 0.0), (6.0, 0.0), (7.0, 1.732), (5.5, 4.330), (0.5, 4.330), (-1.0, 1.732))
ROOM = SceneSpec(
    "hexagon", HEXAGON, 2.6,
    objects=(ObjectSpec("cabinet", (1.0, 3.6), (1.2, 0.5, 1.0), 0.0, "wood"),
             ObjectSpec("table", (4.5, 1.5), (1.2, 0.8, 0.75), 0.0, "dark_wood")),
    openings=(OpeningSpec("door", 0, 1.0, 0.9, 2.0, 0.0), OpeningSpec("window", 3, 1.5, 1.2, 1.0, 0.9)))
WALL_AZIMUTHS = (0.0, 60.0, 120.0)


def _horizontal(deg: float) -> np.ndarray:
    return np.array([np.cos(np.radians(deg)), np.sin(np.radians(deg)), 0.0])


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), 0, 1))))


def test_room_with_three_wall_directions_gets_them_all_and_localizes(tmp_path):
    from ldlloc.pipeline import Localizer, LocalizeParams
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.map.mapfile import read_map, read_map_header
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene

    mesh = build_scene(ROOM)
    params = BuildParams().replaced(features="none", up="z", trans_spacing=0.4, camera_height=(1.2, 1.8))
    report = build_lines_map(mesh_edges(mesh), tmp_path / "hexagon.h5", params)
    assert any(f"Atlanta frame of {k}" in n for n in report.notes for k in (4, 5)), report.notes
    m = read_map(tmp_path / "hexagon.h5")
    P = m.principal_directions
    k = len(P)  # 4, or 5 with the furniture's sides at 90 deg (9 % of the horizontal line length)
    assert m.config["principal_frame"] == "atlanta" and k in (4, 5)
    for true in (np.array([0, 0, 1.0]), *(_horizontal(a) for a in WALL_AZIMUTHS)):
        assert min(_angle(p, true) for p in P) < 1.5
    # every direction has its lines, the fields one function per direction, and the file says version 2
    counts = np.bincount(m.line_groups[m.line_groups >= 0], minlength=k)
    assert np.all(counts >= 4), counts  # the 60- and 120-deg walls: floor and ceiling edges of two each
    assert m.fields["distances"].shape[1] == k
    header = read_map_header(tmp_path / "hexagon.h5")
    assert header["format_version"] == 3 and header["line_group_counts"][3] == counts[3]
    for r in localize_rendered(Localizer(m, LocalizeParams()), mesh,
                               (((4.0, 1.6, 1.5), 30.0, 3.0), ((5.0, 3.0, 1.6), 100.0, 0.0))):
        assert len(set(np.unique(r.arc_groups)) - {-1}) >= 4  # the query's arcs in 4 groups or more


def test_furnished_box_keeps_the_manhattan_frame():
    """A furnished box room (one small table at 30 degrees: clutter, not walls) keeps exactly 3
    orthonormal directions: the further directions' share of the horizontal line length decides."""
    from ldlmap.lines3d.principal import FrameParams, horizontal_peaks, principal_directions_3d, principal_frame
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene

    rect = ((0.0, 0.0), (6.0, 0.0), (6.0, 4.5), (0.0, 4.5))
    spec = SceneSpec("box", rect, 2.5, objects=(
        ObjectSpec("cabinet", (1.0, 4.0), (1.2, 0.5, 1.0), 0.0, "wood"),
        ObjectSpec("table", (4.0, 2.0), (1.2, 0.8, 0.75), 0.0, "dark_wood"),
        ObjectSpec("table", (2.0, 1.5), (0.6, 0.6, 0.75), 30.0, "dark_wood")),
        openings=(OpeningSpec("door", 0, 1.0, 0.9, 2.0, 0.0), OpeningSpec("window", 2, 1.5, 1.2, 1.0, 0.9)))
    lines = mesh_edges(build_scene(spec))
    F, _, kind = principal_frame(lines, principal_directions_3d(lines))
    assert kind == "manhattan" and F.shape == (3, 3)
    np.testing.assert_allclose(F @ F.T, np.eye(3), atol=1e-9)
    _, shares, azimuths = horizontal_peaks(lines, np.array([0, 0, 1.0]), FrameParams(min_share=0.0))
    assert len(shares) == 4 and shares[2:].sum() < FrameParams().extra_share  # the table's 30 and 120 deg
    # the same room with walls in a third direction (a corner cut at 45 deg) gets an Atlanta frame of 4
    cut = ((0.0, 0.0), (6.0, 0.0), (6.0, 1.5), (3.0, 4.5), (0.0, 4.5))
    lines = mesh_edges(build_scene(SceneSpec("cut", cut, 2.5, objects=spec.objects)))
    F, _, kind = principal_frame(lines, principal_directions_3d(lines))
    assert kind == "atlanta" and F.shape == (4, 3)


def _room_arcs(P: np.ndarray, R: np.ndarray, rng) -> np.ndarray:
    segs = []
    for d in P:
        a = rng.uniform([-3, -2, 0], [3, 2, 3], (25, 3))
        segs.append(np.stack([a, a + rng.uniform(0.6, 2.0, (25, 1)) * d], 1))
    return normalize(cam_from_world(np.concatenate(segs), R, np.array([0.3, -0.2, 1.4])))


def test_candidate_rotations_and_labels_for_five_directions():
    """The vertical and 4 horizontals (two perpendicular pairs 30 deg apart): rotations from the
    non-coplanar map triplets contain the truth, pair every map direction with its vanishing point,
    and group the arcs of all five."""
    from ldlloc import rotation

    rng = np.random.default_rng(5)
    P = np.array([[0, 0, 1.0], *(_horizontal(a) for a in (15.0, 105.0, 45.0, 135.0))])
    R = rotation_from_axis_angle(np.array([0.2, -0.1, 1.0]), 2.0)
    arcs = _room_arcs(P, R, rng)
    vps = rotation.vanishing_points(arcs, k=20)
    cands = rotation.candidate_rotations(vps, P)
    assert cands.triplets.shape == (len(cands), 5)
    best = int(np.argmin([rotation_error_deg(Rc, R) for Rc in cands.rotations]))
    assert rotation_error_deg(cands.rotations[best], R) < 1.0
    assert np.all(cands.triplets[best] >= 0)  # all five directions seen and matched
    labels = rotation.rotation_labels(arcs, vps, cands, P)
    assert labels.shape == (len(cands), len(arcs))
    truth = np.repeat(np.arange(5), 25)
    assert np.mean(labels[best] == truth) > 0.9
    # the upright prior keeps the candidates' bookkeeping together
    upright = rotation.filter_by_tilt(cands, rotation.camera_tilt_deg(R) + 2.0)
    assert 0 < len(upright) < len(cands) and upright.triplets.shape == (len(upright), 5)
    assert min(rotation_error_deg(Rc, R) for Rc in upright.rotations) < 1.0
    with pytest.raises(InputError):
        rotation.candidate_rotations(vps, P[:2])
    # a view of the vertical and one wall direction only: no triplet matches, a pair does
    few = _room_arcs(P[:2], R, rng)
    vps = rotation.vanishing_points(few, k=20)
    assert len(rotation.candidate_rotations(vps, P[:3])) == 0  # 3 directions: triplets only
    cands = rotation.candidate_rotations(vps, P)
    assert min(rotation_error_deg(Rc, R) for Rc in cands.rotations) < 1.0


def test_map_file_versions_by_direction_count(tmp_path):
    """Without distance fields, 3 directions: written as version 1 (what every reader knows); more:
    version 2; with fields (stored quantized): version 3. A version-1 file claiming 4 directions is
    refused in one line."""
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.map.mapfile import read_map

    rng = np.random.default_rng(2)
    P = np.array([[0, 0, 1.0], *(_horizontal(a) for a in (0.0, 60.0, 120.0))])
    lines = []
    for d, n in zip(P, (30, 30, 30, 30)):
        a = rng.uniform([0, 0, 0], [6, 4, 2.6], (n, 3))
        lines.append(np.stack([a, a + rng.uniform(0.8, 2.0, (n, 1)) * d], 1))
    params = BuildParams().replaced(features="none", up="z", trans_spacing=1.0, distance_fields=False)
    path = build_lines_map(np.concatenate(lines), tmp_path / "many.h5", params).path
    assert len(read_map(path).principal_directions) == 4
    with h5py.File(path, "r") as h5:
        assert h5.attrs["format_version"] == 2
    box = build_lines_map(np.concatenate(lines[:3]), tmp_path / "box.h5", params).path
    with h5py.File(box, "r") as h5:
        assert h5.attrs["format_version"] == 1 and h5["principal/directions"].shape == (3, 3)
    with h5py.File(path, "r+") as h5:
        h5.attrs["format_version"] = 1
    with pytest.raises(InputError, match="format version 1 with 4 principal directions"):
        read_map(path)
    fields = build_lines_map(np.concatenate(lines[:3]), tmp_path / "fields.h5", params.replaced(distance_fields=True)).path
    with h5py.File(fields, "r") as h5:
        assert h5.attrs["format_version"] == 3 and h5["fields/distances"].dtype == np.uint8
    assert read_map(fields).fields["distances"].dtype == np.float16
