"""Furnished rooms against maps of their layout alone: the ``layout`` benchmark.

Run: ``python bench/bench_layout.py [--per-kind 6] [--seed 39] [--per-split N] [--output bench/layout.json]
[--geometric FIELD=VALUE ...] [--from-truth]``.

It generates ``4 x --per-kind`` rooms of ``ldlmap synth --preset furnished`` (kitchens, bathrooms,
bedrooms, living rooms, cycling through the box, sloped, stepped, arched, curved and L-shaped
apartment shapes: the default 24 rooms hold every function with every shape once; densely
furnished; cached under ``bench/.cache/layout/``), builds each room's map from its layout line
file (``layout/<scene>.obj``: the shell's creases, no doors, windows or furniture) exactly as
``ldlmap build layout.obj -o room.h5`` does (its defaults, through ``build_map``), and localizes
every robot and handheld panorama (upright, cameras 1.1-2.2 m above the floor) with ``ldlloc run``'s defaults and ``--max-tilt 10`` (``run_queries``).

Printed per room function, per shape and overall: within 0.1 m / 5 deg and 0.25 m / 5 deg, search
top-1 and best of the top 20 within 0.5 m / 10 deg, poses marked ``confident`` and how many of them
are right (0.25 m / 5 deg), the misses (beyond 0.25 m / 5 deg) by failure mode (``twin``: turned
150-210 deg, the 180-degree twin; ``slide``: rotation within 5 deg, the height within 0.3 m, the
centre elsewhere; ``height``: the camera more than 0.3 m off in height; ``turn``: a quarter turn,
75-105 deg; ``other``), map size (MB) and
build seconds per room. Per-query rows go to ``bench/layout.json``. ``--geometric FIELD=VALUE``
sets a field of the geometric refinement's parameters (``GeometricParams``, experiments);
``--from-truth`` localizes nothing but starts the geometric refinement at each true pose and
reports, per kind, how many stay within 5 cm and 0.1 m (a slide there is the refinement's), with
Huber's weights and with the default plan's poses competing on the exact loss.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import (CACHE, console, load_line, machine_info, map_tag, parse_field, set_threads, synth_tag,  # noqa: E402
                          write_json)

SPLITS = ("robot", "handheld")
MAX_TILT = 10.0
MISS_MODES = ("twin", "slide", "height", "turn", "other")
HEIGHT_OFF_M = 0.3  # a miss whose camera height is off by more than this is a "height" miss


def furnished_dataset(rooms: int, seed: int, per_split: int | None) -> Path:
    """``rooms`` rooms of the ``furnished`` preset (generated once, then reused)."""
    from ldlmap.synth.generate import generate_dataset

    out = CACHE / "layout" / f"furnished_s{seed}_k{rooms}_n{per_split}_{synth_tag()}"
    if not (out / "dataset.json").exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        generate_dataset(out, "furnished", [], seed, overwrite=True, progress=False, illumination=False,
                         per_split=per_split, scenes=rooms)
    return out


def build_maps(root: Path, camera_height: tuple[float, float] | None = None, up: str | None = None
               ) -> tuple[Path, dict]:
    """One map per room from its layout line file, as ``ldlmap build layout.obj -o room.h5`` makes it
    (``camera_height``: ``--camera-height MIN:MAX``; ``up``: ``--up``); returns the maps' folder and per scene ``{mb,
    build_s}`` (seconds of a build done now or before)."""
    from ldlmap.map import build as map_build
    from ldlmap.map import params as map_params

    band = f"_h{camera_height[0]:g}-{camera_height[1]:g}" if camera_height else ""
    maps = root / f"maps_layout{band}{f'_up{up}' if up else ''}_{map_tag()}"
    maps.mkdir(exist_ok=True)
    params = map_params.params_with(map_params.BuildParams(), features="sift",  # the command's defaults
                                    camera_height=camera_height, up=up)
    info = {}
    for scene in json.loads((root / "dataset.json").read_text())["scenes"]:
        name, target = scene["name"], maps / f"{scene['name']}.h5"
        timing = target.with_suffix(".seconds")
        if not target.exists():
            t0 = time.perf_counter()
            map_build.build_map(root / scene["layout"], target, None, params)
            timing.write_text(f"{time.perf_counter() - t0:.3f}\n")
        info[name] = {"mb": target.stat().st_size / 1e6, "build_s": float(timing.read_text())}
    return maps, info


def miss_mode(row: dict) -> str | None:
    """Why a pose is beyond 0.25 m / 5 deg (None: it is not): twin, height, slide, turn or other."""
    if row["t_error_m"] is None:
        return "other"
    if row["t_error_m"] < 0.25 and row["r_error_deg"] < 5:
        return None
    if row["r_error_deg"] > 150:
        return "twin"
    if abs(row["dz_m"]) > HEIGHT_OFF_M:
        return "height"
    if row["r_error_deg"] < 5:
        return "slide"
    return "turn" if 75 < row["r_error_deg"] < 105 else "other"


def localize_params(geometric: list[str] | None = None):
    """``ldlloc run``'s defaults with ``--max-tilt 10`` and the ``field=value`` overrides of the
    geometric refinement's parameters (experiments)."""
    from dataclasses import replace

    from ldlloc.pipeline import LocalizeParams

    params = LocalizeParams(max_tilt_deg=MAX_TILT)
    geo = {}
    for kv in geometric or []:
        key, value = kv.split("=", 1)
        geo[key] = parse_field(getattr(params.geometric, key), value)
    return replace(params, geometric=replace(params.geometric, **geo))


