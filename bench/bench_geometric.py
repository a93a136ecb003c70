"""Benchmark: geometric refinement from lines alone on synthetic lines-only maps.

Run: ``python bench/bench_geometric.py [--quick] [--threads 1] [--no-features] [--seed 1]``.

The synthetic requirement of lines-only localization: on the extreme, robot and change_robot splits, with lines-only
maps built from the scan's extracted lines and from the true edges, accuracy at 0.1 m / 5 deg
>= 0.9. Data: the cached synthetic demo dataset (``common.demo_dataset``: 2 scenes, 3 panoramas
per split, 1024 x 512). Per scene, two lines-only maps (``features="none"``), cached under
``bench/.cache/geometric/<dataset>/`` with the map-building code's hash (``common.map_tag``):

- ``true_edges``: built from ``gt_lines/<scene>.obj`` (the mesh's true 3D edges);
- ``scan_lines``: ``ldlmap.lines3d.extract_lines`` on ``pcd/<scene>.ply``, written to a ``.obj``
  with ``ldlmap.io.linefiles.write_lines`` and built from that file.

Their candidate translations are a lattice ``trans_spacing = 0.3`` m apart over the free space, at
heights within the band of the scene's query cameras over the three splits (all of their
queries, also with ``--quick``), widened by 0.1 m on both sides (printed and recorded).

Every query of the three splits is localized against each map kind with
``Localizer(map, LocalizeParams(refine_mode=mode))`` for mode ``none`` and ``geometric``, and,
unless ``--no-features``, against the benchmarks' cached SIFT maps (``common.cached_map``) with
``features`` for comparison. One untimed warm-up query per localizer. Prints per map kind x
split x mode: n, accuracy at 0.05 / 0.1 / 0.25 m (5 deg), median errors, the share of queries
whose refinement was kept (``loc.refined``), the search's top-1 within 0.5 m / 10 deg, and
median seconds of the ``refine`` stage and of ``total``; writes ``bench/geometric.json``::

    {"summary": [{"map", "split", "mode", "n", "failed", "acc_0.05m_5deg", "acc_0.1m_5deg",
                  "acc_0.25m_5deg", "median_t_error_m", "median_r_error_deg", "refined_share",
                  "search_top1_0.5m_10deg", "median_refine_s", "median_total_s"}, ...],
     "queries": [...per query...], "maps": {...}, "camera_height": {scene: [lo, hi]},
     "machine": {...}, "code": {...}, "quick": bool, "seconds": wall time}

``--quick``: one scene, 3 queries per split (a smoke run; the numbers mean little).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

SPLITS = ("extreme", "robot", "change_robot")
MAP_KINDS = ("true_edges", "scan_lines")
LINES_MODES = ("none", "geometric")
THRESHOLDS = (("0.05m_5deg", 0.05, 5.0), ("0.1m_5deg", 0.1, 5.0), ("0.25m_5deg", 0.25, 5.0))
SPACING = 0.3
HEIGHT_MARGIN = 0.1


# ------------------------------------------------------------------------------------ maps


def camera_band(ds, scene: str) -> tuple[float, float]:
    """Heights (z) of the scene's query cameras over the three splits, widened by the margin."""
    z = [float(q.center[2]) for q in ds.queries(list(SPLITS), scene=scene)]
    return (round(min(z) - HEIGHT_MARGIN, 3), round(max(z) + HEIGHT_MARGIN, 3))


def lines_only_maps(dataset: Path, ds, scene: str, band: tuple[float, float]) -> dict[str, dict[str, Any]]:
    """The scene's two lines-only maps (built once, then reused): kind -> {path, build info}."""
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.io.linefiles import write_lines
    from ldlmap.io.pointcloud import read_point_cloud
    from ldlmap.lines3d import Lines3DParams, extract_lines

    tag = common.map_tag()
    folder = common.CACHE / "geometric" / dataset.name
    folder.mkdir(parents=True, exist_ok=True)
    key = f"s{SPACING:g}_h{band[0]:.2f}-{band[1]:.2f}_{tag}"
    params = BuildParams().replaced(features="none", trans_spacing=SPACING, camera_height=band)
    out: dict[str, dict[str, Any]] = {}

    scan_obj = folder / f"{scene}_scan_lines_{tag}.obj"
    extract_s = None
    if not scan_obj.exists():
        cloud = read_point_cloud(ds.point_cloud(scene))
        t0 = time.perf_counter()
        segs = extract_lines(cloud.points, Lines3DParams())
        extract_s = time.perf_counter() - t0
        write_lines(scan_obj, segs)
    sources = {"true_edges": dataset / "gt_lines" / f"{scene}.obj", "scan_lines": scan_obj}
    for kind in MAP_KINDS:
        path = folder / f"{scene}_{kind}_{key}.h5"
        info: dict[str, Any] = {"path": str(path), "source": str(sources[kind]), "built_now": False}
        if not path.exists():
            print(f"  building {kind} map of {scene} (camera height {band[0]:.2f}-{band[1]:.2f} m)",
                  file=sys.stderr)
            rep = build_map(sources[kind], path, params=params, name=scene)
            info.update(built_now=True, build_seconds=round(float(sum(rep.seconds.values())), 2))
        if kind == "scan_lines" and extract_s is not None:
            info["extract_seconds"] = round(extract_s, 2)
        out[kind] = info
    return out


