"""Scanner and phone formats (docs/inputs.md): E57 stations and panoramas, LAS/LAZ, glTF/GLB.

Readers against what was written (poses, spherical coordinates, colour and intensity, scale and
offset, y-up): small hand-made inputs. End to end: a synthetic room's scan written as E57 with
its scanner panoramas embedded, built into a map with `ldlmap build`, the panoramas written out
by `ldlmap e57 --images` and checked with `ldlloc run`.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from ldlmap.cli import app as map_app
from ldlmap.core.errors import InputError
from ldlmap.io.cloud import PointCloud
from ldlmap.io.e57 import ImageToWrite, StationToWrite, e57_images, read_e57, write_e57
from ldlmap.io.gltf import Z_UP_FROM_GLTF, read_gltf, write_glb
from ldlmap.io.las import read_las, write_las
from ldlmap.synth.spec import ObjectSpec, OpeningSpec, SceneSpec

runner = CliRunner()
ROOM = SceneSpec("lroom", ((0.0, 0.0), (7.0, 0.0), (7.0, 3.0), (3.0, 3.0), (3.0, 5.0), (0.0, 5.0)), 2.7,
                 objects=(ObjectSpec("cabinet", (1.0, 4.4), (1.2, 0.5, 1.0), 0.0, "wood"),
                          ObjectSpec("table", (5.0, 1.5), (1.2, 0.8, 0.75), 0.0, "dark_wood")),
                 openings=(OpeningSpec("door", 0, 4.5, 0.9, 2.0, 0.0), OpeningSpec("window", 5, 1.0, 1.6, 1.1, 0.9)))


def _jpeg(h: int = 32, w: int = 64) -> bytes:
    import cv2

    img = (np.random.default_rng(1).random((h, w, 3)) * 255).astype(np.uint8)
    return cv2.imencode(".jpg", img)[1].tobytes()


def test_e57_stations_are_placed_by_their_poses_in_cartesian_or_spherical_form(tmp_path):
    rng = np.random.default_rng(0)
    local = rng.uniform(-3, 3, (500, 3))
    Ra = Rotation.from_euler("zyx", [40, 3, -2], degrees=True).as_matrix()
    Rb = Rotation.from_euler("z", -75, degrees=True).as_matrix()
    ta, tb = np.array([10.0, -4.0, 1.5]), np.array([2.0, 7.0, 1.2])
    rgb = rng.integers(0, 256, (500, 3)).astype(np.uint8)
    inten = rng.uniform(0.2, 0.9, 500)
    write_e57(tmp_path / "s.e57", [StationToWrite(local, Ra, ta, colors=rgb, name="north"),
                                   StationToWrite(local, Rb, tb, intensity=inten, spherical=True, name="south")])
    scan = read_e57(tmp_path / "s.e57")
    a, b = scan.stations
    np.testing.assert_allclose(a.points, local @ Ra.T + ta, atol=1e-9)
    np.testing.assert_allclose(b.points, local @ Rb.T + tb, atol=1e-9)  # range/azimuth/elevation round trip
    assert (a.coordinates, b.coordinates) == ("cartesian", "spherical")
    np.testing.assert_array_equal(a.colors, rgb)
    grey = np.rint((inten - inten.min()) / (inten.max() - inten.min()) * 255)  # scaled by intensityLimits
    np.testing.assert_array_equal(b.colors[:, 0], grey)
    assert (a.color_source, b.color_source) == ("color", "intensity")
    only = read_e57(tmp_path / "s.e57", ["south"])
    assert [s.name for s in only.stations] == ["south"] and read_e57(tmp_path / "s.e57", ["0"]).stations[0].name == "north"
    with pytest.raises(InputError, match="no such station"):
        read_e57(tmp_path / "s.e57", ["east"])


def test_e57_images_spherical_kept_pinhole_and_partial_skipped(tmp_path):
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    c = np.array([1.0, 2.0, 1.4])
    write_e57(tmp_path / "i.e57", [StationToWrite(np.random.default_rng(0).random((200, 3)), name="s")],
              [ImageToWrite("pano", R, c, _jpeg(), 64, 32), ImageToWrite("photo", R, c, _jpeg(), 64, 32, kind="pinhole"),
               ImageToWrite("strip", R, c, _jpeg(16, 64), 64, 16)])
    pano, photo, strip = e57_images(tmp_path / "i.e57")
    assert pano.kind == "spherical" and not pano.note and pano.data == _jpeg()
    np.testing.assert_allclose(pano.rot_cam_from_world, R, atol=1e-12)
    np.testing.assert_allclose(pano.center, c)
    assert photo.kind == "pinhole" and "skipped" in photo.note
    # written with the full sphere's pixel size but 16 rows: 45 deg of elevation, not a panorama
    assert "skipped" in strip.note or strip.height == 16


def test_las_and_laz_honour_scale_offset_and_colour_depth(tmp_path):
    rng = np.random.default_rng(0)
    P = rng.uniform(0, 8, (2000, 3)) + [512_345.0, 4_123_456.0, 200.0]
    C = rng.integers(0, 256, (2000, 3)).astype(np.uint8)
    for suffix in (".las", ".laz"):
        write_las(tmp_path / f"a{suffix}", PointCloud(P, C), scale=0.001)
        cloud, note = read_las(tmp_path / f"a{suffix}")
        assert np.abs(cloud.points - P).max() <= 0.0005 + 1e-6  # half the scale: offsets and scales applied
        np.testing.assert_array_equal(cloud.colors, C)
        assert "16-bit" in note
    write_las(tmp_path / "b.las", PointCloud(P, C), sixteen_bit=False)
    np.testing.assert_array_equal(read_las(tmp_path / "b.las")[0].colors, C)  # 8-bit values kept
    write_las(tmp_path / "c.las", PointCloud(P))
    assert read_las(tmp_path / "c.las")[0].colors is None


def test_glb_is_turned_from_y_up_to_z_up_with_texture_colours(tmp_path):
    # a z-up box room 4 x 3 x 2.5 whose floor is red and everything else blue (texture halves)
    from ldlmap.synth.formats import ROOM_FORMATS  # noqa: F401  (the module writes .glb like this)

    lo, hi = np.zeros(3), np.array([4.0, 3.0, 2.5])
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float) * hi
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    tex = np.zeros((8, 16, 3), np.uint8)
    tex[:, :8] = (255, 0, 0)
    tex[:, 8:] = (0, 0, 255)
    uv = np.tile([[0.75, 0.5]] * 3, (len(tris), 1, 1)).astype(np.float32)
    uv[:2] = [0.25, 0.5]  # the floor's two triangles sample the red half
    write_glb(tmp_path / "room.glb", corners, tris, uv, tex)
    cloud, note = read_gltf(tmp_path / "room.glb", 20000)
    assert "+Y up" in note and "z-up" in note
    np.testing.assert_allclose(cloud.points.min(0), lo, atol=1e-6)
    np.testing.assert_allclose(cloud.points.max(0), hi, atol=1e-6)
    floor = cloud.points[:, 2] < 1e-6
    assert floor.sum() > 1000 and np.all(cloud.colors[floor] == (255, 0, 0)) and np.all(cloud.colors[~floor] == (0, 0, 255))
    # the file itself is y-up: its raw vertices' second axis spans the room's height
    import trimesh

    raw = trimesh.load(str(tmp_path / "room.glb"), force="scene").to_geometry().vertices
    np.testing.assert_allclose(raw.max(0) - raw.min(0), [4.0, 2.5, 3.0], atol=1e-6)
    np.testing.assert_allclose(Z_UP_FROM_GLTF @ [0, 1, 0], [0, 0, 1])


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A furnished L-shaped room: its scan, two scanner panoramas, written in the formats."""
    from ldlmap.synth.formats import room_capture, write_room

    cap = room_capture(ROOM, density=1500, pano_width=512)
    d = tmp_path_factory.mktemp("room")
    for fmt in ("ply", "e57", "las", "glb"):
        write_room(fmt, d / f"room.{fmt}", cap)
    return cap, d


