"""`ldlmap prepare --ray` and `ldlloc run --ray` on a local Ray cluster started here (2 CPUs).

One cluster for the module (``cluster`` fixture; under pytest-xdist the ``ray`` group keeps these
tests on one worker, see the Makefile's ``--dist loadgroup``); the commands' ``--ray local`` reuse
its connection. The Ray paths must give the plain paths' maps byte for byte and the same
results but for the timings, also when a worker process is killed mid-task or the run is
interrupted and resumed; without ``--ray`` Ray is never imported.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ldlloc.batch.results import read_results_data
from ldlloc.cli import app as loc_app
from ldlmap.cli import app as map_app
from tests._results_files import without_timings

pytestmark = pytest.mark.xdist_group("ray")
runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]
BUILD = ["--num-views", "2", "--num-trans", "60"]  # small maps: the comparison, not the accuracy


@pytest.fixture(scope="module")
def cluster():
    from ldlmap.batch.ray_cluster import ray_session

    with ray_session("local:2") as ray:
        yield ray


@pytest.fixture(scope="module")
def scans(thin_scans, tmp_path_factory) -> Path:
    """An OmniScenes root with the demo rooms' scans thinned to a tenth, and an empty scan."""
    root = tmp_path_factory.mktemp("scans")
    shutil.copytree(thin_scans / "pcd", root / "pcd")
    (root / "pcd" / "broken_1.txt").write_text("")
    return root


@pytest.fixture(scope="module")
def plain_run(demo_dataset, tmp_path_factory) -> Path:
    """Results of the plain `ldlloc run` over the robot split (10 queries, 2 maps)."""
    out = tmp_path_factory.mktemp("plain") / "robot.json"
    res = runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "robot", "--output", str(out)])
    assert res.exit_code == 0, res.output
    return out


def _ancestors(pid: int) -> list[int]:
    out = []
    while pid > 1:
        stat = Path(f"/proc/{pid}/stat").read_text()
        pid = int(stat[stat.rindex(")") + 2:].split()[1])
        out.append(pid)
    return out


def _ray_workers(title: str) -> list[int]:
    """Pids of this test's Ray worker processes running a task named ``title`` (Ray sets the
    process title to ``ray::<task>``)."""
    pids = []
    for p in Path("/proc").iterdir():
        try:
            if p.name.isdigit() and (p / "cmdline").read_bytes().startswith(f"ray::{title}\0".encode()) \
                    and os.getpid() in _ancestors(int(p.name)):
                pids.append(int(p.name))
        except OSError:
            continue
    return pids


def _kill_first_worker(title: str, after_s: float, killed: list[int], timeout_s: float = 120.0) -> threading.Thread:
    """A thread that SIGKILLs the first worker seen running ``title`` once it has run ``after_s``."""
    def loop() -> None:
        first_seen: dict[int, float] = {}
        end = time.monotonic() + timeout_s
        while not killed and time.monotonic() < end:
            for pid in _ray_workers(title):
                first_seen.setdefault(pid, time.monotonic())
                if time.monotonic() - first_seen[pid] >= after_s:
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                    return
            time.sleep(0.1)

    t = threading.Thread(target=loop, daemon=True)
    t.start()
    return t


def _csv_without_timings(path: Path) -> list[list[str]]:
    rows = list(csv.reader(io.StringIO(path.read_text())))
    keep = [i for i, name in enumerate(rows[0]) if not name.startswith("sec_")]
    return [[row[i] for i in keep] for row in rows]


def test_prepare_on_ray_gives_the_same_maps_with_a_worker_killed(cluster, scans, tmp_path):
    plain = runner.invoke(map_app, ["prepare", str(scans), "--maps", str(tmp_path / "plain"), *BUILD])
    killed: list[int] = []
    killer = _kill_first_worker("build_scene", 1.0, killed)
    on_ray = runner.invoke(map_app, ["prepare", str(scans), "--maps", str(tmp_path / "ray"), *BUILD, "--ray", "local"])
    killer.join()
    assert killed, "no build task was seen running"
    for res in (plain, on_ray):  # the empty scan fails alone, once, with its reason; the others are built
        assert res.exit_code == 1 and "Traceback" not in res.output, res.output
        last = res.output.strip().splitlines()[-1]
        assert last.startswith("error: 1 of 3 scene(s) failed: broken_1:"), last
    assert plain.output.strip().splitlines()[-1] == on_ray.output.strip().splitlines()[-1]
    for scene in ("synthroom_1", "synthroom_2"):
        assert (tmp_path / "ray" / f"{scene}.h5").read_bytes() == (tmp_path / "plain" / f"{scene}.h5").read_bytes()
    assert not (tmp_path / "ray" / "broken_1.h5").exists()
    # Maps up to date: skipped on the workers too.
    res = runner.invoke(map_app, ["prepare", str(scans), "--maps", str(tmp_path / "ray"), *BUILD, "--ray", "local",
                                  "--scene", "synthroom_1", "--scene", "synthroom_2"])
    assert res.exit_code == 0 and res.output.count("up-to-date") == 2, res.output


