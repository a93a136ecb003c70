"""Benchmark: one map of several rooms (the paper's multi-room setting, sec. 4.2) vs. one room's map.

A multi-room synthetic dataset (``ldlmap.synth.multiroom``: ``--rooms`` demo rooms in ONE scan,
``--per-split`` panoramas per split and room, 1024 x 512) is generated once under
``bench/.cache/``. Maps are built with :func:`ldlmap.map.build.build_map` (SIFT features, distance
fields on, defaults otherwise), all with the same density of candidates and views per room:

- the multi-room map of the whole scan, ``N_t = --nt-per-room x rooms`` candidate translations
  and ``--views-per-room x rooms`` rendered views, with the paper's lambda = 0.1;
- the same with a room-scale lambda (:func:`room_scale_lambda`): the paper's length filter is
  relative to the map's extent, so over several rooms it drops most of each room's lines;
- each room's own map (its slice of the same scan), ``N_t = --nt-per-room``.

Every query is localized against the multi-room maps and against its room's own map with
:class:`ldlloc.pipeline.Localizer` (fast pose search on the precomputed fields, one untimed
warm-up query per map). Tables: per map N_t, the median number of candidate rotations N_r,
median pose-search seconds (rotation estimation + ranking, ``Localization.seconds``), median
total seconds, median errors, accuracy at 0.1 m / 5 deg (overall and per split), pose-search
recall (best of the top-20 candidates within 0.5 m / 10 deg) and how often the final estimate
lies in the query's own room; then accuracy / recall per room. Writes ``bench/multiroom.json``.

Run: ``python bench/bench_multiroom.py [--rooms 4] [--per-split 2] [--nt-per-room 800]
[--views-per-room 20] [--threads 1] [--illumination] [--no-own-maps] [--no-room-lambda]
[--json bench/multiroom.json]``.
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

RECALL_M, RECALL_DEG = 0.5, 10.0  # pose-search recall: best of the top-K within these errors
ACC_M, ACC_DEG = 0.1, 5.0  # the paper's main accuracy threshold


def dataset(seed: int, rooms: int, per_split: int, illumination: bool) -> Path:
    """The cached multi-room dataset (generated when missing)."""
    from ldlmap.synth.multiroom import generate_multiroom

    out = common.CACHE / f"multiroom_s{seed}_r{rooms}_n{per_split}{'_ill' if illumination else ''}_{common.synth_tag()}"
    if not (out / "dataset.json").exists():
        print(f"generating {rooms} rooms (seed {seed}, {per_split} per split and room) in {out} ...", flush=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        s = generate_multiroom(out, seed=seed, rooms=rooms, per_split=per_split, illumination=illumination,
                               overwrite=True, progress=False)
        print(f"  {s.images} panoramas, {s.points['multiroom_1']:,} scan points in {s.seconds:.0f} s", flush=True)
    return out


def build(cloud: Path, out: Path, n_t: int, views: int, lam: float = 0.1) -> dict[str, Any]:
    """Build (once) the map of ``cloud``; returns its description (N_t, lines, build seconds, sizes)."""
    import json

    from ldlmap.map.build import BuildParams, build_map

    meta = out.with_suffix(".json")
    if out.exists() and meta.exists():
        return json.loads(meta.read_text())
    out.parent.mkdir(parents=True, exist_ok=True)
    print(f"building {out.name} (N_t = {n_t}, {views} views, lambda = {lam:.3f}) ...", flush=True)
    rep = build_map(cloud, out, params=BuildParams().replaced(num_translations=n_t, num_views=views, lam=lam), name=out.stem)
    info = {"requested_n_t": n_t, "views": views, "lam": lam,
            "build_seconds": {k: round(v, 2) for k, v in rep.seconds.items()}, **rep.counts}
    common.write_json(meta, info)
    return info


def room_scale_lambda(rooms: list[Any], lam: float = 0.1) -> float:
    """The lambda that gives the multi-room map the rooms' mean absolute length threshold.

    The paper's filter drops lines shorter than ``lambda * mean extent`` of the whole map: over
    several rooms the extent, hence the threshold, grows and most of each room's lines go.
    """
    lo = np.min([r.bounds_min for r in rooms], axis=0)
    hi = np.max([r.bounds_max for r in rooms], axis=0)
    per_room = np.mean([np.mean(r.bounds_max - r.bounds_min) for r in rooms])
    return float(lam * per_room / np.mean(hi - lo))


def room_cloud(root: Path, room: Any, out: Path) -> Path:
    """Room ``room``'s own slice of the multi-room scan, as a PLY (written once)."""
    from ldlmap.synth.scan import write_ply

    if not out.exists():
        txt = np.loadtxt(root / "pcd" / "multiroom_1.txt", dtype=np.float64)
        a, b = room.points
        write_ply(out, txt[a:b, :3], txt[a:b, 3:].astype(np.uint8))
    return out


