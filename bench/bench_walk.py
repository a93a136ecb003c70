"""Walks against single images, side by side on the same frames.

Run: ``python bench/bench_walk.py [--data ../shared/data] [--levels floor,rooms] [--threads 1] [--no-relative]``,
``python bench/bench_walk.py --pairs`` (the motion between consecutive panoramas, :func:`pair_fits`), or
``python bench/bench_walk.py --building [--seed 4040] [--width 1024] [--visits 2]``.

The shared ZInD home (19 panoramas in capture order, the panorama number) as one walk,
``ldlloc run --root ... --walk``'s library path (:func:`ldlloc.walk.run.run_walk_queries`): at
``floor`` level against the floor map (the room not given), at ``rooms`` level against the folder
of room maps (``--scene-unknown``). Maps as ``bench/bench_real.py`` builds them (cached). Printed
per frame (single-image and walk errors, verdicts, whether the walk decided) and summarized:
within 0.1 m / 5 deg and 0.25 m / 5 deg, single image against walk, confident poses and how many
of them are wrong, frames the walk decided. Results go to ``bench/walk.json``.

``--building``: a synthetic building walk, the floor not given. ``ldlmap synth --preset building
--per-split 0 --walk tour`` (:func:`ldlmap.synth.building.generate_building`: a tour through every
floor, ``--visits`` rooms entered a floor, up the stairwell; ``--seed``: one no test or bench uses),
cached under ``bench/.cache/walk_building/data_s<seed>_w<width>``; ``ldlmap prepare`` at its defaults
(one map per floor, timed, cached as ``maps_s<seed>``); the walk localized as one walk against the
folder of floor maps (``ldlloc run --root DATA --split walk_tour --walk --scene-unknown``'s library
path). ``--first-pass``: the walk's first pass (each frame's own localization, the searches near
confident frames) saved once under ``bench/.cache/walk_building/first_s<seed>*.pkl`` and the walk
decided from it (:func:`decided`: the same searches near confident frames, motions between images,
path and refinement as the walk, without localizing every frame again; the figures of a full run,
checked on seeds 4040 and 4041): a change of the motion model or the decision measured in minutes, not half an hour, with
where the true pose is among the frames' hypotheses (:func:`redecide`). ``--lattice M``: the walk's
lattice near confident frames (:mod:`ldlloc.walk.lattice`) at this spacing, 0: off (its own first pass,
``first_s<seed>_lattice<M>.pkl``; the frames' own localizations are shared). Scored per frame against
the ground truth the run never sees: within 0.1 m / 5 deg (single
image and walk), right floor, and for the identical rooms (offices, hotel rooms) whether the pose
is in the right copy (:func:`ldlmap.synth.building.room_at`). ``--video``: the building's video walk instead
(``ldlmap synth --walk video``, cached as ``data_s<seed>_..._video``), tracked as ``ldlloc run --video VIDEO --maps
MAPS`` runs it (:func:`run_building_video`; no single-image column). Results: ``bench/walk_building.json``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.bench_building import cli, timed  # noqa: E402
from bench.bench_real import build_maps, use_threads, zind_root_or_none  # noqa: E402
from bench.common import CACHE, console, write_json  # noqa: E402

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

    map_level = "room" if level == "rooms" else level
    maps = build_maps(zind_root, map_level, None)
    queries = open_dataset(zind_root, "zind", map_level=map_level).queries()
    out = CACHE / "real" / f"walk_{level}{'' if args.relative else '_norelative'}.json"
    out.unlink(missing_ok=True)
    t0 = time.perf_counter()
    walk = WalkParams(top_maps=TOP_MAPS, relative=args.relative)
    res = run_walk_queries(queries, maps, out, LocalizeParams(), walk, "cpu",
                           meta={"dataset": "zind"}, scene_unknown=level == "rooms")
    seconds = time.perf_counter() - t0
    rows = frame_rows(res, queries)
    return {"level": level, "seconds": seconds, "frames": rows,
            "single": counts(rows, "single"), "walk": counts(rows, "walk"),
            "walk_decided": sum(r["walk_decided"] for r in rows)}


def frame_rows(results: list, queries: list) -> list[dict]:
    """One row per frame of a walk run, in walk order: its single-image and walk errors and verdicts."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error

    gt = {q.name: q for q in queries}
    rows = []
    for r in sorted(results, key=lambda r: r.walk["frame"] if r.walk else -1):
        q, w = gt[r.name], r.walk or {}
        single = {"t": None, "r": None, "verdict": w.get("single_verdict"), "pose": None}
        if w.get("single_pose"):
            R, t = np.asarray(w["single_pose"]["R"]), np.asarray(w["single_pose"]["t"])
            single.update(t=translation_error(t, q.center), r=rotation_error_deg(R, q.rot_cam_from_world), pose=t.tolist())
        elif r.status != "failed":
            single.update(t=r.t_error_m, r=r.r_error_deg, pose=None if r.t is None else list(r.t))
        rows.append({"name": r.name, "map": None if r.map is None else Path(r.map).stem, "single": single,
                     "walk": {"t": r.t_error_m, "r": r.r_error_deg, "verdict": r.verdict,
                              "pose": None if r.t is None else list(r.t)},
                     "walk_decided": bool(w.get("walk_decided")), "margin": w.get("margin")})
    return rows


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


