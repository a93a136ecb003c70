"""Benchmark: map building (seconds per stage, map size, peak memory) and the number of views.

Run: ``python bench/bench_build.py [--quick] [--points 1000000] [--views 10,20,40,80]``.

1. Builds the map of the synthetic demo scene ``synthroom_1`` (``bench/.cache/demo_s1``) and of
   a room-sized simulated scan of about ``--points`` points (a "standard"-preset room) with the
   default :class:`~ldlmap.map.build.BuildParams` (SIFT, N_t = 800, 40 views). Each build runs in a
   fresh subprocess; its peak memory is that process's ``resource.getrusage(RUSAGE_SELF)
   .ru_maxrss`` at the end of the build: the resident peak of the whole process, Python,
   torch, open3d and OpenCV included. Targets printed beside: under 2 minutes for ~1 M points,
   map under 150 MB.
2. Views need not be rendered at every candidate translation: the demo scene's queries (all
   splits) are localized with maps holding the first 10, 20, 40, 80 views of one 80-view build
   (views are farthest-point sampled from a fixed start, so the first k views are exactly what a
   k-view build renders; checked against the 40-view build of part 1), reporting accuracy and
   refinement time per view count.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

TARGET_SECONDS_1M = 120.0
TARGET_MAP_MB = 150.0
STAGES = ("load", "lines", "principal", "translations", "features", "write", "total")


def _worker(input_path: str, output: str, params_json: str) -> None:
    """Build one map in this process and print its report (with ru_maxrss) as one JSON line."""
    import resource

    from ldlmap.map.build import BuildParams, build_map

    params = BuildParams().replaced(**json.loads(params_json))
    rep = build_map(input_path, output, params=params)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
    print(json.dumps({"seconds": rep.seconds, "counts": rep.counts, "peak_rss_mb": peak_mb}))


def build_in_subprocess(input_path: Path, output: Path, threads: int = 0, **params: Any) -> dict[str, Any]:
    """Run :func:`_worker` in a fresh Python (``threads`` torch threads, 0: default); its JSON report."""
    output.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--threads", str(threads), "--worker", str(input_path),
           str(output), json.dumps(params)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"build of {input_path} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def build_table(reports: dict[str, dict[str, Any]], info: dict[str, Any]):
    """Rich table: one column per build, rows = stages, counts, size and memory, targets."""
    from rich.table import Table

    t = Table(title="Map building (default BuildParams: SIFT, N_t = 800, 40 views, 1024 x 512)")
    t.add_column("")
    for name in reports:
        t.add_column(name, justify="right")
    t.add_column("target", justify="right")
    for st in STAGES:
        tgt = f"< {TARGET_SECONDS_1M:.0f} (1 M pts)" if st == "total" else ""
        t.add_row(f"{st} s", *[common.fmt(r["seconds"].get(st), ".2f") for r in reports.values()], tgt,
                  style="bold" if st == "total" else None)
    t.add_section()
    rows = [("input points", "input_points", "d"), ("3D lines (raw)", "lines_raw", "d"),
            ("3D lines (kept)", "lines", "d"), ("translations N_t", "translations", "d"),
            ("rendered views", "views", "d"), ("keypoints", "keypoints", "d")]
    for label, key, spec in rows:
        t.add_row(label, *[format(r["counts"].get(key, 0), spec) if key in r["counts"] else "-"
                           for r in reports.values()], "")
    t.add_row("map size MB", *[common.fmt(r["counts"]["size_mb"], ".1f") for r in reports.values()],
              f"< {TARGET_MAP_MB:.0f}")
    t.add_row("peak RSS MB (ru_maxrss)", *[common.fmt(r["peak_rss_mb"], ".0f") for r in reports.values()], "")
    t.caption = common.load_line(info)
    return t


def views_sweep(dataset: Path, scene: str, views: list[int], splits: list[str] | None,
                check_map: Path | None) -> list[dict[str, Any]]:
    """Localize the scene's queries with maps holding the first k views of one max(views) build."""
    from ldlloc.batch.accuracy import summarize
    from ldlloc.pipeline import Localizer
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map

    full = read_map(common.cached_map(dataset, scene, num_views=max(views)), load_cloud=False)
    if check_map is not None and check_map.exists():
        ref = read_map(check_map, load_cloud=False).features.view_centers
        k = len(ref)
        if k > full.features.num_views:  # --views below the default: nothing to compare
            print(f"check: skipped (the sweep's largest map has {full.features.num_views} views, the build {k})")
        else:
            same = np.allclose(full.features.view_centers[:k], ref)
            print(f"check: the first {k} views of the {full.features.num_views}-view map "
                  f"{'equal' if same else 'DIFFER FROM'} the views of the {k}-view build")
    queries = open_dataset(dataset, "omniscenes").queries(splits, scene=scene)
    rows = []
    for k in views:
        m = common.subset_views(full, k)
        loc = Localizer(m)
        outs = common.localize_queries(loc, queries)
        s = summarize([o.result for o in outs])
        # how far each query is from the view that served the chosen candidate's translation
        dist = [float(np.min(np.linalg.norm(m.features.view_centers - np.asarray(q.center), axis=1)))
                for q in queries]
        rows.append({"views": k, "count": s["count"], "accuracy": s["accuracy"],
                     "median_t_error_m": s["median_t_error_m"], "median_r_error_deg": s["median_r_error_deg"],
                     "median_refine_s": s["median_seconds"].get("refine"),
                     "median_inliers": float(np.median([o.result.num_inliers for o in outs])),
                     "coarse_only": s["coarse_only"], "failed": s["failed"],
                     "median_query_to_view_m": float(np.median(dist))})
    return rows


