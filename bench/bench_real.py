"""Real panoramas: ZInD homes against lines-only maps of their room layouts.

Run: ``python bench/bench_real.py [--data ../shared/data] [--levels room,floor,rooms] [--threads 1]``.

For every home under ``<data>/zind`` (the project's shared copy holds one, ``000``: 19 real
panoramas, 15 rooms), at each level (``room``: one map per complete room, the room given;
``floor``: one map for all rooms of a floor, the paper's large-scale setting, the room not given;
``rooms``: the room maps, the room not given, ``ldlloc run --scene-unknown``: each panorama
against all room maps of its floor, judged together), the maps are built from the
layouts (``ldlmap prepare --dataset zind``, cached under ``bench/.cache/real/``) and every
panorama is localized with ``ldlloc run``'s library path (layout maps carry no features: the
pose search, then the geometric refinement unless ``--refine none``). Printed per query and
summarized:

- top-1 within 0.5 m / 10 deg (the search's best pose), best of the top 20 within 0.5 m / 10 deg
  (``rooms``: of the chosen room map's search);
- the final pose within 0.5 m / 10 deg, its accuracy at 0.1 m / 5 deg and 0.25 m / 5 deg, median
  errors, the share of queries whose refinement was kept;
- the share of queries whose nearest candidate translation is within 0.25 m of the camera;
- median seconds per stage (``rotation + search`` is the pose search of the targets: under
  50 ms at room level and 150 ms at floor level on 2 cores with 1 thread).

The data path comes from ``--data``, else ``$LDL_REAL_DATA``, else ``../shared/data`` beside
the repository; without data the script says so and exits 0 (``make bench`` runs it only when
the data is there). Results go to ``bench/real.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import CACHE, console, parse_field, source_hash  # noqa: E402

GOOD_T, GOOD_R = 0.5, 10.0  # "right pose" for the search: within 0.5 m and 10 deg


def real_data_root(arg: str | None) -> Path:
    """``--data``, else ``$LDL_REAL_DATA``, else ``<repo>/../shared/data``."""
    return Path(arg or os.environ.get("LDL_REAL_DATA") or ROOT.parent / "shared" / "data")


def zind_root_or_none(arg: str | None) -> Path | None:
    """The ZInD folder of the real data (:func:`real_data_root`), or None after saying it is not there."""
    zind_root = real_data_root(arg) / "zind"
    if not zind_root.is_dir():
        print(f"no real data at {zind_root} (pass --data or set LDL_REAL_DATA): nothing to measure")
        return None
    return zind_root


def use_threads(threads: int) -> None:
    """torch's and OpenCV's threads, as the product sets them (`--threads`)."""
    import cv2
    import torch

    torch.set_num_threads(threads)
    cv2.setNumThreads(threads)


def build_maps(zind_root: Path, level: str, spacing: float | None) -> Path:
    """Maps of every scene at ``level``, cached by the code that builds them."""
    from ldlmap.map.params import BuildParams, params_with
    from ldlmap.batch.prepare import default_params, prepare_dataset

    tag = source_hash("ldlmap", exclude=("synth/",))
    maps = CACHE / "real" / f"{level}_{spacing or 'default'}_{tag}"
    params = params_with(default_params("zind", BuildParams()), trans_spacing=spacing)
    t0 = time.perf_counter()
    out = prepare_dataset(zind_root, "zind", maps, params, map_level=level)
    failed = [o for o in out if o.status == "failed"]
    built = [o for o in out if o.status == "built"]
    console().print(f"{level} maps: {len(out)} scenes, {len(built)} built in {time.perf_counter() - t0:.1f} s, "
                    f"{len(failed)} failed" + "".join(f"\n  {o.scene}: {o.message}" for o in failed))
    return maps


def map_translations(maps: Path, scene: str) -> np.ndarray:
    """Candidate translations (N_t, 3) of a scene's map (empty when it cannot be read)."""
    from ldlmap.core.errors import LdlError
    from ldlmap.map.mapfile import read_map

    try:
        return read_map(maps / f"{scene}.h5", load_cloud=False).translations
    except LdlError:
        return np.zeros((0, 3))


