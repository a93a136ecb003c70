"""Refusals across the commands, each a way input once went wrong: outputs that must not replace
other files (data loss), crashes, wrong successes and their messages. Small inputs: one small
synthetic room (``small``), a lines-only map and a SIFT map of it built here, datasets of a few
symlinked panoramas."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.batch.results import read_results_data
from ldlloc.cli import app as loc_app
from ldlmap.cli import app as map_app
from tests._hostile import assert_clean_failure, error_line, snapshot

pytestmark = pytest.mark.xdist_group("hostile_refusals")  # one worker makes ``small`` and its maps
runner = CliRunner()
REPO = Path(__file__).resolve().parent.parent
SCENE = "box_1"
BOX_SPEC = """
name = "box"
footprint = [[0.0, 0.0], [3.0, 0.0], [3.0, 2.5], [0.0, 2.5]]
ceiling_height = 2.5

[scan]
density = 1500.0
holes = 0

[[objects]]
kind = "table"
center = [1.0, 1.0]
size = [0.8, 0.6, 0.75]
"""
SMALL = ["--width", "64", "--per-split", "1", "--no-illumination", "--quiet"]


def _ok(res) -> None:
    assert res.exit_code == 0, res.output


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """A synthetic dataset of one small room (``box_1``), 64 x 32 panoramas, one per split."""
    root = tmp_path_factory.mktemp("h24") / "small"
    spec = root.parent / "box.toml"
    spec.write_text(BOX_SPEC)
    _ok(runner.invoke(map_app, ["synth", str(root), "--spec", str(spec), "--seed", "3", *SMALL]))
    return root


@pytest.fixture(scope="module")
def line_map(small) -> Path:
    """A lines-only map of the room's true edges, candidates 1 m apart."""
    out = small.parent / "maps_lines" / f"{SCENE}.h5"
    _ok(runner.invoke(map_app, ["build", str(small / "gt_lines" / f"{SCENE}.obj"), "-o", str(out),
                                "--trans-spacing", "1.0"]))
    return out


@pytest.fixture(scope="module")
def sift_map(small) -> Path:
    """A SIFT map of the room's scan (few translations and views: a run imports pycolmap with it)."""
    out = small.parent / "maps_sift" / f"{SCENE}.h5"
    _ok(runner.invoke(map_app, ["build", str(small / "pcd" / f"{SCENE}.ply"), "-o", str(out), "--num-trans", "10",
                                "--num-views", "2", "--features", "sift"]))
    return out


def dataset_of(small: Path, root: Path, n: int) -> Path:
    """A synthetic dataset root of ``n`` robot queries of ``box_1`` (links to one panorama and pose)."""
    pano = next((small / "robot_pano").rglob("*.jpg"))
    pose = next((small / "robot_pose").rglob("*.txt"))
    folder = f"robot_{SCENE}_scene_1"
    (root / "robot_pano" / folder).mkdir(parents=True)
    (root / "robot_pose" / folder).mkdir(parents=True)
    for i in range(n):
        (root / "robot_pano" / folder / f"{i:04d}.jpg").symlink_to(pano)
        (root / "robot_pose" / folder / f"{i:04d}.txt").symlink_to(pose)
    (root / "dataset.json").write_text((small / "dataset.json").read_text())
    return root


def run_args(root: Path, maps: Path, output: Path, *more: str) -> list[str]:
    return ["run", "--root", str(root), "--maps", str(maps), "-o", str(output), *more]


# ------------------------------------------------------------------------------ 2. data loss


def test_run_refuses_replacing_a_json_that_is_not_results(small, line_map, tmp_path):
    root = dataset_of(small, tmp_path / "ds", 2)
    notes = tmp_path / "notes.json"
    notes.write_text('{"my": "notes"}')
    before = snapshot(tmp_path)
    line = assert_clean_failure(runner.invoke(loc_app, run_args(root, line_map.parent, notes)), tmp_path, before)
    assert "is not a results file" in line and "--overwrite" in line
    res = runner.invoke(loc_app, run_args(root, line_map.parent, notes, "--overwrite"))
    assert json.loads(notes.read_text())["summary"]["count"] == 2, res.output  # replaced when asked
    (tmp_path / "table.csv").write_text("my,own\n1,2\n")  # where the CSV of -o table.json would go
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, run_args(root, line_map.parent, tmp_path / "table.json"))
    assert "is not a results CSV" in assert_clean_failure(res, tmp_path, before)


