"""Benchmark of the pose search: exact line distance functions vs. precomputed distance fields.

Over the queries of a synthetic demo dataset (1024 x 512, every split), prints the median seconds
per stage (2D lines, rotation estimation, search exact, search fast on field losses alone
(``rescore=0``), search fast with the default exact re-scoring of the best field poses, the
re-scoring's added seconds, pose search = rotation + fast search) beside the paper's CPU / GPU
columns, and how well each fast variant keeps the exact ranking (is the exact path's best pose
the fast path's first / in its top 3 / top 20; same top-1 loss; same top-20 losses; accuracy of
the best of the top 20 against the ground truth), the interpolation error of the fields against
``ldf_3d`` at the queries' own rotations, the memory of the look-up table and the growth of the
map file. The fast searches are timed as the best of 3 calls (10 ms calls on a shared machine).

The 2D lines, the rotations and the searches are the product's own stages with its defaults
(:meth:`ldlloc.pipeline.Localizer.rotation_stage`, :func:`ldlloc.search.pose_search.search_map`): the
query's kept ratio within its bounds and the vanishing points' ladder of line ratios included.

Run: ``python bench/bench_search.py [--root DATASET] [--threads N] [--max-queries N]
[--json out.json]`` (``--threads`` defaults to 1, as ``ldlloc`` runs). Without ``--root`` the demo
dataset (seed 1) is generated once under
``bench/.cache/search/`` and lines-only maps (no rendered features: the search does not use
them) are built there with the default ``BuildParams`` (distance fields on).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `python bench/bench_search.py` from anywhere imports the working tree
    sys.path.insert(0, str(ROOT))

import common  # noqa: E402  (bench/common.py, beside this script)
from ldlmap.core.cli_common import DEFAULT_THREADS  # noqa: E402

PAPER = {"lines2d": (0.141, 0.141), "rotation": (1.124, 0.009), "search": (0.052, 0.001)}


def _prepare(root: Path | None, cache: Path, seed: int) -> tuple[Path, dict[str, Path], dict[str, float]]:
    """Dataset root and one map per scene (built when missing); build seconds of the fields stage."""
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.datasets import open_dataset

    if root is None:
        root = cache / f"demo_s{seed}"
        if not (root / "dataset.json").exists():
            from ldlmap.synth.generate import generate_dataset

            print(f"generating the demo dataset (seed {seed}) in {root} ...", flush=True)
            generate_dataset(root, "demo", [], seed)
    ds = open_dataset(root, "omniscenes")
    maps, field_secs = {}, {}
    for scene in ds.scenes():
        out = cache / "maps" / f"{root.name}_{scene}.h5"
        if not out.exists():
            print(f"building the lines-only map of {scene} ...", flush=True)
            out.parent.mkdir(parents=True, exist_ok=True)
            rep = build_map(ds.point_cloud(scene), out, params=BuildParams().replaced(features="none"), name=scene)
            field_secs[scene] = rep.seconds.get("fields", float("nan"))
        maps[scene] = out
    return root, maps, field_secs


def _scaling_seconds(n_t: int, rows: int, n_r: int = 30, repeat: int = 7) -> float:
    """Median seconds of the fast search's look-up, loss and top-K for a random table of N_t."""
    import torch

    from ldlloc.search import ldf
    from ldlloc.search.fields import DistanceFields, inlier_loss_from_fields
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    d = (rng.random((n_t, 3, rows + 1, 2 * rows), dtype=np.float32) * np.pi).astype(np.float16)
    F = DistanceFields.from_arrays(d, {"rows": rows})
    R = Rotation.random(n_r, random_state=0).as_matrix()
    x = ldf.query_points(1)
    f2d = torch.rand(n_r, 3, 42) * np.pi
    ts = []
    for _ in range(repeat):
        a = time.perf_counter()
        ldf.top_k_poses(inlier_loss_from_fields(f2d, F.ldf_3d(x, R)), 20)
        ts.append(time.perf_counter() - a)
    return float(np.median(ts))


