"""Benchmark: batch map building and localization on a local Ray cluster, 1 and 2 workers.

Data: ``--rooms`` demo-preset rooms (``random_spec('demo', seed, i)``) with ``--per-split``
panoramas per split and room, all splits (illumination variants included), generated once
under ``bench/.cache/``. Measured, each from scratch:

- ``prepare`` of every scene (``overwrite``, default ``BuildParams``: N_t = 800, 40 SIFT
  views): the plain path (:func:`ldlmap.batch.prepare.prepare_dataset`), then
  :func:`ldlmap.batch.ray_prepare.prepare_dataset_ray` on a local cluster of 1 and of 2 CPUs (one task
  per scene); the maps of the three are compared byte for byte;
- ``run`` of all splits against those maps: :func:`ldlloc.batch.run.run_queries`, then
  :func:`ldlloc.batch.ray_run.run_queries_ray` with 1 and 2 workers (one actor per map).

Wall times include starting the local cluster (measured apart: ``ray.init`` to the first task
result) and, for ``run``, starting the actors and loading their maps. Every process uses one
torch thread (``OMP_NUM_THREADS=1``), so 1 worker is 1 core.

Projection (printed, not measured): with ``W`` workers and one task per map, a batch takes
about ``start + LPT(tasks)``, the longest-processing-time-first schedule of the per-map loads
over ``W`` workers: for ``prepare`` one build per map, for ``run`` per map ``n_q x t_q`` plus its
actor's start and map load (one actor per map: a map's queries never spread over workers).
Inputs: the medians measured here (build seconds per map, seconds per query, actor overhead
per map) and the datasets' sizes (``--omni-*``, ``--stanford-*``). The driver rewrites the
results file after each batch of arrivals; the time of one rewrite of a file of the projected
size is measured too (it runs while the workers go on, so it adds about one rewrite at the end).

Run: ``python bench/bench_ray.py [--rooms 4] [--per-split 2] [--workers 8] [--no-plain] [--quick]
[--json bench/ray.json]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")  # 1 worker = 1 core, in this process and the workers

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

import numpy as np  # noqa: E402


def dataset(seed: int, rooms: int, per_split: int, illumination: bool = True) -> Path:
    """``rooms`` demo-preset rooms, ``per_split`` panoramas per split and room (generated once)."""
    from ldlmap.synth.generate import generate_dataset
    from ldlmap.synth.spec import dump_spec_toml
    from ldlmap.synth.presets import random_spec

    tag = f"ray_s{seed}_k{rooms}_n{per_split}{'' if illumination else '_noill'}_{common.synth_tag()}"
    out = common.CACHE / tag
    if (out / "dataset.json").exists():
        return out
    spec_dir = common.CACHE / f"{tag}_specs"
    spec_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(1, rooms + 1):
        p = spec_dir / f"room{i:02d}.toml"
        p.write_text(dump_spec_toml(replace(random_spec("demo", seed, i), name=f"room{i:02d}")))
        paths.append(p)
    print(f"generating {rooms} rooms, {per_split} panoramas per split ...", flush=True)
    generate_dataset(out, None, paths, seed, overwrite=True, progress=False, illumination=illumination,
                     per_split=per_split)
    return out


def cluster_start(workers: int) -> float:
    """Seconds from ``ray.init`` (local cluster of ``workers`` CPUs) to a first task's result."""
    from ldlmap.batch.ray_cluster import ray_session

    t0 = time.perf_counter()
    with ray_session(f"local:{workers}") as ray:
        ray.get(ray.remote(lambda: 0).remote())
        return time.perf_counter() - t0


def prepare(root: Path, maps: Path, params: Any, workers: int | None) -> dict[str, Any]:
    """Build every scene's map (plain when ``workers`` is None); wall time and per-map seconds."""
    from ldlmap.batch.ray_prepare import prepare_dataset_ray
    from ldlmap.batch.prepare import prepare_dataset

    t0 = time.perf_counter()
    if workers is None:
        out = prepare_dataset(root, "omniscenes", maps, params, overwrite=True)
    else:
        out = prepare_dataset_ray(root, "omniscenes", maps, params, address=f"local:{workers}", overwrite=True)
    wall = time.perf_counter() - t0
    bad = [o for o in out if o.status != "built"]
    if bad:
        raise SystemExit(f"prepare failed: {[(o.scene, o.message) for o in bad]}")
    return {"wall_s": wall, "build_s": {o.scene: o.report.seconds["total"] for o in out}}