def test_run_never_writes_over_the_dataset_manifest(small, line_map, tmp_path):
    root = dataset_of(small, tmp_path / "ds", 2)
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, run_args(root, line_map.parent, root / "dataset.json", "--overwrite"))
    assert "would replace the input" in assert_clean_failure(res, tmp_path, before)


def test_build_refuses_replacing_an_hdf5_file_that_is_not_a_map(small, tmp_path):
    import h5py

    user = tmp_path / "user.h5"
    with h5py.File(user, "w") as h5:
        h5["measurements"] = np.arange(5.0)
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["build", str(small / "gt_lines" / f"{SCENE}.obj"), "-o", str(user)])
    assert "is not an LDL map" in assert_clean_failure(res, tmp_path, before)


def test_synth_overwrite_keeps_the_files_it_did_not_write(small, tmp_path):
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(small, root)
    mine = {"MY_NOTES.txt": "notes", "results/all.json": "{}", "maps/box_1.h5": "map", "pcd/mine.txt": "1 2 3"}
    for rel, text in mine.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    old = json.loads((root / "dataset.json").read_text())
    spec = tmp_path / "box.toml"
    spec.write_text(BOX_SPEC)
    res = runner.invoke(map_app, ["synth", str(root), "--spec", str(spec), "--seed", "4", *SMALL, "--overwrite"])
    _ok(res)
    assert {rel: (root / rel).read_text() for rel in mine} == mine  # every file of the user's, unchanged
    assert "kept 4 file(s)" in res.output
    new = json.loads((root / "dataset.json").read_text())
    assert new["seed"] == 4 and old["seed"] == 3
    written = {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()}
    assert written == set(new["files"]) | {"dataset.json"} | set(mine)  # nothing of the old generation left


# -------------------------------------------------------------------------------- 3. crashes


def _limit_file_size() -> None:
    """In the child: files larger than 4 kB cannot be written (EFBIG, as a full disk's ENOSPC)."""
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)


def test_build_on_a_full_disk_is_one_line_without_temporaries(small, tmp_path):
    out = tmp_path / "full" / "gt.h5"
    out.parent.mkdir()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-m", "ldlmap.cli", "build", str(small / "gt_lines" / f"{SCENE}.obj"),
                           "-o", str(out), "--trans-spacing", "1.0"], capture_output=True, text=True, env=env,
                          cwd=tmp_path, preexec_fn=_limit_file_size, timeout=300)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 1, (proc.returncode, proc.stderr[-2000:])
    assert lines == [f"error: cannot write map {out}: File too large"], proc.stderr[-2000:]
    assert list(out.parent.iterdir()) == []  # no map, no temporary


def _scan(path: Path, scale: float) -> Path:
    """A box-room scan (5 x 4 x 2.6 m, ~9k points) multiplied by ``scale``."""
    from ldlmap.synth.scan import write_ply
    from tests._room_cloud import box_room

    P, _ = box_room(seed=0, density=150, size=(5.0, 4.0, 2.6))
    write_ply(path, P * scale, np.full((len(P), 3), 128, np.uint8))
    return path


@pytest.mark.parametrize("scale, words", [(2e6, "far too large for metres"), (1000.0, "millimetres?")],
                         ids=["enormous", "millimetres"])
def test_lines_refuses_a_scan_not_in_metres_before_the_work(tmp_path, scale, words):
    scan = _scan(tmp_path / "scan.ply", scale)
    before = snapshot(tmp_path)
    line = assert_clean_failure(runner.invoke(map_app, ["lines", str(scan), "-o", str(tmp_path / "out.obj")]),
                                tmp_path, before)
    assert words in line and "--scale 0.001" in line


