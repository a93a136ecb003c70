"""What writing a run's results costs per query as the run grows (until the journal, the results file was
rewritten whole after every query, quadratic in the run's length).

For each size N (default 30, 2000, 3000): a results file of N realistic records (20 search
candidates, 3 competing poses, confidence signals, per-stage seconds: what `ldlloc run` writes)
is made directly, opened by ``ResultsWriter(..., resume=True)`` as ``--resume`` does, and then
``--adds`` more queries are added one by one, each timed (mean, max and total ms per query, the
file's bytes). ``--scratch M`` also times a run of M queries written from an empty file (the
whole cost of a run's results, amortized per query). Prints one table; nothing is asserted.

Before / after: run it with the tree to measure first on ``PYTHONPATH`` (``--tree DIR``), e.g.
``python bench/bench_results_write.py --tree ../main`` and ``python bench/bench_results_write.py``.

``--walk N``: a walk of N frames through the walk's stream (:mod:`ldlloc.walk.stream`: windows of
``--lag`` frames, the path chosen, each frame's record written once decided) and the results
writer, with made-up frames (each 48 hypotheses over two maps, as a real frame keeps, and a
record as large as a real walk frame's; the localization itself is left out: its cost and memory
do not grow with the walk). Prints, at frames 30, 300, 1000, 3000 (and N): the milliseconds to
decide and write a frame and to write it (means over the frames since the last checkpoint), the
process's resident memory (now and its peak: the stream's and the writer's) and the files' bytes.

``--real N --maps MAP --images GLOB``: a real walk of N frames (the panoramas of GLOB in turn,
each held for ``--hold`` frames, 5 frames a second: a video's tracking) localized and written as
``ldlloc run --video`` does it; prints after each block of decided frames the process's resident
memory (now and its peak): flat once the window is full.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="30,2000,3000", help="records already in the file (comma-separated; \"\": none)")
    ap.add_argument("--adds", type=int, default=10, help="queries added (and timed) at each size")
    ap.add_argument("--scratch", type=int, default=0, help="also time a run of this many queries from an empty file")
    ap.add_argument("--tree", default=None, help="source tree to import ldlloc from (default: this one)")
    ap.add_argument("--walk", type=int, default=0, help="also a walk of this many frames (stream and writer)")
    ap.add_argument("--lag", type=int, default=100, help="--walk, --real: the stream's lag (frames)")
    ap.add_argument("--real", type=int, default=0, help="a real walk of this many frames (--maps, --images)")
    ap.add_argument("--maps", default=None, help="--real: the map (.h5) or folder of maps")
    ap.add_argument("--images", default=None, help="--real: the panoramas (a glob), shown in turn")
    ap.add_argument("--hold", type=int, default=10, help="--real: frames each panorama is held for")
    return ap.parse_args()


def record(i: int):
    """A query record as big as a real one of `ldlloc run` (deterministic numbers)."""
    from ldlloc.batch.accuracy import QueryResult

    rot = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    cands = [{"R": rot, "t": [0.1 * k + i * 1e-3, 0.2, 1.5], "loss": -40.0 + k} for k in range(20)]
    return QueryResult(
        image=f"shots/pano_{i:06d}.jpg", scene="room", split="images", name=f"pano_{i:06d}", R=rot,
        t=[1.0 + i * 1e-3, 2.0, 1.5], seconds={s: 0.1 + 1e-4 * i for s in ("lines2d", "rotation", "search", "refine",
                                                                         "confidence", "total")},
        num_rotations=12, num_matches=300, num_inliers=120, refined=True, status="ok", refine_method="features",
        candidates=cands, map="maps/room.h5", confidence=0.9, verdict="confident",
        competitors=[{"R": rot, "t": [3.0, 2.0, 1.5], "loss": -38.0, "why": "180-degree twin"}] * 3,
        confidence_signals={f"signal_{k}": 0.5 for k in range(8)})


def file_of(path: Path, n: int) -> None:
    """Results file ``path`` holding ``n`` records (written directly, as a killed run leaves it)."""
    from dataclasses import asdict

    data = {"format_version": 1, "meta": {"device": "cpu", "dataset": "images", "finished": False},
            "queries": [asdict(record(i)) for i in range(n)]}
    path.write_text(json.dumps(data, indent=1))


def time_adds(n: int, adds: int, folder: Path) -> dict:
    """Open a file of ``n`` records with ``--resume`` and time ``adds`` more queries."""
    from ldlloc.batch.results import ResultsWriter

    path = folder / f"r{n}.json"
    file_of(path, n)
    tick = time.perf_counter()
    w = ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}, resume=True)
    opened = time.perf_counter() - tick
    times = []
    for i in range(n, n + adds):
        r = record(i)
        tick = time.perf_counter()
        w.add(r)
        times.append(time.perf_counter() - tick)
    w.close()
    size = sum(p.stat().st_size for p in folder.glob(f"r{n}.*") if p.is_file())
    return {"n": n, "open_s": opened, "mean_ms": 1e3 * sum(times) / len(times), "max_ms": 1e3 * max(times),
            "bytes": size}


def time_scratch(m: int, folder: Path) -> dict:
    """A whole run of ``m`` queries written from an empty file, then finished."""
    from ldlloc.batch.results import ResultsWriter

    path = folder / "scratch.json"
    records = [record(i) for i in range(m)]
    tick = time.perf_counter()
    worst = 0.0
    with ResultsWriter(path, meta={"device": "cpu", "dataset": "images"}) as w:
        for r in records:
            t0 = time.perf_counter()
            w.add(r)
            worst = max(worst, time.perf_counter() - t0)
        t0 = time.perf_counter()
        if hasattr(w, "finish"):
            w.finish()
        finish = time.perf_counter() - t0
    total = time.perf_counter() - tick
    return {"m": m, "total_s": total, "per_query_ms": 1e3 * total / m, "worst_ms": 1e3 * worst,
            "finish_s": finish, "bytes": path.stat().st_size}


def walk_frame(i: int, maps):
    """Made-up frame ``i`` of a walk down a corridor: 48 hypotheses over two maps (its own pose
    first), a record-sized localization; what :func:`ldlloc.walk.localize.localize_frame` returns."""
    import numpy as np
    from ldlloc.walk.hypotheses import Hypotheses
    from ldlloc.walk.localize import FrameOutcome

    rng = np.random.default_rng(i)
    c = np.array([0.3 * i, 0.0, 1.5])
    centers = np.r_[c[None], c + rng.normal(0, 2, (47, 3))]
    rots = np.repeat(np.eye(3)[None], 48, 0)
    h = Hypotheses(rng.integers(0, 2, 48), rots, centers, np.r_[-60.0, rng.uniform(-55, -10, 47)],
                   np.r_[True, np.zeros(47, bool)])
    loc = type("Loc", (), {"rot_cam_from_world": rots[0], "center": centers[0], "refined": True, "confidence": 0.9,
                           "verdict": "confident", "competitors": [], "message": ""})()
    return FrameOutcome(None, loc=loc, entry=maps.entries[0], hypotheses=h, single_confidence=0.9,
                        single_verdict="confident", single_pose=(rots[0], centers[0]))


def time_walk(n: int, lag: int, folder: Path) -> list[dict]:
    """A walk of ``n`` made-up frames streamed and written (module docstring); rows at checkpoints."""
    from dataclasses import replace
    from ldlloc.batch.results import ResultsWriter
    from ldlloc.walk import stream
    from ldlloc.walk.localize import WalkFrame, WalkParams

    entry = type("Entry", (), {"path": Path("a.h5"), "scene": "a"})
    maps = type("Maps", (), {"entries": [entry(), entry()]})()
    stream.localize_frame = lambda item, *a: (replace(walk_frame(int(item.name[1:]), maps), frame=item), None)
    marks = sorted({m for m in (30, 300, 1000, 3000, n) if m <= n})
    frames = (WalkFrame(f"f{i:06d}", lambda: None, 0.2 * i) for i in range(n))
    rows, times, writes = [], [], []
    tick = time.perf_counter()
    with ResultsWriter(folder / "walk.json", meta={"device": "cpu", "dataset": "images", "walk": {}}) as w:
        for slot in (s for block in stream.stream_walk(frames, maps, WalkParams(), lag) for s in block):
            r = replace(record(slot.index), name=slot.out.frame.name, walk={
                "name": "walk", "frame": slot.index, "time": slot.out.frame.time, "margin": slot.out.walk_margin,
                "single_pose": {"R": slot.out.single_pose[0].tolist(), "t": slot.out.single_pose[1].tolist()}})
            t0 = time.perf_counter()
            w.add(r)
            now = time.perf_counter()
            times.append(now - tick)
            writes.append(now - t0)
            tick = now
            if slot.index + 1 in marks:
                rss, peak = resident()
                rows.append({"frame": slot.index + 1, "ms": 1e3 * sum(times) / len(times),
                             "write_ms": 1e3 * sum(writes) / len(writes), "write_max_ms": 1e3 * max(writes),
                             "held_mb": rss, "peak_mb": peak,
                             "bytes": sum(p.stat().st_size for p in folder.glob("walk.json*"))})
                times, writes = [], []
        w.finish()
    return rows


def resident() -> tuple[float, float]:
    """The process's resident memory now and its peak (MB)."""
    import resource

    rss = int(Path("/proc/self/statm").read_text().split()[1]) * resource.getpagesize()
    return rss / 1e6, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def real_walk(n: int, lag: int, maps: str, images: str, hold: int, folder: Path) -> list[dict]:
    """A real walk of ``n`` frames (module docstring): rows after each block of decided frames."""
    import glob
    from dataclasses import replace
    from ldlloc.batch.images import ImageQuery
    from ldlloc.batch.results import ResultsWriter
    from ldlloc.batch.which_map import MapSet
    from ldlloc.pipeline import LocalizeParams, load_image
    from ldlloc.walk.localize import VIDEO, WalkFrame
    from ldlloc.walk.run import image_frame_record
    from ldlloc.walk.stream import stream_walk

    paths = sorted(glob.glob(images))
    mapset = MapSet.load(maps, LocalizeParams(), "cpu")
    image = lambda i: load_image(paths[(i // hold) % len(paths)])  # noqa: E731
    frames = ((WalkFrame(f"v/{i:06d}", (lambda i=i: image(i)), 0.2 * i), image(i)) for i in range(n))
    rows = []
    tick = time.perf_counter()
    with ResultsWriter(folder / "real.json", meta={"device": "cpu", "dataset": "video", "walk": {}}) as w:
        for slot in (s for block in stream_walk(frames, mapset, replace(VIDEO, top_maps=1), lag) for s in block):
            w.add(image_frame_record(ImageQuery(Path(paths[0]), slot.out.frame.name), slot, LocalizeParams(), "v"))
            if (slot.index + 1) % 10 == 0 or slot.index + 1 == n:
                rss, peak = resident()
                row = {"frame": slot.index + 1, "s": time.perf_counter() - tick, "rss_mb": rss, "peak_mb": peak}
                print(f"{row['frame']:>8} {row['s']:>8.0f} {row['rss_mb']:>8.0f} {row['peak_mb']:>8.0f}", flush=True)
                rows.append(row)
        w.finish()
    return rows


def main() -> None:
    args = parse_args()
    tree = Path(args.tree).resolve() if args.tree else Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(tree))
    import ldlloc.batch.results as results_module

    print(f"ldlloc from {Path(results_module.__file__).parents[2]}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print(f"{'records':>8} {'open s':>8} {'add mean ms':>12} {'add max ms':>11} {'files MB':>9}")
        for n in (int(s) for s in args.sizes.split(",") if s):
            row = time_adds(n, args.adds, folder)
            print(f"{row['n']:>8} {row['open_s']:>8.2f} {row['mean_ms']:>12.1f} {row['max_ms']:>11.1f} "
                  f"{row['bytes'] / 1e6:>9.1f}")
        if args.scratch:
            row = time_scratch(args.scratch, folder)
            print(f"run of {row['m']} queries from an empty file: {row['total_s']:.2f} s in all, "
                  f"{row['per_query_ms']:.2f} ms per query (worst add {row['worst_ms']:.0f} ms, finish "
                  f"{row['finish_s']:.2f} s), {row['bytes'] / 1e6:.1f} MB")
        if args.walk:
            print(f"walk of {args.walk} made-up frames, lag {args.lag}: ms to decide and write a frame, to write it "
                  "(means since the row before) and the slowest write, resident memory now and its peak, files")
            print(f"{'frame':>8} {'ms/frame':>9} {'write ms':>9} {'max ms':>7} {'RSS MB':>8} {'peak MB':>8} "
                  f"{'files MB':>9}")
            for row in time_walk(args.walk, args.lag, folder):
                print(f"{row['frame']:>8} {row['ms']:>9.2f} {row['write_ms']:>9.2f} {row['write_max_ms']:>7.1f} "
                      f"{row['held_mb']:>8.0f} {row['peak_mb']:>8.0f} {row['bytes'] / 1e6:>9.1f}")
        if args.real:
            print(f"real walk of {args.real} frames, lag {args.lag}: resident memory now and its peak")
            print(f"{'frame':>8} {'s':>8} {'RSS MB':>8} {'peak MB':>8}")
            real_walk(args.real, args.lag, args.maps, args.images, args.hold, folder)


if __name__ == "__main__":
    main()