def run_level(zind_root: Path, level: str, args) -> dict:
    from ldlmap.datasets import open_dataset
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.batch.run import run_queries

    from ldlloc.batch.which_map import TOP_MAPS

    map_level = "room" if level == "rooms" else level  # rooms: the room maps, the room not given
    maps = build_maps(zind_root, map_level, args.spacing)
    ds = open_dataset(zind_root, "zind", map_level=map_level)
    queries = ds.queries()
    from dataclasses import replace

    params = LocalizeParams(refine_mode=args.refine)
    if args.max_tilt is not None:
        params = replace(params, max_tilt_deg=args.max_tilt)
    search = {}
    if args.rescore_level is not None:
        search["rescore_query_level"] = args.rescore_level
    if args.diverse is not None:
        d_t, d_r = (float(x) for x in args.diverse.split(","))
        search.update(diverse_translation=d_t, diverse_rotation_deg=d_r)
    for kv in args.search or []:  # --search name=value: any SearchParams field (experiments)
        key, value = kv.split("=", 1)
        default = getattr(params.search, key)
        search[key] = parse_field(default, value) if default is not None else int(value)
    if search:
        params = replace(params, search=replace(params.search, **search))
    geo = {}
    for kv in args.geometric or []:  # --geometric name=value: any GeometricParams field (experiments)
        key, value = kv.split("=", 1)
        geo[key] = parse_field(getattr(params.geometric, key), value)
    if geo:
        params = replace(params, geometric=replace(params.geometric, **geo))
    if args.keep_ratio is not None:
        lo, hi = (float(x) for x in args.keep_ratio.split(","))
        params = replace(params, lines2d=replace(params.lines2d, keep_ratio_bounds=(lo, hi)))
    out = CACHE / "real" / f"results_{level}.json"
    if out.exists():
        out.unlink()
    results = run_queries(queries, maps, out, params, "cpu", meta={"dataset": "zind", "map_level": map_level},
                          top_maps=TOP_MAPS if level == "rooms" else None)
    gt = {q.name: q for q in queries}
    translations: dict[str, np.ndarray] = {}
    rows = []
    for r in results:
        q = gt[r.name]
        if q.scene not in translations:  # each map read once (the floor map is large)
            translations[q.scene] = map_translations(maps, q.scene)
        T = translations[q.scene]
        near = float(np.linalg.norm(T - q.center, axis=1).min()) if len(T) else float("inf")
        n_t = len(T)
        ok = r.status != "failed"
        rows.append({
            "name": r.name, "scene": r.scene, "status": r.status, "message": r.message,
            "chosen_map": None if r.map is None else Path(r.map).stem,
            "t_error_m": r.t_error_m if ok else None, "r_error_deg": r.r_error_deg if ok else None,
            "top1_good": bool(ok and getattr(r, "first_good_rank", None) == 1),
            "final_good": bool(ok and r.t_error_m < GOOD_T and r.r_error_deg < GOOD_R),
            "refined": bool(r.refined), "confident": r.verdict == "confident",
            "first_good_rank": getattr(r, "first_good_rank", None) if ok else None,
            "nearest_candidate_m": near, "num_translations": n_t,
            "num_rotations": r.num_rotations, "rotation_prior": getattr(r, "rotation_prior", ""),
            "seconds": r.seconds,
        })
    return {"level": level, "queries": rows, "summary": summarize(rows)}


