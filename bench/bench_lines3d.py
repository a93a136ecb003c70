"""Benchmark: 3D line extraction on synthetic rooms, stages, precision / recall per seed.

Usage: ``python bench/bench_lines3d.py [--synth] [--seeds 0,1,2,3,4,5] [--preset demo] [--points N]``
(``--synth``: only the synthetic rooms; ``--points N``: only the ``N``-point box room; neither:
both, with a 1 M point box room).

For each seed: ``random_spec(preset, seed)`` -> ``build_scene`` -> the simulated scan with the
preset's defaults (5 mm noise) -> :func:`extract_lines` -> length filter, then precision (against
all true mesh edges) and recall (against the true edges longer than the length threshold, the
issue's "Must show" metric). Because a scan only sees what its stations see, it also prints the
recall against the *observable* long edges (at least 70 % of the edge within 3 cm of a scan
point) and the share of long edges that are observable at all (an upper bound on recall), and
the recall per kind of edge (room shell, door/window frames, furniture kinds), the number of
lines above the length threshold and the kept ratio (the share of raw lines the length filter
keeps, which the 2D line filter matches), the extraction's wall and process CPU seconds (all
threads: what compares with a single-threaded tool) and, at the end, the CPU seconds per stage.
The box room (tests/_room_cloud.py) gives the timings
of the extraction stages and of the downstream stages (principal directions, candidate
translations) on a large cloud.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def synth_room(preset: str, seed: int) -> dict:
    """Scan, true edges and an edge kind per edge ('shell', 'frame' or the furniture kind)."""
    import open3d as o3d

    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scan import sample_scan
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.presets import random_spec

    spec = random_spec(preset, seed)
    mesh = build_scene(spec)
    t = time.perf_counter()
    P, _ = sample_scan(mesh, spec.scan, np.random.default_rng(seed))
    scan_s = time.perf_counter() - t
    E = mesh_edges(mesh)
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                     o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    tri = rs.compute_closest_points(o3d.core.Tensor(E.mean(1).astype(np.float32)))["primitive_ids"].numpy()
    obj, part = mesh.tri_object[tri], mesh.tri_part[tri]
    kind = np.array([("shell" if p == 0 else "frame") if o < 0 else spec.objects[o].kind for o, p in zip(obj, part)])
    return dict(points=P, edges=E, kind=kind, scan_s=scan_s)


def observable(edges: np.ndarray, points: np.ndarray, radius: float = 0.03, cover: float = 0.7) -> np.ndarray:
    """Edges with at least ``cover`` of their length within ``radius`` of a scan point."""
    from scipy.spatial import cKDTree

    from ldlmap.lines3d.metrics import sample_segments

    x, seg = sample_segments(edges, 0.01)
    d, _ = cKDTree(points).query(x, distance_upper_bound=radius, workers=-1)
    return np.bincount(seg, np.isfinite(d), len(edges)) / np.bincount(seg, minlength=len(edges)) >= cover


def found_mask(gt: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Per true edge: found by ``pred`` under the metric of :func:`line_precision_recall`."""
    from ldlmap.lines3d.metrics import covered_samples, sample_segments

    x, seg = sample_segments(gt, 0.01)
    d = gt[:, 1] - gt[:, 0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cov = covered_samples(x, d[seg], pred, 0.05, np.cos(np.radians(5.0)))
    return np.bincount(seg, cov, len(gt)) / np.bincount(seg, minlength=len(gt)) >= 0.7


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2,3,4,5")
    ap.add_argument("--preset", default="demo")
    ap.add_argument("--synth", action="store_true", help="only the synthetic rooms")
    ap.add_argument("--points", type=int, default=0, help="only a box room of this many points")
    args = ap.parse_args()
    synth = args.synth or not args.points
    box_points = args.points or (0 if args.synth else 1_000_000)
    if synth:
        synth_table(args.preset, [int(s) for s in args.seeds.split(",")])
    if box_points:
        box_room_table(box_points)


def synth_table(preset: str, seeds: list[int]) -> None:
    """Per seed: counts, precision / recall, lines above the length threshold, timings."""
    from ldlmap.lines3d import extract_lines_with_stats, filter_by_length, line_precision_recall

    print(f"{'seed':>4} {'points':>8} {'proc':>7} {'planes':>6} {'raw':>5} {'kept':>5} {'ratio':>6} {'prec':>5} {'recall':>6} "
          f"{'obs':>5} {'rec|obs':>7} {'extract_s':>9} {'cpu_s':>6} {'planes_s':>8} {'pl_cpu':>6}  recall per kind (found/long)")
    allk: dict[str, list[int]] = {}
    cpu: list[dict] = []  # per seed: CPU seconds per stage
    for seed in seeds:
        r = synth_room(preset, seed)
        P, E = r["points"], r["edges"]
        t, c = time.perf_counter(), time.process_time()
        raw, st = extract_lines_with_stats(P)
        dt, dc = time.perf_counter() - t, time.process_time() - c
        cpu.append({k[:-6]: v for k, v in st.items() if k.endswith("_cpu_s")})
        kept, _, thr = filter_by_length(raw, P.min(0), P.max(0))
        long = np.linalg.norm(E[:, 1] - E[:, 0], axis=1) >= thr
        precision, _ = line_precision_recall(kept, E)
        _, recall = line_precision_recall(kept, E[long])
        f = found_mask(E[long], kept)
        obs = observable(E[long], P)
        kinds = r["kind"][long]
        per = []
        for k in sorted(set(kinds)):
            a = allk.setdefault(k, [0, 0, 0])
            a[0] += int(f[kinds == k].sum())
            a[1] += int((kinds == k).sum())
            a[2] += int(obs[kinds == k].sum())
            per.append(f"{k} {f[kinds == k].sum()}/{(kinds == k).sum()}")
        print(f"{seed:>4} {len(P):>8} {st['points_processed']:>7} {st['planes']:>6} {len(raw):>5} {len(kept):>5} "
              f"{len(kept) / max(len(raw), 1):>6.1%} {precision:>5.3f} "
              f"{recall:>6.3f} {obs.mean():>5.2f} {f[obs].mean():>7.3f} {dt:>9.1f} {dc:>6.1f} {st['planes_s']:>8.1f} "
              f"{st['planes_cpu_s']:>6.1f}  "
              + ", ".join(per), flush=True)
    print("per kind over all seeds: found / long / observable: "
          + ", ".join(f"{k} {a[0]}/{a[1]}/{a[2]}" for k, a in sorted(allk.items())))
    print("CPU s per stage, mean over seeds: "
          + ", ".join(f"{k} {np.mean([c[k] for c in cpu]):.2f}" for k in cpu[0]))


def box_room_table(points: int) -> None:
    """Stage timings on a box room of ``points`` points (tests/_room_cloud.py)."""
    from ldlmap.lines3d import extract_lines_with_stats, filter_by_length, line_precision_recall
    from ldlmap.lines3d.principal import principal_directions_3d
    from ldlmap.map.translations import candidate_translations
    from tests._room_cloud import box_room

    density = points / (2 * (8 * 6 + 8 * 3 + 6 * 3) + 4)
    P, E = box_room(seed=0, size=(8.0, 6.0, 3.0), n_boxes=4, density=density, yaw_deg=20.0)
    t = time.perf_counter()
    raw, st = extract_lines_with_stats(P)
    rows = [(k, v) for k, v in st.items() if k.endswith("_s")] + [("extract_lines total", time.perf_counter() - t)]
    kept, _, _ = filter_by_length(raw, P.min(0), P.max(0))
    t = time.perf_counter()
    principal_directions_3d(kept)
    rows.append(("principal directions (k=3)", time.perf_counter() - t))
    for method, num in (("octree", 800), ("grid", 1700)):
        t = time.perf_counter()
        C = candidate_translations(P, num=num, method=method)
        rows.append((f"translations {method} N_t={num} (got {len(C)})", time.perf_counter() - t))
    p, r_ = line_precision_recall(kept, E)
    print(f"box room: {len(P)} points, precision {p:.3f}, recall {r_:.3f}")
    for name, sec in rows:
        print(f"  {name:<40} {sec:7.2f}")


if __name__ == "__main__":
    main()