def run(root: Path, maps: Path, out: Path, workers: int | None) -> dict[str, Any]:
    """Localize every query of every split (plain when ``workers`` is None)."""
    from ldlloc.batch.ray_run import run_queries_ray
    from ldlloc.batch.run import run_queries
    from ldlmap.datasets import open_dataset

    queries = open_dataset(root, "omniscenes").queries()
    t0 = time.perf_counter()
    if workers is None:
        results = run_queries(queries, maps, out)
    else:
        results = run_queries_ray(queries, maps, out, address=f"local:{workers}")
    wall = time.perf_counter() - t0
    ok = [r for r in results if r.status != "failed"]
    acc = float(np.mean([r.t_error_m < 0.1 and r.r_error_deg < 5 for r in ok])) if ok else 0.0
    return {"wall_s": wall, "queries": len(results), "failed": len(results) - len(ok), "acc_0.1m_5deg": acc,
            "query_s": [r.seconds.get("total", 0.0) for r in results],
            "per_scene": {s: sum(r.scene == s for r in results) for s in sorted({r.scene for r in results})}}


def lpt_makespan(loads: list[float], workers: int) -> float:
    """Longest processing time first: each load, largest first, to the least busy worker."""
    busy = [0.0] * workers
    for x in sorted(loads, reverse=True):
        busy[int(np.argmin(busy))] += x
    return max(busy)


def results_flush_seconds(sample: Path, n: int, tmp: Path) -> float:
    """Seconds of one rewrite (JSON + CSV) of a results file of ``n`` records like ``sample``'s."""
    from ldlloc.batch.results import ResultsWriter, load_results

    rs, _ = load_results(sample)
    w = ResultsWriter(tmp)
    w.results = [replace(rs[i % len(rs)], name=f"q{i}") for i in range(n)]
    t0 = time.perf_counter()
    w.flush()
    return time.perf_counter() - t0


