"""Building-scale maps: one map per floor, queries localized without their floor.

Run: ``python bench/bench_building.py [--preset building] [--seed S] [--ray] [--threads 1] [--splits robot,...]
[--max-queries N] [--rebuild] [--output bench/building.json]``.

1. **Data.** ``ldlmap synth --preset PRESET`` (``building``: 3 floors of 12 rooms, 6 identical
   offices and 3 identical hotel rooms a floor, a corridor and a stairwell each; one scene per
   floor, all in one world frame), generated once under ``bench/.cache/<preset>/data``
   (``<preset>_s<seed>_w<width>_n<per-split>`` when those are given: ``--seed`` other than 0 is a
   building the confidence was never fitted on) (or
   ``--data DIR``: a building already generated).
2. **Maps.** ``ldlmap prepare DATA --maps .../maps_plain`` (defaults: SIFT, N_t = 800, 40 views),
   one map per floor, wall and CPU seconds and peak memory from ``/usr/bin/time -v`` (kept in
   ``prepare_<tag>.time`` beside the maps: a later run that reuses the maps reports the build
   that made them, when it ran here; ``--rebuild`` builds again). With ``--ray``: the same with
   ``--ray local`` into ``maps_ray_<tag>`` (one task per floor, ``--threads`` each), and whether
   its maps equal those of the plain build. Map size per floor, per room (``rooms`` of the building, corridors
   and stairwells not counted) and per stored dataset (HDF5 storage bytes).
3. **Localization.** ``ldlloc run --images 'DATA/*_pano/**/*.jpg' --maps maps_plain`` (the floor is
   not given: every query is searched on every floor map, the best ``--top-maps`` refined, the
   most confident kept), wall seconds and peak memory of the process. ``--splits`` and
   ``--max-queries`` (every k-th query, so every room keeps some) make it shorter.
4. **Scoring** against the dataset's ground truth (``Query.floor``, ``Query.room``, which the run
   never sees), per floor and per kind of room: final pose within 0.1 m / 5 deg and 0.25 m / 5 deg,
   right floor (the chosen map), right room (the room holding the estimated centre,
   :func:`ldlmap.synth.building.room_at`), the verdicts. For the identical rooms (groups ``office``,
   ``hotel``, ``stairwell``): how often the right copy wins, the pose right *in some copy* (the
   error after moving the estimate by the offset between the copy it landed in and the true one:
   only the copy is wrong), and how often the result is marked ``ambiguous`` when the copy is wrong
   and when it is right; the ``confident`` poses, how many are right (0.25 m / 5 deg) and how many
   lie in a wrong copy; the same counts before the check for copies of identical rooms (the verdict
   judged again without it: :func:`verdict_without_copies`) and how many poses named a copy. Each row keeps the confidence's signals and competitors
   (``bench/bench_confidence.py --building`` judges them). Seconds per query from the results (``seconds``: ``search`` and
   ``rotation`` summed over the floor maps, ``total``): median, mean and 90th percentile.
``--camera-height MIN:MAX`` and ``--num-trans N``: the maps built by ``prepare`` with those options
(candidates only MIN-MAX metres above each floor; N_t per floor) into ``maps_<tag>`` beside
``maps_plain``, and the same run against them.

5. **Search time** apart: ``--timing-queries`` queries searched on every floor map in this process
   (2D lines once, then each map's rotations and search, as the run does), wall and CPU seconds
   per query over all maps (CPU seconds of one thread: what a loaded machine inflates least), and
   this process's peak memory with every map loaded.

Timings are taken on whatever machine runs it; the load (``uptime``) is printed beside them.
Results go to ``--output`` (default ``bench/building.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import CACHE, console, fmt, write_json  # noqa: E402

ACCS = (("0.1m_5deg", 0.1, 5.0), ("0.25m_5deg", 0.25, 5.0))
GOOD_SEARCH = (0.5, 10.0)  # a search pose this close is "found" (refinement can take it from there)
TIME_BIN = "/usr/bin/time"


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def cli(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]


def timed(cmd: list[str], time_file: Path, log: Path) -> dict[str, Any]:
    """Run ``cmd`` under ``/usr/bin/time -v`` (its report to ``time_file``, output to ``log``);
    raise on failure; return :func:`parse_time`'s record."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "160"}
    before = uptime()
    with open(log, "w") as fh:
        rc = subprocess.run([TIME_BIN, "-v", "-o", str(time_file), *cmd], env=env, stdout=fh, stderr=subprocess.STDOUT,
                            cwd=ROOT).returncode
    if rc != 0:
        raise SystemExit(f"failed ({rc}): {' '.join(cmd)}; see {log}")
    out = parse_time(time_file)
    out["uptime_before"], out["uptime_after"] = before, uptime()
    return out


