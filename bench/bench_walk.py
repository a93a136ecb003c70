"""Walks against single images, side by side on the same frames.

Run: ``python bench/bench_walk.py [--data ../shared/data] [--levels floor,rooms] [--threads 1]``.

The shared ZInD home (19 panoramas in capture order, the panorama number) as one walk,
``ldlloc run --root ... --walk``'s library path (:func:`ldlloc.walk.run.run_walk_queries`): at
``floor`` level against the floor map (the room not given), at ``rooms`` level against the folder
of room maps (``--scene-unknown``). Maps as ``bench/bench_real.py`` builds them (cached). Printed
per frame (single-image and walk errors, verdicts, whether the walk decided) and summarized:
within 0.1 m / 5 deg and 0.25 m / 5 deg, single image against walk, confident poses and how many
of them are wrong, frames the walk decided. Results go to ``bench/walk.json``.
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

from bench.bench_real import build_maps, use_threads, zind_root_or_none  # noqa: E402
from bench.common import CACHE, console  # noqa: E402

LEVELS = ("floor", "rooms")


def counts(rows: list[dict], key: str) -> dict:
    """Frames within 0.1 m and 0.25 m / 5 deg, confident (and of them beyond 0.25 m), of ``key`` (single | walk)."""
    te = np.array([r[key]["t"] if r[key]["t"] is not None else np.inf for r in rows])
    re = np.array([r[key]["r"] if r[key]["r"] is not None else np.inf for r in rows])
    conf = np.array([r[key]["verdict"] == "confident" for r in rows])
    right = (te < 0.25) & (re < 5)
    return {"0.1m_5deg": int(((te < 0.1) & (re < 5)).sum()), "0.25m_5deg": int(right.sum()),
            "confident": int(conf.sum()), "confident_wrong": int((conf & ~right).sum()),
            "median_t_m": float(np.median(te))}


def run_level(zind_root: Path, level: str, args) -> dict:
    from ldlmap.datasets import open_dataset
    from ldlloc.batch.which_map import TOP_MAPS
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.walk.localize import WalkParams
    from ldlloc.walk.run import run_walk_queries
    from ldlmap.core.geometry import rotation_error_deg, translation_error

    map_level = "room" if level == "rooms" else level
    maps = build_maps(zind_root, map_level, None)
    queries = open_dataset(zind_root, "zind", map_level=map_level).queries()
    out = CACHE / "real" / f"walk_{level}.json"
    out.unlink(missing_ok=True)
    t0 = time.perf_counter()
    res = run_walk_queries(queries, maps, out, LocalizeParams(), WalkParams(top_maps=TOP_MAPS), "cpu",
                           meta={"dataset": "zind"}, scene_unknown=level == "rooms")
    seconds = time.perf_counter() - t0
    gt = {q.name: q for q in queries}
    rows = []
    for r in sorted(res, key=lambda r: r.walk["frame"] if r.walk else -1):
        q, w = gt[r.name], r.walk or {}
        single = {"t": None, "r": None, "verdict": w.get("single_verdict")}
        if w.get("single_pose"):
            R, t = np.asarray(w["single_pose"]["R"]), np.asarray(w["single_pose"]["t"])
            single.update(t=translation_error(t, q.center), r=rotation_error_deg(R, q.rot_cam_from_world))
        elif r.status != "failed":
            single.update(t=r.t_error_m, r=r.r_error_deg)
        rows.append({"name": r.name, "map": None if r.map is None else Path(r.map).stem, "single": single,
                     "walk": {"t": r.t_error_m, "r": r.r_error_deg, "verdict": r.verdict},
                     "walk_decided": bool(w.get("walk_decided")), "margin": w.get("margin")})
    return {"level": level, "seconds": seconds, "frames": rows,
            "single": counts(rows, "single"), "walk": counts(rows, "walk"),
            "walk_decided": sum(r["walk_decided"] for r in rows)}


def print_level(res: dict) -> None:
    from rich.table import Table

    t = Table(title=f"ZInD walk, {res['level']} level ({res['seconds']:.0f} s)")
    for col in ("frame", "map", "single m", "single deg", "single verdict", "walk m", "walk deg", "walk verdict",
                "walk decided", "margin"):
        t.add_column(col)
    f = lambda x, s: "-" if x is None else format(x, s)  # noqa: E731
    for r in res["frames"]:
        s, w = r["single"], r["walk"]
        t.add_row(r["name"].split("/")[-1], r["map"] or "-", f(s["t"], ".3f"), f(s["r"], ".1f"), str(s["verdict"]),
                  f(w["t"], ".3f"), f(w["r"], ".1f"), str(w["verdict"]), "yes" if r["walk_decided"] else "",
                  str(r["margin"]))
    console().print(t)
    n = len(res["frames"])
    for key in ("single", "walk"):
        c = res[key]
        console().print(f"{res['level']} {key:6s}: 0.1 m / 5 deg {c['0.1m_5deg']}/{n}, 0.25 m / 5 deg "
                        f"{c['0.25m_5deg']}/{n}, confident {c['confident']} (wrong {c['confident_wrong']}), "
                        f"median {c['median_t_m']:.3f} m")
    console().print(f"{res['level']}: frames the walk decided {res['walk_decided']}/{n}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="real data folder (default $LDL_REAL_DATA or ../shared/data)")
    ap.add_argument("--levels", default="floor,rooms", help="floor, rooms (comma-separated; default both)")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    ap.add_argument("--output", default=str(HERE / "walk.json"))
    args = ap.parse_args(argv)
    zind_root = zind_root_or_none(args.data)
    if zind_root is None:
        return 0
    use_threads(args.threads)
    levels = [x.strip() for x in args.levels.split(",") if x.strip()]
    bad = [x for x in levels if x not in LEVELS]
    if bad:
        print(f"unknown level(s) {', '.join(bad)}; valid: {', '.join(LEVELS)}")
        return 2
    results = []
    for level in levels:
        res = run_level(zind_root, level, args)
        print_level(res)
        results.append(res)
    Path(args.output).write_text(json.dumps({"threads": args.threads, "levels": results}, indent=1))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