def truth_starts(root: Path, maps: Path, geometric: list[str] | None = None) -> list[dict]:
    """The geometric refinement started at each query's true pose (its search arcs, the lines seen from
    the candidate translation nearest the truth), once per pose of the default plan (``refinement_plan``
    of one candidate: Huber, Huber from the wide window, the second kernel): how far the first (Huber)
    moves (``move_m``), how far the plan's pose of the best exact loss ends (``plan_move_m``), and the
    exact loss at the truth and at Huber's end. A refinement that leaves the truth slides in the method,
    not the search."""
    from ldlloc.pipeline import Localizer, load_image
    from ldlloc.refine.geometric import refine_poses_geometric, refinement_plan
    from ldlloc.search.pose_search import score_on_map
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map

    params, rows, localizers = localize_params(geometric), [], {}
    for q in open_dataset(root, "omniscenes").queries(list(SPLITS)):
        if q.scene not in localizers:
            localizers[q.scene] = Localizer(read_map(maps / f"{q.scene}.h5", load_cloud=False), params)
        loc = localizers[q.scene]
        m, arcs = loc.map, loc.search(load_image(q.image), MAX_TILT).arcs
        cand, assoc, kernels = refinement_plan(1, params.geometric)
        R, t = np.repeat(q.rot_cam_from_world[None], len(cand), 0), np.repeat(q.center[None], len(cand), 0)
        vis = m.visibility[m.nearest_translation(t)] if m.visibility is not None else None
        g = refine_poses_geometric(arcs, R, t, m.lines, m.line_groups, m.principal_directions, vis, params.geometric,
                                   m.camera_height_band, assoc, kernels)
        loss = score_on_map(arcs, np.concatenate([R[:1], g.rotations]), np.concatenate([t[:1], g.centers]), m)
        best = int(np.argmin(loss[1:]))  # ties: the first (Huber's)
        rows.append({"name": q.name, "scene": q.scene, "move_m": float(np.linalg.norm(g.centers[0] - t[0])),
                     "plan_move_m": float(np.linalg.norm(g.centers[best] - t[0])), "plan_pick": kernels[best],
                     "loss_truth": float(loss[0]), "loss_refined": float(loss[1])})
    return rows


