"""Benchmark: 3D line extraction stages, length filter, principal directions and candidate
translations on a ~1 M point room-like cloud.

Usage: ``python bench/bench_lines3d.py [--points 1000000] [--synth]``. By default the cloud is a
sampled box room with furniture (5 mm noise, tests/_room_cloud.py); ``--synth`` uses the synthetic
scene generator (``ldlmap.synth``: demo preset, simulated scan) and its true mesh edges. Prints a
table of seconds per stage and the precision / recall against the true edges.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def make_cloud(points: int, synth: bool, seed: int) -> tuple[np.ndarray, np.ndarray]:
    if synth:
        from dataclasses import replace

        from ldlmap.synth.edges import mesh_edges
        from ldlmap.synth.scan import ScanParams, mesh_area, sample_scan
        from ldlmap.synth.scene import build_scene
        from ldlmap.synth.spec import random_spec

        mesh = build_scene(random_spec("demo", seed))
        params = replace(ScanParams(), density=points / mesh_area(mesh) * 1.05, max_points=points)
        P, _ = sample_scan(mesh, params, np.random.default_rng(seed))
        return P, mesh_edges(mesh)
    from tests._room_cloud import box_room

    density = points / (2 * (8 * 6 + 8 * 3 + 6 * 3) + 4)  # about the sampled area of the room
    return box_room(seed=seed, size=(8.0, 6.0, 3.0), n_boxes=4, density=density, yaw_deg=20.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--synth", action="store_true", help="use ldlmap.synth (demo preset) instead of a box room")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from ldlmap.lines3d import extract_lines_with_stats, filter_by_length, line_precision_recall
    from ldlmap.principal3d import principal_directions_3d
    from ldlmap.translations import candidate_translations

    P, E = make_cloud(args.points, args.synth, args.seed)
    rows = []
    t = time.perf_counter()
    raw, st = extract_lines_with_stats(P)
    total = time.perf_counter() - t
    rows += [("planes (downsample, normals, regions)", st["planes_s"]), ("plane boundaries", st["boundary_s"]),
             ("plane intersections", st["intersections_s"]), ("collinear merge", st["merge_s"]),
             ("extract_lines total", total)]
    t = time.perf_counter()
    kept, mask, thr = filter_by_length(raw, P.min(0), P.max(0))
    rows.append(("length filter", time.perf_counter() - t))
    t = time.perf_counter()
    principal_directions_3d(kept)
    rows.append(("principal directions (k=3)", time.perf_counter() - t))
    for method, num in (("octree", 800), ("grid", 1700)):
        t = time.perf_counter()
        C = candidate_translations(P, num=num, method=method)
        rows.append((f"translations {method} N_t={num} (got {len(C)})", time.perf_counter() - t))
    gt_long = E[np.linalg.norm(E[:, 1] - E[:, 0], axis=1) >= thr]
    precision, _ = line_precision_recall(kept, E)
    _, recall = line_precision_recall(kept, gt_long)

    print(f"cloud: {len(P)} points ({'synthetic demo scan' if args.synth else 'box room'}), "
          f"{st['points_processed']} after downsampling, {st['planes']} planes")
    print(f"lines: {len(raw)} raw ({st['boundary_segments']} boundary + {st['intersection_segments']} intersection "
          f"pieces before merge), {len(kept)} kept, threshold {thr:.3f} m, kept ratio {mask.mean():.3f}")
    print(f"vs true edges: precision {precision:.3f}, recall {recall:.3f} ({len(gt_long)} edges >= threshold)")
    w = max(len(r[0]) for r in rows)
    print(f"{'stage':<{w}}  seconds")
    for name, sec in rows:
        print(f"{name:<{w}}  {sec:7.3f}")


if __name__ == "__main__":
    main()
