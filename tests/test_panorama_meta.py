"""360 camera metadata: XMP GPano pose and capture time read from JPEG panoramas, the upright
prior around the camera's own gravity, and nonsense angles refused in one line."""

from __future__ import annotations

import struct
from datetime import datetime

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlmap.core.errors import InputError
from ldlmap.io.panorama_meta import camera_up, panorama_metadata, recorded_up, write_gpano
from tests._hostile import error_line

runner = CliRunner()


def _jpeg(h: int = 16, w: int = 32) -> bytes:
    return cv2.imencode(".jpg", np.full((h, w, 3), 128, np.uint8))[1].tobytes()


def _exif(when: str) -> bytes:
    """An APP1 EXIF segment (little-endian TIFF) whose Exif IFD holds DateTimeOriginal."""
    text = when.encode() + b"\x00"
    ifd0 = struct.pack("<H", 1) + struct.pack("<HHII", 0x8769, 4, 1, 26) + struct.pack("<I", 0)
    exif = struct.pack("<H", 1) + struct.pack("<HHII", 0x9003, 2, len(text), 44) + struct.pack("<I", 0)
    tiff = b"II*\x00" + struct.pack("<I", 8) + ifd0 + exif + text
    body = b"Exif\x00\x00" + tiff
    return b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body


def test_gpano_pose_and_capture_time_are_read(tmp_path):
    p = tmp_path / "theta.jpg"
    p.write_bytes(write_gpano(_jpeg(), 12.5, -3.0, 271.0, "2024-05-06T07:08:09"))
    m = panorama_metadata(p)
    assert (m.pitch_deg, m.roll_deg, m.heading_deg) == (12.5, -3.0, 271.0)
    assert m.time == datetime(2024, 5, 6, 7, 8, 9) and m.has_gravity
    # EXIF DateTimeOriginal wins over the XMP's time; element-form GPano values are read too
    data = write_gpano(_jpeg(), 1, 2, time="2020-01-01T00:00:00")
    q = tmp_path / "insta.jpg"
    q.write_bytes(data[:2] + _exif("2023:11:26 14:05:00") + data[2:])
    assert panorama_metadata(q).time == datetime(2023, 11, 26, 14, 5)
    xml = (b'http://ns.adobe.com/xap/1.0/\x00<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf='
           b'"http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description xmlns:GPano="http://ns.google.com/photos/1.0/'
           b'panorama/"><GPano:PosePitchDegrees>-4</GPano:PosePitchDegrees><GPano:PoseRollDegrees>6.5'
           b'</GPano:PoseRollDegrees></rdf:Description></rdf:RDF></x:xmpmeta>')
    r = tmp_path / "elem.jpg"
    r.write_bytes(_jpeg()[:2] + b"\xff\xe1" + struct.pack(">H", len(xml) + 2) + xml + _jpeg()[2:])
    m = panorama_metadata(r)
    assert (m.pitch_deg, m.roll_deg, m.heading_deg, m.time) == (-4.0, 6.5, None, None)
    plain = tmp_path / "plain.jpg"
    plain.write_bytes(_jpeg())
    assert panorama_metadata(plain) == panorama_metadata(plain).__class__() and recorded_up(plain) is None


def test_walk_order_by_capture_time(tmp_path):
    times = ["2024-05-06T07:08:09", "2024-05-06T07:01:00", "2024-05-06T07:05:30"]
    for i, t in enumerate(times):
        (tmp_path / f"p{i}.jpg").write_bytes(write_gpano(_jpeg(), 0, 0, time=t))
    walk = sorted(tmp_path.glob("*.jpg"), key=lambda f: panorama_metadata(f).time)
    assert [f.name for f in walk] == ["p1.jpg", "p2.jpg", "p0.jpg"]


