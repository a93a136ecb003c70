"""A 360 video localized as a tracked walk against frame-by-frame single images.

Run: ``python bench/bench_video.py --root DEMO [--scene synthroom_1] [--frames 40] [--threads 2] [--device cpu|cuda]
[--single-every N]``.

``DEMO``: a synthetic dataset with maps (``ldlmap synth DEMO --preset demo`` then ``ldlmap prepare
DEMO``). A walk is rendered in one room from its mesh (a loop around the room's middle at a walking
speed of 1 m/s, 5 frames a second, the camera turning slowly, 1-2 degrees of tilt, motion blur
along the way), encoded as an mp4 (PyAV), and localized twice on the same frames: as a tracked walk
(:func:`ldlloc.walk.run.run_walk_video`: a search near the previous pose, global only when lost)
and one frame at a time (:func:`ldlloc.batch.which_map.localize_on_maps`; ``--single-every N``: every
N-th frame only, both compared on those frames). Printed: frames a second (the whole walk, and its
tracked frames alone: the median seconds from one frame's decoding to the next, and their stages),
within 0.1 m / 5 deg (all frames, and the compared ones), confident frames (and of them beyond 0.25 m / 5 deg),
tracked, lost and global frames, peak memory, the results
write. ``--repeat N``: the rendered walk played N times in a row as one video (a long walk without
rendering it; each loop jumps back to the start). Results: ``bench/video.json``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

FPS = 5.0
SPEED = 1.0  # m/s


def walk_poses(center0: np.ndarray, middle: np.ndarray, rot0: np.ndarray, n: int, seed: int = 0) -> list:
    """A loop of ``n`` frames around ``middle`` through ``center0``'s distance, 5 frames a second at 1 m/s,
    turning 3 deg a frame, tilted 1-2 deg."""
    from ldlmap.core.geometry import rotation_from_axis_angle

    rng = np.random.default_rng(seed)
    radius = max(0.4, min(1.2, float(np.linalg.norm((center0 - middle)[:2])) * 0.6))
    step = SPEED / FPS / radius  # radians a frame
    out = []
    for k in range(n):
        a = k * step
        t = middle + [radius * np.cos(a), radius * np.sin(a), 0.0]
        t[2] = center0[2] + 0.02 * np.sin(k * 1.3)  # walking height, a little bounce
        tilt = rotation_from_axis_angle(np.array([1.0, 0, 0]), np.radians(rng.uniform(1, 2) * rng.choice([-1, 1])))
        R = tilt @ rot0 @ rotation_from_axis_angle(np.array([0, 0, 1.0]), np.radians(3.0 * k))
        out.append((R, t))
    return out


def walk_params(args):
    """The video walk's parameters with the command line's tracking options."""
    from ldlloc.walk.localize import VIDEO

    return replace(VIDEO, tracking=replace(VIDEO.tracking, refine=args.track_refine, width=args.track_width,
                                           lines=not args.no_track_lines))


def rendered_walk(args, root: Path, map_path: Path, q) -> tuple[Path, list]:
    """The walk's video (rendered and encoded once, cached) and its ground truth per frame ``(R, t)``."""
    from ldlmap.map.mapfile import read_map
    from ldlloc.walk.video import write_video

    video = HERE / ".cache" / "video" / f"{args.scene}_{args.frames}_{args.width}.mp4"
    video.parent.mkdir(parents=True, exist_ok=True)
    truth = video.with_suffix(".poses.npz")  # the cached video's ground truth: the walk's middle depends on the map
    t0 = time.perf_counter()
    if video.exists() and truth.exists():
        with np.load(truth) as z:
            poses = list(zip(z["R"], z["t"]))
    else:  # the same walk each time (a fixed seed): rendered once
        from ldlmap.synth.render import Renderer  # the renderer's mesh library only where a video is rendered
        from ldlmap.synth.scene import build_scene
        from ldlmap.synth.spec import load_spec

        middle = read_map(map_path, load_cloud=False).translations.mean(0)
        poses = walk_poses(q.center, middle, q.rot_cam_from_world, args.frames)
        render = Renderer(build_scene(load_spec(root / "specs" / f"{args.scene}.toml")))
        write_video(video, (render.render(R, t, args.width, supersample=1, blur_px=2.0, blur_angle=0.0).rgb
                            for R, t in poses), fps=FPS)
        np.savez(truth, R=np.array([R for R, _ in poses]), t=np.array([t for _, t in poses]))
        print(f"rendered and encoded {args.frames} frames ({args.width} px) in {time.perf_counter() - t0:.1f} s")
    return video, poses


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True, help="synthetic dataset with maps (ldlmap synth + prepare)")
    ap.add_argument("--scene", default="synthroom_1")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--width", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu", help="cpu or cuda: the torch device of every search and refinement")
    ap.add_argument("--track-refine", default="light", help="the restricted search's poses refined by: light | same | "
                    "geometric")
    ap.add_argument("--track-width", type=int, default=512, help="tracked frames' lines extracted at this width (0: "
                    "the frame's)")
    ap.add_argument("--no-track-lines", action="store_true", help="track by the restricted search alone (no "
                    "refinement of the prediction from lines)")
    ap.add_argument("--repeat", type=int, default=1, help="the rendered walk played this many times in a row (a long "
                    "video without rendering it: the loop jumps back to its start each time)")
    ap.add_argument("--no-single", action="store_true", help="skip the single-image pass")
    ap.add_argument("--single-every", type=int, default=1, help="the single-image pass on every N-th frame only")
    ap.add_argument("--output", default=str(HERE / "video.json"))
    args = ap.parse_args(argv)
    import cv2
    import torch

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlmap.datasets import open_dataset
    from ldlloc.batch.which_map import MapSet, localize_on_maps
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.walk.run import run_walk_video
    from ldlloc.walk.video import decoded_frames, video_info, write_video

    root = Path(args.root)
    map_path = root / "maps" / f"{args.scene}.h5"
    q = [q for q in open_dataset(root, "omniscenes").queries(["robot"]) if q.scene == args.scene][0]
    video, poses = rendered_walk(args, root, map_path, q)
    if args.repeat > 1:  # the same frames again and again, one video (decoded and encoded once, cached)
        looped = video.with_name(f"{video.stem}_x{args.repeat}.mp4")
        if not looped.exists():
            write_video(looped, (img for _ in range(args.repeat) for _, img in decoded_frames(video_info(video))),
                        fps=FPS)
        video, poses = looped, poses * args.repeat
    print(f"video: {video}")
    params = LocalizeParams()
    maps = MapSet.load(map_path, params, args.device)

    def accuracy(Rs, ts, frames, metres: float = 0.1) -> int:
        return int(sum(translation_error(t, poses[k][1]) < metres and rotation_error_deg(R, poses[k][0]) < 5
                       for R, t, k in zip(Rs, ts, frames)))

    out = HERE / ".cache" / "video" / f"results_{Path(args.output).stem}.json"  # a run of its own per --output
    out.unlink(missing_ok=True)
    ticks: list[tuple[float, bool, dict, float]] = []  # per frame: when its own localization ended, tracked,
    # stages, the process's CPU seconds then (a busy machine stretches wall time, far less CPU time)
    t0, c0 = time.perf_counter(), time.process_time()
    recs = run_walk_video(video, maps, out, params, walk_params(args), device=args.device,
                          progress=lambda r: ticks.append((time.perf_counter(), r.walk["tracked"], r.seconds,
                                                           time.process_time())))
    walk_s, walk_cpu = time.perf_counter() - t0, time.process_time() - c0
    recs = sorted(recs, key=lambda r: r.walk["frame"])
    tw = time.perf_counter()
    out.write_text(out.read_text())  # the one write of the walk's records, timed again
    write_s = time.perf_counter() - tw
    every = max(1, args.single_every)
    sub = list(range(0, len(recs), every))
    walk_ok = accuracy([np.array(recs[i].R) for i in sub], [np.array(recs[i].t) for i in sub], sub)
    posed = [i for i, r in enumerate(recs) if r.R is not None]
    all_ok = accuracy([np.array(recs[i].R) for i in posed], [np.array(recs[i].t) for i in posed], posed)
    sure = [i for i in posed if recs[i].verdict == "confident"]
    sure_right = accuracy([np.array(recs[i].R) for i in sure], [np.array(recs[i].t) for i in sure], sure, 0.25)
    tracked = sum(r.walk["tracked"] for r in recs)
    lost = sum(bool(r.walk.get("lost")) for r in recs)
    global_frames = len(recs) - tracked - lost
    by_lines = sum("refined from lines" in r.message for r in recs)
    per_frame = np.diff([t0] + [t for t, _, _, _ in ticks])
    cpu = np.diff([c0] + [c for _, _, _, c in ticks])
    on_track = np.array([tr for _, tr, _, _ in ticks], dtype=bool)
    stages = {k: float(np.median([sec.get(k, 0.0) for (_, tr, sec, _) in ticks if tr]) if on_track.any() else np.nan)
              for k in ("lines2d", "refine", "confidence", "total")}
    track_cpu = float(np.median(cpu[on_track])) if on_track.any() else float("nan")
    t0 = time.perf_counter()
    single = [] if args.no_single else [localize_on_maps(img, maps, None)[0]
                                        for k, (_, img) in enumerate(decoded_frames(video_info(video))) if k % every == 0]
    single_s = time.perf_counter() - t0 if single else float("nan")
    single_ok = accuracy([s.rot_cam_from_world for s in single], [s.center for s in single], sub)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    n, m = len(poses), len(sub)
    track_s = float(np.median(per_frame[on_track])) if on_track.any() else float("nan")
    res = {"frames": n, "width": args.width, "threads": args.threads, "device": args.device, "track_refine": args.track_refine,
           "track_width": args.track_width, "compared_frames": m,
           "walk": {"seconds": walk_s, "cpu_s": walk_cpu, "frames_per_s": n / walk_s, "frames_per_cpu_s": n / walk_cpu,
                    "within_0.1m_5deg": walk_ok, "all_within_0.1m_5deg": all_ok, "confident": len(sure),
                    "confident_wrong": len(sure) - sure_right, "tracked": tracked, "lost": lost,
                    "global": global_frames,
                    "tracked_by_lines": by_lines, "tracked_frame_median_s": track_s, "tracked_stages_median_s": stages,
                    "tracked_frame_median_cpu_s": track_cpu,
                    "global_frames_s": float(per_frame[~on_track].sum())},
           "single": {"seconds": single_s, "frames_per_s": m / single_s, "within_0.1m_5deg": single_ok},
           "peak_rss_mb": peak, "results_write_s": write_s, "results_bytes": out.stat().st_size}
    print_summary(res)
    Path(args.output).write_text(json.dumps(res, indent=1))
    print(f"wrote {args.output}")
    return 0


