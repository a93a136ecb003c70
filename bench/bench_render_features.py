"""Benchmark: map-view rendering, feature extraction and back-projection per view.

Prints median seconds per stage over several translations for a ~1 M point colored cloud at
1024 x 512. Run: ``python bench/bench_render_features.py [--points N] [--views K] [--device cpu]
[--source synth|box] [--superpoint]``.

``--source synth`` scans the synthetic demo room (``ldlmap.synth``; falls back to ``box`` when
unavailable); ``box`` is a textured box room sampled uniformly at random (numpy only).
``--superpoint`` also times SuperPoint with random weights (timing only, no official weights
are needed for that).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def _box_room(n: int, size=(6.0, 5.0, 3.0), seed: int = 0):
    rng = np.random.default_rng(seed)
    s = np.asarray(size)
    areas = np.array([s[0] * s[1]] * 2 + [s[0] * s[2]] * 2 + [s[1] * s[2]] * 2)
    face = rng.choice(6, n, p=areas / areas.sum())
    P = rng.random((n, 3)) * s
    axis = face // 2
    P[np.arange(n), axis] = np.where(face % 2 == 0, 0.0, s[axis])
    cell = np.floor(P / 0.15).astype(np.int64)
    h = (cell[:, 0] * 73856093 ^ cell[:, 1] * 19349663 ^ cell[:, 2] * 83492791) % 100003
    lut = np.random.default_rng(seed + 1).integers(0, 256, (100003, 3), dtype=np.uint8)
    lo, hi = np.array([0.6, 0.6, 0.8]), s - np.array([0.6, 0.6, 1.0])
    return P, lut[h], (lo, hi), "box room (uniform random samples)"


def _synth_room(n: int, seed: int = 0):

    from ldlmap.synth.generate import load_specs
    from ldlmap.synth.scan import ScanParams, mesh_area, sample_scan
    from ldlmap.synth.scene import build_scene

    _, spec = load_specs("demo", [], seed)[0]
    mesh = build_scene(spec)
    params = ScanParams(density=n / mesh_area(mesh) * 1.05, max_points=n)
    pts, cols = sample_scan(mesh, params, np.random.default_rng(seed))
    lo, hi = pts.min(0) + [1.0, 1.0, 1.0], pts.max(0) - [1.0, 1.0, 1.2]
    return pts, cols, (lo, hi), f"synthetic demo room ({len(pts)} scanned points)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--source", choices=["synth", "box"], default="synth")
    ap.add_argument("--superpoint", action="store_true")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch default)")
    args = ap.parse_args()

    import torch

    from ldlmap.features import get_backend
    from ldlmap.map.keypoints3d import backproject_keypoints
    from ldlmap.map.render import PointRenderer, RenderParams

    if args.threads:
        torch.set_num_threads(args.threads)
    if args.source == "synth":
        try:
            P, C, (lo, hi), what = _synth_room(args.points)
        except Exception as exc:  # noqa: BLE001 - the generator is optional for this bench
            print(f"synthetic scene unavailable ({type(exc).__name__}: {exc}); using the box room")
            P, C, (lo, hi), what = _box_room(args.points)
    else:
        P, C, (lo, hi), what = _box_room(args.points)
    rng = np.random.default_rng(0)
    centers = lo + rng.random((args.views, 3)) * (hi - lo)

    t0 = time.perf_counter()
    renderer = PointRenderer(P, C, RenderParams(width=1024, height=512), device=args.device)
    t_setup = time.perf_counter() - t0
    renderer.render(np.eye(3), centers[0])  # warm-up
    backends = {"sift": get_backend("sift", device=args.device)}
    if args.superpoint:
        from ldlmap.features.superpoint import SuperPointBackend, build_superpoint

        torch.manual_seed(0)
        backends["superpoint (random weights)"] = SuperPointBackend(net=build_superpoint(), device=args.device)

    rows: dict[str, list[float]] = {"render": []}
    counts: dict[str, list[int]] = {}
    holes = []
    for c in centers:
        t0 = time.perf_counter()
        view = renderer.render(np.eye(3), c)
        rows["render"].append(time.perf_counter() - t0)
        holes.append(float(np.isnan(view.depth).mean()))
        for name, b in backends.items():
            t0 = time.perf_counter()
            f = b.extract(view.rgb, mask=np.isfinite(view.depth))
            rows.setdefault(f"{name}: extract", []).append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            _, valid = backproject_keypoints(f.keypoints, view.xyz)
            rows.setdefault(f"{name}: back-project", []).append(time.perf_counter() - t0)
            counts.setdefault(name, []).append(int(valid.sum()))

    print(f"scene: {what}; {len(P)} points; spacing {renderer.spacing * 100:.2f} cm; 1024 x 512; "
          f"device {args.device}; torch threads {torch.get_num_threads()}; {args.views} views")
    print(f"renderer setup (upload + spacing estimate): {t_setup:.3f} s; empty pixels median "
          f"{100 * np.median(holes):.2f} %")
    print(f"{'stage':40s} {'median s':>9s} {'max s':>9s}")
    for k, v in rows.items():
        print(f"{k:40s} {np.median(v):9.3f} {np.max(v):9.3f}")
    for name, n in counts.items():
        total = np.median(rows["render"]) + np.median(rows[f"{name}: extract"]) + np.median(rows[f"{name}: back-project"])
        print(f"{name}: {int(np.median(n))} keypoints with 3D per view (median); total per view {total:.3f} s")


if __name__ == "__main__":
    main()