def test_every_format_gives_the_scan_of_the_ply(room):
    from ldlmap.map.inputs import load_input
    from ldlmap.synth.formats import UTM_OFFSET

    cap, d = room
    ply = load_input(d / "room.ply", None, 1000)
    e57 = load_input(d / "room.e57", None, 1000)
    las = load_input(d / "room.las", None, 1000)
    order, o = np.lexsort(ply.points.T), np.lexsort(e57.points.T)  # E57: station by station
    np.testing.assert_allclose(e57.points[o], ply.points[order], atol=1e-9)
    np.testing.assert_array_equal(e57.colors[o], ply.colors[order])
    assert np.abs(las.points - UTM_OFFSET - ply.points).max() < 6e-4  # LAS: in order, to its 1 mm scale
    np.testing.assert_array_equal(las.colors, ply.colors)
    assert "2 of 2 station(s)" in e57.note
    glb = load_input(d / "room.glb", None, 30000)  # the mesh: same box as the scan's, z-up
    np.testing.assert_allclose(glb.points.min(0), cap.mesh.vertices.min(0), atol=0.02)
    np.testing.assert_allclose(glb.points.max(0), cap.mesh.vertices.max(0), atol=0.02)


@pytest.mark.xdist_group("inputs_e57")
def test_e57_scan_builds_a_map_that_localizes_its_own_panoramas(room, tmp_path):
    from ldlloc.cli import app as loc_app

    cap, d = room
    out = tmp_path / "check"
    r = runner.invoke(map_app, ["e57", str(d / "room.e57"), "--images", str(out)])
    assert r.exit_code == 0, r.output
    assert "photo0: pinhole" in r.output and "wrote 2 panorama(s)" in r.output
    r = runner.invoke(map_app, ["build", str(d / "room.e57"), "-o", str(out / "maps" / "room.h5"), "--num-views", "6",
                                "--num-trans", "300", "--stations", "station0,1"])
    assert r.exit_code == 0, r.output
    assert "2 of 2 station(s)" in r.output
    r = runner.invoke(loc_app, ["run", "--root", str(out), "--split", "scanner", "-o", str(tmp_path / "res.json")])
    assert r.exit_code == 0, r.output
    results = json.loads((tmp_path / "res.json").read_text())["queries"]
    assert len(results) == 2
    for q in results:
        assert q["t_error_m"] < 0.1 and q["r_error_deg"] < 5.0, q


def test_las_at_utm_coordinates_is_recentred_with_the_shift_in_the_map(room, tmp_path):
    from ldlmap.core.frame import apply
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.formats import UTM_OFFSET

    cap, d = room
    report = build_map(d / "room.las", tmp_path / "las.h5",
                       params=BuildParams().replaced(features="none", num_translations=100, distance_fields=False))
    assert any("centred on" in n for n in report.notes)
    m = read_map(tmp_path / "las.h5")
    shift = -m.input_to_map[:3, 3]  # X_map = X_input - shift (z-up kept)
    assert np.all(np.abs(shift - (UTM_OFFSET + np.median(cap.points, axis=0))) <= 1.0)
    np.testing.assert_allclose(apply(m.input_to_map, cap.points[:5] + UTM_OFFSET), cap.points[:5] + UTM_OFFSET - shift)
    assert np.abs(m.lines).max() < 20  # stored near the origin, in float32 without losing millimetres