def test_run_on_ray_gives_the_same_results_with_an_actor_killed(cluster, demo_dataset, plain_run, tmp_path):
    from ldlloc.batch.ray_run import run_queries_ray
    from ldlloc.pipeline import LocalizeParams
    from ldlmap.datasets import open_dataset

    ds = open_dataset(demo_dataset, "omniscenes")
    workers: list[tuple[str, int]] = []  # (scene, pid) of each result, in arrival order
    killed: list[tuple[str, int]] = []

    def progress(event) -> None:
        scene = event.label.split()[1].rstrip(":")
        workers.append((scene, event.worker.pid if event.worker else None))
        if not killed and event.worker is not None:  # its actor still has queries queued: kill its process
            os.kill(event.worker.pid, signal.SIGKILL)
            killed.append((scene, event.worker.pid))

    out = tmp_path / "robot.json"
    meta = {"dataset": "synthetic", "root": str(demo_dataset), "splits": ["robot"], "maps": str(demo_dataset / "maps"),
            "scene_unknown": False}  # the meta `ldlloc run` writes
    results = run_queries_ray(ds.queries(["robot"]), demo_dataset / "maps", out, LocalizeParams(), meta=meta,
                              progress=progress)
    scene, pid = killed[0]
    after = [p for s, p in workers[1:] if s == scene]
    assert after and all(p != pid for p in after), workers  # a restarted actor served the rest of its scene
    assert len(results) == 10 and len({r.name for r in results}) == 10
    assert without_timings(out) == without_timings(plain_run)  # same records, same order
    assert _csv_without_timings(out.with_suffix(".csv")) == _csv_without_timings(plain_run.with_suffix(".csv"))


def test_interrupted_ray_run_resumes(cluster, demo_dataset, plain_run, tmp_path):
    """Ctrl-C leaves a results file that --resume completes; a missing map fails its queries once."""
    from ldlloc.batch.ray_run import run_queries_ray
    from ldlloc.pipeline import LocalizeParams
    from ldlmap.datasets import open_dataset

    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "synthroom_1.h5").symlink_to(demo_dataset / "maps" / "synthroom_1.h5")  # synthroom_2 has no map
    out = tmp_path / "robot.json"
    seen = []

    def progress(event) -> None:
        seen.append(event)
        if len(seen) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_queries_ray(open_dataset(demo_dataset, "omniscenes").queries(["robot"]), maps, out, LocalizeParams(),
                        progress=progress)
    first = read_results_data(out)["queries"]  # the JSON and its journal: what --resume finds
    assert len(first) == 3 and len({q["name"] for q in first}) == 3
    deadline = time.monotonic() + 30  # the actors were killed: their CPUs come back
    while cluster.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert cluster.available_resources().get("CPU", 0) == 2
    res = runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "robot", "--maps", str(maps),
                                  "--output", str(out), "--resume", "--ray", "local"])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    names = [q["name"] for q in data["queries"]]
    kept = [q["name"] for q in first if q["status"] != "failed"]  # failed ones are retried, in the plain order
    assert len(names) == 10 and len(set(names)) == 10 and names[:len(kept)] == kept
    plain = {q["name"]: q for q in json.loads(plain_run.read_text())["queries"]}
    for q in data["queries"]:
        if q["scene"] == "synthroom_2":
            assert q["status"] == "failed" and q["message"].startswith("map not found"), q
        else:
            assert q["status"] != "failed" and q["R"] == plain[q["name"]]["R"] and q["t"] == plain[q["name"]]["t"]
    assert out.with_suffix(".csv").read_text().count("\n") == 11


def _one_error_line(res) -> str:
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert res.exit_code == 1 and "Traceback" not in res.output, res.output
    assert len(lines) == 1 and lines[0].startswith("error:"), res.output
    return lines[0]


def test_bad_ray_input_is_one_error_line(cluster, demo_dataset, tmp_path):
    run = ["run", "--root", str(demo_dataset), "--split", "robot", "--output", str(tmp_path / "r.json")]
    assert "--ray must be" in _one_error_line(runner.invoke(loc_app, [*run, "--ray", "nonsense"]))
    assert "local:N" in _one_error_line(runner.invoke(loc_app, [*run, "--ray", "local:0"]))
    line = _one_error_line(runner.invoke(loc_app, [*run, "--ray", "127.0.0.1:1"]))
    assert "cannot reach the Ray cluster" in line
    assert "no GPU" in _one_error_line(runner.invoke(loc_app, [*run, "--ray", "local", "--device", "cuda"]))
    assert not (tmp_path / "r.json").exists()