def summarize(rows: list[dict]) -> dict:
    n = len(rows)
    te = np.array([r["t_error_m"] if r["t_error_m"] is not None else np.inf for r in rows])
    re = np.array([r["r_error_deg"] if r["r_error_deg"] is not None else np.inf for r in rows])
    med = lambda key: float(np.median([r["seconds"].get(key, np.nan) for r in rows if r["seconds"]]))  # noqa: E731
    pose_search = float(np.median([r["seconds"].get("rotation", 0) + r["seconds"].get("search", 0)
                                   for r in rows if "search" in r["seconds"]] or [np.nan]))
    right = (te < 0.25) & (re < 5)
    confident = np.array([r.get("confident", False) for r in rows], dtype=bool)
    return {
        "count": n,
        "failed": sum(r["status"] == "failed" for r in rows),
        "confident": int(confident.sum()),
        "confident_wrong": int((confident & ~right).sum()),  # beyond 0.25 m / 5 deg
        "top1_0.5m_10deg": float(np.mean([r["top1_good"] for r in rows])),
        "final_0.5m_10deg": float(np.mean([r["final_good"] for r in rows])),
        "refined": float(np.mean([r["refined"] for r in rows])),
        "top20_0.5m_10deg": float(np.mean([r["first_good_rank"] is not None for r in rows])),
        "acc_0.1m_5deg": float(np.mean((te < 0.1) & (re < 5))),
        "acc_0.25m_5deg": float(np.mean((te < 0.25) & (re < 5))),
        "median_t_error_m": float(np.median(te)),
        "median_r_error_deg": float(np.median(re)),
        "nearest_candidate_within_0.25m": float(np.mean([r["nearest_candidate_m"] < 0.25 for r in rows])),
        "median_num_translations": float(np.median([r["num_translations"] for r in rows])),
        "median_seconds": {k: med(k) for k in ("lines2d", "rotation", "search", "refine", "total")},
        "median_pose_search_seconds": pose_search,
    }


def print_level(res: dict) -> None:
    from rich.table import Table

    t = Table(title=f"ZInD, {res['level']} level: per query (final pose errors; the search's top-1 and rank)")
    for col in ("query", "map", "status", "t err m", "r err deg", "search top-1 ok", "first ok rank", "nearest cand m",
                "N_t", "N_r", "search s"):
        t.add_column(col)
    for r in res["queries"]:
        f = lambda x, s: "-" if x is None else format(x, s)  # noqa: E731
        own, chosen = r["scene"].split("/")[-1], r.get("chosen_map")
        t.add_row(r["name"], own if chosen in (None, own) else f"{own} -> {chosen}", r["status"], f(r["t_error_m"], ".3f"), f(r["r_error_deg"], ".1f"),
                  "yes" if r["top1_good"] else "no", f(r["first_good_rank"], "d"), f(r["nearest_candidate_m"], ".3f"),
                  str(r["num_translations"]), str(r["num_rotations"]),
                  f(r["seconds"].get("rotation", 0) + r["seconds"].get("search", 0) if r["seconds"] else None, ".3f"))
    console().print(t)


def print_summary(results: list[dict]) -> None:
    from rich.table import Table

    t = Table(title="ZInD summary (the real-data targets in brackets)")
    t.add_column("metric")
    for r in results:
        t.add_column(f"{r['level']} level", justify="right")
    targets = {"room": {"top1_0.5m_10deg": ">= 0.8", "top20_0.5m_10deg": ">= 0.95", "median_pose_search_seconds": "< 0.05"},
               "floor": {"top1_0.5m_10deg": ">= 0.5", "top20_0.5m_10deg": ">= 0.8", "median_pose_search_seconds": "< 0.15"}}
    keys = ["count", "failed", "confident", "confident_wrong", "top1_0.5m_10deg", "top20_0.5m_10deg", "final_0.5m_10deg", "refined", "acc_0.1m_5deg", "acc_0.25m_5deg",
            "median_t_error_m", "median_r_error_deg", "nearest_candidate_within_0.25m", "median_num_translations",
            "median_pose_search_seconds"]
    for k in keys:
        cells = []
        for r in results:
            v = r["summary"][k]
            cell = f"{v:.3f}" if isinstance(v, float) else str(v)
            tgt = targets.get(r["level"], {}).get(k)
            cells.append(cell + (f" [{tgt}]" if tgt else ""))
        t.add_row(k, *cells)
    for stage in ("lines2d", "rotation", "search", "refine", "total"):
        t.add_row(f"median {stage} s", *[f"{r['summary']['median_seconds'][stage]:.3f}" for r in results])
    console().print(t)


