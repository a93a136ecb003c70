"""Benchmark: per-stage localization time beside the paper's runtime table, and accuracy per split.

Run: ``python bench/bench_localize.py [--quick] [--device cpu|cuda] [--seed 1] [--root DATASET]``.

Localizes every query of the synthetic demo dataset (``bench/.cache/demo_s1``: 2 scenes, all
splits, 1024 x 512) against maps built with the default :class:`~ldlmap.map.build.BuildParams`
(SIFT, N_t = 800, 40 views) through :class:`ldlloc.pipeline.Localizer` with the default
:class:`~ldlloc.pipeline.LocalizeParams`. One untimed warm-up query first (caches, lazy imports).
Prints one Rich table of median seconds per stage (lines2d, rotation, search, refine, total)
beside the paper's CPU and GPU columns, then accuracy per split, and writes
``bench/results.json``::

    {"stages": {"lines2d": s, "rotation": s, "search": s, "refine": s, "total": s},
     "device": "cpu", "accuracy": {split: {...}}, "machine": {...},
     "runs": {device: {stages, accuracy, machine, queries: [per-query errors, status, seconds]}}}

When CUDA is available (or ``--device cuda``) the queries are also run on the GPU and its
column is added (``stages``/``device`` at the top level stay those of the CPU run).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402
from ldlmap.core.cli_common import DEFAULT_THREADS  # noqa: E402

STAGES = ("lines2d", "rotation", "search", "refine", "total")
TARGETS = {"lines2d": 0.15, "rotation": 0.02, "search": None, "refine": None, "total": 1.5}
# pose search target (rotation + search) is 50 ms: shown as its own row


def run_device(dataset: Path, device: str, splits: list[str] | None, progress: bool = True,
               prepared: bool = False) -> dict[str, Any]:
    """Localize every query of every scene on ``device``; per-stage medians and per-split accuracy.
    ``prepared``: use the dataset's own maps (``<dataset>/maps/<scene>.h5`` of ``ldlmap prepare``)."""
    from ldlloc.batch.accuracy import group_by, summarize
    from ldlloc.pipeline import Localizer, load_image
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map

    ds = open_dataset(dataset, "omniscenes")
    outcomes = []
    for scene in ds.scenes():
        queries = ds.queries(splits, scene=scene)
        if not queries:
            continue
        map_path = dataset / "maps" / f"{scene}.h5" if prepared else common.cached_map(dataset, scene)
        loc = Localizer(read_map(map_path, load_cloud=False), device=device)
        loc.localize(load_image(queries[0].image))  # warm-up, untimed
        done = (lambda i, n, s=scene: print(f"\r  {device} {s}: {i}/{n}", end="", file=sys.stderr)) if progress else None
        outcomes += common.localize_queries(loc, queries, done)
        if progress:
            print(file=sys.stderr)
    results = [o.result for o in outcomes]
    ok = [r for r in results if r.status != "failed"]
    stages = {s: float(np.median([r.seconds[s] for r in ok])) for s in STAGES}
    pose_search = float(np.median([r.seconds["rotation"] + r.seconds["search"] for r in ok]))
    acc = {split: summarize(rs) for split, rs in group_by(results, "split").items()}
    acc["all"] = summarize(results)
    queries = [{"name": r.name, "scene": r.scene, "split": r.split, "status": r.status,
                "t_error_m": r.t_error_m, "r_error_deg": r.r_error_deg, "num_rotations": r.num_rotations,
                "num_inliers": r.num_inliers, "seconds": r.seconds, "message": r.message} for r in results]
    return {"stages": stages, "pose_search": pose_search, "accuracy": acc,
            "count": len(results), "failed": len(results) - len(ok), "queries": queries,
            "median_num_rotations": acc["all"]["median_num_rotations"],
            "machine": common.machine_info(device)}