def localize(map_path: Path, queries: list[Any], rooms: list[Any], label: str) -> dict[str, Any]:
    """Localize ``queries`` against one map; medians, accuracy per split, recall, right room."""
    from ldlloc.pipeline import Localizer, load_image
    from ldlmap.map.mapfile import read_map

    m = read_map(map_path, load_cloud=False)
    loc = Localizer(m, device="cpu")
    loc.localize(load_image(queries[0].image))  # warm-up, untimed
    done = lambda i, n: print(f"\r  {label}: {i}/{n}", end="", file=sys.stderr, flush=True)  # noqa: E731
    outcomes = common.localize_queries(loc, queries, done)
    print(file=sys.stderr)
    rows = []
    for q, o in zip(queries, outcomes):
        r = o.result
        own = [x for x in rooms if x.contains(q.center)[0]]
        row = {"image": str(q.image), "split": q.split, "room": own[0].index if own else None,
               "failed": o.loc is None}
        if o.loc is not None:
            terr, rerr = common.candidate_errors(o.loc, q)
            row.update(t_error_m=float(r.t_error_m), r_error_deg=float(r.r_error_deg),
                       search_s=float(r.seconds["rotation"] + r.seconds["search"]), total_s=float(r.seconds["total"]),
                       n_r=int(o.loc.num_rotations),
                       recall=bool(np.any((terr < RECALL_M) & (rerr < RECALL_DEG))),
                       right_room=bool(own and own[0].contains(o.loc.center)[0]), refined=bool(r.refined))
        rows.append(row)
    return {"map": map_path.name, "n_t": int(len(m.translations)), "lines": int(len(m.lines)),
            "fields_mb": float(sum(v.nbytes for v in m.fields.values()) / 1e6) if m.fields else 0.0,
            **summarize(rows), "per_query": rows}


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians, accuracy at 0.1 m / 5 deg per split and overall, recall and right-room rate of
    per-query rows (failed queries count as not localized)."""
    ok = [r for r in rows if not r["failed"]]

    def med(key: str) -> float:
        return float(np.median([r[key] for r in ok])) if ok else float("nan")

    def acc(rs: list[dict]) -> float:
        return float(np.mean([(not r["failed"]) and r["t_error_m"] < ACC_M and r["r_error_deg"] < ACC_DEG
                              for r in rs])) if rs else float("nan")

    splits = sorted({r["split"] for r in rows}, key=lambda s: (s.startswith("change"), s.startswith("extreme_"), s))
    return {"queries": len(rows), "failed": len(rows) - len(ok), "median_n_r": med("n_r"),
            "median_search_s": med("search_s"), "median_total_s": med("total_s"),
            "median_t_error_m": med("t_error_m"), "median_r_error_deg": med("r_error_deg"),
            "accuracy_0.1m_5deg": {**{s: acc([r for r in rows if r["split"] == s]) for s in splits}, "all": acc(rows)},
            "recall_top20_0.5m_10deg": float(np.mean([r.get("recall", False) for r in rows])) if rows else float("nan"),
            "right_room": float(np.mean([r.get("right_room", False) for r in rows])) if rows else float("nan")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rooms", type=int, default=4)
    ap.add_argument("--per-split", type=int, default=2, help="panoramas per split and room")
    ap.add_argument("--nt-per-room", type=int, default=800, help="N_t per room (multi-room map: x rooms)")
    ap.add_argument("--views-per-room", type=int, default=20, help="rendered feature views per room")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--illumination", action="store_true", help="also the extreme_* illumination splits")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (1 on a shared machine)")
    ap.add_argument("--no-own-maps", action="store_true", help="skip the rooms' own maps")
    ap.add_argument("--no-room-lambda", action="store_true", help="skip the multi-room map with room-scale lambda")
    ap.add_argument("--json", type=Path, default=common.ROOT / "bench" / "multiroom.json")
    args = ap.parse_args(argv)
    common.set_threads(args.threads)
    from ldlmap.datasets import open_dataset
    from ldlmap.synth.multiroom import read_layout

    t0 = time.perf_counter()
    root = dataset(args.seed, args.rooms, args.per_split, args.illumination)
    rooms = read_layout(root)
    ds = open_dataset(root, "omniscenes")
    queries = ds.queries(scene="multiroom_1")
    maps_dir = common.CACHE / "maps" / f"{root.name}_{common.map_tag()}"  # rebuilt when the builder changes
    n_multi, v_multi = args.nt_per_room * args.rooms, args.views_per_room * args.rooms
    cloud = ds.point_cloud("multiroom_1")
    maps: dict[str, Any] = {}
    results: dict[str, dict[str, Any]] = {}
    variants = [("multi", 0.1)] + ([] if args.no_room_lambda else [("multi_room_lambda", room_scale_lambda(rooms))])
    for key, lam in variants:
        path = maps_dir / f"multiroom_nt{n_multi}_v{v_multi}_lam{lam:.3f}.h5"
        maps[key] = build(cloud, path, n_multi, v_multi, lam)
        label = f"{args.rooms} rooms, one map" + ("" if key == "multi" else f", lambda {lam:.3f} (room scale)")
        results[label] = localize(path, queries, rooms, label)
    if not args.no_own_maps:
        rows = []
        for room in rooms:
            own = [q for q in queries if room.contains(q.center)[0]]
            path = maps_dir / f"room{room.index}_nt{args.nt_per_room}_v{args.views_per_room}.h5"
            maps[f"room{room.index}"] = build(room_cloud(root, room, maps_dir / f"room{room.index}.ply"), path,
                                              args.nt_per_room, args.views_per_room)
            res = localize(path, own, [room], f"room {room.index} map")
            rows += res["per_query"]
        results["each room, its own map"] = {"map": "room<i>_*.h5", "n_t": maps["room1"]["translations"],
                                             "lines": None, "fields_mb": None, **summarize(rows), "per_query": rows}

    info = common.machine_info("cpu")
    _print_tables(results, rooms, info)
    out = {"dataset": str(root), "rooms": args.rooms, "per_split": args.per_split, "nt_per_room": args.nt_per_room,
           "views_per_room": args.views_per_room, "maps": maps,
           "results": {k: {kk: vv for kk, vv in v.items() if kk != "per_query"} for k, v in results.items()},
           "per_room": _per_room(results, rooms),
           "per_query": {k: v["per_query"] for k, v in results.items()},
           "machine": info, "seconds": round(time.perf_counter() - t0, 1)}
    common.write_json(args.json, out)
    print(f"wrote {args.json}")
    return 0


def _per_room(results: dict[str, dict[str, Any]], rooms: list[Any]) -> dict[str, dict[str, Any]]:
    """Per room and map: accuracy at 0.1 m / 5 deg and pose-search recall over the room's queries."""
    out: dict[str, dict[str, Any]] = {}
    for room in rooms:
        key = f"room {room.index}"
        out[key] = {}
        for name, res in results.items():
            rows = [r for r in res["per_query"] if r["room"] == room.index]
            s = summarize(rows)
            out[key][name] = {"queries": s["queries"], "accuracy": s["accuracy_0.1m_5deg"]["all"],
                              "recall": s["recall_top20_0.5m_10deg"], "right_room": s["right_room"]}
    return out