def map_summary(path: str) -> dict[str, Any]:
    from ldlmap.map.mapfile import read_map

    m = read_map(path, load_cloud=False)
    return {"lines_raw": int(len(m.lines_raw)), "lines": int(len(m.lines)), "kept_ratio": float(m.kept_ratio),
            "translations": int(len(m.translations)), "features": m.features.backend if m.features else None}


# ------------------------------------------------------------------------------- localizing


def run_queries(map_path: Path | str, kind: str, mode: str, queries: list, progress: bool) -> list[dict[str, Any]]:
    """Localize ``queries`` against one map with one refinement mode; one record per query."""
    from ldlloc.pipeline import LocalizeParams, Localizer, load_image
    from ldlmap.core.errors import InputError
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlmap.map.mapfile import read_map

    loc = Localizer(read_map(map_path, load_cloud=False), LocalizeParams(refine_mode=mode))
    try:  # warm-up, untimed (lazy imports, caches)
        loc.localize(load_image(queries[0].image))
    except InputError:
        pass
    recs = []
    for i, q in enumerate(queries):
        rec: dict[str, Any] = {"map": kind, "mode": mode, "scene": q.scene, "split": q.split, "name": q.name,
                               "status": "failed", "t_error_m": None, "r_error_deg": None, "refined": False}
        try:
            r = loc.localize(load_image(q.image))
        except InputError as exc:
            rec["message"] = str(exc)
        else:
            c_r = rotation_error_deg(r.candidates_rot[0], q.rot_cam_from_world)
            c_t = translation_error(r.candidates_center[0], q.center)
            rec.update(status=r.status, t_error_m=float(translation_error(r.center, q.center)),
                       r_error_deg=float(rotation_error_deg(r.rot_cam_from_world, q.rot_cam_from_world)),
                       refined=bool(r.refined), refine_method=r.refine_method,
                       refine_residual_deg=r.refine_residual_deg,
                       search_top1_t_error_m=float(c_t), search_top1_r_error_deg=float(c_r),
                       chosen_coarse_t_error_m=float(translation_error(r.coarse_center, q.center)),
                       num_rotations=int(r.num_rotations), num_lines=int(r.num_lines),
                       num_matches=int(r.num_matches), num_inliers=int(r.num_inliers),
                       seconds={k: float(v) for k, v in r.seconds.items()}, message=r.message)
        recs.append(rec)
        if progress:
            print(f"\r  {kind:10s} {mode:9s} {q.scene}: {i + 1}/{len(queries)}", end="", file=sys.stderr)
    if progress:
        print(file=sys.stderr)
    return recs


def summarize(recs: list[dict[str, Any]]) -> dict[str, Any]:
    """Accuracy, median errors, refined share and median seconds of a group of query records."""
    n = len(recs)
    terr = np.array([r["t_error_m"] if r["t_error_m"] is not None else np.inf for r in recs], float)
    rerr = np.array([r["r_error_deg"] if r["r_error_deg"] is not None else np.inf for r in recs], float)
    ok = [r for r in recs if r["status"] != "failed"]
    out: dict[str, Any] = {"n": n, "failed": n - len(ok)}
    for name, m, d in THRESHOLDS:
        out[f"acc_{name}"] = float(np.mean((terr < m) & (rerr < d))) if n else None
    out["median_t_error_m"] = float(np.median(terr)) if n else None
    out["median_r_error_deg"] = float(np.median(rerr)) if n else None
    out["refined_share"] = float(np.mean([r["refined"] for r in recs])) if n else None
    top1 = [r.get("search_top1_t_error_m", np.inf) < 0.5 and r.get("search_top1_r_error_deg", np.inf) < 10
            for r in recs]
    out["search_top1_0.5m_10deg"] = float(np.mean(top1)) if n else None
    for stage in ("refine", "total"):
        v = [r["seconds"][stage] for r in ok if stage in r.get("seconds", {})]
        out[f"median_{stage}_s"] = float(np.median(v)) if v else None
    return out


# ---------------------------------------------------------------------------------- output


def table(rows: list[dict[str, Any]], title: str, caption: str):
    from rich.table import Table

    t = Table(title=title, caption=caption)
    cols = ("map", "split", "mode", "n", "fail", "0.05m/5", "0.1m/5", "0.25m/5", "t err m", "R err deg",
            "refined", "search top1", "refine s", "total s")
    for c in cols:
        t.add_column(c, justify="left" if c in ("map", "split", "mode") else "right")
    prev = None
    for r in rows:
        if prev is not None and r["map"] != prev:
            t.add_section()
        prev = r["map"]
        f = common.fmt
        acc = f(r["acc_0.1m_5deg"], ".2f")
        if r["mode"] != "none" and r["acc_0.1m_5deg"] is not None:
            acc = f"[green]{acc}[/]" if r["acc_0.1m_5deg"] >= 0.9 else f"[red]{acc}[/]"
        t.add_row(r["map"], r["split"], r["mode"], str(r["n"]), str(r["failed"]), f(r["acc_0.05m_5deg"], ".2f"),
                  acc, f(r["acc_0.25m_5deg"], ".2f"), f(r["median_t_error_m"], ".3f"),
                  f(r["median_r_error_deg"], ".2f"), f(r["refined_share"], ".2f"),
                  f(r["search_top1_0.5m_10deg"], ".2f"), f(r["median_refine_s"], ".3f"),
                  f(r["median_total_s"], ".3f"), style="bold" if r["split"] == "all" else None)
    return t


