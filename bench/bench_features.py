"""Benchmark: feature backends (sift, aliked, disk, xfeat) through the whole pipeline.

Run: ``python bench/bench_features.py [--seed 23] [--per-split 1] [--backends sift,aliked,disk,xfeat]
[--frames image,map] [--extractions equirect,cube] [--gap none,hard] [--splits robot,extreme] [--threads 1]``.

For each backend, maps of the synthetic demo dataset of ``--seed`` (an unseen seed: the tests use
7, the other benchmarks 1) are built with the default :class:`~ldlmap.map.build.BuildParams` but
``features`` (40 views; build seconds per room timed once and cached beside the map), then the
first ``--per-split`` queries per split and scene are localized with the default
:class:`~ldlloc.pipeline.LocalizeParams` but ``query_frame`` (``image``: features of the panorama
as taken; ``map``: of the panorama rotated into the map's frame by the best candidate rotation)
and ``--extractions`` (``equirect``: features of the whole panoramas, map views and queries alike;
``cube``: of their six 90-degree cube faces, :class:`ldlmap.features.sphere.CubeFaces`).
Per backend, frame and appearance gap it prints accuracy at 0.1 m / 5 deg and 0.05 m / 5 deg,
the share of queries whose feature refinement failed (the pose then comes from the geometric
fallback or stays coarse), median feature matches and PnP inliers, refine seconds per query
(median and mean) and map build seconds per room; it writes ``bench/results_features.json``.

Appearance gap ``hard``: the map's views are rendered from the scan's colours; each query image
is changed, deterministically per query, by an exposure of 2^U(-1, 1) (+-1 EV), per-channel
colour gains U(0.7, 1.3), a gamma U(0.6, 1.6), a Gaussian blur of sigma U(1, 2.5) px and
Gaussian noise of 3 grey levels: exposure, colour and blur at once, on every split (the
illumination splits change one of exposure, gamma or white balance, and nothing blurs but the
extreme split's motion).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

BACKENDS = ("sift", "aliked", "disk", "xfeat")


def harder_appearance(img: np.ndarray, key: str) -> np.ndarray:
    """``img`` with the ``hard`` appearance gap of the module docstring, seeded by ``key``."""
    import cv2

    rng = np.random.default_rng(zlib.crc32(key.encode()))
    x = img.astype(np.float32) / 255.0
    x = x * 2.0 ** rng.uniform(-1.0, 1.0) * rng.uniform(0.7, 1.3, 3)[None, None]
    x = np.clip(x, 0.0, 1.0) ** rng.uniform(0.6, 1.6)
    x = cv2.GaussianBlur(x, (0, 0), float(rng.uniform(1.0, 2.5)), borderType=cv2.BORDER_REFLECT)
    x = x + rng.normal(0.0, 3.0 / 255.0, x.shape).astype(np.float32)
    return np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)


def run(dataset: Path, backend: str, frame: str, gap: str, per_split: int, splits: list[str] | None = None,
        progress: bool = True, extraction: str = "equirect") -> dict[str, Any]:
    """Localize the selected queries with maps of ``backend``; one row of the tables."""
    from ldlloc.pipeline import LocalizeParams, Localizer
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map

    ds = open_dataset(dataset, "omniscenes")
    transform = (lambda img, q: harder_appearance(img, q.name)) if gap == "hard" else None
    rows, builds = [], []
    for scene in ds.scenes():
        queries = [q for split in splits or ds.splits() for q in ds.queries(split, scene=scene)[:per_split]]
        path = common.cached_map(dataset, scene, 40, backend, feature_extraction=extraction)
        builds.append(common.build_seconds(path))
        loc = Localizer(read_map(path, load_cloud=False), LocalizeParams(query_frame=frame))

        def done(i: int, n: int) -> None:
            if progress:
                print(f"\r  {backend} {extraction} {frame} {gap} {scene}: {i}/{n}", end="\n" if i == n else "",
                      file=sys.stderr)

        for o in common.localize_queries(loc, queries, done, transform):
            r, out = o.result, o.loc
            rows.append({"name": r.name, "split": r.split, "t_err": np.inf if out is None else r.t_error_m,
                         "r_err": np.inf if out is None else r.r_error_deg,
                         "features_ok": out is not None and out.refine_method.startswith("features"),
                         "matches": r.num_matches, "inliers": r.num_inliers,
                         "refine_s": None if out is None else out.seconds["refine"],
                         **({"message": r.message} if out is None else {})})
    t = np.array([r["t_err"] for r in rows])
    a = np.array([r["r_err"] for r in rows])
    ref = [r["refine_s"] for r in rows if r["refine_s"] is not None]
    return {"backend": backend, "extraction": extraction, "frame": frame, "gap": gap, "count": len(rows),
            "acc_0.1m_5deg": float(np.mean((t < 0.1) & (a < 5))), "acc_0.05m_5deg": float(np.mean((t < 0.05) & (a < 5))),
            "fallback_share": float(np.mean([not r["features_ok"] for r in rows])),
            "median_matches": float(np.median([r["matches"] for r in rows])),
            "median_inliers": float(np.median([r["inliers"] for r in rows])),
            "refine_s_median": float(np.median(ref)) if ref else None, "refine_s_mean": float(np.mean(ref)) if ref else None,
            "build_s_per_room": float(np.mean(builds)) if None not in builds else None, "queries": rows}


def table(rows: list[dict[str, Any]], machine: dict[str, Any]):
    from rich.table import Table

    t = Table(title="Feature backends, full pipeline (synthetic demo, unseen seed)")
    for col in ("backend", "extraction", "query frame", "gap", "n", "0.1m/5", "0.05m/5", "fell back", "matches", "inliers",
                "refine s (med)", "refine s (mean)", "build s/room"):
        t.add_column(col, justify="left" if col in ("backend", "extraction", "query frame", "gap") else "right")
    for r in rows:
        t.add_row(r["backend"], r.get("extraction", "equirect"), r["frame"], r["gap"], str(r["count"]), common.fmt(r["acc_0.1m_5deg"], ".2f"),
                  common.fmt(r["acc_0.05m_5deg"], ".2f"), common.fmt(r["fallback_share"], ".2f"),
                  common.fmt(r["median_matches"], ".0f"), common.fmt(r["median_inliers"], ".0f"),
                  common.fmt(r["refine_s_median"], ".2f"), common.fmt(r["refine_s_mean"], ".2f"),
                  common.fmt(r["build_s_per_room"], ".0f"))
    t.caption = common.load_line(machine)
    return t


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=23, help="demo dataset seed (unseen by the tests and other benchmarks)")
    ap.add_argument("--per-split", type=int, default=1, help="queries per split and scene (the demo has 3)")
    ap.add_argument("--backends", default=",".join(BACKENDS))
    ap.add_argument("--frames", default="map", help="query frames to compare: image, map or both (comma-separated)")
    ap.add_argument("--extractions", default="equirect", help="panorama feature extraction: equirect, cube or both "
                    "(comma-separated)")
    ap.add_argument("--gap", default="none,hard", help="appearance gaps: none, hard (comma-separated)")
    ap.add_argument("--splits", default=None, help="comma-separated splits (default: all eight)")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (0: torch default)")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "results_features.json")
    args = ap.parse_args(argv)
    common.set_threads(args.threads)
    dataset = common.demo_dataset(args.seed)
    rows = []
    combos = itertools.product(args.backends.split(","), args.extractions.split(","), args.frames.split(","),
                               args.gap.split(","))
    for backend, extraction, frame, gap in combos:
        rows.append(run(dataset, backend, frame, gap, args.per_split, args.splits.split(",") if args.splits else None,
                        extraction=extraction))
        machine = common.machine_info()
        common.console().print(table(rows[-1:], machine))
        result = {"rows": rows, "machine": machine, "seed": args.seed, "per_split": args.per_split,
                  "splits": args.splits}
        common.write_json(args.output, json.loads(json.dumps(result, default=float)))  # after each row
    common.console().print(table(rows, machine))
    print(f"wrote {args.output}")
    return result


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"bench_features: {time.perf_counter() - t0:.0f} s")