def test_without_ray_flag_ray_is_not_imported(demo_dataset, plain_run, scans, tmp_path):
    """In a fresh interpreter: the plain commands never import Ray; a missing Ray is one error line."""
    script = f"""
import sys
from typer.testing import CliRunner
from ldlloc.cli import app as loc_app
from ldlmap.cli import app as map_app
r = CliRunner()
res = r.invoke(map_app, ["prepare", {str(scans)!r}, "--maps", {str(tmp_path / 'maps')!r}, "--scene", "broken_1"])
assert res.exit_code == 1 and "broken_1" in res.output, res.output
res = r.invoke(loc_app, ["run", "--root", {str(demo_dataset)!r}, "--split", "robot", "--output", {str(plain_run)!r},
                         "--resume"])
assert res.exit_code == 0, res.output
assert "ray" not in sys.modules and "ldlmap.batch.ray_cluster" not in sys.modules, sorted(m for m in sys.modules if "ray" in m)
sys.modules["ray"] = None  # as if Ray were not installed
res = r.invoke(map_app, ["prepare", {str(scans)!r}, "--ray", "local"])
print(res.output)
"""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --ray needs Ray"), proc.stdout


def test_worker_imports_this_source_tree(cluster):
    """The workers import the toolkit from the driver's source folder (runtime_env PYTHONPATH)."""
    import ldlmap

    def where() -> str:
        import ldlmap

        return ldlmap.__file__

    assert cluster.get(cluster.remote(where).remote()) == ldlmap.__file__


def test_image_run_on_ray_equals_the_plain_one(cluster, demo_dataset, tmp_path):
    """`run --images --ray`: actors holding both maps give the plain image run's records (and its
    failed one for a corrupt image) but for the timings."""
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    for room, stem in (("synthroom_1", "0001"), ("synthroom_2", "0003")):
        (imgs / f"{room}.jpg").symlink_to(demo_dataset / "robot_pano" / f"robot_{room}_scene_1" / f"{stem}.jpg")
    (imgs / "broken.jpg").write_bytes(b"\x00" * 64)
    base = ["run", "--images", str(imgs), "--maps", str(demo_dataset / "maps"), "--top-maps", "1"]
    for out, extra in ((tmp_path / "plain.json", []), (tmp_path / "ray.json", ["--ray", "local"])):
        res = runner.invoke(loc_app, [*base, *extra, "--output", str(out)])
        assert res.exit_code == 0, res.output
    plain, on_ray = (json.loads((tmp_path / f"{k}.json").read_text())["queries"] for k in ("plain", "ray"))
    strip = lambda rs: [{k: v for k, v in r.items() if k not in ("seconds", "message")} for r in rs]  # noqa: E731
    assert strip(plain) == strip(on_ray)
    assert [r["scene"] for r in on_ray] == ["(none)", "synthroom_1", "synthroom_2"]
    assert on_ray[0]["status"] == "failed" and "image" in on_ray[0]["message"]


def test_scene_unknown_run_on_ray_equals_the_plain_one(cluster, demo_dataset, tmp_path):
    """`run --scene-unknown --ray`: one actor per scene folder, holding its maps, gives the plain
    run's records but for the timings (the chosen map included)."""
    base = ["run", "--root", str(demo_dataset), "--split", "robot", "--scene", "synthroom_2", "--scene-unknown",
            "--top-maps", "1"]
    for out, extra in ((tmp_path / "plain.json", []), (tmp_path / "ray.json", ["--ray", "local"])):
        res = runner.invoke(loc_app, [*base, *extra, "--output", str(out)])
        assert res.exit_code == 0, res.output
    plain, on_ray = (json.loads((tmp_path / f"{k}.json").read_text())["queries"] for k in ("plain", "ray"))
    strip = lambda rs: [{k: v for k, v in r.items() if k not in ("seconds", "message")} for r in rs]  # noqa: E731
    assert strip(plain) == strip(on_ray) and len(on_ray) == 5
    assert all(r["map"] == str(demo_dataset / "maps" / "synthroom_2.h5") for r in on_ray)