def pair_fits(zind_root: Path) -> dict:
    """The motion between each two consecutive panoramas of the ZInD tour (:func:`ldlloc.walk.relative.relative_pose`,
    the panoramas as taken: upright) against the ground truth: rotation and direction errors (deg), the
    step's length from the floor (the true camera height times its length in camera heights) and CPU seconds."""
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.datasets import open_dataset
    from ldlloc.pipeline import load_image
    from ldlloc.walk.relative import panorama_features, relative_pose

    qs = sorted(open_dataset(zind_root, "zind", map_level="floor").queries(), key=lambda q: int(q.name.split("_")[-1]))
    t0 = time.process_time()
    feats = [panorama_features(load_image(q.image)) for q in qs]
    rows = [{"features_cpu_s": (time.process_time() - t0) / len(qs)}]
    for a, b, fa, fb in zip(qs[:-1], qs[1:], feats[:-1], feats[1:]):
        t0 = time.process_time()
        rel = relative_pose(fa, fb)
        Ra, Rb = np.asarray(a.rot_cam_from_world), np.asarray(b.rot_cam_from_world)
        step = Ra @ (np.asarray(b.center) - np.asarray(a.center))
        row = {"pair": f"{a.name.split('/')[-1]} -> {b.name.split('/')[-1]}", "metres": float(np.linalg.norm(step)),
               "cpu_s": time.process_time() - t0, "fit": rel is not None}
        if rel is not None:
            row.update(inliers=rel.inliers, matches=rel.matches, rot_deg=rotation_error_deg(rel.rot, Rb @ Ra.T),
                       dir_deg=float(np.degrees(np.arccos(np.clip(rel.direction @ step / row["metres"], -1, 1)))),
                       length_m=None if rel.per_height is None else rel.per_height * float(np.asarray(a.center)[2]))
        console().print(row)
        rows.append(row)
    fit = [r for r in rows[1:] if r["fit"]]
    console().print(f"{len(fit)} / {len(rows) - 1} pairs fit; rotation error median "
                    f"{np.median([r['rot_deg'] for r in fit]):.2f} deg, direction {np.median([r['dir_deg'] for r in fit]):.1f} deg")
    return {"pairs": rows}


# ------------------------------------------------------------------------------ building walk

WALK_CACHE = CACHE / "walk_building"


