"""The first ten minutes of a new user: line files given to `ldlmap lines`, picture
formats, `ldlloc localize --gt` and JSON errors, principal directions in `ldlmap info`, and CLI
modules that import nothing heavy."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlmap.cli import app as map_app
from tests._hostile import error_line

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]

# One small file per line-file format that `ldlmap lines` must recognise (docs/formats.md).
LINE_FILES = {
    "ours.txt": "# ldl lines v1\n0 0 0 1 0 0\n0 0 0 0 1 0\n1 1 0 1 1 2\n",
    "line3dpp.txt": "1 0 0 0 1 0 0 1 0 3 10 10 20 20\n2 0 0 0 0 1 0 0 1 0 0 1 1 0\n",
    "lsd3d.txt": "0 0 0 1\n0.5 0 0 1\n1 0 0 1\n0 0 0 2\n0 1 0 2\n",
    "lines.obj": "v 0 0 0\nv 1 0 0\nv 1 1 0\nl 1 2\nl 2 3\n",
}


# ---------------------------------------------------------------------------- 1: line files


@pytest.mark.parametrize("name", sorted(LINE_FILES))
def test_lines_says_what_to_do_with_a_line_file(tmp_path, name):
    src = tmp_path / name
    src.write_text(LINE_FILES[name])
    out = tmp_path / "out" / "lines.obj"
    line = error_line(runner.invoke(map_app, ["lines", str(src), "-o", str(out), "--png", str(tmp_path / "t.png")]))
    assert "is a 3D line file" in line and "not a scan" in line
    assert f"ldlmap build {src}" in line and f"--lines {src}" in line
    assert not (tmp_path / "out").exists() and not (tmp_path / "t.png").exists()


def test_line_files_are_told_from_clouds_and_meshes(tmp_path):
    from ldlmap.io.linefiles import read_lines, sniff_line_file

    for name, text in LINE_FILES.items():
        (tmp_path / name).write_text(text)
        assert sniff_line_file(tmp_path / name) is not None, name
        assert len(read_lines(tmp_path / name)) >= 2
    others = {
        "xyz.txt": "0 0 0\n1 0 0\n0 1 0\n",
        "xyzrgb.txt": "0 0 0 255 0 0\n1 0 0 0 255 0\n",  # 6 columns: a colored cloud, even with integer ends
        "count.txt": "2\n0 0 0\n1 1 1\n",
        "mesh.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nf 1 2 3\n",
        "nan.txt": "0 0 0 1\nnan 0 0 1\n",
        "words.txt": "hello world\n",
        "cloud.ply": "ply\n",
    }
    for name, text in others.items():
        (tmp_path / name).write_text(text)
        assert sniff_line_file(tmp_path / name) is None, name
    assert sniff_line_file(tmp_path / "missing.txt") is None


def test_build_reads_a_line_file_by_content(tmp_path):
    """Our .txt rows would pass for a 6-column cloud: `build` must take them as lines."""
    from ldlmap.map.inputs import load_input
    from ldlmap.core.errors import InputError

    src = tmp_path / "ours.txt"
    src.write_text(LINE_FILES["ours.txt"])
    got = load_input(src, None, 1000)
    assert got.points is None and got.lines.shape == (3, 2, 3)
    with pytest.raises(InputError, match="not a scan"):
        load_input(src, src, 1000)


# ---------------------------------------------------------------------------- 2: pictures

MAGIC = {".png": b"\x89PNG", ".jpg": b"\xff\xd8\xff", ".jpeg": b"\xff\xd8\xff", ".bmp": b"BM",
         ".tif": (b"II*\x00", b"MM\x00*"), ".tiff": (b"II*\x00", b"MM\x00*"), ".webp": b"RIFF"}


def has_format(path: Path, ext: str) -> bool:
    head = path.read_bytes()[:12]
    return head.startswith(MAGIC[ext]) and (ext != ".webp" or head[8:12] == b"WEBP")


def test_pictures_are_written_in_the_format_of_their_extension(tmp_path):
    from ldlmap.core.errors import InputError
    from ldlmap.core.pictures import PICTURE_SUFFIXES, check_picture_path, write_picture

    img = np.zeros((40, 60, 3), np.uint8)
    img[10:30, 20:40] = (0, 128, 255)
    for ext in PICTURE_SUFFIXES:
        for suffix in (ext, ext.upper()):
            p = write_picture(tmp_path / f"pic{suffix}", img)
            assert has_format(p, ext), suffix
    for bad in ("x.gif", "x", "x.h5", "x.jpg.txt"):
        with pytest.raises(InputError, match="cannot write"):
            check_picture_path(tmp_path / bad, "--vis")
    with pytest.raises(InputError, match="--png x.gif"):
        check_picture_path("x.gif", "--png")
    with pytest.raises(InputError, match="cannot write .gif"):
        write_picture(tmp_path / "x.gif", img)
    assert not list(tmp_path.glob("x*")) and not list(tmp_path.glob(".*tmp*"))


def test_picture_options_refuse_unknown_formats_before_any_work(tmp_path):
    cloud = tmp_path / "room.txt"
    np.savetxt(cloud, np.random.default_rng(0).uniform(0, 3, size=(300, 3)))
    out = tmp_path / "out" / "lines.obj"
    assert "--png" in error_line(runner.invoke(map_app, ["lines", str(cloud), "-o", str(out), "--png",
                                                         str(tmp_path / "top.gif")]))
    assert "--png" in error_line(runner.invoke(map_app, ["build", str(cloud), "-o", str(tmp_path / "m.h5"),
                                                         "--png", str(tmp_path / "m.gif")]))
    missing = tmp_path / "missing.h5"  # refused before the map (or the image) is even looked at
    assert "--vis" in error_line(runner.invoke(loc_app, ["localize", str(missing), str(tmp_path / "p.jpg"),
                                                         "--vis", str(tmp_path / "v.gif")]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.txt"]


def test_top_view_picture_is_a_jpeg_when_asked(tmp_path):
    from ldlmap.lines3d import draw_top_view

    segs = np.array([[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [0, 1, 0]], [[0, 0, 0], [0, 0, 1]]], float)
    draw_top_view(segs, str(tmp_path / "top.jpg"), size=64)
    assert has_format(tmp_path / "top.jpg", ".jpg")


# --------------------------------------------------------------------- 3: --gt and JSON errors


def test_localize_gt_prints_errors_and_threshold(demo_dataset, tmp_path):
    from ldlmap.datasets import read_pose_txt, write_pose_txt

    map_path = demo_dataset / "maps" / "synthroom_1.h5"
    img = sorted((demo_dataset / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[0]
    pose = Path(str(img).replace("_pano", "_pose")).with_suffix(".txt")
    res = runner.invoke(loc_app, ["localize", str(map_path), str(img), "--json", "--gt", str(pose),
                                  "--vis", str(tmp_path / "v.png")])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    R, t = read_pose_txt(pose)
    assert out["t_error_m"] == pytest.approx(np.linalg.norm(np.array(out["t"]) - t), abs=1e-5)
    assert out["t_error_m"] < 0.1 and out["r_error_deg"] < 5 and out["localized"] is True
    assert out["gt"] == str(pose) and set(out["load_seconds"]) == {"read_map", "wait_map", "setup"}
    assert has_format(tmp_path / "v.png", ".png")
    # A known pose 1 m away: the same estimate is 1 m off and not localized (text output).
    far = tmp_path / "far.txt"
    write_pose_txt(far, R, t + np.array([0.6, 0.8, 0.0]))
    res = runner.invoke(loc_app, ["localize", str(map_path), str(img), "--gt", str(far)])
    assert res.exit_code == 0, res.output
    line = next(x for x in res.output.splitlines() if x.startswith("error against far.txt"))
    err_m = float(line.split(":")[1].split("m,")[0])
    assert abs(err_m - 1.0) < 0.1 and "not localized (not within 0.1 m / 5 deg)" in line


def test_gt_reads_the_stanford_pose_json(tmp_path):
    from ldlmap.datasets import read_pose_file, read_stanford_pose

    p = tmp_path / "camera_x_office_1_frame_equirectangular_domain_pose.json"
    p.write_text(json.dumps({"camera_location": [1.0, 2.0, 1.5], "final_camera_rotation": [1.4, 0.02, 2.1]}))
    R, t = read_pose_file(p)
    R2, t2 = read_stanford_pose(p)
    np.testing.assert_allclose(R, R2)
    np.testing.assert_allclose(t, [1.0, 2.0, 1.5])
    (tmp_path / "pose.yaml").write_text("t: [0, 0, 0]\n")
    res = runner.invoke(loc_app, ["localize", str(tmp_path / "m.h5"), str(tmp_path / "p.jpg"),
                                  "--gt", str(tmp_path / "pose.yaml")])
    assert "unsupported pose file" in error_line(res)


def test_json_errors_are_json(tmp_path):
    missing = tmp_path / "missing.h5"
    img = tmp_path / "pano.jpg"
    for args, code, needle in (
        ([str(missing), str(img), "--json"], 1, "image not found"),
        ([str(missing), str(img), "--json", "--vis", str(tmp_path / "v.gif")], 1, "--vis"),
        ([str(missing), str(img), "--json", "--gt", str(tmp_path / "none.txt")], 1, "pose file not found"),
        ([str(missing), str(img), "--json", "--top-k", "abc"], 2, "--top-k"),
        ([str(missing), str(img), "--json", "--top-k", "0"], 1, "--top-k"),
    ):
        res = runner.invoke(loc_app, ["localize", *args])
        assert res.exit_code == code, res.output
        assert "Traceback" not in res.output
        assert needle in json.loads(res.stdout)["error"], res.stdout
    # Without --json the same error stays one plain line.
    assert "image not found" in error_line(runner.invoke(loc_app, ["localize", str(missing), str(img)]))
    # With a readable panorama, the missing map (read in a thread beside the imports) is the error.
    import cv2

    pano = tmp_path / "real.png"
    cv2.imwrite(str(pano), np.zeros((64, 128, 3), np.uint8))  # the smallest panorama ldlloc reads
    res = runner.invoke(loc_app, ["localize", str(missing), str(pano), "--json"])
    assert res.exit_code == 1 and "map not found" in json.loads(res.stdout)["error"]
    (tmp_path / "bad.h5").write_text("not a map")
    res = runner.invoke(loc_app, ["localize", str(tmp_path / "bad.h5"), str(pano), "--json"])
    assert res.exit_code == 1 and "HDF5" in json.loads(res.stdout)["error"]


def test_a_failed_localization_is_a_json_error(demo_dataset, tmp_path):
    import cv2

    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), np.full((256, 512, 3), 128, np.uint8))
    res = runner.invoke(loc_app, ["localize", str(demo_dataset / "maps" / "synthroom_1.h5"), str(grey), "--json"])
    assert res.exit_code == 1 and "lines" in json.loads(res.stdout)["error"]


# ------------------------------------------------------------------------------ 4: info


def test_info_shows_principal_directions_and_group_counts(tmp_path):
    from ldlmap.map.mapfile import read_map_header, write_map
    from tests.test_mapfile import make_map

    m = make_map()
    a = np.radians(88.0)
    m.principal_directions = np.array([[1.0, 0.0, 0.0], [np.cos(a), np.sin(a), 0.0], [0.0, 0.0, 1.0]])
    p = write_map(tmp_path / "room_1.h5", m)
    assert read_map_header(p)["line_group_counts"] == {g: int(np.sum(m.line_groups == g)) for g in (0, 1, 2, -1)}
    res = runner.invoke(map_app, ["info", str(p)])
    assert res.exit_code == 0, res.output
    text = res.output
    assert "principal directions" in text and "d0 = [ 1.0000,  0.0000,  0.0000]" in text
    assert "d1 = [ 0.0349,  0.9994,  0.0000]" in text
    assert "d0-d1 88.00 deg" in text and "d0-d2 90.00 deg" in text and "d1-d2 90.00 deg" in text
    for g in (0, 1, 2):
        row = next(x for x in text.splitlines() if f"d{g} = [" in x)
        assert f"{int(np.sum(m.line_groups == g))} lines" in row
    row = next(x for x in text.splitlines() if "lines in no group" in x)
    assert str(int(np.sum(m.line_groups == -1))) in row


# ------------------------------------------------------------------------- 5: light imports


def test_cli_modules_import_nothing_heavy():
    """`ldlmap --help` / `ldlloc --help` must not pay for torch, open3d and friends."""
    heavy = ("torch", "open3d", "cv2", "h5py", "scipy", "pycolmap", "pymeshlab", "numpy")
    code = ("import json, sys; import ldlmap.cli, ldlloc.cli; "
            f"print(json.dumps([m for m in {heavy!r} if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert json.loads(out.stdout) == []


@pytest.mark.parametrize("module", ["ldlmap.cli", "ldlloc.cli"])
def test_help_runs_as_a_module(module):
    out = subprocess.run([sys.executable, "-m", module, "--help"], cwd=ROOT, capture_output=True, text=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "COLUMNS": "120"})
    assert out.returncode == 0 and "Usage" in out.stdout and ("localize" in out.stdout or "build" in out.stdout)


def test_distance_fields_reject_non_finite_float16_values():
    """Setup checks the float16 fields from their bits (a float16 pass took up to 0.5 s per map)."""
    from ldlloc.search.fields import DistanceFields
    from ldlmap.core.errors import InputError

    G = 4
    d = np.random.default_rng(0).uniform(0, 1.5, size=(3, 3, G + 1, 2 * G)).astype(np.float16)
    d[0, 0, 0, 0] = -0.0  # finite values of either sign pass
    d[0, 0, 0, 1] = -1.0
    DistanceFields.from_arrays(d, {"rows": G})
    for bad in (np.nan, np.inf, -np.inf):
        e = d.copy()
        e[2, 1, G, 2 * G - 1] = bad
        with pytest.raises(InputError, match="NaN or infinite"):
            DistanceFields.from_arrays(e, {"rows": G})
        with pytest.raises(InputError, match="NaN or infinite"):
            DistanceFields.from_arrays(e.astype(np.float32), {"rows": G})


@pytest.mark.parametrize("app_name,command", [("ldlmap", c) for c in ("info", "lines", "synth", "build", "prepare")]
                         + [("ldlloc", c) for c in ("localize", "run", "report", "export")] + [("ldlmap", None), ("ldlloc", None)])
def test_help_is_not_an_error(app_name, command):
    """--help ends a command through click's/typer's own exit: exit 0, the help, no error line."""
    res = runner.invoke(map_app if app_name == "ldlmap" else loc_app, [c for c in (command, "--help") if c])
    assert res.exit_code == 0 and "Usage" in res.output and "error" not in res.output.lower().split("usage")[0], res.output
    assert "internal error" not in res.output