def localize(root: Path, maps: Path, geometric: list[str] | None = None) -> list[dict]:
    """Every query of :data:`SPLITS` on its room's map, ``ldlloc run``'s defaults and ``--max-tilt 10``
    (``geometric``: ``field=value`` overrides of the geometric refinement's parameters, experiments)."""
    from ldlloc.batch.run import run_queries
    from ldlmap.datasets import open_dataset

    queries = open_dataset(root, "omniscenes").queries(list(SPLITS))
    out = maps / "results.json"
    if out.exists():
        out.unlink()
    results = run_queries(queries, maps, out, localize_params(geometric), "cpu", meta={"dataset": "layout"})
    truth = {q.name: q for q in queries}
    rows = []
    for r in results:
        q = truth[r.name]
        ok = r.status != "failed" and r.t is not None
        est = (np.asarray(r.input_frame["t"]) if r.input_frame else np.asarray(r.t)) if ok else None
        rows.append({"name": r.name, "scene": r.scene, "split": r.split, "status": r.status,
                     "t_error_m": r.t_error_m if ok else None, "r_error_deg": r.r_error_deg if ok else None,
                     "camera_z_m": float(q.center[2]), "dz_m": float(est[2] - q.center[2]) if ok else None,
                     "first_good_rank": r.first_good_rank, "verdict": r.verdict, "confidence": r.confidence,
                     "seconds": r.seconds.get("total")})
    for row in rows:
        row["miss"] = miss_mode(row)
    return rows


def summarize(rows: list[dict], rooms: dict) -> dict:
    te = np.array([r["t_error_m"] if r["t_error_m"] is not None else np.inf for r in rows])
    re = np.array([r["r_error_deg"] if r["r_error_deg"] is not None else np.inf for r in rows])
    right = (te < 0.25) & (re < 5)
    confident = np.array([r["verdict"] == "confident" for r in rows], dtype=bool)
    modes = [r["miss"] for r in rows if r["miss"] is not None]
    n = max(len(rows), 1)
    return {"queries": len(rows), "rooms": len(rooms),
            "acc_0.1m_5deg": float(np.sum((te < 0.1) & (re < 5)) / n), "acc_0.25m_5deg": float(right.sum() / n),
            "top1": float(np.mean([r["first_good_rank"] == 1 for r in rows])) if rows else 0.0,
            "top20": float(np.mean([r["first_good_rank"] is not None for r in rows])) if rows else 0.0,
            "confident": int(confident.sum()), "confident_right": int((confident & right).sum()),
            "misses": {m: modes.count(m) for m in MISS_MODES},
            "map_mb": float(np.mean([v["mb"] for v in rooms.values()])) if rooms else 0.0,
            "build_s": float(np.mean([v["build_s"] for v in rooms.values()])) if rooms else 0.0}


def print_table(table: dict) -> None:
    from rich.table import Table

    t = Table(title=f"furnished rooms, layout-only maps (--max-tilt {MAX_TILT:g})")
    cols = ("kind", "rooms", "queries", "0.1m/5deg", "0.25m/5deg", "top-1", "top-20", "confident (right)",
            "misses: twin/slide/height/turn/other", "map MB", "build s")
    for col in cols:
        t.add_column(col, justify="left" if col == "kind" else "right")
    for kind, s in table.items():
        m = s["misses"]
        t.add_row(kind, str(s["rooms"]), str(s["queries"]), f"{s['acc_0.1m_5deg']:.2f}", f"{s['acc_0.25m_5deg']:.2f}",
                  f"{s['top1']:.2f}", f"{s['top20']:.2f}", f"{s['confident']} ({s['confident_right']})",
                  "/".join(str(m[k]) for k in MISS_MODES), f"{s['map_mb']:.1f}", f"{s['build_s']:.1f}")
    console().print(t)