def building_data(args) -> Path:
    """The building with its tour (``--seed``, ``--width``, ``--visits``), generated once (timed)."""
    from ldlmap.synth.building import generate_building

    out = WALK_CACHE / (f"data_s{args.seed}_w{args.width}" + ("" if args.visits == 2 else f"_v{args.visits}")
                        + doors_tag(args) + ("_video" if args.video else ""))
    if not (out / "dataset.json").exists():
        console().print(f"generating the building and its {'video' if args.video else 'tour'} into {out}")
        t0 = time.perf_counter()
        generate_building(out, "building", args.seed, per_split=0, width=args.width,
                          walk=("video",) if args.video else ("tour",),
                          walk_visits=args.visits, progress=False, illumination=False, doors=args.doors,
                          walk_doors=args.walk_doors)
        write_json(out.parent / f"{out.name}_synth.json", {"wall_s": time.perf_counter() - t0})
    return out


def doors_tag(args) -> str:
    """The caches' tag of the building's doors: none when closed in scans and tour alike, ``_open`` for a
    tour with them open through closed-door scans, ``_doors_open`` when the scans see them open too."""
    walked = args.walk_doors or args.doors
    if args.doors == "closed":
        return "" if walked == "closed" else "_open"
    return "_doors_open" + ("" if walked == "open" else "_walk_closed")


def building_maps(data: Path, args) -> tuple[Path, dict]:
    """``ldlmap prepare DATA`` at its defaults (one map per floor) into ``maps_s<seed>``, built once
    (timed with ``/usr/bin/time``; the record of the build kept beside the maps)."""
    name = f"maps_s{args.seed}" + ("" if args.doors == "closed" else f"_doors_{args.doors}")  # the scans' doors
    maps, record = WALK_CACHE / name, WALK_CACHE / f"{name}.json"
    if not all((maps / f"floor_{f}.h5").exists() for f in range(3)):
        console().print(f"building the floor maps into {maps} (ldlmap prepare defaults: tens of minutes on 2 cores)")
        rec = timed(cli("ldlmap.cli", "prepare", str(data), "--maps", str(maps), "--overwrite"),
                    WALK_CACHE / f"prepare_{name[5:]}.time", WALK_CACHE / f"prepare_{name[5:]}.log")
        write_json(record, rec)
    return maps, (json.loads(record.read_text()) if record.exists() else {})


def copy_rows(rows: list[dict], queries: list, data: Path) -> None:
    """Add to each frame's row its true floor, room and group and, single image and walk alike, the
    room its pose stands in (``room_at``) and whether that is the true room (the right copy)."""
    from ldlmap.synth.building import read_building, room_at

    rooms = read_building(data)
    by_id = {r.id: r for r in rooms}
    gt = {q.name: q for q in queries}
    for row in rows:
        q = gt[row["name"]]
        true = by_id.get(q.room)
        row.update(floor=q.floor, room=q.room, kind=true.kind if true else None, group=true.group if true else None)
        for key in ("single", "walk"):
            got = None if row[key]["pose"] is None else room_at(rooms, np.asarray(row[key]["pose"]))
            row[key]["room"] = None if got is None else got.id
            row[key]["right_room"] = got is not None and got.id == q.room


def building_counts(rows: list[dict]) -> dict:
    """Per key (single | walk): all frames within 0.1 m / 5 deg, and the identical rooms' frames in the right copy."""
    same = [r for r in rows if r["group"] in ("office", "hotel")]
    out = {}
    for key in ("single", "walk"):
        ok = lambda r: r[key]["t"] is not None and r[key]["t"] < 0.1 and r[key]["r"] < 5  # noqa: E731
        out[key] = {"0.1m_5deg": sum(map(ok, rows)), "frames": len(rows),
                    "identical_frames": len(same), "right_copy": sum(r[key]["right_room"] for r in same),
                    "identical_0.1m_5deg": sum(map(ok, same)),
                    "right_floor": sum(r[key]["room"] is not None and r[key]["room"].startswith(f"f{r['floor']}_")
                                       for r in rows),
                    **counts(rows, key)}
    return out