def _print_tables(results: dict[str, dict[str, Any]], rooms: list[Any], info: dict[str, Any]) -> None:
    from rich.table import Table

    con = common.console()
    t = Table(title="multi-room map vs. each room's own map (SIFT refinement, fast pose search on fields)")
    for c in ("map", "queries", "N_t", "N_r", "search s", "total s", "t err m", "R err deg", "acc", "recall@20",
              "right room"):
        t.add_column(c, justify="left" if c == "map" else "right")
    for name, r in results.items():
        t.add_row(name, f"{r['queries']}" + (f" ({r['failed']} failed)" if r["failed"] else ""), str(r["n_t"]),
                  common.fmt(r["median_n_r"], ".0f"), common.fmt(r["median_search_s"], ".3f"),
                  common.fmt(r["median_total_s"], ".2f"), common.fmt(r["median_t_error_m"], ".3f"),
                  common.fmt(r["median_r_error_deg"], ".2f"), common.fmt(r["accuracy_0.1m_5deg"]["all"], ".2f"),
                  common.fmt(r["recall_top20_0.5m_10deg"], ".2f"), common.fmt(r["right_room"], ".2f"))
    con.print(t)
    splits = [s for s in next(iter(results.values()))["accuracy_0.1m_5deg"] if s != "all"]
    t2 = Table(title="accuracy at 0.1 m / 5 deg per split")
    t2.add_column("map")
    for s in splits:
        t2.add_column(s, justify="right")
    for name, r in results.items():
        t2.add_row(name, *[common.fmt(r["accuracy_0.1m_5deg"].get(s), ".2f") for s in splits])
    con.print(t2)
    per_room = _per_room(results, rooms)
    t3 = Table(title="per room: accuracy / pose-search recall@20")
    t3.add_column("room")
    for name in results:
        t3.add_column(name, justify="right")
    for room, by_map in per_room.items():
        t3.add_row(f"{room} ({next(iter(by_map.values()))['queries']} q)",
                   *[f"{common.fmt(v['accuracy'], '.2f')} / {common.fmt(v['recall'], '.2f')}" for v in by_map.values()])
    con.print(t3)
    print("search s = rotation estimation + ranking (median); acc: 0.1 m / 5 deg; recall@20: best of the top-20 "
          "search candidates within 0.5 m / 10 deg; right room: the final estimate lies in the query's room")
    print(common.load_line(info))


if __name__ == "__main__":
    raise SystemExit(main())