# ------------------------------------------------------------------------ 4. wrong successes


def _pcd(path: Path, n: int, keep: float) -> Path:
    """An ASCII PCD of ``n`` coloured points, cut after the first ``keep`` of its text."""
    rng = np.random.default_rng(0)
    P, C = rng.uniform(0, 3, (n, 3)), rng.integers(0, 256, (n, 3))
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH {n}\n"
            f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n")
    rows = "".join(f"{p[0]:.4f} {p[1]:.4f} {p[2]:.4f} {c[0] * 65536 + c[1] * 256 + c[2]}\n" for p, c in zip(P, C))
    path.write_text(head + rows[: int(len(rows) * keep)])
    return path


def test_a_truncated_ascii_pcd_is_refused(tmp_path):
    from ldlmap.core.errors import InputError
    from ldlmap.io.pointcloud import read_point_cloud

    assert len(read_point_cloud(_pcd(tmp_path / "whole.pcd", 3000, 1.0))) == 3000
    with pytest.raises(InputError, match="header says 3000 points, it holds 100:"):
        read_point_cloud(_pcd(tmp_path / "cut.pcd", 3000, 0.033))
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["build", str(tmp_path / "cut.pcd"), "-o", str(tmp_path / "m.h5")])
    assert "truncated PCD" in assert_clean_failure(res, tmp_path, before)


@pytest.mark.parametrize("band, words", [("-1:2", "0 <= MIN <= MAX"), ("0:0", "MAX > 0"),
                                         ("5:9", "lies above the ceiling")])
def test_a_camera_height_band_must_meet_the_room(small, tmp_path, band, words):
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["build", str(small / "gt_lines" / f"{SCENE}.obj"), "-o", str(tmp_path / "m.h5"),
                                  "--trans-spacing", "1.0", "--camera-height", band])
    assert words in assert_clean_failure(res, tmp_path, before)


def test_a_scan_map_keeps_its_candidates_in_the_camera_height_band(small, tmp_path):
    """``--camera-height`` on a scan: the N_t candidates stand MIN-MAX m above the scan's floor (its
    lowest surface), as ``map info`` says; a band above the ceiling is one line, no file."""
    from ldlmap.map.mapfile import read_map

    scan, out = small / "pcd" / f"{SCENE}.ply", tmp_path / "band.h5"
    _ok(runner.invoke(map_app, ["build", str(scan), "-o", str(out), "--features", "none", "--num-trans", "60",
                                "--camera-height", "1.0:1.4"]))
    m = read_map(out, load_cloud=False)
    floor = float(np.percentile(m.lines[..., 2], 0.5))
    z = m.translations[:, 2] - floor
    assert len(z) >= 40 and z.min() >= 1.0 - 0.15 and z.max() <= 1.4 + 0.15, (z.min(), z.max())
    info = runner.invoke(map_app, ["info", str(out)])
    assert "1.00-1.40 m above the floor" in info.output
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["build", str(scan), "-o", str(tmp_path / "high.h5"), "--features", "none",
                                  "--num-trans", "60", "--camera-height", "8:9"])
    assert "within 8-9 m above the floor" in assert_clean_failure(res, tmp_path, before)


def test_a_scan_map_of_sparse_candidates_warns(small, tmp_path):
    """A scan whose N_t candidates stand far apart (a whole floor at one room's N_t; here 10 in a room)
    says so, with the options that help; a room at its usual density does not."""
    scan = small / "pcd" / f"{SCENE}.ply"
    sparse = runner.invoke(map_app, ["build", str(scan), "-o", str(tmp_path / "sparse.h5"), "--features", "none",
                                     "--num-trans", "10"])
    _ok(sparse)
    text = " ".join(sparse.output.split())
    assert "candidate translations stand a median" in text and "--num-trans" in text and "--camera-height" in text
    dense = runner.invoke(map_app, ["build", str(scan), "-o", str(tmp_path / "dense.h5"), "--features", "none",
                                    "--num-trans", "400"])
    _ok(dense)
    assert "stand a median" not in " ".join(dense.output.split())