def run_building(args) -> dict:
    from ldlmap.datasets import open_dataset
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.walk.run import run_walk_queries

    data = building_data(args)
    maps, build = building_maps(data, args)
    if args.video:
        return run_building_video(data, maps, build, args)
    queries = open_dataset(data, "omniscenes").queries("walk_tour")
    out = WALK_CACHE / f"walk_s{args.seed}.json"
    out.unlink(missing_ok=True)
    walk = walk_params(args)
    cache = first_cache(args)
    t0 = time.perf_counter()
    if args.first_pass:  # the walk decided again from its saved first pass (computed once)
        rows = decided(queries, maps, cache, walk)
    else:
        res = run_walk_queries(queries, maps, out, LocalizeParams(), walk, "cpu",
                               meta={"dataset": "synthetic"}, scene_unknown=True)
        rows = frame_rows(res, queries)
    seconds = time.perf_counter() - t0
    copy_rows(rows, queries, data)
    out = {"seed": args.seed, "width": args.width, "visits": args.visits, "doors": args.doors,
           "walk_doors": args.walk_doors or args.doors,
           "seconds": seconds, "prepare": build, "frames": rows, **building_counts(rows), "walk_decided": sum(r["walk_decided"] for r in rows)}
    if args.first_pass:  # where the truth is among the hypotheses the walk chose from
        import pickle

        hyp = redecide(pickle.loads(cache.read_bytes()), queries, walk, data)["rows"]
        out["truth_in_hypotheses"] = {"own_search": sum(r["near_own"] for r in hyp),
                                      "any": sum(r["near_any"] for r in hyp), "frames": len(hyp),
                                      "within": "0.5 m / 10 deg"}
        T = {f: map_contents(maps / f"floor_{f}.h5").translations for f in {q.floor for q in queries}}
        d = np.array([np.linalg.norm(T[q.floor] - q.center, axis=1).min() for q in queries])
        out["nearest_candidate_m"] = {"median": float(np.median(d)), "p90": float(np.percentile(d, 90)),
                                      "over_0.3m": int((d > 0.3).sum())}  # to each frame's true position
    return out


def run_building_video(data: Path, maps: Path, build: dict, args) -> dict:
    """``--video``: the building's video walk (``video/walk_video.mp4``) as ``ldlloc run --video VIDEO --maps
    MAPS`` runs it (tracked, the floor not given), scored per frame against the walk's ground truth."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlmap.datasets import open_dataset
    from ldlloc.batch.which_map import TOP_MAPS, MapSet
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.walk.localize import VIDEO
    from ldlloc.walk.run import run_walk_video

    queries = sorted(open_dataset(data, "omniscenes").queries("walk_video"), key=lambda q: int(Path(q.image).stem))
    out = WALK_CACHE / f"walk_s{args.seed}_video.json"
    out.unlink(missing_ok=True)
    t0, c0 = time.perf_counter(), time.process_time()
    mapset = MapSet.load(maps, LocalizeParams())
    res = run_walk_video(data / "video" / "walk_video.mp4", mapset, out, LocalizeParams(),
                         replace(VIDEO, top_maps=TOP_MAPS), None, None, "cpu")
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    rows = []
    for r in sorted(res, key=lambda r: r.walk["frame"]):
        q, w = queries[r.walk["frame"]], r.walk
        walk = {"t": None, "r": None, "verdict": r.verdict, "pose": None}
        if r.t is not None:
            walk.update(t=translation_error(np.asarray(r.t), q.center), r=rotation_error_deg(np.asarray(r.R), q.rot_cam_from_world),
                        pose=list(r.t))
        rows.append({"name": q.name, "map": None if r.map is None else Path(r.map).stem, "walk_decided": bool(w.get("walk_decided")),
                     "margin": w.get("margin"), "tracked": bool(w.get("tracked")), "lost": bool(w.get("lost")),
                     "walk": walk, "single": {"t": None, "r": None, "verdict": None, "pose": None}})
    copy_rows(rows, queries, data)
    return {"seed": args.seed, "width": args.width, "visits": args.visits, "doors": args.doors,
            "walk_doors": args.walk_doors or args.doors, "video": True,
            "seconds": seconds, "cpu_s": cpu, "prepare": build, "frames": rows, **building_counts(rows),
            "walk_decided": sum(r["walk_decided"] for r in rows), "tracked": sum(r["tracked"] for r in rows),
            "lost": sum(r["lost"] for r in rows)}


def walk_params(args):
    """The walk's parameters of a building run: the defaults, the lattice spacing ``--lattice`` (0: off)."""
    from dataclasses import replace

    from ldlloc.batch.which_map import TOP_MAPS
    from ldlloc.walk.localize import WalkParams

    walk = WalkParams(top_maps=TOP_MAPS, scan_walls=args.scan_walls)
    if args.lattice is None:
        return walk
    return replace(walk, lattice=replace(walk.lattice, spacing_m=args.lattice))