def code_info() -> dict[str, Any]:
    """Commit, whether the localizer's sources differ from it, and their hash (the tree moves)."""
    def git(*a: str) -> str:
        try:
            return subprocess.run(["git", *a], cwd=common.ROOT, capture_output=True, text=True,
                                  timeout=20).stdout.strip()
        except Exception:  # noqa: BLE001 - informative only
            return ""
    return {"commit": git("rev-parse", "--short", "HEAD"),
            "dirty": git("status", "--porcelain", "--", "ldlloc", "ldlmap").splitlines(),
            "ldlloc_hash": common.source_hash("ldlloc"), "ldlmap_map_tag": common.map_tag()}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: 1 scene, 3 queries per split")
    ap.add_argument("--seed", type=int, default=1, help="demo dataset seed")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    ap.add_argument("--no-features", action="store_true", help="skip the SIFT maps' feature refinement")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "geometric.json")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    common.set_threads(args.threads)
    from ldlmap.datasets import open_dataset

    wall0 = time.perf_counter()
    progress = not args.no_progress
    dataset = common.demo_dataset(args.seed)
    ds = open_dataset(dataset, "omniscenes")
    scenes = ds.scenes()[:1] if args.quick else ds.scenes()
    code = code_info()

    bands, maps, recs = {}, {}, []
    for scene in scenes:
        band = camera_band(ds, scene)
        bands[scene] = list(band)
        built = lines_only_maps(dataset, ds, scene, band)
        queries = []
        for split in SPLITS:
            qs = ds.queries(split, scene=scene)
            queries += qs[:3] if args.quick else qs
        for kind in MAP_KINDS:
            maps[f"{scene}/{kind}"] = {**built[kind], **map_summary(built[kind]["path"])}
            for mode in LINES_MODES:
                recs += run_queries(built[kind]["path"], kind, mode, queries, progress)
        if not args.no_features:
            sift = common.cached_map(dataset, scene)
            maps[f"{scene}/sift"] = {"path": str(sift), **map_summary(str(sift))}
            recs += run_queries(sift, "sift", "features", queries, progress)
    wall = time.perf_counter() - wall0

    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for r in recs:
        groups.setdefault((r["map"], r["split"], r["mode"]), []).append(r)
        groups.setdefault((r["map"], "all", r["mode"]), []).append(r)
    kinds = list(MAP_KINDS) + ([] if args.no_features else ["sift"])
    rows = []
    for kind in kinds:
        for split in (*SPLITS, "all"):
            for mode in (*LINES_MODES, "features"):
                if (kind, split, mode) in groups:
                    rows.append({"map": kind, "split": split, "mode": mode, **summarize(groups[(kind, split, mode)])})

    machine = common.machine_info("cpu")
    con = common.console()
    band_txt = ", ".join(f"{s} {lo:.2f}-{hi:.2f} m" for s, (lo, hi) in bands.items())
    maps_txt = "; ".join(f"{k}: {v['lines']}/{v['lines_raw']} lines, N_t {v['translations']}" for k, v in maps.items())
    caption = (f"lines-only maps: lattice {SPACING:g} m, camera-height band = query cameras' heights over "
               f"{'/'.join(SPLITS)} widened by {HEIGHT_MARGIN:g} m ({band_txt}); {maps_txt}\n"
               f"search top1 = search's best pose within 0.5 m / 10 deg; refined = share with loc.refined; "
               f"seconds are medians; code {code['commit']}{' (dirty ldlloc/ldlmap)' if code['dirty'] else ''}, "
               f"ldlloc {code['ldlloc_hash']}\n" + common.load_line(machine) + f"; wall {wall:.0f} s")
    title = (f"Geometric refinement on lines-only maps (synthetic demo{', QUICK' if args.quick else ''}; "
             f"target: 0.1m/5 >= 0.9 with geometric)")
    con.print(table(rows, title, caption))
    result = {"summary": rows, "queries": recs, "maps": maps, "camera_height": bands,
              "camera_height_margin_m": HEIGHT_MARGIN, "trans_spacing_m": SPACING,
              "dataset": str(dataset.relative_to(common.ROOT)) if dataset.is_relative_to(common.ROOT) else str(dataset),
              "machine": machine, "code": code, "quick": bool(args.quick), "seconds": round(wall, 1)}
    common.write_json(args.output, result)
    con.print(f"wrote {args.output}")
    return result


if __name__ == "__main__":
    main()