def project(name: str, maps: int, queries: int, workers: int, t_build: float, t_query: float,
            t_actor: float, t_start: float, flush_s: float) -> dict[str, Any]:
    """Projected wall time of prepare and run of a dataset (queries spread evenly over maps)."""
    per_map = np.full(maps, queries // maps) + (np.arange(maps) < queries % maps)
    prep = t_start + lpt_makespan([t_build] * maps, workers)
    runs = t_start + lpt_makespan(list(per_map * t_query + t_actor), workers) + flush_s
    one = maps * t_build, queries * t_query + maps * t_actor  # one worker, no cluster
    return {"dataset": name, "maps": maps, "queries": queries, "workers": workers,
            "prepare_h": prep / 3600, "run_h": runs / 3600, "prepare_1worker_h": one[0] / 3600,
            "run_1worker_h": one[1] / 3600, "run_ideal_h": (one[1] / workers + t_start) / 3600,
            "results_rewrite_s": flush_s}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", type=int, default=4)
    ap.add_argument("--per-split", type=int, default=2)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--workers", type=int, default=8, help="workers of the projection")
    ap.add_argument("--omni-maps", type=int, default=12, help="OmniScenes: scene maps (7 rooms, 12 scenes)")
    ap.add_argument("--omni-queries", type=int, default=4000, help="OmniScenes: panoramas")
    ap.add_argument("--stanford-maps", type=int, default=270, help="Stanford 2D-3D-S: room maps (6 areas)")
    ap.add_argument("--stanford-queries", type=int, default=1413, help="Stanford 2D-3D-S: panoramas")
    ap.add_argument("--no-plain", action="store_true", help="skip the plain (no Ray) runs")
    ap.add_argument("--quick", action="store_true", help="small maps, 1 panorama per split: a smoke test")
    ap.add_argument("--json", type=Path, default=common.ROOT / "bench" / "ray.json")
    args = ap.parse_args()

    from rich.table import Table

    from ldlmap.map.build import BuildParams

    con = common.console()
    per_split = 1 if args.quick else args.per_split
    root = dataset(args.seed, args.rooms, per_split, illumination=not args.quick)
    params = BuildParams().replaced(num_views=4, num_translations=200) if args.quick else BuildParams()
    work = common.CACHE / "ray_bench_out"
    configs: list[tuple[str, int | None]] = ([] if args.no_plain else [("plain", None)]) + [("ray1", 1), ("ray2", 2)]
    starts = {w: cluster_start(w) for _, w in configs if w}
    out: dict[str, Any] = {"machine": common.machine_info(), "rooms": args.rooms, "per_split": per_split,
                           "quick": args.quick, "cluster_start_s": starts, "prepare": {}, "run": {}}
    for label, w in configs:
        print(f"prepare {label} ...", flush=True)
        out["prepare"][label] = prepare(root, work / f"maps_{label}", params, w)
    first = configs[0][0]
    same = all((work / f"maps_{label}" / f"{s}.h5").read_bytes() == (work / f"maps_{first}" / f"{s}.h5").read_bytes()
               for label, _ in configs for s in out["prepare"][first]["build_s"])
    for label, w in configs:
        print(f"run {label} ...", flush=True)
        out["run"][label] = run(root, work / f"maps_{first}", work / f"results_{label}.json", w)

    table = Table(title=f"Ray, local cluster: {args.rooms} scenes, {out['run'][first]['queries']} queries (all splits)")
    table.add_column("step")
    for label, _ in configs:
        table.add_column({"plain": "plain (no Ray)", "ray1": "Ray, 1 worker", "ray2": "Ray, 2 workers"}[label],
                         justify="right")
    table.add_column("speed-up 2 vs 1 worker", justify="right")
    for step in ("prepare", "run"):
        walls = [out[step][label]["wall_s"] for label, _ in configs]
        table.add_row(f"{step} wall s", *[f"{x:.1f}" for x in walls],
                      f"{out[step]['ray1']['wall_s'] / out[step]['ray2']['wall_s']:.2f}x")
    table.add_row("cluster start s", *["-" if w is None else f"{starts[w]:.1f}" for _, w in configs], "")
    con.print(table)
    r1 = out["run"]["ray1"]
    con.print(f"maps identical across paths: {same}; accuracy at 0.1 m / 5 deg: "
              + ", ".join(f"{label} {out['run'][label]['acc_0.1m_5deg']:.2f}" for label, _ in configs), soft_wrap=True)

    # Projection from the 1-worker measurements.
    t_build = float(np.median(list(out["prepare"]["ray1"]["build_s"].values())))
    t_query = float(np.median(r1["query_s"]))
    t_start = starts[1]
    t_actor = max(0.0, (r1["wall_s"] - t_start - float(np.sum(r1["query_s"]))) / len(r1["per_scene"]))
    flush = {n: results_flush_seconds(work / "results_ray1.json", n, work / f"flush_{n}.json")
             for n in (args.omni_queries, args.stanford_queries)}
    proj = [project("OmniScenes", args.omni_maps, args.omni_queries, args.workers, t_build, t_query, t_actor,
                    t_start, flush[args.omni_queries]),
            project("Stanford 2D-3D-S", args.stanford_maps, args.stanford_queries, args.workers, t_build, t_query,
                    t_actor, t_start, flush[args.stanford_queries])]
    out["projection"] = {"inputs": {"build_s_per_map": t_build, "query_s": t_query, "actor_s_per_map": t_actor,
                                    "cluster_start_s": t_start}, "datasets": proj}
    table = Table(title=f"Projection on {args.workers} workers (per map {t_build:.1f} s build, per query "
                        f"{t_query:.2f} s, per actor {t_actor:.1f} s start + map load, cluster start {t_start:.1f} s)")
    for col in ("dataset", "maps", "queries", "prepare h", "run h", "run h, queries spread ideally",
                "1 worker: prepare h / run h", "results rewrite s"):
        table.add_column(col, justify="right")
    for p in proj:
        table.add_row(p["dataset"], str(p["maps"]), str(p["queries"]), f"{p['prepare_h']:.2f}", f"{p['run_h']:.2f}",
                      f"{p['run_ideal_h']:.2f}", f"{p['prepare_1worker_h']:.2f} / {p['run_1worker_h']:.2f}",
                      f"{p['results_rewrite_s']:.2f}")
    con.print(table)
    con.print(common.load_line(out["machine"]), soft_wrap=True)
    common.write_json(args.json, out)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