def first_cache(args) -> Path:
    """The saved first pass of a building run (``first_s<seed>.pkl``; tagged by the doors (:func:`doors_tag`),
    ``_lattice<spacing>`` when not the default).
    The frames' own localizations (``first_s<seed>_<frame>.pkl``) are shared by every variant."""
    tag = "" if args.lattice is None else f"_lattice{args.lattice:g}"
    return WALK_CACHE / f"first_s{args.seed}{doors_tag(args)}{tag}.pkl"


def part_path(cache: Path, k: int) -> Path:
    """Frame ``k``'s own localization beside the first pass ``cache`` (shared by its variants: :func:`first_cache`)."""
    base = cache.stem.split("_lattice")[0]
    return cache.with_name(f"{base}_{k:04d}.pkl")


def walk_frames(queries: list, params) -> list:
    """The walk's frames (:class:`ldlloc.walk.localize.WalkFrame`) of dataset ``queries`` in walk order."""
    from ldlloc.batch.run import tilt_bound_for
    from ldlloc.batch.images import load_image
    from ldlloc.walk.localize import WalkFrame

    return [WalkFrame(q.name, (lambda p=q.image: load_image(p)), None, tilt_bound_for(q, params)) for q in queries]


def first_pass(queries: list, maps_path: Path, cache: Path, chunk: tuple[int, int] | None = None,
               walk=None) -> dict:
    """The walk's first pass (each frame's own localization and the searches near confident frames:
    what :func:`ldlloc.walk.localize.localize_walk` does before it chooses the path) against the map
    or folder of maps ``maps_path``, saved once to ``cache`` (pickle): :func:`redecide` chooses the
    path again from it in seconds. The frames' own localizations come from :func:`own_pass`
    (``chunk``: only those frames, returning {}); the searches near confident frames use ``walk``
    (:class:`ldlloc.walk.localize.WalkParams`, None: the defaults)."""
    import pickle

    from ldlloc.walk.localize import WalkParams, augment

    if cache.exists():
        return pickle.loads(cache.read_bytes())
    walk = walk or WalkParams()
    outs, maps = own_pass(queries, maps_path, cache, chunk, walk)
    if chunk is not None:
        return {}
    augment(outs, maps, walk)
    return save_pass(outs, maps, cache)


