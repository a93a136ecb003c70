"""Your own panoramas (``ldlloc run --images``): which map, accuracy and throughput on the real ZInD home.

Run: ``python bench/bench_images.py [--data ../shared/data] [--room-maps DIR] [--floor-map FILE]
[--top-maps 1,2,3,5] [--throughput 100] [--localize-runs 3] [--threads 1]``.

On the shared ZInD home (``<data>/zind/000``: 19 panoramas, 15 rooms), with the maps of
``bench/bench_real.py`` (built and cached under ``bench/.cache/real/``, or the folders given):

1. **Which room.** The 19 panoramas against the folder of the 15 room maps, the room not given,
   with :func:`ldlloc.batch.images.run_images` (the library path of ``ldlloc run --images
   panos/ --maps rooms/``) at ``--top-maps`` = the default: right room (the room the dataset
   assigns) and final accuracy at 0.1 m / 5 deg and 0.25 m / 5 deg against the ground truth,
   which the run never sees; beside the map-given run (``ldlloc run``'s dataset path, each panorama
   against its own room). A sweep over the number of maps refined (``--top-maps`` values) with
   :func:`ldlloc.batch.which_map.localize_on_maps` (one pass at the largest N; a smaller N keeps
   :func:`~ldlloc.batch.which_map.choose_map` over the first N of the ranking).
2. **Floor map.** The same 19 against the floor map (one map: no choice), beside the map-given
   floor run.
3. **Throughput.** ``--throughput`` panoramas (the 19 real ones repeated, as symlinks with
   distinct names) in one process against one room map and against the floor map: panoramas
   per minute, map loading included and not; beside ``ldlloc localize`` per panorama (one process
   each: start-up, map read and localize; ``--localize-runs`` panoramas).

Both runs use the upright prior of the ZInD reader (``--max-tilt 10``), so they differ only by
the map being given. Per-stage median seconds are printed for each run. The machine's load
(``uptime``) is printed with the timings. Results go to ``bench/images.json``. Without data the
script says so and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import console  # noqa: E402

MAX_TILT = 10.0  # the ZInD reader's upright prior (ldlloc.pipeline.UPRIGHT_MAX_TILT_DEG), for both runs
ACCS = (("0.1m_5deg", 0.1, 5.0), ("0.25m_5deg", 0.25, 5.0))


def load() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def errors(R, t, q) -> tuple[float, float]:
    from ldlmap.core.geometry import rotation_error_deg, translation_error

    return translation_error(np.asarray(t), q.center), rotation_error_deg(np.asarray(R), q.rot_cam_from_world)


def accuracy(errs: list[tuple[float, float] | None]) -> dict[str, int]:
    """Queries within each threshold (None: failed)."""
    return {k: int(sum(e is not None and e[0] < m and e[1] < d for e in errs)) for k, m, d in ACCS}


def stage_medians(results) -> dict[str, float]:
    stages = sorted({s for r in results for s in r.seconds})
    return {s: float(np.median([r.seconds[s] for r in results if s in r.seconds and r.status != "failed"]))
            for s in stages}


def map_given(zind_root: Path, maps: Path, level: str, params, tmp: Path) -> dict:
    """The dataset run (each panorama against its own map): errors per query name."""
    from ldlmap.datasets import open_dataset
    from ldlloc.batch.run import run_queries

    ds = open_dataset(zind_root, "zind", map_level=level)
    t0 = time.perf_counter()
    res = run_queries(ds.queries(), maps, tmp / f"given_{level}.json", params, "cpu")
    wall = time.perf_counter() - t0
    errs = {r.name: (None if r.status == "failed" else (r.t_error_m, r.r_error_deg)) for r in res}
    return {"errors": errs, "accuracy": accuracy(list(errs.values())), "seconds": stage_medians(res),
            "wall_s": wall, "queries": {q.name: q for q in ds.queries()}}


def image_run(panos: Path, maps: Path, params, top_maps: int, out: Path):
    """``run --images panos --maps maps`` through the library; returns results, wall seconds, map-load seconds."""
    from ldlloc.batch.images import find_images, image_run_meta, run_images
    from ldlloc.batch.which_map import MapSet

    queries = find_images(panos)
    t0 = time.perf_counter()
    mapset = MapSet.load(maps, params)
    t_load = time.perf_counter() - t0
    res = run_images(queries, mapset, out, params, meta=image_run_meta(str(panos), maps, top_maps), top_maps=top_maps)
    return res, time.perf_counter() - t0, t_load


def by_image(queries: dict) -> dict[str, object]:
    return {Path(q.image).resolve(): q for q in queries.values()}


def which_room(zind_root: Path, room_maps: Path, params, default_n: int, sweep: list[int], tmp: Path) -> dict:
    given = map_given(zind_root, room_maps, "room", params, tmp)
    gt = by_image(given["queries"])
    res, wall, t_load = image_run(zind_root / "000" / "panos", room_maps, params, default_n, tmp / "rooms.json")
    rows, errs = [], []
    for r in res:
        q = gt[Path(r.image).resolve()]
        e = None if r.status == "failed" else errors(r.R, r.t, q)
        errs.append(e)
        rows.append({"image": Path(r.image).name, "truth": q.scene.split("/")[-1], "chosen": r.scene.split("/")[-1],
                     "right_room": r.scene == q.scene, "runner_up": (r.map_runner_up or {}).get("map", "-"),
                     "t_error_m": None if e is None else e[0], "r_error_deg": None if e is None else e[1],
                     "given_t_error_m": (given["errors"][q.name] or (None,))[0], "status": r.status,
                     "verdict": r.verdict, "confidence": r.confidence})
    confident = [e for r, e in zip(rows, errs) if r["verdict"] == "confident"]
    out = {"top_maps": default_n, "right_room": int(sum(r["right_room"] for r in rows)), "count": len(rows),
           "confident": len(confident), "confident_wrong": len(confident) - accuracy(confident)["0.25m_5deg"],
           "accuracy": accuracy(errs), "given_accuracy": given["accuracy"], "seconds": stage_medians(res),
           "given_seconds": given["seconds"], "wall_s": wall, "map_load_s": t_load, "rows": rows,
           "sweep": sweep_top_maps(zind_root, room_maps, params, sweep, gt)}
    return out


def sweep_top_maps(zind_root: Path, room_maps: Path, params, sweep: list[int], gt: dict) -> list[dict]:
    """Right room and accuracy for each N of ``sweep``, from one pass at the largest N."""
    from ldlloc.batch.images import find_images
    from ldlloc.batch.which_map import MapSet, choose_map, localize_on_maps
    from ldlloc.pipeline import load_image

    mapset = MapSet.load(room_maps, params)
    n_max = max(sweep)
    per_n = {n: {"right": 0, "errs": [], "confident": []} for n in sweep}
    for q_img in find_images(zind_root / "000" / "panos"):
        q = gt[Path(q_img.image).resolve()]
        _, choice = localize_on_maps(load_image(q_img.image), mapset, params.max_tilt_deg, n_max)
        for n in sweep:
            c = choose_map([o for o in choice.ranked[:n] if o.loc is not None])
            per_n[n]["right"] += c.entry.scene == q.scene
            per_n[n]["errs"].append(errors(c.loc.rot_cam_from_world, c.loc.center, q))
            if c.loc.verdict == "confident":
                per_n[n]["confident"].append(per_n[n]["errs"][-1])
    return [{"top_maps": n, "right_room": v["right"], "accuracy": accuracy(v["errs"]), "confident": len(v["confident"]),
             "confident_wrong": len(v["confident"]) - accuracy(v["confident"])["0.25m_5deg"]} for n, v in per_n.items()]


def floor(zind_root: Path, floor_map: Path, params, tmp: Path) -> dict:
    given = map_given(zind_root, floor_map.parent.parent, "floor", params, tmp)
    gt = by_image(given["queries"])
    res, wall, t_load = image_run(zind_root / "000" / "panos", floor_map, params, 1, tmp / "floor.json")
    errs = [None if r.status == "failed" else errors(r.R, r.t, gt[Path(r.image).resolve()]) for r in res]
    return {"count": len(res), "accuracy": accuracy(errs), "given_accuracy": given["accuracy"],
            "seconds": stage_medians(res), "given_seconds": given["seconds"], "wall_s": wall, "map_load_s": t_load}


def throughput(zind_root: Path, map_path: Path, params, n: int, tmp: Path, label: str) -> dict:
    """``n`` panoramas (the real ones repeated) in one process against ``map_path``."""
    panos = sorted((zind_root / "000" / "panos").glob("*.jpg"))
    folder = tmp / f"repeat_{label}"
    folder.mkdir()
    for i in range(n):
        (folder / f"{i:03d}_{panos[i % len(panos)].name}").symlink_to(panos[i % len(panos)].resolve())
    before = load()
    res, wall, t_load = image_run(folder, map_path, params, 1, tmp / f"throughput_{label}.json")
    return {"map": str(map_path), "count": n, "failed": sum(r.status == "failed" for r in res), "wall_s": wall,
            "map_load_s": t_load, "per_minute": 60 * n / wall, "per_minute_without_load": 60 * n / (wall - t_load),
            "seconds": stage_medians(res), "uptime_before": before, "uptime_after": load()}


def localize_per_image(zind_root: Path, map_path: Path, runs: int, threads: int) -> dict:
    """``ldlloc localize MAP PANO`` in a new process per panorama: wall seconds each."""
    panos = sorted((zind_root / "000" / "panos").glob("*.jpg"))[:runs]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    walls = []
    before = load()
    for p in panos:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "ldlloc.cli", "localize", str(map_path), str(p), "--max-tilt",
                        str(MAX_TILT), "--threads", str(threads), "--json"], env=env, check=True, capture_output=True)
        walls.append(time.perf_counter() - t0)
    return {"map": str(map_path), "seconds": walls, "per_minute": 60 / float(np.median(walls)),
            "uptime_before": before, "uptime_after": load()}


def print_report(res: dict) -> None:
    from rich.table import Table

    c = console()
    room = res.get("room")
    if room:
        t = Table(title=f"ZInD, 19 panoramas vs the folder of 15 room maps (top {room['top_maps']} refined)")
        for col in ("image", "truth", "chosen", "right", "t err m", "given t err m", "status", "verdict"):
            t.add_column(col)
        f = lambda x: "-" if x is None else f"{x:.3f}"  # noqa: E731
        for r in room["rows"]:
            t.add_row(r["image"], r["truth"], r["chosen"], "yes" if r["right_room"] else "NO", f(r["t_error_m"]),
                      f(r["given_t_error_m"]), r["status"], r["verdict"] or "-")
        c.print(t)
        c.print(f"right room {room['right_room']} / {room['count']}; accuracy {room['accuracy']} "
                f"(map given: {room['given_accuracy']}); confident {room['confident']}, of them beyond 0.25 m / 5 deg "
                f"{room['confident_wrong']}; wall {room['wall_s']:.1f} s (maps loaded in "
                f"{room['map_load_s']:.1f} s)")
        c.print(f"median seconds, which map: {room['seconds']}\nmedian seconds, map given: {room['given_seconds']}")
        for s in room["sweep"]:
            c.print(f"  --top-maps {s['top_maps']}: right room {s['right_room']} / {room['count']}, "
                    f"accuracy {s['accuracy']}, confident {s['confident']} ({s['confident_wrong']} beyond 0.25 m / 5 deg)")
    fl = res.get("floor")
    if fl:
        c.print(f"floor map: accuracy {fl['accuracy']} (dataset run: {fl['given_accuracy']}); "
                f"median seconds {fl['seconds']} (dataset run: {fl['given_seconds']})")
    for tp in res.get("throughput", []):
        c.print(f"throughput {Path(tp['map']).name}: {tp['count']} panoramas in {tp['wall_s']:.1f} s = "
                f"{tp['per_minute']:.1f} per minute ({tp['per_minute_without_load']:.1f} without the "
                f"{tp['map_load_s']:.1f} s map load); {tp['failed']} failed; median stages {tp['seconds']}; "
                f"load before: {tp['uptime_before']}; after: {tp['uptime_after']}")
    for lp in res.get("localize", []):
        c.print(f"`ldlloc localize` per panorama on {Path(lp['map']).name}: "
                f"{', '.join(f'{s:.2f}' for s in lp['seconds'])} s = {lp['per_minute']:.1f} per minute; "
                f"load before: {lp['uptime_before']}; after: {lp['uptime_after']}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="real data folder (default $LDL_REAL_DATA or ../shared/data)")
    ap.add_argument("--room-maps", default=None, help="folder of the room maps (default: bench_real's cache, built "
                    "when missing)")
    ap.add_argument("--floor-map", default=None, help="the floor map (default: bench_real's cache)")
    ap.add_argument("--top-maps", default="1,2,3,5", help="numbers of maps refined to compare (the default of "
                    "`run --images` is the one measured with run_images)")
    ap.add_argument("--throughput", type=int, default=100, help="panoramas of the throughput runs (0: none)")
    ap.add_argument("--localize-runs", type=int, default=3, help="panoramas localized one process each (0: none)")
    ap.add_argument("--parts", default="room,floor,throughput,localize", help="what to measure")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--output", default=str(HERE / "images.json"))
    args = ap.parse_args(argv)
    from bench.bench_real import build_maps, use_threads, zind_root_or_none

    zind_root = zind_root_or_none(args.data)
    if zind_root is None:
        return 0
    use_threads(args.threads)
    from ldlloc.batch.which_map import TOP_MAPS
    from ldlloc.pipeline import LocalizeParams

    params = LocalizeParams(max_tilt_deg=MAX_TILT)
    room_maps = Path(args.room_maps) if args.room_maps else build_maps(zind_root, "room", None)
    floor_map = (Path(args.floor_map) if args.floor_map
                 else build_maps(zind_root, "floor", None) / "000" / "floor_01.h5")
    parts = set(args.parts.split(","))
    out: dict = {"load_at_start": load(), "threads": args.threads}
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        if "room" in parts:
            out["room"] = which_room(zind_root, room_maps, params, TOP_MAPS, [int(x) for x in args.top_maps.split(",")],
                                     tmp)
        if "floor" in parts:
            out["floor"] = floor(zind_root, floor_map, params, tmp)
        one_room = sorted(room_maps.rglob("*.h5"))[0]
        if "throughput" in parts and args.throughput:
            out["throughput"] = [throughput(zind_root, m, params, args.throughput, tmp, label)
                                 for label, m in (("room", one_room), ("floor", floor_map))]
        if "localize" in parts and args.localize_runs:
            out["localize"] = [localize_per_image(zind_root, m, args.localize_runs, args.threads)
                               for m in (one_room, floor_map)]
    print_report(out)
    Path(args.output).write_text(json.dumps(out, indent=1, default=str))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