def parse_time(path: Path) -> dict[str, Any]:
    """Wall and CPU seconds and peak RSS (the largest process, MB) of a ``/usr/bin/time -v`` report."""
    text = Path(path).read_text()

    def field(name: str) -> str:
        m = re.search(rf"^\s*{re.escape(name)}:\s*(.+)$", text, re.M)
        if not m:
            raise SystemExit(f"{path}: no '{name}' line (not a /usr/bin/time -v report)")
        return m.group(1).strip()

    wall = 0.0
    for part in field("Elapsed (wall clock) time (h:mm:ss or m:ss)").split(":"):
        wall = wall * 60 + float(part)
    return {"wall_s": wall, "user_s": float(field("User time (seconds)")),
            "system_s": float(field("System time (seconds)")),
            "peak_rss_mb": int(field("Maximum resident set size (kbytes)")) / 1024.0}


def dataset(args) -> Path:
    """The building: ``--data``, or generated once under ``bench/.cache/<preset>/data``
   (``<preset>_w<width>_n<per-split>`` when those are given)."""
    if args.data:
        return Path(args.data)
    tag = args.preset + (f"_s{args.seed}" if args.seed else "") + (f"_w{args.width}" if args.width else "") + (
        f"_n{args.per_split}" if args.per_split else "")
    out = CACHE / tag / "data"
    if (out / "dataset.json").exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    extra = (["--width", str(args.width)] if args.width else []) + (
        ["--per-split", str(args.per_split)] if args.per_split else []) + (["--seed", str(args.seed)] if args.seed else [])
    console().print(f"generating {args.preset} into {out} (slow: about 5 min for the full building on 2 cores)")
    rec = timed(cli("ldlmap.cli", "synth", str(out), "--preset", args.preset, "--quiet", *extra),
                out.parent / "synth.time", out.parent / "synth.log")
    write_json(out.parent / "synth.json", rec)
    return out


def map_options(args) -> list[str]:
    """The ``prepare`` options of the maps under test (``--camera-height``, ``--num-trans``)."""
    return ((["--camera-height", args.camera_height] if args.camera_height else [])
            + (["--num-trans", str(args.num_trans)] if args.num_trans else []))


def maps_tag(args) -> str:
    """``plain`` for the defaults, else e.g. ``h0.9-1.7_n1600``."""
    parts = ([f"h{args.camera_height.replace(':', '-')}"] if args.camera_height else []) + (
        [f"n{args.num_trans}"] if args.num_trans else [])
    return "_".join(parts) or "plain"


def prepare(data: Path, maps: Path, args, ray: bool) -> dict[str, Any]:
    """``ldlmap prepare`` (with :func:`map_options`) into ``maps`` (built, or reused with the record of
    the build that made them)."""
    tag = maps.name.removeprefix("maps_")
    time_file, log = maps.parent / f"prepare_{tag}.time", maps.parent / f"prepare_{tag}.log"
    have = sorted(maps.glob("*.h5")) if maps.is_dir() else []
    if have and not args.rebuild:  # the record of the build that made them, when it ran here
        rec = parse_time(time_file) if time_file.exists() else {}
        rec["reused"] = True
    else:
        maps.mkdir(parents=True, exist_ok=True)
        cmd = cli("ldlmap.cli", "prepare", str(data), "--maps", str(maps), "--threads", str(args.threads), "--overwrite",
                  *map_options(args))
        if ray:
            cmd += ["--ray", "local"]
        rec = timed(cmd, time_file, log)
        rec["reused"] = False
    rec["threads"], rec["options"] = args.threads, map_options(args)
    rec["maps"] = {p.stem: p.stat().st_size for p in sorted(maps.glob("*.h5"))}
    return rec