def print_summary(res: dict) -> None:
    """The run's figures (:func:`main`'s ``res``) in a few lines."""
    w, n, m = res["walk"], res["frames"], res["compared_frames"]
    stages = w["tracked_stages_median_s"]
    print(f"tracked walk : {w['frames_per_s']:.2f} frames/s ({n} frames, {w['seconds']:.1f} s; CPU {w['cpu_s']:.1f} s: "
          f"{w['frames_per_cpu_s']:.2f} frames per CPU s), {w['all_within_0.1m_5deg']}/{n} within 0.1 m / 5 deg; "
          f"{w['global']} global, {w['lost']} lost (the prediction, no search); confident {w['confident']} "
          f"(beyond 0.25 m / 5 deg: {w['confident_wrong']})")
    print(f"             : {w['tracked']} tracked ({w['tracked_by_lines']} refined from lines alone), tracked frames "
          f"{1 / w['tracked_frame_median_s']:.1f} frames/s (median {w['tracked_frame_median_s'] * 1000:.0f} ms: "
          + ", ".join(f"{k} {v * 1000:.0f}" for k, v in stages.items())
          + f" ms; CPU {w['tracked_frame_median_cpu_s'] * 1000:.0f} ms), global frames {w['global_frames_s']:.1f} s; "
          f"{w['within_0.1m_5deg']}/{m} within 0.1 m / 5 deg")
    s = res["single"]
    print(f"single images: {s['frames_per_s']:.2f} frames/s, {s['within_0.1m_5deg']}/{m} within 0.1 m / 5 deg")
    print(f"peak memory {res['peak_rss_mb']:.0f} MB; the walk's results written once: {res['results_write_s'] * 1000:.1f} ms, "
          f"{res['results_bytes'] / 1024:.0f} kB")


if __name__ == "__main__":
    sys.exit(main())