def print_sweep(sweep: list[dict]) -> None:
    """Per level and spacing: queries within 0.1 m and 0.25 m / 5 deg, the search's top-1 and top 20
    (counts of 19), the poses marked confident (of them beyond 0.25 m / 5 deg), the median error; and
    each level's sums over the spacings."""
    from rich.table import Table

    t = Table(title="ZInD over candidate spacings (counts of queries)")
    for col in ("level", "spacing m", "N_t median", "top-1", "top 20", "0.1 m / 5 deg", "0.25 m / 5 deg",
                "confident (wrong)", "median m"):
        t.add_column(col, justify="right")
    sums: dict[str, list[int]] = {}
    for r in sweep:
        s, n = r["summary"], r["summary"]["count"]
        row = [round(s["top1_0.5m_10deg"] * n), round(s["top20_0.5m_10deg"] * n), round(s["acc_0.1m_5deg"] * n),
               round(s["acc_0.25m_5deg"] * n), s["confident"], s["confident_wrong"]]
        acc = sums.setdefault(r["level"], [0] * len(row))
        sums[r["level"]] = [a + b for a, b in zip(acc, row)]
        t.add_row(r["level"], f"{r['spacing']:.2f}", f"{s['median_num_translations']:.0f}", *map(str, row[:4]),
                  f"{row[4]} ({row[5]})", f"{s['median_t_error_m']:.3f}")
    for level, acc in sums.items():
        t.add_row(level, "sum", "", *map(str, acc[:4]), f"{acc[4]} ({acc[5]})", "")
    console().print(t)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="real data folder (default $LDL_REAL_DATA or ../shared/data)")
    ap.add_argument("--levels", default="room,floor,rooms",
                    help="levels, comma-separated: room, floor, rooms (room maps, the room not given; default all)")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    ap.add_argument("--spacing", default=None,
                    help="candidate translation spacing in metres (default: the map's); several, comma-separated "
                         "(e.g. 0.2,0.25,0.3,0.35,0.4): one run per spacing and a table of them, to tell a change "
                         "from the spread of 19 queries")
    ap.add_argument("--refine", default="auto", help="auto (geometric for these lines-only maps) | geometric | none")
    ap.add_argument("--max-tilt", type=float, default=None, help="upright prior in degrees (default: the reader's)")
    ap.add_argument("--rescore-level", type=int, default=None, help="query-point level of the exact re-scoring")
    ap.add_argument("--diverse", default=None, help="top-K diversity 'METRES,DEGREES' (default: the search's)")
    ap.add_argument("--search", action="append", help="SearchParams field=value (repeatable, for experiments)")
    ap.add_argument("--geometric", action="append", help="GeometricParams field=value (repeatable, for experiments)")
    ap.add_argument("--keep-ratio", default=None, help="2D kept-ratio bounds 'MIN,MAX' (default: Lines2DParams')")
    ap.add_argument("--output", default=str(HERE / "real.json"))
    args = ap.parse_args(argv)
    zind_root = zind_root_or_none(args.data)
    if zind_root is None:
        return 0
    use_threads(args.threads)
    levels = [x.strip() for x in args.levels.split(",") if x.strip()]
    spacings = [float(x) for x in args.spacing.split(",")] if args.spacing else [None]
    if len(spacings) > 1:
        sweep = []
        for spacing in spacings:
            for level in levels:
                res = run_level(zind_root, level, argparse.Namespace(**{**vars(args), "spacing": spacing}))
                sweep.append({"spacing": spacing, **res})
        print_sweep(sweep)
        Path(args.output).write_text(json.dumps({"data": str(zind_root.parent), "threads": args.threads, "sweep": sweep}, indent=1))
        print(f"wrote {args.output}")
        return 0
    args.spacing = spacings[0]
    results = []
    for level in levels:
        res = run_level(zind_root, level, args)
        print_level(res)
        results.append(res)
    print_summary(results)
    Path(args.output).write_text(json.dumps({"data": str(zind_root.parent), "threads": args.threads, "levels": results}, indent=1))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
