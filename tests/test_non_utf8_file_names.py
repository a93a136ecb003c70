"""File names that are not UTF-8 (``b"z\\xff.png"``, an output folder ``b"vis\\xe9"``): panoramas are
read and pictures written through Python's file I/O (:mod:`ldlmap.io.imagefile`), never by OpenCV
from a path, which crashed with SIGSEGV. Each command runs in its own process, as a user runs it (a
crash is exit 139, not a test runner gone)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests._results_files import record, write_results

pytestmark = pytest.mark.xdist_group("non_utf8_file_names")  # one worker makes ``room``

REPO = Path(__file__).resolve().parents[1]
TRUE_CENTER = np.array([0.3, -0.4, -0.1])


def _cli(program: str, *args: str | bytes | Path, cwd: Path) -> subprocess.CompletedProcess:
    """``python -m <program>.cli ARGS`` in ``cwd`` with byte-exact arguments."""
    argv = [sys.executable.encode(), b"-m", f"{program}.cli".encode(), *(os.fsencode(a) for a in args)]
    env = {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200"}
    return subprocess.run(argv, cwd=cwd, capture_output=True, env=env, timeout=600)


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A small box room's map (lines only) and a panorama of it saved as ``b"z\\xff.png"``."""
    import open3d as o3d

    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.imagefile import write_image
    from ldlmap.io.pointcloud import write_point_cloud
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.map.render import PointRenderer, RenderParams
    from tests._room_cloud import box_room

    tmp = tmp_path_factory.mktemp("non_utf8")
    P, _ = box_room(seed=0, density=800, size=(5.0, 4.0, 2.6))
    P = P - np.round(np.median(P, axis=0))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
    colors = (60 + 180 * np.abs(np.asarray(pc.normals))).astype(np.uint8)
    write_point_cloud(tmp / "room.ply", PointCloud(P, colors))
    build_map(tmp / "room.ply", tmp / "room.h5", params=BuildParams().replaced(features="none", num_translations=100,
                                                                     distance_fields=False))
    R = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.4)
    img = PointRenderer(P, colors, RenderParams(width=512, height=256)).render(R, TRUE_CENTER).rgb
    shots = tmp / "shots"
    shots.mkdir()
    pano = shots / os.fsdecode(b"z\xff.png")
    write_image(pano, img[..., ::-1])
    return tmp, tmp / "room.h5", pano


def test_localize_json_and_vis(room, tmp_path):
    _, map_path, pano = room
    vis = tmp_path / os.fsdecode(b"vis\xe9") / os.fsdecode(b"p\xff.jpg")
    done = _cli("ldlloc", "localize", map_path, pano, "--json", "--vis", vis, cwd=tmp_path)
    assert done.returncode == 0, done.stderr.decode(errors="replace")[-2000:]
    out = json.loads(done.stdout)
    assert out["picture_error"] is None and np.linalg.norm(np.array(out["t"]) - TRUE_CENTER) < 0.1
    from ldlmap.core.pictures import is_own_picture

    assert is_own_picture(vis)
    done = _cli("ldlloc", "localize", map_path, pano, "--vis", vis, cwd=tmp_path)  # printed, not JSON
    assert done.returncode == 0 and b"z\\udcff.png" in done.stdout, done.stderr.decode(errors="replace")[-2000:]


def test_report_html_of_a_non_utf8_image(room, tmp_path):
    _, _, pano = room
    results = write_results(tmp_path / "r.json", [record("z", pano)])
    page = tmp_path / os.fsdecode(b"r\xe9.html")
    done = _cli("ldlloc", "report", results, "--html", page, cwd=tmp_path)
    assert done.returncode == 0, done.stderr.decode(errors="replace")[-2000:]
    assert page.read_text(encoding="utf-8").count('class="thumb"') == 1


def test_save_vis_into_a_non_utf8_folder(room, tmp_path):
    """`run --images` with its pictures into ``b"out/vis\\xe9"`` (the results file of a panorama
    whose own name is not UTF-8 is the results writer's matter, not tested here)."""
    import shutil

    tmp, map_path, pano = room
    shutil.copy(pano, tmp_path / "pano.png")
    vis = tmp_path / "out" / os.fsdecode(b"vis\xe9")
    done = _cli("ldlloc", "run", "--images", tmp_path / "pano.png", "--maps", map_path, "--save-vis", vis,
                "-o", tmp_path / "r.json", cwd=tmp_path)
    assert done.returncode == 0, done.stderr.decode(errors="replace")[-2000:]
    assert len(list(vis.rglob("*.jpg"))) == 1


def test_colmap_export_refuses_a_non_utf8_name_in_one_line(room, tmp_path):
    _, _, pano = room
    results = write_results(tmp_path / "r.json", [record("z", pano)])
    done = _cli("ldlloc", "export", results, "--format", "colmap", "-o", tmp_path / "model", cwd=tmp_path)
    err = done.stderr.decode(errors="replace").strip().splitlines() + done.stdout.decode(errors="replace").strip(
    ).splitlines()
    assert done.returncode == 1 and len(err) == 1 and "not valid UTF-8" in err[0], err
    assert not (tmp_path / "model").exists()
