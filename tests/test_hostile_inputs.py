"""Hostile scanner, phone and BIM files and the options that go with them (docs/inputs.md): one
line ``error: ...``, exit 1, nothing written (no map, no temporary file, no panorama folder)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlmap.cli import app
from tests._hostile import assert_clean_failure, snapshot

runner = CliRunner()


def _e57(d, stations=1, images=()):
    from ldlmap.io.e57 import StationToWrite, write_e57

    pts = np.random.default_rng(0).uniform(0, 4, (400, 3))
    return write_e57(d / "s.e57", [StationToWrite(pts, name=f"st{i}") for i in range(stations)], list(images))


def _truncated_e57(d):
    data = _e57(d).read_bytes()
    (d / "s.e57").unlink()
    p = d / "cut.e57"
    p.write_bytes(data[: len(data) // 2])
    return p


def _no_points_e57(d):
    return _e57(d, stations=0)


def _las_no_colour(d):
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.las import write_las

    return write_las(d / "grey.las", PointCloud(np.random.default_rng(0).uniform(0, 4, (500, 3))))


def _laz_cut(d):
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.las import write_las

    p = write_las(d / "a.laz", PointCloud(np.random.default_rng(0).uniform(0, 4, (5000, 3))))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 3])
    return p


def _gltf_no_mesh(d):
    import json

    p = d / "empty.gltf"
    p.write_text(json.dumps({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"name": "n"}]}))
    return p


def _glb_garbage(d):
    p = d / "bad.glb"
    p.write_bytes(b"glTF\x02\x00\x00\x00" + b"\x00" * 40)
    return p


def _ifc(d, storeys=True, units="metre"):
    from ldlmap.synth.ifc import StoreyToWrite, write_ifc
    from ldlmap.synth.spec import SceneSpec

    room = SceneSpec("box", ((0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (0.0, 3.0)), 2.5)
    return write_ifc(d / "m.ifc", [StoreyToWrite("L0", 0.0, [room]), StoreyToWrite("L1", 3.0, [room])] if storeys else [],
                     units=units)


def _ifc_no_storeys(d):
    return _ifc(d, storeys=False)


def _ifc_text(d):
    p = d / "bad.ifc"
    p.write_text("ISO-10303-21;\nHEADER;\nthis is not a model\n")
    return p


def _ply_room(d):
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.pointcloud import write_point_cloud

    return write_point_cloud(d / "room.ply", PointCloud(np.random.default_rng(0).uniform(0, 4, (500, 3))))


# (case id, make the input, extra options, words the error line must hold)
CASES = [
    ("e57-truncated", _truncated_e57, [], "cannot read E57"),
    ("e57-no-points", _no_points_e57, [], "no scan stations"),
    ("e57-unknown-station", _e57, ["--stations", "st7"], "no such station"),
    ("e57-empty-station-list", _e57, ["--stations", "st0,,"], "separated by commas"),
    ("las-no-colour", _las_no_colour, [], "no colors"),
    ("laz-truncated", _laz_cut, [], "cannot read LAS/LAZ"),
    ("gltf-no-mesh", _gltf_no_mesh, [], "no triangle mesh"),
    ("glb-garbage", _glb_garbage, [], "cannot read glTF"),
    ("ifc-no-storeys", _ifc_no_storeys, [], "no storeys"),
    ("ifc-not-a-model", _ifc_text, [], "cannot read IFC"),
    ("ifc-unknown-storey", _ifc, ["--storey", "L9"], "no such storey"),
    ("ifc-unknown-class", _ifc, ["--include", "IfcCoffeeMachine"], "not an IFC class"),
    ("ifc-one-file-for-storeys", _ifc, ["-o", "maps.h5"], "give -o a folder"),
    ("ifc-scale", _ifc, ["--scale", "0.3048"], "do not apply"),
    ("ifc-png-many-storeys", _ifc, ["--png", "top.png"], "pick a storey"),
    ("ifc-lines-option", _ifc, ["--lines", "x.txt"], "do not apply"),
    ("ifc-include-empty", _ifc, ["--storey", "L0", "--include", ""], "class names separated by commas"),
    ("ifc-band-above-ceiling", _ifc, ["--storey", "L0", "--camera-height", "5:6"], "above the ceiling of storey 'L0'"),
    ("gltf-not-json", lambda d: (d / "g.gltf").write_text("{not json") and d / "g.gltf", [], "not JSON"),
    ("stations-on-a-ply", _ply_room, ["--stations", "0"], "goes with an E57"),
    ("storey-on-a-ply", _ply_room, ["--storey", "L0"], "goes with an IFC"),
    ("include-on-a-ply", _ply_room, ["--include", "IfcBeam"], "goes with an IFC"),
]


@pytest.mark.parametrize("case, make, options, words", CASES, ids=[c[0] for c in CASES])
def test_bad_scanner_and_bim_inputs_fail_in_one_line(tmp_path, case, make, options, words):
    src = make(tmp_path)
    if "--lines" in options:
        (tmp_path / "x.txt").write_text("0 0 0 1 0 0\n")
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["build", str(src), *[str(tmp_path / o) if o in ("maps.h5", "top.png") else o
                                                    for o in options]])
    line = assert_clean_failure(res, tmp_path, before)
    assert words in line, line


def test_ifc_in_feet_is_converted_not_refused(tmp_path):
    from ldlmap.io.ifc import read_ifc

    storeys, note = read_ifc(_ifc(tmp_path, units="foot"), "L1")
    assert "feet" in note and storeys[0].elevation == pytest.approx(3.0)
    assert storeys[0].vertices[:, :2].max() == pytest.approx(4.2, abs=1e-6)  # 4 m room, 0.2 m walls: metres


def test_e57_images_command_bad_inputs(tmp_path):
    from ldlmap.io.e57 import ImageToWrite

    bad_jpeg = b"\xff\xd8not really a jpeg"
    for i, images in enumerate(([], [ImageToWrite("p", np.eye(3), np.zeros(3), bad_jpeg, 64, 32)],
                                [ImageToWrite("p", np.eye(3), np.zeros(3), bad_jpeg, 64, 32, kind="pinhole")])):
        d = tmp_path / str(i)
        d.mkdir()
        src = _e57(d, images=images)
        before = snapshot(d)
        line = assert_clean_failure(runner.invoke(app, ["e57", str(src), "--images", str(d / "out")]), d, before)
        assert "nothing to write" in line, line
    src = _e57(tmp_path)
    line = assert_clean_failure(runner.invoke(app, ["e57", str(src), "--images", str(src)]), tmp_path, snapshot(tmp_path))
    assert "would replace the input" in line, line