def test_walks_on_ray_equal_the_plain_run_also_resumed(cluster, demo_dataset, tmp_path):
    """`run --walk --ray`: one actor per walk (a scene's queries), never split, gives the plain run's
    records but for the timings; resumed from a file a killed run left (the first walk's first
    frames written), the actor goes on from its last written frame and the file is the same."""
    base = ["run", "--root", str(demo_dataset), "--split", "robot", "--walk", "--lag", "1"]
    plain, on_ray = tmp_path / "plain.json", tmp_path / "ray.json"
    res = runner.invoke(loc_app, [*base, "--output", str(plain)])
    assert res.exit_code == 0, res.output
    data = json.loads(plain.read_text())
    data["meta"]["finished"] = False  # as a run killed after its third frame leaves it
    data["queries"] = data["queries"][:3]
    on_ray.write_text(json.dumps(data))
    res = runner.invoke(loc_app, [*base, "--output", str(on_ray), "--resume", "--ray", "local"])
    assert res.exit_code == 0, res.output
    assert without_timings(on_ray) == without_timings(plain)
    assert _csv_without_timings(on_ray.with_suffix(".csv")) == _csv_without_timings(plain.with_suffix(".csv"))
    walks = {q["walk"]["name"] for q in json.loads(on_ray.read_text())["queries"]}
    assert walks == {"synthroom_1", "synthroom_2"}


@pytest.fixture(scope="module")
def two_videos(demo_dataset, tmp_path_factory) -> Path:
    """A folder of two 5 fps videos (512 x 256) in demo room 1: ``a.mp4`` walks 0.1 m a frame towards the
    room's middle for 14 frames, turning 3 degrees a frame; ``b.mp4`` is its first 6 frames."""
    import numpy as np
    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.render import Renderer
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.spec import load_spec
    from ldlloc.walk.video import write_video

    q = [q for q in open_dataset(demo_dataset, "omniscenes").queries(["robot"]) if q.scene == "synthroom_1"][0]
    middle = read_map(demo_dataset / "maps" / "synthroom_1.h5", load_cloud=False).translations.mean(0)
    step = (middle - q.center) * [1, 1, 0]
    step = 0.1 * step / np.linalg.norm(step)
    render = Renderer(build_scene(load_spec(demo_dataset / "specs" / "synthroom_1.toml")))
    frames = [render.render(q.rot_cam_from_world @ rotation_from_axis_angle(np.array([0, 0, 1.0]), np.radians(3 * k)),
                            q.center + k * step, 512, supersample=1).rgb for k in range(14)]
    folder = tmp_path_factory.mktemp("videos")
    write_video(folder / "a.mp4", iter(frames), fps=5)
    write_video(folder / "b.mp4", iter(frames[:6]), fps=5)
    return folder


def test_videos_on_ray_one_actor_each_killed_then_resumed(cluster, demo_dataset, two_videos, tmp_path, monkeypatch):
    """`run --video DIR --ray`: one actor per video; the actor of the longer walk is killed (SIGKILL)
    after it handed back its first block, with no restart left: the run ends with one error line and
    the records written; `--resume` completes every walk, and the file equals an uninterrupted run's
    but for the timings."""
    from dataclasses import replace
    from ldlloc.batch import ray_run
    from ldlloc.walk.localize import VIDEO
    from ldlloc.pipeline import LocalizeParams
    from ldlmap.core.errors import LdlError

    base = ["run", "--video", str(two_videos), "--maps", str(demo_dataset / "maps" / "synthroom_1.h5"), "--lag", "1"]
    plain, out = tmp_path / "plain.json", tmp_path / "ray.json"
    res = runner.invoke(loc_app, [*base, "--output", str(plain)])
    assert res.exit_code == 0, res.output
    killed: list[int] = []

    def progress(event) -> None:
        if not killed and event.label.startswith("a:") and event.worker is not None:
            os.kill(event.worker.pid, signal.SIGKILL)
            killed.append(event.worker.pid)

    monkeypatch.setattr(ray_run, "RETRIES", 0)  # no restart: the walk stops where it was killed
    meta = {k: json.loads(plain.read_text())["meta"][k] for k in ("dataset", "maps", "top_maps")}  # as the CLI's
    with pytest.raises(LdlError, match="the walk of a stopped .*--resume"):
        ray_run.run_video_walks_ray(sorted(two_videos.glob("*.mp4")), demo_dataset / "maps" / "synthroom_1.h5", out,
                                    LocalizeParams(), replace(VIDEO, top_maps=meta["top_maps"]), meta=meta,
                                    progress=progress, lag=1)
    assert killed
    first = read_results_data(out)["queries"]
    frames = {w: sorted(q["walk"]["frame"] for q in first if q["walk"]["name"] == w) for w in ("a", "b")}
    assert frames["b"] == list(range(6)) and 0 < len(frames["a"]) < 14 and frames["a"] == list(range(len(frames["a"])))
    res = runner.invoke(loc_app, [*base, "--output", str(out), "--resume"])
    assert res.exit_code == 0, res.output
    assert without_timings(out) == without_timings(plain)
    names = [q["name"] for q in json.loads(out.read_text())["queries"]]
    assert names == [f"a/{k:06d}" for k in range(14)] + [f"b/{k:06d}" for k in range(6)]