def stage_table(runs: dict[str, dict[str, Any]]):
    """Median seconds per stage: ours per device beside the paper's CPU and GPU columns."""
    from rich.table import Table

    t = Table(title="Localization runtime per query (median s; synthetic demo, 1024 x 512, all splits)")
    t.add_column("stage")
    for dev in runs:
        t.add_column(f"ours {dev}", justify="right")
    t.add_column("paper CPU", justify="right")
    t.add_column("paper GPU", justify="right")
    t.add_column("target (2-core CPU)", justify="right")
    for s in STAGES:
        tgt = TARGETS.get(s)
        t.add_row(common.PAPER_STAGE_NAMES[s] + f" ({s})", *[common.fmt(r["stages"][s], ".3f") for r in runs.values()],
                  f"{common.PAPER_SECONDS[s][0]:.3f}", f"{common.PAPER_SECONDS[s][1]:.3f}",
                  f"< {tgt}" if tgt else "", style="bold" if s == "total" else None)
    t.add_section()
    t.add_row("pose search (rotation + search)", *[common.fmt(r["pose_search"], ".3f") for r in runs.values()],
              f"{common.PAPER_SECONDS['rotation'][0] + common.PAPER_SECONDS['search'][0]:.3f}",
              f"{common.PAPER_SECONDS['rotation'][1] + common.PAPER_SECONDS['search'][1]:.3f}", "< 0.05")
    t.add_row("median N_r", *[common.fmt(r["median_num_rotations"], ".0f") for r in runs.values()], "", "", "<= 30")
    first = next(iter(runs.values()))
    t.caption = f"{first['count']} queries; " + common.load_line(first["machine"])
    return t


def accuracy_table(run: dict[str, Any], device: str):
    from rich.table import Table

    t = Table(title=f"Accuracy per split ({device})")
    for col in ("split", "n", "failed", "coarse only", "t err m", "R err deg", "0.05m/5", "0.1m/5", "0.2m/10"):
        t.add_column(col, justify="right" if col != "split" else "left")
    for split, s in run["accuracy"].items():
        a = s["accuracy"]
        t.add_row(split, str(s["count"]), str(s["failed"]), str(s["coarse_only"]),
                  common.fmt(s["median_t_error_m"], ".3f"), common.fmt(s["median_r_error_deg"], ".2f"),
                  common.fmt(a["0.05m_5deg"], ".2f"), common.fmt(a["0.1m_5deg"], ".2f"),
                  common.fmt(a["0.2m_10deg"], ".2f"), style="bold" if split == "all" else None)
    return t


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: robot and extreme splits only")
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cpu, plus cuda when available)")
    ap.add_argument("--seed", type=int, default=1, help="demo dataset seed")
    ap.add_argument("--root", type=Path, default=None, help="an OmniScenes-layout dataset with the maps of "
                    "`ldlmap prepare` in ROOT/maps, instead of the cached demo (e.g. on a machine that cannot build maps)")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "results.json")
    ap.add_argument("--threads", type=int, default=DEFAULT_THREADS,
                    help=f"CPU threads of torch and OpenCV (default {DEFAULT_THREADS}, as ldlloc runs; 0: the libraries')")
    args = ap.parse_args(argv)
    common.set_threads(args.threads)
    import torch

    if args.device:
        devices = [args.device]
    else:
        devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    splits = ["robot", "extreme"] if args.quick else None
    dataset = args.root.resolve() if args.root else common.demo_dataset(args.seed)
    runs = {dev: run_device(dataset, dev, splits, prepared=args.root is not None) for dev in devices}
    con = common.console()
    con.print(stage_table(runs))
    for dev, run in runs.items():
        con.print(accuracy_table(run, dev))
    main_dev = devices[0]
    main_run = runs[main_dev]
    result = {
        "stages": main_run["stages"],
        "pose_search": main_run["pose_search"],
        "device": main_dev,
        "accuracy": main_run["accuracy"],
        "machine": main_run["machine"],
        "paper": {s: {"cpu": c, "gpu": g} for s, (c, g) in common.PAPER_SECONDS.items()},
        "runs": runs,
        "dataset": str(dataset.relative_to(common.ROOT)) if dataset.is_relative_to(common.ROOT) else str(dataset),
        "quick": bool(args.quick),
    }
    common.write_json(args.output, result)
    con.print(f"wrote {args.output}")
    return result


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"bench_localize: {time.perf_counter() - t0:.0f} s")
