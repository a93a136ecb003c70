"""Benchmark: SfM-like Line3D++ maps: kept lines, principal directions, up axis.

Usage: ``python bench/bench_sfm.py [--seeds 0,1,2,3] [--preset demo] [--units 0.37] [--far 8] [--out DIR]
[--localize ROOT [--queries 5]] [--threads 1]``

For each seed: the true edges of ``random_spec(preset, seed)`` become an SfM-like Line3D++ file
(``tests/_sfm_lines.py``: edges cut into 5-35 cm pieces with 1 cm noise, 30 % short clutter, 8 far
outliers; then a random rotation, ``--units`` per metre and an offset), and ``ldlmap build`` runs
on it (``--scale 1/units``, lines only, no distance fields). Printed per scene, before (the
paper's filter on the min / max box, voted directions, the input frame kept: what ``build`` did
before its SfM handling; with the far outliers in the min / max box it keeps nothing and the build
fails, ``--far 0`` leaves them out) and after (``build`` now): raw and kept lines, the query's kept ratio, the
smallest angle between two principal directions, the largest angle of a voted direction to the
orthonormal frame, and the angle of the map's z axis to the true up.

``--localize ROOT`` (a synthetic dataset, e.g. ``ldlmap synth ROOT --preset demo --seed 7``): the
true edges of each scene (``gt_lines``) become an SfM-like file the same way (up = -y, 0.37 units
per metre, offset (5, -2, 1)); maps are built with the length filter's floor by count only
(``min_kept_length_share`` 0) and with the default floor by length share, and the first
``--queries`` robot panoramas of the scene are localized (geometric refinement); the pose is
taken in the input frame and compared with the truth there (errors in metres).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _min_pair_angle(P: np.ndarray) -> float:
    c = max(abs(float(P[i] @ P[j])) for i in range(3) for j in range(i))
    return float(np.degrees(np.arccos(min(c, 1.0))))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def before(segs: np.ndarray, scale: float, true_up: np.ndarray) -> dict:
    """The pipeline before the SfM handling: scaled input as is, min / max box, paper filter, voted directions."""
    from ldlloc.lines2d import query_keep_ratio
    from ldlmap.lines3d import filter_by_length
    from ldlmap.lines3d.principal import principal_directions_3d

    L = segs * scale
    P3 = L.reshape(-1, 3)
    kept, mask, _ = filter_by_length(L, P3.min(0), P3.max(0), 0.1)
    pair = _min_pair_angle(principal_directions_3d(kept)) if len(kept) else float("nan")  # 0 kept: build failed
    ratio = float(mask.mean())
    return {"kept": int(mask.sum()), "ratio": ratio, "query": query_keep_ratio(ratio) if ratio > 0 else float("nan"),
            "pair": pair, "dev": float("nan"), "up_err": _angle(np.array([0.0, 0.0, 1.0]), true_up)}


def after(path: Path, out: Path, scale: float, true_up: np.ndarray) -> dict:
    from ldlloc.lines2d import query_keep_ratio
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.core.frame import decompose
    from ldlmap.map.mapfile import read_map

    params = BuildParams().replaced(features="none", distance_fields=False, scale=scale, trans_spacing=1.0)
    report = build_map(path, out, params=params)
    m = read_map(out, load_cloud=False)
    _, R, _ = decompose(m.input_to_map)
    return {"kept": len(m.lines), "ratio": m.kept_ratio, "query": query_keep_ratio(m.kept_ratio),
            "pair": _min_pair_angle(m.principal_directions), "dev": max(m.config["principal_deviation_deg"]),
            "up_err": _angle(R @ true_up, np.array([0.0, 0.0, 1.0])), "source": m.config["frame"]["up_source"],
            "warnings": len(report.warnings)}


def localize(root: Path, out: Path, queries: int) -> None:
    """SfM-like maps of a synthetic dataset's true edges; robot queries localized in the input frame."""
    from ldlloc.pipeline import LocalizeParams, Localizer, load_image
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.datasets import read_pose_txt
    from ldlmap.core.frame import pose_to_input, similarity
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.io.linefiles import read_lines
    from ldlmap.map.mapfile import read_map
    from tests._sfm_lines import rotation_with_up, sfm_like_lines, write_line3dpp_txt

    k, offset = 0.37, np.array([5.0, -2.0, 1.0])
    R0 = rotation_with_up(np.array([0.0, -1.0, 0.0]), 30.0)
    A_true = similarity(1 / k, R0.T, -R0.T @ offset / k)
    print(f"\nlocalization, robot queries of {root} (first {queries} per scene), pose in the input frame")
    print(f"{'scene':12s} {'floor':>9s} {'kept':>10s} | within 0.1 m / 5 deg | 0.5 m / 10 deg | median error")
    for gt in sorted((root / "gt_lines").glob("*.txt")):
        scene = gt.stem
        path = write_line3dpp_txt(out / f"{scene}_sfm.txt", sfm_like_lines(read_lines(gt), np.random.default_rng(0),
                                                                              R0, k, offset))
        images = sorted((root / "robot_pano").rglob(f"*{scene}_scene*/*.jpg"))[:queries]
        for label, share in (("count", 0.0), ("length", BuildParams().lines.min_kept_share)):
            params = BuildParams().replaced(features="none", scale=1 / k, trans_spacing=0.4, min_kept_length_share=share)
            build_map(path, out / f"{scene}_{label}.h5", params=params)
            m = read_map(out / f"{scene}_{label}.h5", load_cloud=False)
            loc = Localizer(m, LocalizeParams())
            err = []
            for img in images:
                R, t = read_pose_txt(Path(str(img).replace("_pano", "_pose")).with_suffix(".txt"))
                R_true, t_true = pose_to_input(R, t, A_true)
                R_in, t_in = loc.localize(load_image(img)).input_frame_pose()
                err.append((np.linalg.norm(t_in - t_true) / k, rotation_error_deg(R_in, R_true)))
            e = np.array(err).reshape(-1, 2)
            print(f"{scene:12s} {label:>9s} {len(m.lines):4d} / {len(m.lines_raw):4d} | "
                  f"{int(np.sum((e[:, 0] < 0.1) & (e[:, 1] < 5))):2d} / {len(e)} | "
                  f"{int(np.sum((e[:, 0] < 0.5) & (e[:, 1] < 10))):2d} / {len(e)} | "
                  f"{np.median(e[:, 0]):.3f} m {np.median(e[:, 1]):.2f} deg")