def own_pass(queries: list, maps_path: Path, cache: Path, chunk: tuple[int, int] | None, walk) -> tuple[list, object]:
    """Each frame's own localization against ``maps_path`` (the walk's outcomes, in order, and the
    :class:`ldlloc.batch.which_map.MapSet`), kept beside ``cache`` as it is done (``<cache
    stem>_<frame>.pkl``) and read back from there: ``chunk`` (first, end) localizes only those frames
    (processes side by side)."""
    import pickle

    from ldlloc.batch.which_map import MapSet
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.walk.localize import FrameOutcome, WalkFrame, localize_frame

    params = LocalizeParams()
    maps = MapSet.load(maps_path, params, "cpu", recursive=False)
    index = {id(e): i for i, e in enumerate(maps.entries)}
    outs, ref, trackers = [], None, {}
    for k, fr in enumerate(walk_frames(queries, params)):
        part = part_path(cache, k)  # each frame's own localization, kept (runs in parallel)
        if part.exists():
            o = pickle.loads(part.read_bytes())
            o.frame = fr
        elif chunk is not None and not chunk[0] <= k < chunk[1]:
            continue
        else:
            o, ref = localize_frame(fr, outs[-1] if outs else None, maps, walk, ref, trackers, index)
            o.own_count = 0 if o.hypotheses is None else len(o.hypotheses)
            keep = FrameOutcome(WalkFrame(fr.name, None), loc=o.loc, hypotheses=o.hypotheses, error=o.error,
                                single_confidence=o.single_confidence, single_verdict=o.single_verdict,
                                single_pose=o.single_pose, competitors=o.competitors, copies=o.copies)
            keep.own_count, keep.map = o.own_count, None if o.entry is None else index[id(o.entry)]
            part.write_bytes(pickle.dumps(keep))
            o.map = keep.map
        if o.map is not None:
            o.entry = maps.entries[o.map]
        if "copies" not in vars(o):  # saved before the walk kept the copies of a frame's room: found again
            o.copies = copies_again(o, maps, index)
        outs.append(o)
        console().print(f"first pass {k + 1}/{len(queries)}: {o.single_verdict}")
    return outs, maps


def copies_again(o, maps, index: dict[int, int]):
    """The copies of frame ``o``'s room (:func:`ldlloc.walk.copies.room_copies`) from its image's lines
    detected again (a first pass saved before the walk kept them); none detected where it named none."""
    from ldlloc.walk.copies import copies_undecided, room_copies
    from ldlloc.walk.localize import frame_arcs

    if o.entry is None or o.hypotheses is None or not copies_undecided(o.loc):
        return None
    return room_copies(o.loc, o.entry, maps.entries, index, frame_arcs(o.frame, o.entry.localizer), o.hypotheses)


def save_pass(outs: list, maps, cache: Path) -> dict:
    """The first pass of ``outs`` (after the searches near confident frames) written to ``cache``, as
    :func:`redecide` reads it."""
    import pickle

    saved = [{"name": o.frame.name, "error": o.error, "verdict": o.single_verdict, "confidence": o.single_confidence,
              "pose": o.single_pose, "competitors": o.competitors, "tracked": o.tracked, "own_count": o.own_count,
              "map": o.map, "refined": bool(o.loc and o.loc.refined),
              "hyp": None if o.hypotheses is None else vars(o.hypotheses)} for o in outs]
    cache.write_bytes(pickle.dumps({"maps": [str(e.path) for e in maps.entries], "frames": saved}))
    return pickle.loads(cache.read_bytes())


def redecide(saved: dict, queries: list, walk=None, data: Path | None = None) -> dict:
    """The walk's path chosen again from the saved first pass (:func:`first_pass`) with ``walk``
    (:class:`ldlloc.walk.localize.WalkParams`), scored per frame on the chosen hypothesis (a final pose
    as refined, a search pose coarse: the walk refines it near itself), with where the truth is among
    the hypotheses (``near_own``: among the frame's own search poses, ``near_any``: also among those
    of the searches near confident frames; within 0.5 m / 10 deg). ``data``: a synthetic building
    (the rooms the poses stand in)."""
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.synth.building import read_building, room_at
    from ldlloc.walk.hypotheses import Hypotheses
    from ldlloc.walk.localize import FrameOutcome, WalkFrame, WalkParams, walk_path
    from ldlloc.walk.motion import FreeSpace

    walk = walk or WalkParams()
    free = FreeSpace.of_maps([map_contents(Path(p)) for p in saved["maps"]], walk.scan_walls) if walk.walls else None
    live = []
    for s in saved["frames"]:
        if s["hyp"] is None or not len(s["hyp"]["loss"]):
            continue
        o = FrameOutcome(WalkFrame(s["name"], None), hypotheses=Hypotheses(**s["hyp"]), single_pose=s["pose"],
                         single_verdict=s["verdict"], competitors=s["competitors"], tracked=s["tracked"])
        o.saved = s
        live.append(o)
    path = walk_path(live, walk, free=free)
    rooms = read_building(data) if data is not None else None
    at = lambda p: None if rooms is None or (r := room_at(rooms, p)) is None else r.id  # noqa: E731
    gt, rows = {q.name: q for q in queries}, []
    for o, j in zip(live, path.choice):
        q, h = gt[o.saved["name"]], o.hypotheses
        te = np.linalg.norm(h.center - q.center, axis=1)
        re = np.array([rotation_error_deg(R, q.rot_cam_from_world) for R in h.rot_cam_from_world])
        good = (te < 0.5) & (re < 10)
        rows.append({"name": q.name, "room": getattr(q, "room", None), "floor": getattr(q, "floor", None),
                     "verdict": o.saved["verdict"], "single_t": float(np.linalg.norm(o.saved["pose"][1] - q.center)),
                     "single_r": float(rotation_error_deg(o.saved["pose"][0], q.rot_cam_from_world)),
                     "single_room": at(o.saved["pose"][1]), "t": float(te[j]), "r": float(re[j]),
                     "final": bool(h.final[j]), "chosen": j, "map": int(h.map_index[j]), "walk_room": at(h.center[j]),
                     "near_own": bool(good[:o.saved["own_count"]].any()), "near_any": bool(good.any()),
                     "good_idx": np.flatnonzero(good).tolist(), "n": len(h)})
    return {"rows": rows, "cost": path.cost}


