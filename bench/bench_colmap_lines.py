"""Benchmark: 3D lines of a COLMAP model from its photos (ldlmap.sfm.photo_lines), stages and accuracy.

Usage: ``python bench/bench_colmap_lines.py [--seeds 10,5,0] [--photos 24] [--width 640]
[--model DIR --images DIR] [--no-map]``

Per seed: a demo-preset room photographed by :func:`ldlmap.synth.sfm.write_colmap_workspace`
(pinhole photos, a sparse model with tracks and far outliers, no ``fused.ply``; cached in
``bench/.cache``), then :func:`reconstruct_lines` with its per-stage seconds, and:

- precision: share of the reconstructed lines longer than the map's length threshold
  (0.1 x the mean extent of the true edges) that are true mesh edges
  (:func:`ldlmap.lines3d.line_precision_recall`: 70 % within 5 cm and 5 deg);
- on-surface: share of all reconstructed lines lying on the mesh (4 of 5 samples within 3 cm),
  texture and poster lines included, which are real 3D lines but not mesh edges;
- recall: share of the long true edges that three photos see (two: in brackets) that are found;
- the map build from the workspace (``build_map``, lines-only, features none) per stage;
- ``--queries N`` (default 6) upright panoramas rendered in the room (the robot split's poses)
  localized against that map (``ldlloc``, geometric refinement) and against a lines-only map of
  the room's true edges built the same way: accuracy at 0.1 m / 5 deg and median errors.

``--model``/``--images``: a real COLMAP model and its photos instead (timings and counts only).
Seeds 10 and 5 are rooms with plaster walls and carpet; seed 0 has wallpaper and parquet (texture
lines lower the precision against mesh edges, not the on-surface share).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import CACHE, synth_tag  # noqa: E402


def workspace(seed: int, photos: int, width: int):
    """The synthetic COLMAP workspace of ``random_spec('demo', seed)`` and its truth (cached)."""
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.sfm import SfmCapture, seen_edges, write_colmap_workspace
    from ldlmap.synth.presets import random_spec

    mesh = build_scene(random_spec("demo", seed))
    cap = SfmCapture(num_images=photos, width=width, height=width * 3 // 4, seed=seed)
    out = CACHE / f"colmap_s{seed}_n{photos}_w{width}_{synth_tag()}"
    edges = mesh_edges(mesh)
    if not (out / "truth.npz").exists():
        t = time.perf_counter()
        sfm = write_colmap_workspace(mesh, out, cap)
        print(f"seed {seed}: workspace written in {time.perf_counter() - t:.1f} s "
              f"({sfm.num_points} points + {sfm.num_outliers} outliers)")
        np.savez(out / "truth.npz", seen2=seen_edges(mesh, edges, sfm, cap, 2), seen3=seen_edges(mesh, edges, sfm, cap, 3))
    truth = np.load(out / "truth.npz")
    return out, mesh, edges, truth["seen2"], truth["seen3"]


def on_surface(mesh, lines: np.ndarray, tol: float = 0.03) -> float:
    from ldlmap.synth.render import Renderer

    if len(lines) == 0:
        return 0.0
    s = np.linspace(0.1, 0.9, 5)
    P = (lines[:, None, 0] + s[None, :, None] * (lines[:, None, 1] - lines[:, None, 0])).reshape(-1, 3)
    return float(((Renderer(mesh).distance(P).reshape(len(lines), -1) <= tol).mean(1) >= 0.8).mean())


def build_seconds(ws: Path, images: Path | None, out: Path) -> tuple[dict, dict]:
    from ldlmap.map.build import BuildParams, build_map

    rep = build_map(ws, out, params=BuildParams().replaced(features="none"), images_path=images)
    return rep.seconds, rep.counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="10,5,0")
    ap.add_argument("--photos", type=int, default=24)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--model", type=Path, default=None, help="a real COLMAP model (folder or workspace)")
    ap.add_argument("--images", type=Path, default=None, help="its photos (default: the workspace's images folder)")
    ap.add_argument("--no-map", action="store_true", help="skip the map build (and the localization)")
    ap.add_argument("--queries", type=int, default=6, help="panoramas localized against each map (0: none)")
    args = ap.parse_args()

    from ldlmap.io.colmap import find_images_dir, read_colmap_views, resolve_model_dir
    from ldlmap.lines3d import line_precision_recall
    from ldlmap.sfm.photo_lines import reconstruct_lines

    stages = ("read", "segments", "triangulate", "score", "merge")
    head = f"{'input':>10} {'photos':>6} {'segs':>5} {'cands':>6} {'lines':>5} " + " ".join(f"{s + '_s':>13}" for s in stages)
    if args.model is not None:
        model = resolve_model_dir(args.model)
        if model is None:
            sys.exit(f"error: not a COLMAP model: {args.model}")
        cv = read_colmap_views(model)
        images = args.images or find_images_dir(model, [v.name for v in cv.views])
        if images is None:
            sys.exit(f"error: photos not found beside {model}: pass --images")
        res = reconstruct_lines(cv, images)
        print(head)
        _row("model", res, stages)
        if not args.no_map:
            sec, counts = build_seconds(args.model, args.images, CACHE / "colmap_model.h5")
            print("map build:", " ".join(f"{k} {v:.2f}" for k, v in sec.items()), counts)
        return

    print(head + f" {'prec':>5} {'on-surf':>7} {'recall':>6} {'(2 photos)':>10} {'long':>5}")
    for seed in (int(s) for s in args.seeds.split(",")):
        ws, mesh, edges, seen2, seen3 = workspace(seed, args.photos, args.width)
        res = reconstruct_lines(ws / "sparse" / "0", ws / "images")
        L = res.lines
        thr = 0.1 * np.mean(np.ptp(edges.reshape(-1, 3), axis=0))
        long_pred = L[np.linalg.norm(L[:, 1] - L[:, 0], axis=1) > thr]
        long_true = np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1) > thr
        precision = line_precision_recall(long_pred, edges)[0]
        r3 = line_precision_recall(L, edges[seen3 & long_true])[1]
        r2 = line_precision_recall(L, edges[seen2 & long_true])[1]
        _row(f"seed {seed}", res, stages, f" {precision:>5.2f} {on_surface(mesh, L):>7.2f} {r3:>6.2f} {r2:>10.2f} "
                                          f"{len(long_pred):>5}")
        if not args.no_map:
            out = CACHE / f"colmap_s{seed}.h5"
            sec, counts = build_seconds(ws, None, out)
            print(f"{'':>10} map build (lines-only, features none): " + ", ".join(f"{k} {v:.2f}" for k, v in sec.items())
                  + f" s; {counts['lines']} lines kept, {counts['translations']} translations")
            if args.queries:
                localize_table(mesh, edges, out, args.queries, seed)


def localize_table(mesh, edges: np.ndarray, map_path: Path, n: int, seed: int) -> None:
    """Localize ``n`` rendered upright panoramas against the reconstructed-lines map and a map of
    the true edges (same candidate spacing)."""
    from ldlloc.pipeline import LocalizeParams, Localizer
    from ldlmap.map.build import BuildParams, build_lines_map
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.map.mapfile import read_map
    from ldlmap.synth.poses import sample_poses
    from ldlmap.synth.render import Renderer

    renderer = Renderer(mesh)
    poses = sample_poses(mesh, "robot", n, np.random.default_rng(seed), renderer=renderer)
    images = [renderer.render(R, t, 1024, 512).rgb for R, t in poses]
    true_map = CACHE / f"colmap_s{seed}_true_edges.h5"
    build_lines_map(edges, true_map, BuildParams().replaced(features="none"), name="true_edges")
    for name, path in (("photo lines", map_path), ("true edges", true_map)):
        loc = Localizer(read_map(path), LocalizeParams())
        err, secs = [], []
        for (R, t), img in zip(poses, images):
            tic = time.perf_counter()
            out = loc.localize(img)
            secs.append(time.perf_counter() - tic)
            err.append((np.linalg.norm(out.center - t), rotation_error_deg(out.rot_cam_from_world, R)))
        e = np.array(err)
        ok = np.mean((e[:, 0] < 0.1) & (e[:, 1] < 5))
        print(f"{'':>10} localize {n} panoramas, {name} map: {ok:.2f} within 0.1 m / 5 deg, median "
              f"{np.median(e[:, 0]):.3f} m / {np.median(e[:, 1]):.2f} deg, {np.median(secs):.2f} s per query")


def _row(name: str, res, stages, extra: str = "") -> None:
    c = res.counts
    print(f"{name:>10} {c['photos']:>6} {c['segments']:>5} {c['candidates']:>6} {c['lines']:>5} "
          + " ".join(f"{res.seconds.get(s, 0.0):>13.3f}" for s in stages) + extra)


if __name__ == "__main__":
    main()