def test_prepare_zind_checks_the_camera_height_band(tmp_path):
    from tests.test_zind import write_tiny_home

    write_tiny_home(tmp_path / "zind")
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["prepare", str(tmp_path / "zind"), "--dataset", "zind", "--maps",
                                  str(tmp_path / "maps"), "--camera-height", "-1:2"])
    assert "0 <= MIN <= MAX" in assert_clean_failure(res, tmp_path, before)


def _record(**fields) -> dict:
    from dataclasses import asdict

    from ldlloc.batch.accuracy import QueryResult

    r = asdict(QueryResult(image="a.jpg", scene=SCENE, split="robot", name=f"robot/{SCENE}_scene_1/0000",
                           R=np.eye(3).tolist(), t=[1.0, 1.0, 1.0], t_error_m=0.01, r_error_deg=0.2))
    return {**r, **fields}


@pytest.mark.parametrize("lacks", ["status", "t_error_m"])
def test_records_lacking_status_or_errors_are_refused(small, line_map, tmp_path, lacks):
    rec = _record()
    del rec[lacks]
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"format_version": 1, "meta": {}, "queries": [rec]}))
    before = snapshot(tmp_path)
    line = assert_clean_failure(runner.invoke(loc_app, ["report", str(path)]), tmp_path, before)
    assert f"queries[0] lacks {lacks}, query robot/{SCENE}_scene_1/0000" in line
    root = dataset_of(small, tmp_path / "ds", 1)
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, run_args(root, line_map.parent, path, "--resume"))
    assert f"lacks {lacks}" in assert_clean_failure(res, tmp_path, before)


def test_localize_refuses_an_absurd_ground_truth(small, line_map, tmp_path):
    pose = tmp_path / "pose.txt"
    pose.write_text("1 0 0 1e300\n0 1 0 0\n0 0 1 0\n")
    pano = next((small / "robot_pano").rglob("*.jpg"))
    for extra in ([], ["--json"]):
        res = runner.invoke(loc_app, ["localize", str(line_map), str(pano), "--gt", str(pose), *extra])
        assert res.exit_code == 1 and "beyond 1e+08" in res.output and "inf" not in res.output, res.output


def test_maps_with_absurd_coordinates_are_refused(line_map, small, tmp_path):
    import shutil

    import h5py

    from ldlmap.map import mapfile

    bad = tmp_path / "far.h5"
    shutil.copy(line_map, bad)
    with h5py.File(bad, "a") as h5:  # one segment end at 1e30 m, checksums made to agree
        seg = h5["lines/segments"][...]
        seg[0, 1, 0] = 1e30
        h5["lines/segments"][...] = seg
        h5.attrs[mapfile._CHECKSUMS] = json.dumps(mapfile._checksums(*mapfile._read_datasets(h5, bad)), sort_keys=True)
    pano = next((small / "robot_pano").rglob("*.jpg"))
    for args in (["info", str(bad)], ["localize", str(bad), str(pano)]):
        res = runner.invoke(map_app if args[0] == "info" else loc_app, args)
        assert "lines has coordinates of 1e+30 m" in error_line(res), res.output


def test_prepare_zind_on_a_tour_without_rooms_is_an_error(tmp_path):
    from tests.test_zind import tiny_home_json, write_tiny_home

    data = tiny_home_json()
    data["merger"]["floor_01"] = {}
    write_tiny_home(tmp_path / "zind", data)
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["prepare", str(tmp_path / "zind"), "--dataset", "zind", "--maps",
                                  str(tmp_path / "maps")])
    assert "no complete room" in assert_clean_failure(res, tmp_path, before)