def storage(map_path: Path) -> dict[str, int]:
    """Storage bytes of each dataset of a map (compressed, as on disk)."""
    import h5py

    out: dict[str, int] = {}
    with h5py.File(map_path, "r") as h5:
        h5.visititems(lambda n, o: out.__setitem__(n, int(o.id.get_storage_size()))
                      if isinstance(o, h5py.Dataset) else None)
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def same_maps(a: Path, b: Path) -> bool:
    """Whether two folders hold the same maps byte for byte."""
    fa, fb = sorted(p.name for p in a.glob("*.h5")), sorted(p.name for p in b.glob("*.h5"))
    return fa == fb and all((a / n).read_bytes() == (b / n).read_bytes() for n in fa)


def select_images(data: Path, splits: list[str] | None, max_queries: int | None) -> tuple[Path, list]:
    """The query panoramas (linked into one folder, named ``<split>/<scene>/<stem>``) and their queries."""
    from ldlmap.datasets import open_dataset

    ds = open_dataset(data)
    queries = ds.queries(splits) if splits else ds.queries()
    queries = sorted(queries, key=lambda q: q.name)
    if max_queries and len(queries) > max_queries:
        step = len(queries) / max_queries
        queries = [queries[int(i * step)] for i in range(max_queries)]
    folder = data.parent / "query_links"
    if folder.exists():
        shutil.rmtree(folder)
    for q in queries:
        link = folder / f"{q.name}{Path(q.image).suffix}"
        link.parent.mkdir(parents=True, exist_ok=True)
        link.symlink_to(Path(q.image).resolve())
    return folder, queries


def localize(images: Path, maps: Path, out: Path, args) -> dict[str, Any]:
    cmd = cli("ldlloc.cli", "run", "--images", str(images), "--maps", str(maps), "--output", str(out),
              "--threads", str(args.threads), "--overwrite")
    if args.top_maps:
        cmd += ["--top-maps", str(args.top_maps)]
    return timed(cmd, out.with_suffix(".time"), out.with_suffix(".log"))