def search_query(loc, q) -> tuple[dict, np.ndarray]:
    """One query through the product's stages: the 2D lines, the rotation stage, the exact search and
    the fast search (fields alone, then with the exact re-scoring, each the best of 3 calls). Returns
    its row (seconds, agreement with the exact ranking, accuracy) and its candidate rotations."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlloc.pipeline import load_image
    from ldlloc.search.pose_search import SearchParams, search_map

    m = loc.map
    img = load_image(q.image)
    a = time.perf_counter()
    lines = loc.detect_lines(img)
    b = time.perf_counter()
    rs = loc.rotation_stage(lines)
    arcs, rots, labels = rs.arcs, rs.rotations, rs.labels
    c = time.perf_counter()
    exact = search_map(arcs, labels, rots.rotations, m, SearchParams(use_fields=False))
    d = time.perf_counter()

    def fast_search(params: SearchParams):  # best of 3 calls
        secs = []
        for _ in range(3):
            a0 = time.perf_counter()
            res = search_map(arcs, labels, rots.rotations, m, params, fields=loc.fields)
            secs.append(time.perf_counter() - a0)
        return res, min(secs)

    plain, plain_s = fast_search(SearchParams(rescore=0))
    fast, fast_s = fast_search(SearchParams())
    best = (int(exact.translation_index[0]), int(exact.rotation_index[0]))

    def agreement(res, tag: str) -> dict:
        top = list(zip(res.translation_index.tolist(), res.rotation_index.tolist()))
        return {f"{tag}_top1": best == top[0], f"{tag}_top3": best in top[:3], f"{tag}_top20": best in top,
                f"{tag}_same_top1_loss": bool(res.losses[0] == exact.losses[0]),
                f"{tag}_same_losses": bool(np.array_equal(res.losses, exact.losses))}

    def best_of(res) -> tuple[float, float]:
        te = np.array([translation_error(t, q.center) for t in res.centers])
        re = np.array([rotation_error_deg(R, q.rot_cam_from_world) for R in res.rotations])
        ok = (te < 0.5) & (re < 10.0)
        return float(ok.any()), float(te[0] < 0.5 and re[0] < 10.0)

    (ex_top, ex_first), (fa_top, fa_first), (pl_top, pl_first) = best_of(exact), best_of(fast), best_of(plain)
    return dict(query=q.name, lines=len(arcs), rotations=len(rots), lines2d=b - a, rotation=c - b,
                search_exact=d - c, search_fields=plain_s, search_fast=fast_s, rescore=fast_s - plain_s,
                pose_search=(c - b) + fast_s, pose_search_fields=(c - b) + plain_s, **agreement(plain, "fields"),
                **agreement(fast, "rescored"), exact_top20_ok=ex_top, fields_top20_ok=pl_top, fast_top20_ok=fa_top,
                exact_top1_ok=ex_first, fields_top1_ok=pl_first, fast_top1_ok=fa_first), rots.rotations


def interpolation_error(loc, rotations: np.ndarray) -> np.ndarray:
    """|fields - ldf_3d| at these rotations, on 100 of the map's candidate translations."""
    from ldlloc.search import ldf

    m = loc.map
    x = ldf.query_points(1)
    sel = np.linspace(0, len(m.translations) - 1, 100).astype(int)
    ref = ldf.ldf_3d(x, rotations, m.translations[sel], m.lines, m.line_groups)
    got = loc.fields.ldf_3d(x, rotations).permute(3, 0, 2, 1).float()[sel]
    return (got - ref).abs().flatten().numpy()


def run_queries(ds, locs: dict, max_queries: int) -> tuple[list[dict], np.ndarray]:
    """Every query of every split (at most ``max_queries``, 0: all): rows and interpolation errors."""
    from ldlmap.core.errors import InputError

    rows: list[dict] = []
    errs: list[np.ndarray] = []
    for split in ds.splits():
        for scene in ds.scenes():
            for q in ds.queries(split, scene):
                if max_queries and len(rows) >= max_queries:
                    break
                try:
                    row, rotations = search_query(locs[scene], q)
                except InputError:  # no candidate rotation: not searched
                    continue
                rows.append(dict(split=split, scene=scene, **row))
                if len(errs) < 24:  # interpolation error at this query's rotations
                    errs.append(interpolation_error(locs[scene], rotations))
    if not rows:
        sys.exit("no query could be searched")
    return rows, np.concatenate(errs)