def decided(queries: list, maps_path: Path, cache: Path, walk=None) -> list[dict]:
    """The walk decided from its frames' saved own localizations (:func:`own_pass`, read back or made
    and saved) as :func:`ldlloc.walk.localize.localize_walk` decides it: the searches near confident frames
    and the motion between consecutive images (:func:`ldlloc.walk.localize.augment`, run again: the
    saved first pass does not keep the motions the path's steps are weighed by), then the path and a
    chosen search pose searched and refined near itself (:func:`ldlloc.walk.localize.decide`); one row
    per frame as :func:`frame_rows` gives them."""
    import pickle

    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlloc.walk.localize import WalkParams, augment, decide

    walk = walk or WalkParams()
    outs, maps = own_pass(queries, maps_path, cache, None, walk)
    if cache.exists():
        saved = pickle.loads(cache.read_bytes())
        assert [str(e.path) for e in maps.entries] == saved["maps"], "the maps changed since the first pass"
    augment(outs, maps, walk)
    if not cache.exists():  # the first pass, saved for redecide
        save_pass(outs, maps, cache)
    decide(outs, maps, walk)
    gt, rows = {q.name: q for q in queries}, []
    for o in outs:
        q = gt[o.frame.name]
        err = lambda R, t: (float(translation_error(t, q.center)),  # noqa: E731
                            float(rotation_error_deg(R, q.rot_cam_from_world)))
        st, sr = err(*o.single_pose) if o.single_pose is not None else (None, None)
        wt, wr = err(o.loc.rot_cam_from_world, o.loc.center) if o.loc is not None else (None, None)
        rows.append({"name": q.name, "map": None if o.entry is None else Path(o.entry.path).stem,
                     "single": {"t": st, "r": sr, "verdict": o.single_verdict,
                                "pose": None if o.single_pose is None else np.asarray(o.single_pose[1]).tolist()},
                     "walk": {"t": wt, "r": wr, "verdict": None if o.loc is None else o.loc.verdict,
                              "pose": None if o.loc is None else np.asarray(o.loc.center).tolist()},
                     "walk_decided": bool(o.walk_decided), "margin": o.walk_margin})
    return rows


def map_contents(path: Path):
    """The map at ``path`` (:class:`ldlmap.map.contents.LdlMap`), cached per process."""
    from ldlmap.map.mapfile import read_map

    if path not in MAPS:
        MAPS[path] = read_map(path, load_cloud=False)
    return MAPS[path]


MAPS: dict = {}