def search_timing(maps: Path, queries: list, count: int, threads: int) -> dict[str, Any]:
    """Pose search (rotation + search) of ``count`` queries on every map of ``maps`` in this process,
    as ``run --images`` does it (2D lines once, then each map): wall and CPU seconds per query summed
    over the maps. CPU seconds (one thread) are what a loaded machine does not inflate."""
    import resource

    from ldlmap.core.cli_common import set_threads
    from ldlmap.core.errors import InputError
    from ldlloc.batch.which_map import MapSet
    from ldlloc.pipeline import LocalizeParams, load_image

    set_threads(threads)
    mapset = MapSet.load(maps, LocalizeParams())
    step = max(1, len(queries) // max(1, count))
    wall, cpu, failed = [], [], 0
    for q in queries[::step][:count]:
        img = load_image(q.image)
        lines = mapset.entries[0].localizer.detect_lines(img)
        w0, c0 = time.perf_counter(), time.process_time()
        for e in mapset.entries:
            try:
                e.localizer.search(img, None, lines)
            except InputError:  # no rotation matches this map's directions: as the run, the next map
                failed += 1
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return {"count": len(wall), "maps": len(mapset.entries), "failed_searches": failed, "wall_median": float(np.median(wall)),
            "cpu_median": float(np.median(cpu)), "cpu_p90": float(np.percentile(cpu, 90)),
            "cpu_max": float(np.max(cpu)), "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "uptime": uptime()}


def shift_error(r, q, rooms_by_id: dict, got_room) -> tuple[float, float] | None:
    """Errors of the estimate moved from the copy it landed in to the true room (identical rooms:
    same spec at another offset); None when it landed outside a copy of the true room."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error

    true = rooms_by_id.get(q.room)
    if true is None or got_room is None or true.group is None or got_room.group != true.group:
        return None
    t = np.asarray(r.t) - got_room.offset + true.offset
    return translation_error(t, q.center), rotation_error_deg(np.asarray(r.R), q.rot_cam_from_world)


def score(results: list, queries: list, data: Path) -> list[dict[str, Any]]:
    """One row per query: floor, room, kind, group, errors, right floor and room, verdict, seconds."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlmap.synth.building import read_building, room_at

    rooms = read_building(data)
    by_id = {r.id: r for r in rooms}
    gt = {Path(q.image).resolve(): q for q in queries}
    rows = []
    for r in results:
        q = gt[Path(r.image).resolve()]
        true = by_id.get(q.room)
        row: dict[str, Any] = {"name": q.name, "split": q.split, "floor": q.floor, "room": q.room,
                               "kind": true.kind if true else None, "group": true.group if true else None,
                               "status": r.status, "verdict": r.verdict, "confidence": r.confidence,
                               "signals": dict(r.confidence_signals or {}), "competitors": [c["why"] for c in r.competitors],
                               "map": Path(r.map).stem if r.map else None, "seconds": dict(r.seconds)}
        row["verdict_before"] = verdict_without_copies(r)
        if r.status == "failed" or r.t is None:
            row.update(t_err=None, r_err=None, got_room=None, right_floor=False, right_room=False, copy_err=None,
                       search_err=None)
            rows.append(row)
            continue
        got = room_at(rooms, np.asarray(r.t))
        row["t_err"] = translation_error(np.asarray(r.t), q.center)
        row["r_err"] = rotation_error_deg(np.asarray(r.R), q.rot_cam_from_world)
        row["got_room"] = got.id if got else None
        row["right_floor"] = row["map"] == f"floor_{q.floor}"
        row["right_room"] = got is not None and got.id == q.room
        row["copy_err"] = shift_error(r, q, by_id, got)
        c = r.candidates[0] if r.candidates else None
        row["search_err"] = None if c is None else (
            translation_error(np.asarray(c["t"]), q.center), rotation_error_deg(np.asarray(c["R"]), q.rot_cam_from_world))
        rows.append(row)
    return rows


def verdict_without_copies(r) -> str | None:
    """The verdict of a record as the code before the copies check gave it (:mod:`ldlloc.refine.copies`):
    judged again without the ``copies`` signal and the copies named (the same run)."""
    from ldlloc.confidence import COPY_WHY, judge

    sig = dict(r.confidence_signals or {})
    if r.verdict is None or "copies" not in sig:
        return r.verdict
    del sig["copies"]
    return judge(sig, [c for c in r.competitors if not str(c.get("why", "")).startswith(COPY_WHY)])[1]


def within(e, m: float, d: float) -> bool:
    return e is not None and e[0] < m and e[1] < d


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts of a group of rows (see the module docstring)."""
    n = len(rows)
    pose = [None if r["t_err"] is None else (r["t_err"], r["r_err"]) for r in rows]
    out: dict[str, Any] = {"count": n}
    for k, m, d in ACCS:
        out[k] = sum(within(e, m, d) for e in pose)
    out["search_top1"] = sum(within(r["search_err"], *GOOD_SEARCH) for r in rows)
    out["right_floor"] = sum(r["right_floor"] for r in rows)
    out["right_room"] = sum(r["right_room"] for r in rows)
    out["failed"] = sum(r["status"] == "failed" for r in rows)
    out["verdicts"] = {v: sum(r["verdict"] == v for r in rows) for v in ("confident", "ambiguous", "failed")}
    out["confident_right"] = sum(r["verdict"] == "confident" and within(
        None if r["t_err"] is None else (r["t_err"], r["r_err"]), 0.25, 5.0) for r in rows)
    before = [r for r in rows if r.get("verdict_before", r["verdict"]) == "confident"]
    out["confident_before"] = len(before)
    out["confident_right_before"] = sum(within(None if r["t_err"] is None else (r["t_err"], r["r_err"]), 0.25, 5.0)
                                        for r in before)
    out["copies_named"] = sum(bool((r["signals"] or {}).get("copies")) for r in rows)
    ident = [r for r in rows if r["group"] is not None]
    if ident:
        wrong = [r for r in ident if not r["right_room"]]
        right = [r for r in ident if r["right_room"]]
        out["right_copy_pose"] = sum(r["right_room"] and within((r["t_err"], r["r_err"]), 0.1, 5.0) for r in ident)
        out["some_copy_pose"] = sum(within(r["copy_err"], 0.1, 5.0) or within(
            None if r["t_err"] is None else (r["t_err"], r["r_err"]), 0.1, 5.0) for r in ident)
        out["ambiguous_when_wrong_copy"] = [sum(r["verdict"] == "ambiguous" for r in wrong), len(wrong)]
        out["confident_wrong_copy"] = sum(r["verdict"] == "confident" for r in wrong if r["t_err"] is not None)
        out["confident_wrong_copy_before"] = sum(r.get("verdict_before", r["verdict"]) == "confident" for r in wrong
                                                 if r["t_err"] is not None)
        out["ambiguous_when_right_copy"] = [sum(r["verdict"] == "ambiguous" for r in right), len(right)]
    return out


def seconds(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    ok = [r for r in rows if r["status"] != "failed"]
    out = {}
    for stage in ("lines2d", "rotation", "search", "refine", "choose", "total"):
        v = np.array([r["seconds"][stage] for r in ok if stage in r["seconds"]])
        if len(v):
            out[stage] = {"median": float(np.median(v)), "mean": float(v.mean()), "p90": float(np.percentile(v, 90)),
                          "max": float(v.max())}
    return out


def report(res: dict[str, Any]) -> None:
    from rich.table import Table

    c = console()
    t = Table(title=f"{res['preset']}: {res['queries']} queries against the floor maps of {res['maps']} "
                    "(floor not given)")
    for col in ("part", "n", "0.1 m/5 deg", "0.25 m/5 deg", "search top-1", "right floor", "right room",
                "right copy + pose", "pose in some copy", "ambiguous (wrong copy)", "ambiguous (right copy)",
                "confident (right 0.25 m/5 deg)", "confident in a wrong copy", "before copies: confident (right), "
                "wrong copy", "copies named", "ambiguous", "failed"):
        t.add_column(col)
    for name, s in res["summary"].items():
        n = s["count"]
        f = lambda k: f"{s[k] / n:.2f}" if n else "-"  # noqa: E731
        pair = lambda k: f"{s[k][0]}/{s[k][1]}" if k in s else "-"  # noqa: E731
        t.add_row(name, str(n), f("0.1m_5deg"), f("0.25m_5deg"), f("search_top1"), f("right_floor"), f("right_room"),
                  f("right_copy_pose") if "right_copy_pose" in s else "-",
                  f("some_copy_pose") if "some_copy_pose" in s else "-", pair("ambiguous_when_wrong_copy"),
                  pair("ambiguous_when_right_copy"), f"{s['verdicts']['confident']} ({s['confident_right']})",
                  str(s.get("confident_wrong_copy", "-")),
                  f"{s['confident_before']} ({s['confident_right_before']}), {s.get('confident_wrong_copy_before', '-')}",
                  str(s["copies_named"]), str(s["verdicts"]["ambiguous"]), str(s["failed"]))
    c.print(t)
    for stage, v in res["seconds"].items():
        c.print(f"  {stage:9s} median {fmt(v['median'])} s, mean {fmt(v['mean'])}, p90 {fmt(v['p90'])}, "
                f"max {fmt(v['max'])}")
    st = res.get("search_timing")
    if st:
        c.print(f"pose search (rotation + search) on all {st['maps']} maps, {st['count']} queries in one process: "
                f"CPU median {st['cpu_median']:.3f} s, p90 {st['cpu_p90']:.3f}, max {st['cpu_max']:.3f}; wall median "
                f"{st['wall_median']:.3f} s; peak RSS {st['peak_rss_mb']:.0f} MB; {st['uptime']}")
    run = res["run"]
    c.print(f"run: wall {run['wall_s']:.0f} s, CPU {run['user_s'] + run['system_s']:.0f} s, peak RSS "
            f"{run['peak_rss_mb']:.0f} MB; load before: {run['uptime_before']}; after: {run['uptime_after']}")
    for tag in ("prepare", "prepare_ray"):
        p = res.get(tag)
        if not p:
            continue
        sizes = p["maps"]
        total = sum(sizes.values())
        built = (f"wall {p['wall_s']:.0f} s, CPU {p['user_s'] + p['system_s']:.0f} s, peak RSS {p['peak_rss_mb']:.0f} MB"
                 if "wall_s" in p else "maps reused, no record of their build")
        c.print(f"{tag}: {built}, threads {p['threads']}{' (reused maps)' if p['reused'] else ''}"
                f"; maps {', '.join(f'{k} {v / 1e6:.1f} MB' for k, v in sizes.items())}; total {total / 1e6:.1f} MB, "
                f"{total / 1e6 / res['rooms']:.2f} MB per room ({res['rooms']} rooms), "
                f"{total / 1e6 / res['spaces']:.2f} MB per space ({res['spaces']} with corridors and stairwells)")
    if "ray_maps_equal_plain" in res:
        c.print(f"ray maps equal the plain ones byte for byte: {res['ray_maps_equal_plain']}")
    first = next(iter(res["storage"].values()))
    c.print("storage of " + next(iter(res["storage"])) + ": " +
            ", ".join(f"{k} {v / 1e6:.2f} MB" for k, v in list(first.items())[:8]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="building", help="building (the 36-room building) or building_small")
    ap.add_argument("--seed", type=int, default=0, help="--seed of the generated building (0: the preset's default;"
                    " another: a building the confidence was never fitted on)")
    ap.add_argument("--data", default=None, help="a building already generated (default: generated under bench/.cache)")
    ap.add_argument("--width", type=int, default=None, help="panorama width when generating (default: the preset's)")
    ap.add_argument("--per-split", type=int, default=None, help="panoramas per split and room when generating")
    ap.add_argument("--ray", action="store_true", help="also prepare on a local Ray cluster (timed apart)")
    ap.add_argument("--rebuild", action="store_true", help="build the maps again (default: reuse them and their record)")
    ap.add_argument("--threads", type=int, default=1, help="--threads of prepare and run")
    ap.add_argument("--top-maps", type=int, default=None, help="--top-maps of the run (default: the run's)")
    ap.add_argument("--splits", default=None, help="comma-separated splits to localize (default: all)")
    ap.add_argument("--max-queries", type=int, default=None, help="localize every k-th query, this many at most")
    ap.add_argument("--camera-height", default=None, metavar="MIN:MAX",
                    help="prepare's --camera-height: candidates only MIN-MAX m above each floor (maps_<tag>)")
    ap.add_argument("--num-trans", type=int, default=None, help="prepare's --num-trans: N_t per floor map (maps_<tag>)")
    ap.add_argument("--timing-queries", type=int, default=40, help="queries of the in-process search timing (0: none)")
    ap.add_argument("--rescore", action="store_true", help="score the run already made against these maps again "
                    "(no localization)")
    ap.add_argument("--output", default=str(HERE / "building.json"))
    args = ap.parse_args(argv)
    if not Path(TIME_BIN).exists():
        print(f"{TIME_BIN} is needed for the peak memory (apt-get install time)")
        return 1
    from ldlmap.synth.building import read_building

    data = dataset(args)
    work = data.parent
    res: dict[str, Any] = {"preset": args.preset, "data": str(data), "threads": args.threads}
    t0 = time.perf_counter()
    maps_dir = work / f"maps_{maps_tag(args)}"
    res["prepare"] = prepare(data, maps_dir, args, ray=False)
    if args.ray:
        res["prepare_ray"] = prepare(data, work / f"maps_ray_{maps_tag(args)}", args, ray=True)
        res["ray_maps_equal_plain"] = same_maps(maps_dir, work / f"maps_ray_{maps_tag(args)}")
    rooms = read_building(data)
    res["rooms"] = sum(r.kind not in ("corridor", "stairwell") for r in rooms)
    res["spaces"] = len(rooms)
    res["maps"] = str(maps_dir)
    res["storage"] = {p.stem: storage(p) for p in sorted(maps_dir.glob("*.h5"))}
    images, queries = select_images(data, args.splits.split(",") if args.splits else None, args.max_queries)
    res["queries"] = len(queries)
    run_json = work / ("run.json" if maps_dir.name == "maps_plain" else f"run_{maps_dir.name}.json")
    if args.rescore and run_json.exists() and run_json.with_suffix(".time").exists():
        res["run"] = {**parse_time(run_json.with_suffix(".time")), "uptime_before": "rescored", "uptime_after": "-"}
    else:
        res["run"] = localize(images, maps_dir, run_json, args)
    from ldlloc.batch.results import load_results

    results, _ = load_results(run_json)
    rows = score(results, queries, data)
    parts: dict[str, list] = {"all": rows}
    for f in sorted({r["floor"] for r in rows}):
        parts[f"floor {f}"] = [r for r in rows if r["floor"] == f]
    parts["own rooms (room, corridor)"] = [r for r in rows if r["group"] is None]
    for kind in ("room", "corridor"):  # the corridors share their floor's plan: only posters and 1-2 cabinets differ
        parts[f"own rooms: {kind}"] = [r for r in rows if r["group"] is None and r["kind"] == kind]
    for g in sorted({r["group"] for r in rows if r["group"]}):
        parts[f"identical: {g}"] = [r for r in rows if r["group"] == g]
    res["summary"] = {k: summarize(v) for k, v in parts.items()}
    res["seconds"] = seconds(rows)
    if args.timing_queries:
        res["search_timing"] = search_timing(maps_dir, queries, args.timing_queries, args.threads)
    res["rows"] = rows
    res["bench_wall_s"] = time.perf_counter() - t0
    report(res)
    write_json(Path(args.output), res)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