def report_truth_starts(root: Path, rows: list[dict], args) -> None:
    """Per kind: how many refinements started at the truth stay within 5 cm and 0.1 m, the median move,
    and how often the truth has the strictly better exact loss; rows to ``--output``."""
    scenes = {s["name"]: s for s in json.loads((root / "dataset.json").read_text())["scenes"]}
    table = {}
    for key in ("function", "shape", None):
        for value in sorted({scenes[r["scene"]][key] for r in rows}) if key else ["all"]:
            sel = [r for r in rows if key is None or scenes[r["scene"]][key] == value]
            move, plan = np.array([r["move_m"] for r in sel]), np.array([r["plan_move_m"] for r in sel])
            table[value] = {"queries": len(sel), "within_0.05m": int(np.sum(move < 0.05)),
                            "within_0.1m": int(np.sum(move < 0.1)), "median_move_m": float(np.median(move)),
                            "plan_within_0.05m": int(np.sum(plan < 0.05)), "plan_within_0.1m": int(np.sum(plan < 0.1)),
                            "truth_better": int(sum(r["loss_truth"] < r["loss_refined"] for r in sel))}
            console().print(f"{value:10s} {len(sel):3d} queries: within 5 cm {table[value]['within_0.05m']}, "
                            f"0.1 m {table[value]['within_0.1m']}, median move {table[value]['median_move_m']:.3f} m, "
                            f"truth's loss better {table[value]['truth_better']}; the plan's best loss: within 5 cm "
                            f"{table[value]['plan_within_0.05m']}, 0.1 m {table[value]['plan_within_0.1m']}")
    write_json(args.output, {"machine": machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
                             "from_truth": table, "queries": rows})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--per-kind", type=int, default=6, help="rooms per room function (4 functions)")
    ap.add_argument("--seed", type=int, default=39)
    ap.add_argument("--per-split", type=int, default=None, help="panoramas per split and room (default: the preset's 1)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--camera-height", default=None, metavar="MIN:MAX",
                    help="build the maps with ldlmap build's --camera-height MIN:MAX (default: not given)")
    ap.add_argument("--up", default=None, help="build the maps with ldlmap build's --up (default: auto)")
    ap.add_argument("--geometric", action="append", help="GeometricParams field=value (repeatable, for experiments)")
    ap.add_argument("--from-truth", action="store_true",
                    help="instead of localizing: the geometric refinement started at each true pose, per kind")
    ap.add_argument("--output", type=Path, default=HERE / "layout.json")
    args = ap.parse_args()
    set_threads(args.threads)
    t0 = time.perf_counter()
    root = furnished_dataset(4 * args.per_kind, args.seed, args.per_split)
    t1 = time.perf_counter()
    band = tuple(float(x) for x in args.camera_height.split(":")) if args.camera_height else None
    maps, rooms = build_maps(root, band, args.up)
    t2 = time.perf_counter()
    if args.from_truth:
        report_truth_starts(root, truth_starts(root, maps, args.geometric), args)
        return
    rows = localize(root, maps, args.geometric)
    t3 = time.perf_counter()
    scenes = {s["name"]: s for s in json.loads((root / "dataset.json").read_text())["scenes"]}
    for row in rows:
        row["function"], row["shape"] = scenes[row["scene"]]["function"], scenes[row["scene"]]["shape"]
    table = {}
    for key in ("function", "shape"):
        for value in sorted({r[key] for r in rows}):
            sel = [r for r in rows if r[key] == value]
            table[value] = summarize(sel, {s: rooms[s] for s in {r["scene"] for r in sel}})
    table["all"] = summarize(rows, rooms)
    print_table(table)
    console().print(f"data {t1 - t0:.0f} s, maps {t2 - t1:.0f} s, localization {t3 - t2:.0f} s; {load_line(machine_info())}")
    write_json(args.output, {"machine": machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
                          "seconds": {"data": t1 - t0, "maps": t2 - t1, "localize": t3 - t2},
                          "summary": table, "queries": rows})
    console().print(f"results: {args.output}")


if __name__ == "__main__":
    main()