def print_building(res: dict) -> None:
    from rich.table import Table

    t = Table(title=f"building walk, seed {res['seed']}, floor not given ({res['seconds']:.0f} s)")
    for col in ("frame", "room", "single m", "single room", "walk m", "walk room", "walk verdict", "decided"):
        t.add_column(col)
    f = lambda x: "-" if x is None else f"{x:.3f}"  # noqa: E731
    for r in res["frames"]:
        s, w = r["single"], r["walk"]
        t.add_row(r["name"].split("/")[-1], str(r["room"]), f(s["t"]), str(s["room"]), f(w["t"]), str(w["room"]),
                  str(w["verdict"]), "yes" if r["walk_decided"] else "")
    console().print(t)
    for key in ("single", "walk"):
        c = res[key]
        console().print(f"{key:6s}: 0.1 m / 5 deg {c['0.1m_5deg']}/{c['frames']}, identical rooms in the right copy "
                        f"{c['right_copy']}/{c['identical_frames']} (within 0.1 m / 5 deg {c['identical_0.1m_5deg']}), "
                        f"right floor {c['right_floor']}, confident {c['confident']} (wrong {c['confident_wrong']})")
    console().print(f"frames the walk decided: {res['walk_decided']}/{len(res['frames'])}")
    if "truth_in_hypotheses" in res:
        h = res["truth_in_hypotheses"]
        console().print(f"the true pose among the frame's hypotheses ({h['within']}): {h['any']}/{h['frames']} "
                        f"({h['own_search']} from its own search); the nearest candidate translation to the "
                        f"true position: {res['nearest_candidate_m']}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="real data folder (default $LDL_REAL_DATA or ../shared/data)")
    ap.add_argument("--levels", default="floor,rooms", help="floor, rooms (comma-separated; default both)")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    ap.add_argument("--output", default=None, help="results (default bench/walk.json, bench/walk_building.json)")
    ap.add_argument("--building", action="store_true", help="the synthetic building walk instead of ZInD")
    ap.add_argument("--no-relative", dest="relative", action="store_false",
                    help="ZInD: without the motion between consecutive images (ldlloc.walk.relative): the walk before it")
    ap.add_argument("--pairs", action="store_true",
                    help="ZInD: only the motion between consecutive panoramas against the ground truth")
    ap.add_argument("--seed", type=int, default=4040, help="--building: the building's seed (no test uses 4040)")
    ap.add_argument("--width", type=int, default=1024, help="--building: panorama width")
    ap.add_argument("--visits", type=int, default=2, help="--building: rooms the walk enters a floor")
    ap.add_argument("--first-pass", action="store_true",
                    help="--building: decide the walk from its first pass saved under bench/.cache (computed once: "
                         "each frame's own localization and the searches near confident frames), in minutes")
    ap.add_argument("--doors", choices=("closed", "open"), default="closed",
                    help="--building: the building's doors in its scans (and its tour unless --walk-doors): "
                         "ldlmap synth --doors; the maps are built again for open doors")
    ap.add_argument("--walk-doors", choices=("closed", "open"), default=None,
                    help="--building: the tour's doors (default: as --doors; ldlmap synth --walk-doors)")
    ap.add_argument("--video", action="store_true",
                    help="--building: the building's video walk (ldlmap synth --walk video), tracked as ldlloc run --video runs it")
    ap.add_argument("--scan-walls", action="store_true",
                    help="--building: the walk reads the scan maps' stored footprints as walls (off by default)")
    ap.add_argument("--lattice", type=float, default=None,
                    help="--building: the walk's lattice spacing in metres near confident frames, e.g. 0.2 (0: off; "
                         "default: WalkParams', off)")
    args = ap.parse_args(argv)
    if args.building:
        use_threads(args.threads)
        res = run_building(args)
        print_building(res)
        output = args.output or str(HERE / "walk_building.json")
        write_json(Path(output), res)
        print(f"wrote {output}")
        return 0
    args.output = args.output or str(HERE / "walk.json")
    zind_root = zind_root_or_none(args.data)
    if zind_root is None:
        return 0
    use_threads(args.threads)
    if args.pairs:
        write_json(Path(args.output), pair_fits(zind_root))
        return 0
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