def views_table(rows: list[dict[str, Any]], scene: str, info: dict[str, Any]):
    from rich.table import Table

    t = Table(title=f"Rendered views vs localization ({scene}, all splits; first k views of one build)")
    for col in ("views", "n", "acc 0.05m/5", "acc 0.1m/5", "acc 0.2m/10", "t err m", "R err deg",
                "refine s (median)", "inliers (median)", "coarse only", "view dist m"):
        t.add_column(col, justify="right")
    for r in rows:
        a = r["accuracy"]
        t.add_row(str(r["views"]), str(r["count"]), common.fmt(a["0.05m_5deg"], ".2f"),
                  common.fmt(a["0.1m_5deg"], ".2f"), common.fmt(a["0.2m_10deg"], ".2f"),
                  common.fmt(r["median_t_error_m"], ".3f"), common.fmt(r["median_r_error_deg"], ".2f"),
                  common.fmt(r["median_refine_s"], ".3f"), common.fmt(r["median_inliers"], ".0f"),
                  str(r["coarse_only"]), common.fmt(r["median_query_to_view_m"], ".2f"),
                  style="bold" if r["views"] == 40 else None)
    t.caption = "default num_views = 40 (bold); " + common.load_line(info)
    return t


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small smoke run: 200 k points, views 10 and 40, 2 splits")
    ap.add_argument("--points", type=int, default=None, help="points of the room-sized scan (default 1 M)")
    ap.add_argument("--views", default=None, help="comma-separated view counts (default 10,20,40,80)")
    ap.add_argument("--seed", type=int, default=1, help="demo dataset seed")
    ap.add_argument("--skip-large", action="store_true", help="skip the room-sized scan")
    ap.add_argument("--skip-views", action="store_true", help="skip the view-count sweep")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "build_results.json")
    ap.add_argument("--worker", nargs=3, metavar=("INPUT", "OUTPUT", "PARAMS"), help=argparse.SUPPRESS)
    ap.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: torch default)")
    args = ap.parse_args(argv)
    common.set_threads(args.threads)
    if args.worker:
        _worker(*args.worker)
        return {}

    points = args.points or (200_000 if args.quick else 1_000_000)
    views = [int(v) for v in (args.views or ("10,40" if args.quick else "10,20,40,80")).split(",")]
    splits = ["robot", "extreme"] if args.quick else None
    con = common.console()
    dataset = common.demo_dataset(args.seed)
    scene = "synthroom_1"
    from ldlmap.datasets import open_dataset

    demo_cloud = open_dataset(dataset, "omniscenes").point_cloud(scene)
    out_dir = common.CACHE / "build_bench"
    reports: dict[str, dict[str, Any]] = {}
    rep = build_in_subprocess(demo_cloud, out_dir / f"demo_s{args.seed}_{scene}.h5", args.threads)
    rep["counts"]["input_points"] = _count_points(demo_cloud)
    reports[f"demo {scene}"] = rep
    if not args.skip_large:
        scan, meta = common.room_scan(points)
        rep = build_in_subprocess(scan, out_dir / f"{scan.stem}.h5", args.threads)
        rep["counts"]["input_points"] = meta["points"]
        ext = "x".join(f"{x:.1f}" for x in meta["extent_m"])
        reports[f"room scan {meta['points'] / 1e6:.2f} M pts ({ext} m)"] = rep
    info = common.machine_info()
    con.print(build_table(reports, info))
    result: dict[str, Any] = {"builds": reports, "machine": info,
                              "peak_memory": "ru_maxrss of a fresh subprocess per build (whole process)",
                              "targets": {"total_s_1M": TARGET_SECONDS_1M, "map_mb": TARGET_MAP_MB}}
    if not args.skip_views:
        rows = views_sweep(dataset, scene, views, splits, out_dir / f"demo_s{args.seed}_{scene}.h5")
        info = common.machine_info()
        con.print(views_table(rows, scene, info))
        result["views"] = rows
    result["machine_end"] = common.machine_info()
    common.write_json(args.output, result)
    con.print(f"wrote {args.output}")
    return result


def _count_points(path: Path) -> int:
    """Number of points of a cloud file (read through the toolkit's reader)."""
    from ldlmap.io.pointcloud import read_point_cloud

    return int(len(read_point_cloud(path).points))


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    if "--worker" not in sys.argv:
        print(f"bench_build: {time.perf_counter() - t0:.0f} s")
