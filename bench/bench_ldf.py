"""Benchmark of the ldlloc core: 2D line extraction, vanishing points + rotations, ldf_3d + loss.

Prints a table of median seconds. Run: ``python bench/bench_ldf.py [--device cpu|cuda]``.
Workload (the paper's runtime setting): N_t = 800 translations, N_r = 30 rotations, |Q| = 42, ~300 3D lines,
a 1024 x 512 synthetic panorama of a textured box room.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _median_time(fn, repeat: int) -> tuple[float, object]:
    out, ts = None, []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), out


def _textured_room(width: int = 1024, height: int = 512, seed: int = 0):
    """Box-room panorama with rectangles (posters, frames) on the faces; returns image, R, t, lines."""
    import cv2

    from ldlmap.core.geometry import bearing_from_pixel, pixel_centers, rotation_from_axis_angle

    rng = np.random.default_rng(seed)
    lo, hi = np.array([-3.0, -2.0, 0.0]), np.array([3.0, 2.0, 3.0])
    R = rotation_from_axis_angle(rng.normal(size=3), 0.6)
    t = np.array([0.5, -0.3, 1.4])
    d = bearing_from_pixel(pixel_centers(width, height), width, height) @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = (np.where(d > 0, hi, lo) - t) / d
    tt = np.where(np.isfinite(tt) & (tt > 0), tt, np.inf)
    axis = np.argmin(tt, axis=-1)
    hit = t + np.take_along_axis(tt, axis[..., None], -1) * d
    face = 2 * axis + (np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0)
    img = rng.integers(40, 220, 6)[face].astype(np.float64)
    lines = []
    for _ in range(60):  # axis-aligned rectangles on random faces
        ax = rng.integers(0, 3)
        side = rng.integers(0, 2)
        a, b = [k for k in range(3) if k != ax]
        c = rng.uniform(lo, hi)
        half = rng.uniform(0.1, 0.6, 2)
        on = (face == 2 * ax + side) & (np.abs(hit[..., a] - c[a]) < half[0]) & (np.abs(hit[..., b] - c[b]) < half[1])
        img = np.where(on, rng.integers(0, 255), img)
        corner = np.zeros((4, 3))
        corner[:, ax] = (lo, hi)[side][ax]
        corner[:, a] = c[a] + half[0] * np.array([-1, 1, 1, -1])
        corner[:, b] = c[b] + half[1] * np.array([-1, -1, 1, 1])
        lines += [[corner[k], corner[(k + 1) % 4]] for k in range(4)]
    img = cv2.GaussianBlur(img.astype(np.float32), (3, 3), 0)
    img = np.repeat(np.clip(img + rng.normal(scale=3, size=img.shape), 0, 255).astype(np.uint8)[..., None], 3, 2)
    return img, R, t, np.array(lines)


def main() -> None:
    import torch

    from ldlmap.core.geometry import rotation_error_deg
    from ldlloc.search import ldf
    from ldlloc import lines2d, rotation

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))
    rows = []

    img, R_true, t_true, lines3d = _textured_room()
    lines2d.detect_lines(img)  # warm the crop-map cache
    t_lines, arcs = _median_time(lambda: lines2d.detect_lines(img), args.repeat)
    rows.append(("2D line extraction (1024x512, 26 crops)", t_lines, f"{len(arcs)} arcs"))

    P3 = np.eye(3)
    t_vp, vps = _median_time(lambda: rotation.vanishing_points(arcs, 20), args.repeat)
    t_rot, cands = _median_time(lambda: rotation.candidate_rotations(vps, P3), args.repeat)
    err = min(rotation_error_deg(r, R_true) for r in cands.rotations) if len(cands) else float("nan")
    rows.append(("vanishing points (k=20)", t_vp, f"{len(vps)} VPs"))
    rows.append(("candidate rotations", t_rot, f"N_r={len(cands)}, best err {err:.2f} deg"))
    t_lab, labels = _median_time(lambda: rotation.labels_for_rotations(arcs, vps, cands.triplets), args.repeat)
    rows.append(("2D groups per rotation", t_lab, f"{labels.shape}"))

    dev = torch.device(args.device)
    rng = np.random.default_rng(1)
    L = 300
    lines = lines3d[rng.choice(len(lines3d), L, replace=len(lines3d) < L)]
    groups = np.argmax(np.abs(lines[:, 1] - lines[:, 0]), axis=1)
    T = rng.uniform([-2.5, -1.5, 0.3], [2.5, 1.5, 2.7], size=(800, 3))
    ridx = np.arange(30) % max(1, len(cands))  # exactly N_r = 30 (cycled if fewer candidates)
    Rs = cands.rotations[ridx] if len(cands) else np.repeat(np.eye(3)[None], 30, 0)
    labels = labels[ridx] if len(cands) else np.zeros((30, len(arcs)), np.int64)
    x = ldf.query_points(1, device=dev)
    Rt = torch.as_tensor(Rs, dtype=torch.float32, device=dev)
    Tt = torch.as_tensor(T, dtype=torch.float32, device=dev)
    Lt = torch.as_tensor(lines, dtype=torch.float32, device=dev)
    Gt = torch.as_tensor(groups, device=dev)
    f2d = ldf.decomposed_distance_2d(x, torch.as_tensor(arcs, dtype=torch.float32, device=dev),
                                     torch.as_tensor(labels, device=dev))

    def sync():
        if dev.type == "cuda":
            torch.cuda.synchronize()

    def run_f3d(chunk):
        f = ldf.ldf_3d(x, Rt, Tt, Lt, Gt, chunk=chunk)
        sync()
        return f

    best = None
    for chunk in (4, 16, 64):
        run_f3d(chunk)
        t_f3d, f3d = _median_time(lambda: run_f3d(chunk), max(1, args.repeat // 2))
        rows.append((f"ldf_3d N_t=800 N_r=30 Q=42 L=300 chunk={chunk}", t_f3d, ""))
        best = f3d
    for kind in ("inlier", "l1", "median"):
        t_loss, loss = _median_time(lambda: (ldf.pose_loss(f2d, best, kind=kind), sync())[0], args.repeat)
        rows.append((f"pose_loss {kind} (800 x 30)", t_loss, ""))
    t_top, _ = _median_time(lambda: ldf.top_k_poses(loss, 20), args.repeat)
    rows.append(("top-20 poses", t_top, ""))

    dev_name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else f"cpu ({args.threads} threads)"
    print(f"\nldlloc core benchmark on {dev_name}")
    w = max(len(r[0]) for r in rows)
    print(f"{'stage'.ljust(w)}  {'median s':>10}  notes")
    for name, sec, note in rows:
        print(f"{name.ljust(w)}  {sec:10.4f}  {note}")


if __name__ == "__main__":
    main()
