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
    ap.add_argument("--sizes", default="30,2000,3000", help="records already in the file (comma-separated)")
    ap.add_argument("--adds", type=int, default=10, help="queries added (and timed) at each size")
    ap.add_argument("--scratch", type=int, default=0, help="also time a run of this many queries from an empty file")
    ap.add_argument("--tree", default=None, help="source tree to import ldlloc from (default: this one)")
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


def main() -> None:
    args = parse_args()
    tree = Path(args.tree).resolve() if args.tree else Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(tree))
    import ldlloc.batch.results as results_module

    print(f"ldlloc from {Path(results_module.__file__).parents[2]}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print(f"{'records':>8} {'open s':>8} {'add mean ms':>12} {'add max ms':>11} {'files MB':>9}")
        for n in (int(s) for s in args.sizes.split(",")):
            row = time_adds(n, args.adds, folder)
            print(f"{row['n']:>8} {row['open_s']:>8.2f} {row['mean_ms']:>12.1f} {row['max_ms']:>11.1f} "
                  f"{row['bytes'] / 1e6:>9.1f}")
        if args.scratch:
            row = time_scratch(args.scratch, folder)
            print(f"run of {row['m']} queries from an empty file: {row['total_s']:.2f} s in all, "
                  f"{row['per_query_ms']:.2f} ms per query (worst add {row['worst_ms']:.0f} ms, finish "
                  f"{row['finish_s']:.2f} s), {row['bytes'] / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
