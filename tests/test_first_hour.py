"""The first hour of a new user: one thread by default everywhere, progress that names the
running stage, `ldlloc run` before `ldlmap prepare`, messages that name only real options, result
names that cannot collide, synthetic datasets called synthetic, pictures with a caption and a
legend, and help pages that read alike."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.main import get_command
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlmap.cli import app as map_app
from tests._hostile import error_line

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
SCENE = "robot_synthroom_1_scene_1"
APPS = {"ldlmap": map_app, "ldlloc": loc_app}


def commands() -> dict[tuple[str, str], object]:
    """Every command of both programs, as click commands, by (program, name)."""
    return {(prog, name): cmd for prog, app in APPS.items() for name, cmd in get_command(app).commands.items()}


def option_names(cmd) -> set[str]:
    """The long options a command accepts (``--help`` included)."""
    return {o for p in cmd.params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")} | {"--help"}


def box_lines() -> np.ndarray:
    """The edges of a 4 x 3 x 2.5 m room (each in two pieces) and a door and a window frame."""
    c = np.array([[x, y, z] for x in (0, 4) for y in (0, 3) for z in (0, 2.5)], float)
    segs = []
    for a in range(8):
        for b in range(a + 1, 8):
            if np.sum(c[a] != c[b]) == 1:
                m = (c[a] + c[b]) / 2
                segs += [[c[a], m], [m, c[b]]]
    segs += [[[1, 0, 0], [1, 0, 2]], [[2, 0, 0], [2, 0, 2]], [[1, 0, 2], [2, 0, 2]],
             [[4, 1, 0.8], [4, 2, 0.8]], [[4, 1, 1.6], [4, 2, 1.6]]]
    return np.array(segs, float)


def tiny_root(tmp_path: Path, demo: Path, synthetic: bool = True, grey: bool = False) -> Path:
    """A dataset root named ``data`` with one robot query of synthroom_1 (a grey panorama when
    ``grey``) and an empty maps folder; written by `ldlmap synth` when ``synthetic``."""
    import cv2

    root = tmp_path / "data"
    for kind in ("pano", "pose"):
        (root / f"robot_{kind}" / SCENE).mkdir(parents=True)
    pano = root / "robot_pano" / SCENE / "0000.jpg"
    if grey:
        cv2.imwrite(str(pano), np.full((512, 1024, 3), 128, np.uint8))
    else:
        shutil.copy(demo / "robot_pano" / SCENE / "0000.jpg", pano)
    shutil.copy(demo / "robot_pose" / SCENE / "0000.txt", root / "robot_pose" / SCENE / "0000.txt")
    if synthetic:
        (root / "dataset.json").write_text(json.dumps({"generator": "ldlmap.synth", "layout": "omniscenes"}))
    (root / "maps").mkdir()
    return root


# --------------------------------------------------------------------------- 1: threads


def test_threads_is_one_option_with_one_default_in_every_heavy_command():
    from ldlmap.core.cli_common import DEFAULT_THREADS

    cmds = commands()
    seen = {}
    for key in (("ldlmap", "build"), ("ldlmap", "prepare"), ("ldlloc", "localize"), ("ldlloc", "run")):
        (opt,) = [p for p in cmds[key].params if "--threads" in p.opts]
        seen[key] = (opt.default, opt.help, opt.metavar)
    assert len(set(seen.values())) == 1, seen
    assert next(iter(seen.values()))[0] == DEFAULT_THREADS == 1


@pytest.mark.parametrize("args", [["ldlmap", "build", "{tmp}/none.ply"], ["ldlmap", "prepare", "{tmp}/none"],
                                  ["ldlloc", "localize", "{tmp}/m.h5", "{tmp}/p.jpg"],
                                  ["ldlloc", "run", "--root", "{tmp}/none"]])
def test_threads_is_checked_before_any_work(tmp_path, args):
    prog, *rest = [a.format(tmp=tmp_path) for a in args]
    for bad in ("-1", "1025"):
        line = error_line(runner.invoke(APPS[prog], [*rest, "--threads", bad]))
        assert "--threads must be an integer in [0, 1024]" in line
    assert list(tmp_path.iterdir()) == []


def test_set_threads_sets_torch_opencv_and_numpys_blas():
    code = ("import numpy; from ldlmap.core.cli_common import set_threads; set_threads(3); import torch, cv2; "
            "from threadpoolctl import threadpool_info; "
            "print(torch.get_num_threads(), cv2.getNumThreads(), *sorted({p['num_threads'] for p in threadpool_info()}))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert out.stdout.split() == ["3", "3", "3"]  # every BLAS / OpenMP pool numpy loaded: 3 threads


# --------------------------------------------------------------------------- 2: progress


def test_build_says_when_each_stage_starts_and_counts_the_distance_fields(tmp_path):
    from ldlmap.map.build import BuildParams, build_lines_map

    events = []
    rep = build_lines_map(box_lines(), tmp_path / "box.h5", BuildParams().replaced(trans_spacing=1.0, features="none"),
                          name="box", progress=lambda *e: events.append(e))
    stages = list(dict.fromkeys(stage for stage, _, _ in events))
    assert stages == ["load", "lines", "principal", "translations", "fields", "features", "write"]
    n_t = rep.counts["translations"]
    for stage in stages[1:]:  # each stage is announced (done 0) before it ends (done == total)
        mine = [(d, t) for s, d, t in events if s == stage]
        assert mine[0][0] == 0 and mine[-1][0] == mine[-1][1], (stage, mine)
    fields = [d for s, d, t in events if s == "fields"]
    assert [t for s, d, t in events if s == "fields"] == [n_t] * len(fields)
    assert len(fields) >= 3 and fields == sorted(fields) and fields[-1] == n_t  # steps in between


def test_the_progress_rows_name_the_running_stage_with_its_own_timer():
    import io
    import time

    from rich.console import Console

    from ldlmap.core.cli_common import StageProgress

    out = Console(file=io.StringIO(), force_terminal=True, width=160)
    with StageProgress(out, "maps", total=2, unit="scenes") as bar:
        bar.stage("synthroom_1", "translations", 0, 1)
        started = bar.bar.tasks[1].start_time
        time.sleep(0.01)  # the monotonic clock moves on, so a restarted timer has a later start
        bar.stage("synthroom_1", "fields", 0, 800)  # a new stage: named at once, its timer restarts
        bar.stage("synthroom_1", "fields", 412, 800)
        row = bar.bar.tasks[1]
        assert row.description == "synthroom_1: distance fields" and row.completed == 412 and row.total == 800
        assert row.fields["count"] == "412/800 translations" and row.start_time > started
        bar.job_done(1)
        assert bar.bar.tasks[0].fields["count"] == "1/2 scenes"
        text = Console(file=io.StringIO(), width=160)
        text.print(bar.bar.get_renderable())
        shown = text.file.getvalue()
    assert "synthroom_1: distance fields" in shown and "412/800 translations" in shown and "1/2 scenes" in shown


# --------------------------------------------------------------------- 3: maps missing


def test_run_before_prepare_says_how_to_build_the_maps(demo_dataset, tmp_path):
    root = tiny_root(tmp_path, demo_dataset)
    out = tmp_path / "r.json"
    line = error_line(runner.invoke(loc_app, ["run", "--root", str(root), "-o", str(out)]))
    assert "no maps" in line and f"{root / 'maps' / 'synthroom_1.h5'}" in line
    assert f"`ldlmap prepare {root} --maps {root / 'maps'}`" in line
    assert f"`ldlloc run --root {root} --maps {root / 'maps'}`" in line
    assert not out.exists()
    # With --maps, the commands name that folder.
    line = error_line(runner.invoke(loc_app, ["run", "--root", str(root), "-o", str(out), "--maps",
                                              str(tmp_path / "mine")]))
    assert f"--maps {tmp_path / 'mine'}`" in line


def test_run_before_prepare_on_a_read_only_dataset_suggests_maps_elsewhere(demo_dataset, tmp_path, monkeypatch):
    import os

    root = tiny_root(tmp_path, demo_dataset)
    real = os.access
    monkeypatch.setattr(os, "access",  # the dataset folder alone is read-only
                        lambda p, mode, **kw: (mode != os.W_OK or Path(p) != root) and real(p, mode, **kw))
    line = error_line(runner.invoke(loc_app, ["run", "--root", str(root), "-o", str(tmp_path / "r.json")]))
    assert f"`ldlmap prepare {root} --maps maps/data`" in line and "--maps maps/data`" in line
    # prepare itself refuses to write into the read-only folder, before any work, and says where instead.
    (root / "maps").rmdir()
    line = error_line(runner.invoke(map_app, ["prepare", str(root)]))
    assert "read-only" in line and "--maps DIR" in line


def test_run_in_which_no_query_could_run_exits_non_zero(demo_dataset, tmp_path):
    root = tiny_root(tmp_path, demo_dataset, grey=True)
    shutil.copy(demo_dataset / "maps" / "synthroom_1.h5", root / "maps" / "synthroom_1.h5")
    out = tmp_path / "r.json"
    res = runner.invoke(loc_app, ["run", "--root", str(root), "-o", str(out)])
    assert res.exit_code == 1, res.output
    assert "by scene" not in res.output  # no tables of zeros
    last = [x for x in res.output.splitlines() if x.strip()][-1]
    assert last.startswith("error: none of the 1 queries could be localized"), res.output
    assert "failed robot/synthroom_1_scene_1/0000" in res.output and out.exists()


# ------------------------------------------------------------ 4: options in messages


def _bad_invocations(tmp: Path) -> list[tuple[str, str, list[str]]]:
    """For every command: its required arguments (paths that are not there, or a file where a
    folder goes) followed by each value-taking option given a bad value, and with nothing more."""
    (tmp / "file").write_text("x")
    base = {("ldlmap", "info"): [f"{tmp}/none.h5"], ("ldlmap", "lines"): [f"{tmp}/none.ply", "-o", f"{tmp}/o.obj"],
            ("ldlmap", "synth"): [f"{tmp}/file"], ("ldlmap", "build"): [f"{tmp}/none.ply"],
            ("ldlmap", "prepare"): [f"{tmp}/none"], ("ldlmap", "e57"): [f"{tmp}/none.e57"], ("ldlloc", "localize"): [f"{tmp}/m.h5", f"{tmp}/p.jpg"],
            ("ldlloc", "run"): ["--root", f"{tmp}/none"], ("ldlloc", "report"): [f"{tmp}/none.json"],
            ("ldlloc", "export"): [f"{tmp}/none.json", "--format", "ply", "-o", f"{tmp}/o.ply"]}
    cases = []
    for key, cmd in commands().items():
        cases.append((*key, base[key]))
        for p in cmd.params:
            if p.param_type_name == "option" and not p.is_flag and p.opts[-1] not in ("--ray",):
                for bad in ("-1", "bogus"):
                    cases.append((*key, [*base[key], p.opts[-1], bad]))
    return cases


def test_messages_name_only_options_of_their_command(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./data: the default dataset roots are missing too
    cmds = commands()
    named: dict[str, set[str]] = {}
    for prog, name, args in _bad_invocations(tmp_path):
        res = runner.invoke(APPS[prog], [name, *args])
        assert res.exit_code != 0 and "internal error" not in res.output and "Traceback" not in res.output, (
            prog, name, args, res.output)
        used = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", res.output))
        named.setdefault(f"{prog} {name}", set()).update(used)
        assert used <= option_names(cmds[(prog, name)]), (prog, name, args, res.output)
    # The default roots: `prepare` takes ROOT as an argument, `run` as --root.
    line = error_line(runner.invoke(map_app, ["prepare"]))
    assert "`ldlmap prepare ROOT`" in line and "--root" not in line
    assert "`ldlloc run --root ROOT`" in error_line(runner.invoke(loc_app, ["run"]))
    assert "--num-trans" in named["ldlmap build"] and "--top-k" in named["ldlloc run"]  # the walk saw them


# --------------------------------------------------------------- 5: result file names


def test_default_result_names_cannot_collide():
    from ldlloc.batch.run import default_results_path

    names = {
        default_results_path("zind", "zind", Path("data/zind"), None, map_level="room"),
        default_results_path("zind", "zind", Path("data/zind"), None, map_level="floor"),
        default_results_path("omniscenes", "omniscenes", Path("data/omniscenes"), None),
        default_results_path("synthetic", "omniscenes", Path("demo_out/data"), None),
        default_results_path("synthetic", "omniscenes", Path("other/rooms"), None),
        default_results_path("synthetic", "omniscenes", Path("other/rooms"), ["robot"]),
        default_results_path("synthetic", "omniscenes", Path("other/rooms"), ["robot", "extreme"]),
        default_results_path("synthetic", "omniscenes", Path("other/rooms"), ["robot"], scene="synthroom_1"),
        default_results_path("stanford", "stanford", Path("data/stanford2d3ds"), ["area_3"], scene="area_3/office_1"),
    }
    assert len(names) == 9 and all(p.parent == Path("results") and p.suffix == ".json" for p in names)
    assert Path("results/zind_room_all.json") in names and Path("results/zind_floor_all.json") in names
    assert Path("results/omniscenes_all.json") in names and Path("results/synthetic_data_all.json") in names
    assert Path("results/stanford_area_3_area_3-office_1.json") in names


# ------------------------------------------------------ 6: synthetic is called synthetic


def test_a_synthetic_dataset_is_called_synthetic(demo_dataset, tmp_path, monkeypatch):
    from ldlmap.datasets import open_dataset

    assert open_dataset(demo_dataset, None).label == "synthetic"
    assert open_dataset(tiny_root(tmp_path / "real", demo_dataset, synthetic=False), None).label == "omniscenes"
    root = tiny_root(tmp_path, demo_dataset)
    shutil.copy(demo_dataset / "maps" / "synthroom_1.h5", root / "maps" / "synthroom_1.h5")
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(loc_app, ["run", "--root", str(root), "--split", "robot", "--no-refine"])
    assert res.exit_code == 0, res.output
    assert "synthetic by scene" in res.output and "omniscenes" not in res.output
    written = tmp_path / "results" / "synthetic_data_robot.json"
    assert json.loads(written.read_text())["meta"]["dataset"] == "synthetic"
    assert "unknown synthetic split nowhere" in error_line(runner.invoke(loc_app, ["run", "--root", str(root),
                                                                                   "--split", "nowhere"]))
    res = runner.invoke(loc_app, ["run", "--root", str(root), "--dataset", "synthetic", "--split", "robot",
                                  "--no-refine", "-o", str(tmp_path / "again.json")])
    assert res.exit_code == 0 and "synthetic by split" in res.output, res.output
    res = runner.invoke(map_app, ["prepare", str(root)])  # no scan: the scene fails, the table says synthetic
    assert "(synthetic)" in res.output and "omniscenes" not in res.output


# ------------------------------------------------------------------------ 7: pictures


def _band_rows(picture: np.ndarray, height: int) -> np.ndarray:
    """The rows of ``picture`` under its first ``height`` rows (the caption band)."""
    return picture[height:]


def _has_colour(img: np.ndarray, bgr: tuple[int, int, int], tol: int = 12) -> bool:
    return bool((np.abs(img.astype(int) - np.array(bgr)).max(-1) <= tol).any())


def test_localization_pictures_have_a_caption_and_a_legend():
    from ldlmap.core.pictures import BAND_BGR, GROUP_COLORS_BGR
    from ldlloc.visualize import localization_caption, localization_picture

    h, w = 128, 256
    img = np.full((h, w, 3), 200, np.uint8)
    loc = SimpleNamespace(arcs=np.array([[[1.0, 0, 0], [0, 1.0, 0]]]), arc_groups=np.array([0]), refined=True,
                          refine_method="features", rot_cam_from_world=np.eye(3), center=np.zeros(3),
                          status="ok", message="")
    ldl_map = SimpleNamespace(lines=np.array([[[1.0, 0, 0], [1.0, 0, 1.0]]]), line_groups=np.array([2]),
                              visibility=None, principal_directions=np.eye(3)[[2, 0, 1]])
    caption = localization_caption("robot/0000.jpg", loc, (0.0123, 0.456))
    assert caption.startswith("robot/0000.jpg: error 0.012 m, 0.46 deg: localized (within 0.1 m / 5 deg)")
    assert "not localized" in localization_caption("x.jpg", loc, (0.5, 0.1))
    assert localization_caption("x.jpg", loc).startswith("x.jpg: ok, refined by features, no ground truth")
    pic = localization_picture(img, loc, ldl_map, caption)
    assert pic.shape[1] == w and pic.shape[0] > 2 * h
    band = _band_rows(pic, 2 * h)
    assert _has_colour(band, BAND_BGR, 0) and _has_colour(band, (255, 255, 255), 40)  # text on the band
    for g in (0, 1, 2, -1):
        assert _has_colour(band, GROUP_COLORS_BGR[g]), g


def test_localize_and_info_pictures_carry_the_caption(demo_dataset, tmp_path):
    import cv2

    from ldlmap.core.pictures import BAND_BGR

    map_path = demo_dataset / "maps" / "synthroom_1.h5"
    img = demo_dataset / "robot_pano" / SCENE / "0000.jpg"
    res = runner.invoke(loc_app, ["localize", str(map_path), str(img), "--vis", str(tmp_path / "v.png"),
                                  "--gt", str(demo_dataset / "robot_pose" / SCENE / "0000.txt"), "--no-refine"])
    assert res.exit_code == 0, res.output
    pic, h = cv2.imread(str(tmp_path / "v.png")), cv2.imread(str(img)).shape[0]
    assert pic.shape[0] > 2 * h and _has_colour(_band_rows(pic, 2 * h), BAND_BGR, 0)
    res = runner.invoke(map_app, ["info", str(map_path), "--png", str(tmp_path / "m.png")])
    assert res.exit_code == 0 and f"wrote {tmp_path / 'm.png'}" in res.output, res.output
    pic = cv2.imread(str(tmp_path / "m.png"))
    assert pic.shape[0] > pic.shape[1] // 3 and _has_colour(pic[pic.shape[1] // 3:], BAND_BGR, 0)
    assert "--png" in error_line(runner.invoke(map_app, ["info", str(map_path), "--png", str(tmp_path / "m.gif")]))


# ---------------------------------------------------------------------- 8: help pages


USAGE_WORD = re.compile(r"^(\[OPTIONS\]|COMMAND|\[ARGS\]\.\.\.|[A-Z][A-Z_]*(\.\.\.)?|\[[A-Z][A-Z_]*\](\.\.\.)?)$")


@pytest.mark.parametrize("prog, name", [(p, None) for p in APPS] + sorted(commands()))
def test_help_pages_read_alike(prog, name):
    res = runner.invoke(APPS[prog], [*([name] if name else []), "--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    text = res.output
    assert not re.search(r"<(bool|path|str|int|float|list\[[^\]]*\])>", text), text
    usage = next(x for x in text.splitlines() if "Usage:" in x).split("Usage:")[1].split()
    words = usage[usage.index(name) + 1:] if name else usage[1:]
    assert all(USAGE_WORD.match(w) for w in words), words
    if name in ("info", "localize"):
        assert "MAP" in words
    if name == "run":
        for split in ("robot", "change_handheld", "extreme_gamma", "area_5a", "area_6"):
            assert split in text, split
