"""Run the benchmarks in sequence and print their tables (``make bench``).

Run: ``python bench/run_all.py [--only build,localize] [--quick] [--device cuda]``.

Benchmarks (in this order; names for ``--only``):

- ``lines3d``: 3D line extraction stages and precision / recall on synthetic rooms (bench_lines3d.py)
- ``render``: view rendering, features and back-projection per view (bench_render_features.py)
- ``ldf``: 2D lines, rotations and ldf_3d + loss on a fixed workload (bench_ldf.py)
- ``build``: map building per stage, map size, peak memory, views vs accuracy (bench_build.py)
- ``localize``: per-stage localization time beside the paper's, accuracy per split; writes
  ``bench/results.json`` (bench_localize.py)
- ``ablation``: decomposition and losses on the synthetic extreme split; writes
  ``bench/ablation.json`` (bench_ablation.py)
- ``geometric``: geometric refinement on the synthetic extreme, robot and change_robot splits with
  lines-only maps (true edges, extracted scan lines) and SIFT maps; writes ``bench/geometric.json``
  (bench_geometric.py)
- ``colmap``: 3D lines of synthetic COLMAP models from their photos (no fused.ply), stages,
  precision / recall against the true edges, the lines-only map build (bench_colmap_lines.py)
- ``ray``: ``prepare`` of 4 scenes and ``run`` of all their splits on a local Ray cluster with 1 and 2
  workers, and the projected time of OmniScenes and Stanford 2D-3D-S on 8 workers; writes
  ``bench/ray.json`` (bench_ray.py; 15-30 min on 2 cores, so only with ``--only ray``)
- ``real``: real ZInD panoramas against their layout maps, room and floor level; writes
  ``bench/real.json`` (bench_real.py; prints a note and measures nothing when the real data,
  ``--data`` / ``$LDL_REAL_DATA`` / ``../shared/data``, is absent)
- ``walk``: the real ZInD panoramas as one walk in capture order, single image against walk
  (bench_walk.py; a note and no measurement without the real data, as ``real``)
- ``startup``: ``ldlmap --help``, ``ldlloc --help`` and one ``ldlloc localize`` as fresh processes,
  wall and CPU seconds with localize's stages (map read, setup, query, the rest); writes
  ``bench/startup.json`` (bench_startup.py)
- ``sfm``: SfM-like Line3D++ maps: kept lines, principal directions and up axis,
  before and after (bench_sfm.py; ``--localize ROOT`` when run alone also localizes)
- ``results``: writing a run's results file, ms per added query at 30 / 2000 / 3000 records, a
  run of 3000 from an empty file and a walk of 3000 made-up frames streamed and written
  (bench_results_write.py)
- ``building``: the 36-room building, one map per floor, queries localized without
  their floor; writes ``bench/building.json`` (bench_building.py; an hour and more on 2 cores the
  first time, so only with ``--only building``)
- ``inputs``: one room as .ply, .e57, .las, .laz, .glb and .ifc: build time and peak memory per
  format, its queries localized on each map; the E57's own panoramas; a 3-storey IFC building
  (bench_inputs.py; about 10 min on 2 busy cores, so only with ``--only inputs``)

Each runs in its own Python process (so one's memory and threads do not skew the next). Data
and maps are cached under ``bench/.cache/``; the first run generates them. ``--quick`` runs
every benchmark on small inputs (a smoke test of the scripts, not a measurement).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

# name -> (script, full-run arguments, quick-run arguments)
BENCHES: dict[str, tuple[str, list[str], list[str]]] = {
    "lines3d": ("bench_lines3d.py", ["--synth"], ["--points", "200000"]),
    "render": ("bench_render_features.py", [], ["--points", "200000", "--views", "2"]),
    "ldf": ("bench_ldf.py", [], ["--repeat", "2"]),
    "search": ("bench_search.py", [], ["--max-queries", "8"]),
    "build": ("bench_build.py", [], ["--quick"]),
    "localize": ("bench_localize.py", [], ["--quick"]),
    "ablation": ("bench_ablation.py", [], ["--quick"]),
    "multiroom": ("bench_multiroom.py", [], ["--rooms", "2", "--per-split", "1", "--no-room-lambda"]),
    "colmap": ("bench_colmap_lines.py", [], ["--seeds", "10", "--photos", "8", "--no-map"]),
    "real": ("bench_real.py", [], ["--levels", "room"]),
    "walk": ("bench_walk.py", [], ["--levels", "floor"]),
    "geometric": ("bench_geometric.py", [], ["--quick"]),
    "ray": ("bench_ray.py", [], ["--quick"]),
    "startup": ("bench_startup.py", [], ["--runs", "1"]),
    "sfm": ("bench_sfm.py", [], ["--seeds", "0"]),
    "building": ("bench_building.py", [], ["--preset", "building_small", "--width", "256", "--per-split", "1"]),
    "inputs": ("bench_inputs.py", [], ["--views", "4", "--num-trans", "200", "--density", "800"]),
    "results": ("bench_results_write.py", ["--scratch", "3000", "--walk", "3000"], ["--sizes", "30,300", "--adds", "3"]),
}
ON_REQUEST = {"ray", "building", "inputs"}  # slow: run only when named in --only
DEVICE_AWARE = {"render", "ldf", "localize", "ablation"}
THREAD_AWARE = {"render", "ldf", "build", "localize", "ablation", "real", "walk", "geometric", "startup", "sfm",
                "building"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, help=f"comma-separated subset of: {', '.join(BENCHES)}")
    ap.add_argument("--quick", action="store_true", help="small smoke run of every benchmark")
    ap.add_argument("--device", default=None, help="torch device for the device-aware benchmarks")
    ap.add_argument("--threads", type=int, default=None,
                    help="torch intra-op threads for every benchmark (default: each script's default); "
                         "use 1 on a shared, oversubscribed machine")
    ap.add_argument("--keep-going", action="store_true", help="run the others when one fails")
    args = ap.parse_args(argv)

    names = [n for n in BENCHES if n not in ON_REQUEST] if not args.only else [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in names if n not in BENCHES]
    if unknown:
        print(f"error: unknown benchmark(s) {', '.join(unknown)}; valid: {', '.join(BENCHES)}", file=sys.stderr)
        return 2
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(HERE.parent), os.environ.get("PYTHONPATH")]))}
    failed, times = [], {}
    for name in names:
        script, full, quick = BENCHES[name]
        cmd = [sys.executable, str(HERE / script), *(quick if args.quick else full)]
        if args.device and name in DEVICE_AWARE:
            cmd += ["--device", args.device]
        if args.threads is not None and name in THREAD_AWARE:
            cmd += ["--threads", str(args.threads)]
        load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
        print(f"\n=== {name}: {' '.join(cmd[1:])} (load average {load})", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.call(cmd, env=env, cwd=HERE.parent)
        times[name] = time.perf_counter() - t0
        if rc != 0:
            failed.append(name)
            print(f"=== {name} FAILED (exit {rc})", file=sys.stderr, flush=True)
            if not args.keep_going:
                break
    print("\n=== summary: " + ", ".join(f"{n} {s:.0f} s" for n, s in times.items())
          + (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