def main(argv: list[str] | None = None) -> int:
    from scipy.spatial.transform import Rotation

    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.presets import random_spec
    from tests._sfm_lines import sfm_like_lines, write_line3dpp_txt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--preset", default="demo")
    ap.add_argument("--units", type=float, default=0.37, help="input units per metre")
    ap.add_argument("--far", type=int, default=8, help="far outlier segments per scene")
    ap.add_argument("--out", type=Path, default=None, help="keep the line files and maps here")
    ap.add_argument("--localize", type=Path, default=None, help="synthetic dataset root: localize its robot queries")
    ap.add_argument("--queries", type=int, default=5, help="robot queries per scene (--localize)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (1 on a busy machine)")
    a = ap.parse_args(argv)
    from bench.common import load_line, machine_info, set_threads

    set_threads(a.threads)
    print(load_line(machine_info()))
    out = a.out or Path(tempfile.mkdtemp(prefix="bench_sfm_"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"{'scene':8s} {'raw':>5s} | {'kept':>11s} | {'kept ratio':>13s} | {'query ratio':>11s} | "
          f"{'min pair angle':>14s} | {'max dev':>7s} | {'up error deg':>13s} | source")
    for seed in (int(s) for s in a.seeds.split(",")):
        rng = np.random.default_rng(seed)
        edges = mesh_edges(build_scene(random_spec(a.preset, seed, 1)))
        R0 = Rotation.random(random_state=seed).as_matrix()
        segs = sfm_like_lines(edges, rng, R0, a.units, rng.uniform(-10, 10, 3), far_outliers=a.far)
        path = write_line3dpp_txt(out / f"sfm_{seed}.txt", segs)
        true_up = R0 @ np.array([0.0, 0.0, 1.0])
        b = before(segs, 1 / a.units, true_up)
        n = after(path, out / f"sfm_{seed}.h5", 1 / a.units, true_up)
        print(f"seed {seed:<3d} {len(segs):5d} | {b['kept']:4d} -> {n['kept']:4d} | {b['ratio']:.3f} -> {n['ratio']:.3f} | "
              f"{b['query']:.2f} -> {n['query']:.2f} | {b['pair']:5.1f} -> {n['pair']:5.1f} | {n['dev']:7.1f} | "
              f"{b['up_err']:5.1f} -> {n['up_err']:4.1f} | {n['source']} ({n['warnings']} warnings)")
    if a.localize is not None:
        localize(a.localize, out, a.queries)
    print(f"files in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
