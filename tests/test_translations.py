"""Candidate translations: inside the room, clear of the scan, near the requested count, covering."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from ldlmap.core.errors import InputError
from ldlmap.map.translations import candidate_translations
from tests._room_cloud import box_room

SIZE = (6.0, 4.5, 2.8)
YAW = 30.0


@pytest.fixture(scope="module")
def room():
    pts, edges = box_room(seed=0, size=SIZE, n_boxes=3, density=1500.0, yaw_deg=YAW)
    c, s = np.cos(np.radians(YAW)), np.sin(np.radians(YAW))
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    centre = np.array([SIZE[0] / 2, SIZE[1] / 2, 0.0])

    def to_room(X):  # undo the yaw: room frame [0, W] x [0, D] x [0, H]
        return (X - centre) @ R + centre

    E = to_room(edges)
    boxes = [(E[12 + 12 * k: 24 + 12 * k].reshape(-1, 3).min(0), E[12 + 12 * k: 24 + 12 * k].reshape(-1, 3).max(0))
             for k in range((len(E) - 12) // 12)]
    return pts, to_room, boxes


@pytest.mark.parametrize("method,num", [("octree", 800), ("grid", 1700), ("octree", 60)])
def test_candidates_inside_free_space(room, method, num):
    pts, to_room, boxes = room
    C = candidate_translations(pts, num=num, method=method, clearance=0.25)
    assert abs(len(C) - num) <= 0.15 * num
    X = to_room(C)
    assert np.all((X > 0) & (X < np.array(SIZE))), "all candidates inside the room"
    for lo, hi in boxes:
        assert not np.any(np.all((X > lo) & (X < hi), axis=1)), "no candidate inside furniture"
    d, _ = cKDTree(pts).query(C)
    assert d.min() >= 0.25
    # Coverage: free positions of the room have a candidate nearby.
    rng = np.random.default_rng(1)
    Q = rng.uniform([0.6, 0.6, 0.6], np.array(SIZE) - 0.6, size=(400, 3))
    for lo, hi in boxes:
        Q = Q[~np.all((Q > lo - 0.5) & (Q < hi + 0.5), axis=1)]
    dq, _ = cKDTree(X).query(Q)
    spacing = (np.prod(SIZE) / num) ** (1 / 3)
    assert np.max(dq) < 2.0 * spacing, (np.max(dq), spacing)


def test_prior_centers_and_bad_input(room):
    pts, _, _ = room
    prior = np.array([[1.0, 1.0, 1.5], [2.0, 2.0, 1.5]])
    C = candidate_translations(pts, num=50, method="grid", prior_centers=prior)
    assert np.allclose(C[-2:], prior)
    with pytest.raises(InputError):
        candidate_translations(pts, num=10, method="voronoi")
    with pytest.raises(InputError):
        candidate_translations(np.zeros((0, 3)), num=10)
    bad = pts[:100].copy()
    bad[3, 2] = np.nan
    with pytest.raises(InputError):
        candidate_translations(bad, num=10)


# ------------------------------------------------------------------ maps without a scan


def _layout_lines(poly: np.ndarray, height: float) -> np.ndarray:
    """Floor and ceiling edges and vertical corners of a room outline (what a layout map holds)."""
    L = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        L += [[[*a, 0.0], [*b, 0.0]], [[*a, height], [*b, height]], [[*a, 0.0], [*a, height]]]
    return np.array(L, dtype=np.float64)


L_ROOM = np.array([[0, 0], [5, 0], [5, 2], [2, 2], [2, 4], [0, 4]], dtype=np.float64)  # an L-shaped room


def test_spaced_candidates_cover_the_layout_at_the_camera_height():
    from ldlmap.core.polygon import distance_to_boundary, points_in_polygon
    from ldlmap.map.translations import Walkable, spaced_translations

    spacing = 0.3
    C = spaced_translations(_layout_lines(L_ROOM, 2.5), spacing, Walkable((L_ROOM,), None, (1.4, 1.4)))
    assert np.allclose(C[:, 2], 1.4), "one level at the known camera height"
    assert points_in_polygon(C[:, :2], L_ROOM).all(), "every candidate inside the room"
    area = 5 * 2 + 2 * 2
    assert abs(len(C) - area / spacing ** 2) < 0.15 * area / spacing ** 2, "count follows the spacing"
    rng = np.random.default_rng(0)
    Q = rng.uniform([0, 0], [5, 4], size=(2000, 2))
    Q = Q[points_in_polygon(Q, L_ROOM) & (distance_to_boundary(Q, L_ROOM) > 0.15)]  # no camera against a wall
    d, _ = cKDTree(C[:, :2]).query(Q)
    assert d.max() <= spacing / np.sqrt(2) + 1e-6, "any camera position is within spacing / sqrt(2)"
    # A height band: levels at most `spacing` apart, inside the band.
    C2 = spaced_translations(_layout_lines(L_ROOM, 2.5), spacing, Walkable((L_ROOM,), None, (1.0, 1.8)))
    levels = np.unique(np.round(C2[:, 2], 6))
    assert len(levels) == 3 and levels.min() > 1.0 and levels.max() < 1.8 and np.diff(levels).max() <= spacing


def test_spaced_candidates_reach_through_doors_and_never_skip_a_small_room():
    from ldlmap.map.translations import Walkable, spaced_translations

    closet = np.array([[0, 0], [0.5, 0], [0.5, 0.5], [0, 0.5]], dtype=np.float64)
    door = np.array([[[0.5, 0.05], [0.5, 0.45]]])  # in the closet's right wall
    lines = _layout_lines(closet, 2.4)
    C = spaced_translations(lines, 0.6, Walkable((closet,), None, (1.4, 1.4)))
    assert len(C) >= 1 and np.all((C[:, :2] > 0) & (C[:, :2] < 0.5)), "a room smaller than the spacing gets a candidate"
    C = spaced_translations(lines, 0.2, Walkable((closet,), door, (1.4, 1.4)), portal_depth=1.0)
    outside = C[C[:, 0] > 0.5]
    assert len(outside) and outside[:, 0].max() > 1.2, "cameras in front of the door are covered"
    assert np.all((outside[:, 1] > -0.4) & (outside[:, 1] < 0.9)), "only in front of the door"


def test_spaced_candidates_from_lines_alone_and_bad_input():
    from ldlmap.map.translations import spaced_translations

    lines = _layout_lines(L_ROOM, 2.5)
    C = spaced_translations(lines, 0.3, z_range=(1.5, 1.5))
    assert len(C) > 50 and np.allclose(C[:, 2], 1.5)
    assert np.all((C[:, :2] > -0.2) & (C[:, :2] < [5.2, 4.2])), "inside the lines' footprint"
    with pytest.raises(InputError):
        spaced_translations(lines, 0.0)
    with pytest.raises(InputError):
        spaced_translations(lines, 0.3, z_range=(1.0, float("nan")))
    with pytest.raises(InputError):
        spaced_translations(np.zeros((0, 2, 3)), 0.3)


def test_lines_only_map_records_spacing_and_info_prints_it(tmp_path):
    from typer.testing import CliRunner

    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.cli import app
    from ldlmap.io.linefiles import write_lines
    from ldlmap.map.mapfile import read_map
    from ldlmap.map.translations import Walkable

    lines = _layout_lines(L_ROOM, 2.5)
    rep = build_lines_map(lines, tmp_path / "room.h5", BuildParams().replaced(features="none", trans_spacing=0.4),
                          name="lroom", walkable=Walkable((L_ROOM,), None, (1.4, 1.4)))
    m = read_map(rep.path)
    assert m.lines_only and len(m.translations) == rep.counts["translations"] > 50
    assert m.config["translations"] == {"method": "spacing", "spacing": 0.4, "region": "layout polygons",
                                        "floors": [0.0], "camera_height_source": "layout", "camera_height": [1.4, 1.4],
                                        "camera_z": [[1.4, 1.4]]}
    runner = CliRunner()
    res = runner.invoke(app, ["info", str(rep.path)], terminal_width=200)
    assert res.exit_code == 0 and "spaced 0.40 m" in res.output and str(len(m.translations)) in res.output
    # From a line file on the command line, with a camera-height band.
    write_lines(tmp_path / "room.obj", lines)
    res = runner.invoke(app, ["build", str(tmp_path / "room.obj"), "-o", str(tmp_path / "cli.h5"),
                              "--trans-spacing", "0.5", "--camera-height", "1.2:1.6"], terminal_width=200)
    assert res.exit_code == 0, res.output
    T = read_map(tmp_path / "cli.h5").translations
    assert np.all((T[:, 2] > 1.2) & (T[:, 2] < 1.6))
    for bad in (["--camera-height", "1.6:1.2"], ["--camera-height", "tall"], ["--trans-spacing", "-1"]):
        res = runner.invoke(app, ["build", str(tmp_path / "room.obj"), "-o", str(tmp_path / "bad.h5"), *bad])
        assert res.exit_code == 1 and "error:" in res.output and not (tmp_path / "bad.h5").exists(), bad


def test_far_outliers_neither_stretch_nor_fill_the_free_space(room):
    """SfM maps have a few far outlier points / segments: the free-space grid is fitted to the bulk."""
    from ldlmap.map.translations import spaced_translations

    pts, to_room, _ = room
    far = np.array([[80.0, -60.0, 40.0], [-70.0, 90.0, -30.0], [200.0, 5.0, 1.0]])
    C0 = candidate_translations(pts, 200, "octree", 0.25)
    C = candidate_translations(np.concatenate([pts, far]), 200, "octree", 0.25)
    R = to_room(C)
    assert np.all((R > [-0.05, -0.05, -0.05]) & (R < np.array(SIZE) + 0.05)), "inside the room"
    assert abs(len(C) - len(C0)) <= 10
    lines = _layout_lines(L_ROOM, 2.5)
    outliers = np.stack([far, far + 0.3], axis=1)
    C = spaced_translations(np.concatenate([lines, outliers]), 0.3, z_range=(1.5, 1.5))
    assert len(C) > 50 and np.all((C[:, :2] > -0.2) & (C[:, :2] < [5.2, 4.2]))


def test_band_above_floor_puts_the_candidates_where_cameras_stand(room):
    """With a camera band the N_t candidates lie in it and sit closer to camera positions."""
    from ldlmap.map.translations import TranslationParams

    pts, to_room, boxes = room
    whole = to_room(candidate_translations(pts, num=300, method="octree", clearance=0.25))
    band = to_room(candidate_translations(pts, num=300, method="octree", clearance=0.25,
                                          params=TranslationParams(band_above_floor=(1.0, 1.6))))
    assert abs(len(band) - 300) <= 0.15 * 300
    floor = np.percentile(to_room(pts)[:, 2], 0.5)
    z = band[:, 2] - floor
    assert z.min() >= 1.0 - 0.11 and z.max() <= 1.6 + 0.11  # voxel centres within the band (0.1 m voxels)
    assert (whole[:, 2] - floor).min() < 0.8 and (whole[:, 2] - floor).max() > 1.8  # without: floor to ceiling
    rng = np.random.default_rng(2)
    cams = rng.uniform([0.6, 0.6, 1.1], [SIZE[0] - 0.6, SIZE[1] - 0.6, 1.5], size=(300, 3))
    for lo, hi in boxes:
        cams = cams[~np.all((cams > lo - 0.3) & (cams < hi + 0.3), axis=1)]
    near_band = cKDTree(band).query(cams)[0]
    near_whole = cKDTree(whole).query(cams)[0]
    assert np.median(near_band) < 0.8 * np.median(near_whole)