def stage_table(con, rows: list[dict], n_t: int) -> tuple[dict, dict]:
    """The median and p90 seconds per stage beside the paper's; returns both."""
    from rich.table import Table
    from ldlloc.search.pose_search import SearchParams

    med = {k: float(np.median([r[k] for r in rows])) for k in
           ("lines2d", "rotation", "search_exact", "search_fields", "search_fast", "rescore", "pose_search_fields",
            "pose_search")}
    p90 = {k: float(np.percentile([r[k] for r in rows], 90)) for k in med}
    t = Table(title=f"Pose search over {len(rows)} synthetic queries (1024x512), N_t ~ {n_t}, "
                    f"median N_r = {int(np.median([r['rotations'] for r in rows]))}, |Q| = 42")
    for col in ("stage", "median s", "p90 s", "paper CPU s", "paper GPU s"):
        t.add_column(col, justify="right" if col != "stage" else "left")
    names = [("lines2d", "2D lines (LSD, arcs)", "lines2d"),
             ("rotation", "rotation stage (length filter, vanishing points, rotations)", "rotation"),
             ("search_exact", "search, exact ldf_3d", "search"),
             ("search_fields", "search, distance fields only (rescore=0)", "search"),
             ("search_fast", f"search, fields + exact re-scoring of {SearchParams().rescore}", "search"),
             ("rescore", "  re-scoring added (per-query difference)", ""),
             ("pose_search_fields", "pose search = rotation + fields only", None),
             ("pose_search", "pose search = rotation + fields + re-scoring", None)]
    for key, label, paper in names:
        pc, pg = PAPER[paper] if paper else (PAPER["rotation"][0] + PAPER["search"][0],
                                              PAPER["rotation"][1] + PAPER["search"][1])
        paper_cols = ("", "") if paper == "" else (f"{pc:.3f}", f"{pg:.3f}")
        t.add_row(label, f"{med[key]:.4f}", f"{p90[key]:.4f}", *paper_cols)
    con.print(t)
    return med, p90


def agreement_table(con, rows: list[dict], err: np.ndarray) -> dict:
    """How well the fast variants keep the exact ranking, and their accuracy; returns the fractions."""
    from rich.table import Table

    agreement = {f"{tag}_{k}": float(np.mean([r[f"{tag}_{k}"] for r in rows]))
                 for tag in ("fields", "rescored") for k in ("top1", "top3", "top20", "same_top1_loss", "same_losses")}
    a = Table(title="Fast vs exact ranking (fraction of queries)")
    for col in ("measure", "fields only", "fields + re-scoring", "exact"):
        a.add_column(col, justify="right" if col != "measure" else "left")
    for k, lab in (("top1", "exact best pose is the fast first"), ("top3", "exact best pose in fast top 3"),
                   ("top20", "exact best pose in fast top 20"), ("same_top1_loss", "same top-1 loss"),
                   ("same_losses", "same top-20 losses")):
        a.add_row(lab, f"{agreement['fields_' + k]:.3f}", f"{agreement['rescored_' + k]:.3f}", "")
    for k, lab in (("top20_ok", "a top-20 pose within 0.5 m, 10 deg"), ("top1_ok", "top-1 pose within 0.5 m, 10 deg")):
        a.add_row(lab, *[f"{np.mean([r[f'{tag}_{k}'] for r in rows]):.3f}" for tag in ("fields", "fast", "exact")])
    a.add_row("interpolation error mean / p95 / p99 / max (rad)",
              f"{err.mean():.4f} / {np.percentile(err, 95):.4f} / {np.percentile(err, 99):.4f} / {err.max():.4f}")
    con.print(a)
    return agreement