def test_a_self_intersecting_zind_room_is_left_out_with_a_warning(tmp_path):
    from ldlmap.io.zind import read_zind_home
    from tests.test_zind import tiny_home_json, write_tiny_home

    data = tiny_home_json()
    pano = data["merger"]["floor_01"]["complete_room_01"]["partial_room_01"]["pano_1"]
    pano["layout_complete"]["vertices"] = [[-1.0, -1.0], [2.0, 1.5], [2.0, -1.0], [-1.0, 1.5]]  # a bow tie
    pano["layout_complete"]["doors"] = pano["layout_complete"]["openings"] = []
    home = write_tiny_home(tmp_path / "zind", data)
    h = read_zind_home(home)
    assert sorted(r for _, r in h.rooms) == ["complete_room_02"]
    assert len(h.warnings) == 1 and "complete_room_01" in h.warnings[0] and "crosses itself" in h.warnings[0]
    res = runner.invoke(map_app, ["prepare", str(tmp_path / "zind"), "--dataset", "zind", "--maps",
                                  str(tmp_path / "maps")])
    assert res.exit_code == 0 and "complete_room_01 left out" in res.output, res.output
    assert sorted(p.name for p in (tmp_path / "maps").rglob("*.h5")) == ["complete_room_02.h5"]


def test_lines_refuses_an_output_folder(small, tmp_path):
    (tmp_path / "out").mkdir()
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["lines", str(small / "pcd" / f"{SCENE}.ply"), "-o", str(tmp_path / "out")])
    assert "is a folder" in assert_clean_failure(res, tmp_path, before)


def test_map_levels_are_for_zind_only(small, tmp_path):
    before = snapshot(tmp_path)
    res = runner.invoke(map_app, ["prepare", str(small), "--map-level", "floor", "--maps", str(tmp_path / "m")])
    assert "--map-level is for ZInD" in assert_clean_failure(res, tmp_path, before)


def test_no_refine_contradicting_refine_is_an_error(small, line_map):
    pano = next((small / "robot_pano").rglob("*.jpg"))
    res = runner.invoke(loc_app, ["localize", str(line_map), str(pano), "--no-refine", "--refine", "both"])
    assert "contradicts --refine both" in error_line(res)


# ------------------------------------------------------------------------------ 5. messages


@pytest.mark.parametrize("where", ["-o", "--png"])
def test_unwritable_output_folders_are_refused_before_the_work(small, tmp_path, where):
    args = ["build", str(small / "gt_lines" / f"{SCENE}.obj"), "--trans-spacing", "1.0"]
    args += ["-o", "/proc/ldl.h5"] if where == "-o" else ["-o", str(tmp_path / "m.h5"), "--png", "/proc/ldl.png"]
    before = snapshot(tmp_path)
    line = assert_clean_failure(runner.invoke(map_app, args), tmp_path, before)
    assert f"cannot write {where} /proc/ldl." in line and "ldltmp" not in line
    res = runner.invoke(map_app, ["lines", str(small / "pcd" / f"{SCENE}.ply"), "-o", str(tmp_path / "l.obj"),
                                  "--png", "/proc/ldl.png"])
    assert "cannot write --png /proc/ldl.png" in assert_clean_failure(res, tmp_path, before)


def test_run_says_a_root_is_not_stanford(small, tmp_path):
    res = runner.invoke(loc_app, ["run", "--root", str(small), "--dataset", "stanford", "-o", str(tmp_path / "r.json")])
    assert "not a Stanford 2D-3D-S root" in error_line(res)


def test_sigterm_ends_a_run_quietly_and_a_rerun_does_not_replace_its_results(small, sift_map, tmp_path):
    root = dataset_of(small, tmp_path / "ds", 400)  # far more than run in the seconds before the signal
    out = tmp_path / "r.json"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "ldlloc.cli", *run_args(root, sift_map.parent, out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if json.loads(out.read_text())["queries"]:
                break
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, (proc.returncode, stderr[-3000:])
    assert [line for line in stderr.splitlines() if line.strip()] == ["error: terminated"], stderr[-3000:]
    data = read_results_data(out)  # the JSON and its journal: what a --resume would find
    done = len(data["queries"])
    assert 0 < done < 400 and data["meta"]["finished"] is False
    before = snapshot(tmp_path)
    line = assert_clean_failure(runner.invoke(loc_app, run_args(root, sift_map.parent, out)), tmp_path, before)
    assert f"holds {done} results of a run that did not finish" in line and "--resume" in line