@pytest.mark.parametrize("pitch, roll, heading, words", [
    (95, 0, None, "PosePitchDegrees = 95 is outside [-90, 90]"),
    (0, -180, None, "PoseRollDegrees = -180 is outside (-180, 180]"),
    (0, 0, 360, "PoseHeadingDegrees = 360 is outside [0, 360)"),
    ("nan", 0, None, "PosePitchDegrees = nan is outside"),
    ("up", 0, None, "is not a number"),
])
def test_nonsense_angles_are_refused_in_one_line(tmp_path, pitch, roll, heading, words):
    p = tmp_path / "bad.jpg"
    p.write_bytes(write_gpano(_jpeg(), pitch, roll, heading))
    with pytest.raises(InputError) as err:
        panorama_metadata(p)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_camera_up_follows_gpano_signs():
    np.testing.assert_allclose(camera_up(0, 0), [0, 0, 1], atol=1e-12)
    # pitched up: the image centre (+x) rises, so the world's up leans towards +x in the camera
    assert camera_up(20, 0)[0] == pytest.approx(np.sin(np.radians(20))) and abs(camera_up(20, 0)[1]) < 1e-12
    # rolled (the horizon turns counter-clockwise in the image): the left (+y) rises, up leans to +y
    assert camera_up(0, 20)[1] == pytest.approx(np.sin(np.radians(20))) and abs(camera_up(0, 20)[0]) < 1e-12
    assert np.degrees(np.arccos(camera_up(15, -8)[2])) == pytest.approx(np.degrees(np.arccos(
        np.cos(np.radians(15)) * np.cos(np.radians(8)))), abs=1e-9)


@pytest.mark.xdist_group("inputs_gravity")
def test_upright_prior_around_the_cameras_gravity(tmp_path):
    """A panorama pitched 15 deg and rolled -8 deg: a 5 deg bound around level finds no rotation;
    around the gravity its XMP records, the pose is found."""
    from ldlloc.pipeline import LocalizeParams, Localizer, load_image
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.render import Renderer
    from ldlmap.synth.scene import build_scene
    from tests.test_atlanta_frame import ROOM

    mesh = build_scene(ROOM)
    build_lines_map(mesh_edges(mesh), tmp_path / "m.h5", BuildParams().replaced(features="none", up="z", trans_spacing=0.4,
                                                                     camera_height=(1.2, 1.8), distance_fields=False))
    pitch, roll = 15.0, -8.0
    from scipy.spatial.transform import Rotation

    world_from_cam = Rotation.from_euler("ZYX", [30.0, -pitch, roll], degrees=True).as_matrix()
    R = world_from_cam.T
    np.testing.assert_allclose(R @ [0, 0, 1], camera_up(pitch, roll), atol=1e-12)
    center = np.array([4.0, 1.6, 1.5])
    img = Renderer(mesh).render(R, center, 512).rgb
    p = tmp_path / "tilted.jpg"
    p.write_bytes(write_gpano(cv2.imencode(".jpg", img[..., ::-1])[1].tobytes(), pitch, roll))
    loc = Localizer(read_map(tmp_path / "m.h5"), LocalizeParams())
    with pytest.raises(InputError, match="within the tilt bound"):
        loc.localize(load_image(p), max_tilt_deg=5.0)
    out = loc.localize(load_image(p), max_tilt_deg=5.0, camera_up=recorded_up(p))
    assert np.linalg.norm(out.center - center) < 0.1 and rotation_error_deg(out.rot_cam_from_world, R) < 5.0
    # the CLI: a panorama whose XMP pitch is nonsense fails in one line, and nothing is written
    from ldlloc.cli import app

    bad = tmp_path / "bad.jpg"
    bad.write_bytes(write_gpano(cv2.imencode(".jpg", img[..., ::-1])[1].tobytes(), 123, 0))
    line = error_line(runner.invoke(app, ["localize", str(tmp_path / "m.h5"), str(bad), "--max-tilt", "10"]))
    assert "PosePitchDegrees = 123 is outside" in line
