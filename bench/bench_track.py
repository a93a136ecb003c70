"""The video tracker alone: each frame of the building's video walk tracked from the truth before it.

Run: ``python bench/bench_track.py --seed 4044 [--threads 1] [--output F]``.

The building and its video walk, and its floor maps at ``ldlmap prepare`` defaults, are those of
``bench/bench_walk.py --building --video --visits 1 --seed S`` (generated and built once, cached under
``bench/.cache/walk_building``). Each frame whose two frames before stand on its floor is tracked
(:func:`ldlloc.walk.track.track`) from the prediction the walk makes when those two were right: their
true poses moved on at their velocity (:func:`ldlloc.walk.track.predict`'s constant velocity), on the
true floor's map, the lines the frame before's true pose explains as the reference. A walk's own
numbers also depend on its global frames, which choose among identical rooms, and one decision there
moves hundreds of frames (``bench_walk.py --building --video``); this measures the tracker alone: how
each frame was tracked (``lines``: step 1, the prediction refined from lines; ``search``: step 2, the
restricted search; ``lost``) and how far off it landed (within
0.1 m / 5 deg, within 0.5 m / 5 deg, beyond), by the frame's true step and turn, with the median CPU
seconds of a frame. Results: ``bench/track.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.bench_walk import building_data, building_maps  # noqa: E402
from bench.common import console, set_threads, write_json  # noqa: E402


def how(loc) -> str:
    """How a tracked frame was found (its message)."""
    from ldlloc.walk.track import is_lost

    if is_lost(loc):
        return "lost"
    return "lines" if "refined from lines" in loc.message else "search"


def band(t: float | None, r: float | None) -> str:
    """The error band of a frame's pose (``t`` metres and ``r`` degrees off; None: no pose)."""
    if t is None:
        return "beyond"
    return "0.1m" if t < 0.1 and r < 5 else ("0.5m" if t < 0.5 and r < 5 else "beyond")


def track_frames(data: Path, maps_path: Path) -> list[dict]:
    """Each frame tracked from the truth of the two before (module docstring): one row a frame."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlmap.datasets import open_dataset
    from ldlloc.batch.which_map import MapSet, poses_loss
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.walk.track import TorchThreads, TrackBasis, TrackParams, frame_arcs, predicted_from, track
    from ldlloc.walk.video import decoded_frames, video_info

    queries = sorted(open_dataset(data, "omniscenes").queries("walk_video"), key=lambda q: int(Path(q.image).stem))
    maps = MapSet.load(maps_path, LocalizeParams())
    by_scene = {e.scene: e for e in maps.entries}
    p, cache, threads = TrackParams(), {}, TorchThreads()
    rows, before = [], None
    frames = decoded_frames(video_info(data / "video" / "walk_video.mp4"))
    with console().status("tracking") as status:
        for k, (_, img) in enumerate(frames):
            q, last = queries[k], before
            before = img
            if k < 2 or queries[k - 1].scene != q.scene or queries[k - 2].scene != q.scene:
                continue
            status.update(f"tracking frame {k + 1} / {len(queries)}")
            entry, q1, q2 = by_scene[q.scene], queries[k - 1], queries[k - 2]
            R1, t1 = q1.rot_cam_from_world, q1.center
            moving = np.linalg.norm(t1 - q2.center) <= p.max_step_m  # as next_basis: a longer step is no velocity
            pred = predicted_from(TrackBasis(entry, R1, t1, t1 - q2.center if moving else None,
                                             R1 @ q2.rot_cam_from_world.T if moving else None))
            arcs, _ = frame_arcs(last, entry, p)
            ref = float(poses_loss(entry.localizer, arcs, R1[None], t1[None])[0])
            cpu = time.process_time()
            got = track(img, pred, None, p, ref, cache, threads)
            cpu = time.process_time() - cpu
            threads.release()
            t = r = None
            if got is not None:
                t = translation_error(got[0].center, q.center)
                r = rotation_error_deg(got[0].rot_cam_from_world, q.rot_cam_from_world)
            rows.append({"frame": k, "how": "global" if got is None else how(got[0]), "t": t, "r": r, "cpu_s": cpu,
                         "step_m": float(np.linalg.norm(q.center - q1.center)),
                         "turn_deg": rotation_error_deg(q.rot_cam_from_world, q1.rot_cam_from_world)})
    return rows


def summary(rows: list[dict]) -> dict:
    """Counts by how and band; the same for the frames that turned more than 20 deg or stepped more than 0.5 m."""
    def counts(sub):
        c = Counter(f"{r['how']} {band(r['t'], r['r'])}" for r in sub)
        return {"frames": len(sub), "within_0.1m_5deg": sum(band(r["t"], r["r"]) == "0.1m" for r in sub),
                "lost": sum(r["how"] == "lost" for r in sub), **dict(sorted(c.items()))}

    fast = [r for r in rows if r["turn_deg"] > 20]
    jump = [r for r in rows if r["step_m"] > 0.5]
    rest = [r for r in rows if r["turn_deg"] <= 20 and r["step_m"] <= 0.5]
    return {"all": counts(rows), "turned_over_20deg": counts(fast), "stepped_over_0.5m": counts(jump),
            "the_rest": counts(rest), "median_frame_cpu_s": float(np.median([r["cpu_s"] for r in rows]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=4044, help="the building's seed (bench_walk --building --video)")
    ap.add_argument("--walk-doors", choices=("closed", "open"), default="closed",
                    help="the video's doors (bench_walk --walk-doors): open, it walks through them frame by frame")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    ap.add_argument("--output", default=str(HERE / "track.json"), help="results (default bench/track.json)")
    args = ap.parse_args(argv)
    walk = argparse.Namespace(seed=args.seed, width=1024, visits=1, video=True, doors="closed", walk_doors=args.walk_doors)
    set_threads(args.threads)
    data = building_data(walk)
    maps, _ = building_maps(data, walk)
    rows = track_frames(data, maps)
    res = {"seed": args.seed, **summary(rows), "frames": rows}
    for key in ("all", "turned_over_20deg", "stepped_over_0.5m", "the_rest"):
        s = res[key]
        extra = ", ".join(f"{k} {v}" for k, v in s.items() if k not in ("frames", "within_0.1m_5deg", "lost"))
        print(f"{key:18s}: {s['within_0.1m_5deg']} / {s['frames']} within 0.1 m / 5 deg, {s['lost']} lost ({extra})")
    print(f"median frame: {res['median_frame_cpu_s'] * 1000:.0f} ms CPU")
    write_json(Path(args.output), res)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