def memory_tables(con, maps: dict, map_paths: dict, field_secs: dict, prep_s: float, n_t: int,
                  rows_g: int) -> tuple[dict, dict]:
    """The look-up table's memory, the map file's size and the fast search's scaling with N_t."""
    from rich.table import Table
    from ldlmap.map.fields3d import field_bytes

    sizes = {s: Path(p).stat().st_size / 1e6 for s, p in map_paths.items()}
    stored = {s: maps[s].fields["distances"].nbytes / 1e6 for s in maps}
    mem = Table(title=f"Memory and map size (grid G = {rows_g}: {rows_g + 1} x {2 * rows_g} nodes, float16)")
    mem.add_column("measure")
    mem.add_column("value", justify="right")
    mem.add_row(f"look-up table, N_t = {n_t}", f"{field_bytes(n_t, rows_g) / 1e6:.1f} MB")
    mem.add_row("look-up table, N_t = 1700", f"{field_bytes(1700, rows_g) / 1e6:.1f} MB")
    mem.add_row("fields in the map file (uncompressed / whole map gzip)",
                f"{np.mean(list(stored.values())):.1f} MB / {np.mean(list(sizes.values())):.1f} MB")
    mem.add_row("fields build stage (s per map, when built now)",
                ", ".join(f"{v:.1f}" for v in field_secs.values()) or "cached")
    mem.add_row("table preparation at map load (s)", f"{prep_s:.3f}")
    con.print(mem)
    sc = Table(title="Fast search scaling with N_t (look-up + inlier loss + top 20; "
                     "N_r = 30, |Q| = 42, random tables)")
    for col in ("N_t", "table MB", "median s"):
        sc.add_column(col, justify="right")
    scaling = {}
    for n in (800, 1700, 5000):
        scaling[n] = _scaling_seconds(n, rows_g)
        sc.add_row(str(n), f"{field_bytes(n, rows_g) / 1e6:.0f}", f"{scaling[n]:.4f}")
    con.print(sc)
    return sizes, scaling


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", type=Path, default=None, help="OmniScenes-layout dataset (default: demo, cached)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the generated demo dataset")
    ap.add_argument("--threads", type=int, default=DEFAULT_THREADS,
                    help=f"CPU threads of torch and OpenCV (default {DEFAULT_THREADS}, as ldlloc runs; 0: the libraries')")
    ap.add_argument("--max-queries", type=int, default=0, help="stop after this many queries (0: all)")
    ap.add_argument("--json", type=Path, default=None, help="write the numbers here")
    args = ap.parse_args()

    import torch

    from ldlmap.datasets import open_dataset
    from ldlmap.map.fields3d import field_bytes
    from ldlmap.map.mapfile import read_map
    from ldlloc.pipeline import LocalizeParams, Localizer

    common.set_threads(args.threads)
    cache = Path(os.environ.get("LDL_BENCH_CACHE", ROOT / "bench" / ".cache")) / "search"
    root, map_paths, field_secs = _prepare(args.root, cache, args.seed)
    ds = open_dataset(root, "omniscenes")
    maps = {s: read_map(p, load_cloud=False) for s, p in map_paths.items()}
    t0 = time.perf_counter()
    locs = {s: Localizer(m, LocalizeParams(do_refine=False)) for s, m in maps.items()}  # prepares the fields
    prep_s = (time.perf_counter() - t0) / max(1, len(maps))
    if any(loc.fields is None for loc in locs.values()):
        sys.exit("a map has no distance fields: delete bench/.cache/search/maps and rerun")
    rows, err = run_queries(ds, locs, args.max_queries)
    n_t = int(np.median([len(m.translations) for m in maps.values()]))
    rows_g = int(next(iter(maps.values())).fields_attrs.get("rows", 64))
    con = common.console()
    med, p90 = stage_table(con, rows, n_t)
    agreement = agreement_table(con, rows, err)
    sizes, scaling = memory_tables(con, maps, map_paths, field_secs, prep_s, n_t, rows_g)
    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    con.print(f"torch threads {torch.get_num_threads()}, CPU count {os.cpu_count()}, "
              f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    if args.json:
        args.json.write_text(json.dumps({
            "median_seconds": med, "p90_seconds": p90, "agreement": agreement,
            "interpolation_error": {"mean": float(err.mean()), "p95": float(np.percentile(err, 95)),
                                    "p99": float(np.percentile(err, 99)), "max": float(err.max())},
            "table_mb": {str(n_t): field_bytes(n_t, rows_g) / 1e6, "1700": field_bytes(1700, rows_g) / 1e6},
            "map_mb": sizes, "scaling_seconds": scaling, "threads": torch.get_num_threads(), "load": load,
            "queries": rows}, indent=1))


if __name__ == "__main__":
    main()
