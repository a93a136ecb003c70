"""Rooms that are not boxes: localization per room kind and split.

Run: ``python bench/bench_shapes.py [--scenes 2] [--per-split 3] [--maps edges,scan] [--max-tilt 10]
[--build field=value]``.

For each room kind of the generator (``angled``: 5-8 walls at 30/45/60 deg; ``sloped``: shed and
gable ceilings of 15-45 deg; ``stepped``; ``arched``: segmental barrel vaults; ``curved``: bays,
rounded corners and round rooms as fine polygons) it generates ``--scenes`` furnished rooms (the
kind's preset, seed ``--seed``) with ``--per-split`` panoramas in each of the robot, handheld and
extreme splits (cached under ``bench/.cache/shapes/``), builds the maps and localizes every
panorama with the defaults (``ldlloc run``'s library path):

- ``edges``: lines-only maps of the scene's true creases (``gt_lines/``), ``--up z``, no features
  (what ``ldlmap build lines.obj --up z`` makes): the method's own ceiling;
- ``scan``: maps from the simulated scan with the defaults of ``ldlmap prepare`` (3D line
  extraction and SIFT features).

``--build atlanta_frame=false`` gives every edge map the Manhattan frame (the comparison of
docs/measurements.md#atlanta-frame), ``--build max_horizontals=2`` Atlanta frames of the vertical
and the main two horizontals only (docs/measurements.md#atlanta-many).

Printed per kind and split, per map kind: search top-1 and best of the top 20 within 0.5 m / 10 deg,
final within 0.1 m / 5 deg and 0.25 m / 5 deg, median errors, and how many final poses are upside
down (camera up more than 90 deg from the truth's), and how many poses are marked confident (of them
beyond 0.25 m / 5 deg). Results go to ``bench/shapes.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import (CACHE, console, machine_info, map_tag, parse_field,  # noqa: E402
                          preset_rooms_dataset, set_threads, synth_tag, write_json)

SPLITS = ("robot", "handheld", "extreme")


def shapes_dataset(kind: str, scenes: int, seed: int, per_split: int) -> Path:
    """``scenes`` rooms of ``kind`` with ``per_split`` panoramas in each of :data:`SPLITS`."""
    out = CACHE / "shapes" / f"{kind}_s{seed}_k{scenes}_n{per_split}_{synth_tag()}"
    return preset_rooms_dataset(out, out.with_name(out.name + "_specs"), kind, seed, scenes, kind,
                                {split: per_split for split in SPLITS})


def build_maps(root: Path, source: str, overrides: dict | None = None) -> Path:
    """One map per scene of ``root`` from its true edges (``edges``) or its scan (``scan``);
    ``overrides``: BuildParams config keys of the edge maps (experiments)."""
    from ldlmap.batch.prepare import default_params, prepare_dataset
    from ldlmap.datasets import open_dataset
    from ldlmap.io.linefiles import read_lines
    from ldlmap.map.build import BuildParams, build_lines_map

    tag = "".join(f"_{k}={v}" for k, v in sorted((overrides or {}).items()))
    maps = root / f"maps_{source}{tag}_{map_tag()}"
    ds = open_dataset(root, "omniscenes")
    if source == "scan":
        prepare_dataset(root, "omniscenes", maps, default_params("omniscenes"))
        return maps
    params = BuildParams().replaced(features="none", up="z").replaced(**(overrides or {}))
    for scene in ds.scenes():
        target = maps / f"{scene}.h5"
        if not target.exists():
            build_lines_map(read_lines(ds.gt_line_file(scene)), target, params, name=scene, source=f"edges:{scene}")
    return maps


def localize(root: Path, maps: Path, max_tilt: float | None) -> list[dict]:
    from ldlloc.batch.run import run_queries
    from ldlloc.pipeline import LocalizeParams
    from ldlmap.datasets import open_dataset

    queries = open_dataset(root, "omniscenes").queries(list(SPLITS))
    params = LocalizeParams(max_tilt_deg=max_tilt)
    out = maps / f"results_tilt{max_tilt}.json"
    if out.exists():
        out.unlink()
    results = run_queries(queries, maps, out, params, "cpu", meta={"dataset": "shapes"})
    truth = {q.name: q for q in queries}
    rows = []
    for r in results:
        q = truth[r.name]
        ok = r.status != "failed"
        upside_down = False
        if ok:
            up_est = np.asarray(r.R)[:, 2] if r.input_frame is None else np.asarray(r.input_frame["R"])[:, 2]
            upside_down = bool(np.dot(up_est, np.asarray(q.rot_cam_from_world)[:, 2]) < 0)
        rows.append({"name": r.name, "scene": r.scene, "split": r.split, "status": r.status,
                     "t_error_m": r.t_error_m if ok else None, "r_error_deg": r.r_error_deg if ok else None,
                     "first_good_rank": r.first_good_rank if ok else None, "upside_down": upside_down,
                     "confident": r.verdict == "confident", "seconds": r.seconds})
    return rows


def summarize(rows: list[dict]) -> dict:
    te = np.array([r["t_error_m"] if r["t_error_m"] is not None else np.inf for r in rows])
    re = np.array([r["r_error_deg"] if r["r_error_deg"] is not None else np.inf for r in rows])
    ranks = [r["first_good_rank"] for r in rows]
    confident = np.array([r["confident"] for r in rows], dtype=bool)
    return {
        "count": len(rows),
        "top1": float(np.mean([k == 1 for k in ranks])) if rows else None,
        "top20": float(np.mean([k is not None for k in ranks])) if rows else None,
        "acc_0.1m_5deg": float(np.mean((te < 0.1) & (re < 5))) if rows else None,
        "acc_0.25m_5deg": float(np.mean((te < 0.25) & (re < 5))) if rows else None,
        "median_t_error_m": float(np.median(te)) if rows else None,
        "median_r_error_deg": float(np.median(re)) if rows else None,
        "upside_down": int(sum(r["upside_down"] for r in rows)),
        "confident": int(confident.sum()),
        "confident_wrong": int((confident & ~((te < 0.25) & (re < 5))).sum()),  # beyond 0.25 m / 5 deg
    }


def print_table(title: str, table: dict) -> None:
    from rich.table import Table

    t = Table(title=title)
    for col in ("kind", "split", "queries", "top-1 0.5m/10deg", "top-20", "final 0.1m/5deg", "final 0.25m/5deg",
                "median t m", "median r deg", "upside down", "confident (wrong)"):
        t.add_column(col, justify="right" if col not in ("kind", "split") else "left")
    for (kind, split), s in table.items():
        f = lambda x, spec=".2f": "-" if x is None else format(x, spec)  # noqa: E731
        t.add_row(kind, split, str(s["count"]), f(s["top1"]), f(s["top20"]), f(s["acc_0.1m_5deg"]),
                  f(s["acc_0.25m_5deg"]), f(s["median_t_error_m"], ".3f"), f(s["median_r_error_deg"], ".2f"),
                  str(s["upside_down"]), f"{s['confident']} ({s['confident_wrong']})")
    console().print(t)


def main() -> None:
    from ldlmap.synth.shapes import SHAPE_KINDS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kinds", default=",".join(SHAPE_KINDS))
    ap.add_argument("--scenes", type=int, default=2, help="rooms per kind")
    ap.add_argument("--per-split", type=int, default=3)
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--maps", default="edges", help="edges, scan or edges,scan")
    ap.add_argument("--max-tilt", type=float, default=None, help="upright prior (deg); default free rotation")
    ap.add_argument("--build", action="append", default=[], help="key=value: a BuildParams config key of the edge maps")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=HERE / "shapes.json")
    args = ap.parse_args()
    set_threads(args.threads)
    from ldlmap.map.build import BuildParams

    overrides = {}
    for kv in args.build:
        key, value = kv.split("=", 1)
        overrides[key] = parse_field(BuildParams().config()[key], value)
    report = {"machine": machine_info(), "args": {k: str(v) for k, v in vars(args).items()}, "maps": {}}
    for source in args.maps.split(","):
        table, all_rows = {}, []
        for kind in args.kinds.split(","):
            t0 = time.perf_counter()
            root = shapes_dataset(kind, args.scenes, args.seed, args.per_split)
            maps = build_maps(root, source, overrides)
            t1 = time.perf_counter()
            rows = localize(root, maps, args.max_tilt)
            for r in rows:
                r["kind"] = kind
            all_rows += rows
            for split in SPLITS:
                table[(kind, split)] = summarize([r for r in rows if r["split"] == split])
            table[(kind, "all")] = summarize(rows)
            console().print(f"{source} maps, {kind}: data and maps {t1 - t0:.0f} s, localization "
                            f"{time.perf_counter() - t1:.0f} s")
        table[("all", "all")] = summarize(all_rows)
        print_table(f"{source} maps ({'free rotation' if args.max_tilt is None else f'--max-tilt {args.max_tilt:g}'})",
                    table)
        report["maps"][source] = {"summary": {f"{k}/{s}": v for (k, s), v in table.items()}, "queries": all_rows}
    write_json(args.out, report)
    console().print(f"results: {args.out}")


if __name__ == "__main__":
    main()
