"""Benchmark: start-up of the command-line programs and one `ldlloc localize`, as a user runs them.

Run: ``python bench/bench_startup.py [--runs 5] [--tree PATH] [--baseline PATH] [--threads N]``.

Each command runs as a fresh subprocess, the way the console scripts run it
(``from ldlloc.cli import app; app()``), ``--runs`` times; the table prints the median and the smallest wall
seconds (the smallest is the least disturbed by other work on a shared machine) and the median
CPU (user + sys) seconds:

- ``python3 -c pass`` (the interpreter alone) and ``ldlmap --help``, ``ldlloc --help``;
- the imports ``localize`` needs (torch, cv2, h5py, pycolmap, ``ldlloc.pipeline``), alone;
- ``ldlloc localize MAP PANO --json`` of one robot panorama of the synthetic demo room
  ``synthroom_1`` (1024 x 512) on its map (``bench/.cache``: demo dataset seed 1, default
  :class:`~ldlmap.map.build.BuildParams`: SIFT, N_t = 800, 40 views, distance fields), split into
  the stages it reports (``load_seconds``: the map read, which runs in a thread beside the
  imports, the wait for it after them, the setup; ``seconds``: the query's lines2d, rotation,
  search, refine) and the rest (interpreter, imports, argument parsing, exit) = wall - wait for
  the map - setup - query.

``--tree PATH`` times the package in PATH instead of this working tree, ``--baseline PATH`` times
another tree beside it, run for run (e.g. ``git archive`` of an older commit, to compare before
and after under the same load); ``--threads N`` passes ``--threads N`` to ``localize`` (default:
the command's own default). Targets: ``--help`` under 0.5 s, one ``localize`` under
2 s wall on the 2-core development machine. Writes ``bench/startup.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

TARGETS = {"ldlmap --help": 0.5, "ldlloc --help": 0.5, "ldlloc localize": 2.0}
QUERY_STAGES = ("lines2d", "rotation", "search", "refine")
LOCALIZE_IMPORTS = "import torch, cv2, h5py, pycolmap, ldlloc.pipeline"


def _script(program: str) -> list[str]:
    """The command line of a console script: ``python -c 'from <program>.cli import app; app()'``."""
    return [sys.executable, "-c", f"import sys; sys.argv[0] = {program!r}; from {program}.cli import app; app()"]


def timed(cmd: list[str], env: dict[str, str], cwd: Path) -> tuple[float, float, str]:
    """Run ``cmd`` in ``cwd``; its wall seconds, CPU seconds (user + sys) and stdout. Raises on failure."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=cwd)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[-4:])} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, proc.stdout


def localize_inputs(seed: int = 1, scene: str = "synthroom_1") -> tuple[Path, Path]:
    """The demo room's map and its first robot panorama (generated and built once, then cached)."""
    from ldlmap.datasets import open_dataset

    dataset = common.demo_dataset(seed)
    query = open_dataset(dataset, "omniscenes").queries("robot", scene=scene)[0]
    return common.cached_map(dataset, scene), Path(query.image)


def _commands(map_path: Path, pano: Path, threads: int | None) -> dict[str, list[str]]:
    loc_args = ["localize", str(map_path), str(pano), "--json"] + (["--threads", str(threads)] if threads else [])
    return {
        "python3 -c pass": [sys.executable, "-c", "pass"],
        "ldlmap --help": _script("ldlmap") + ["--help"],
        "ldlloc --help": _script("ldlloc") + ["--help"],
        "imports of localize": [sys.executable, "-c", LOCALIZE_IMPORTS],
        "ldlloc localize": _script("ldlloc") + loc_args,
    }


def measure(trees: dict[str, Path], map_path: Path, pano: Path, runs: int, threads: int | None) -> dict[str, Any]:
    """Per tree: median wall / CPU seconds of every command, and of localize's reported stages.

    Runs are interleaved (run i of every command of every tree, then run i + 1), so a change of
    the machine's load touches every command and tree alike."""
    commands = _commands(map_path, pano, threads)
    samples = {t: {k: [] for k in commands} for t in trees}
    stages: dict[str, list[dict[str, float]]] = {t: [] for t in trees}
    for i in range(runs):
        for tree, path in trees.items():
            # in the tree itself: `python -c` puts the working folder first on sys.path
            env = {**os.environ, "PYTHONPATH": str(path), "COLUMNS": "120"}
            for name, cmd in commands.items():
                wall, cpu, out = timed(cmd, env, path)
                samples[tree][name].append((wall, cpu))
                if name == "ldlloc localize":
                    res = json.loads(out)
                    s = {k: float(v) for k, v in res["seconds"].items()}
                    s.update({k: float(v) for k, v in res.get("load_seconds", {}).items()})
                    waited = s.get("wait_map", s.get("read_map", 0.0))  # the read overlaps the imports
                    s["rest"] = wall - s["total"] - waited - s.get("setup", 0.0)
                    stages[tree].append(s)
        print(f"\r  run {i + 1}/{runs}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    out: dict[str, Any] = {}
    for tree, path in trees.items():
        med = {k: {"wall": float(np.median([w for w, _ in v])), "wall_min": float(min(w for w, _ in v)),
                   "cpu": float(np.median([c for _, c in v]))} for k, v in samples[tree].items()}
        keys = sorted({k for s in stages[tree] for k in s})
        stage_med = {k: float(np.median([s[k] for s in stages[tree] if k in s])) for k in keys}
        out[tree] = {"tree": str(path), "commands": med, "localize_stages": stage_med, "samples": samples[tree]}
    return out


def table(results: dict[str, Any], title: str):
    """Median seconds per command and per stage of `localize` for each tree, with the targets."""
    from rich.table import Table

    t = Table(title=title)
    t.add_column("command / stage")
    for tree in results:
        t.add_column(f"{tree} wall s", justify="right")
        t.add_column(f"{tree} min wall s", justify="right")
        t.add_column(f"{tree} CPU s", justify="right")
    t.add_column("target (wall)", justify="right")
    first = next(iter(results.values()))
    for name in first["commands"]:
        tgt = TARGETS.get(name)
        cells = [f"{r['commands'][name][k]:.3f}" for r in results.values() for k in ("wall", "wall_min", "cpu")]
        t.add_row(name, *cells, f"< {tgt:g}" if tgt else "", style="bold" if tgt else None)
    t.add_section()
    names = {"read_map": "localize: map read (in a thread, beside the imports)",
             "wait_map": "localize: wait for the map after the imports", "setup": "localize: setup (Localizer)",
             "total": "localize: query total", "rest": "localize: rest (interpreter, imports, CLI, exit)"}
    for k in ("read_map", "wait_map", "setup", *QUERY_STAGES, "total", "rest"):
        cells = [c for r in results.values() for c in (common.fmt(r["localize_stages"].get(k)), "", "")]
        t.add_row(names.get(k, f"localize: {k}"), *cells, "")
    return t


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="runs of each command (median)")
    ap.add_argument("--tree", type=Path, default=common.ROOT, help="source tree to time (default: this one)")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="another source tree to time beside it, interleaved (e.g. a `git archive` of an older commit)")
    ap.add_argument("--threads", type=int, default=None, help="--threads for localize (default: its own)")
    ap.add_argument("--seed", type=int, default=1, help="demo dataset seed")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "startup.json")
    args = ap.parse_args(argv)
    map_path, pano = localize_inputs(args.seed)
    trees = {"this": args.tree.resolve()}
    if args.baseline is not None:
        trees["baseline"] = args.baseline.resolve()
    load_before = os.getloadavg()
    results = measure(trees, map_path, pano, max(1, args.runs), args.threads)
    machine = {**common.machine_info("cpu"), "load_average_before": [round(x, 2) for x in load_before],
               "torch_threads": args.threads or "localize's default"}
    result = {"trees": results, "runs": max(1, args.runs), "machine": machine, "map": str(map_path),
              "pano": str(pano), **results["this"]}
    con = common.console()
    where = ", ".join(f"{k} = {v}" for k, v in trees.items())
    con.print(table(results, f"Start-up and one localize (median of {result['runs']} fresh processes; {where})"))
    con.print(f"{pano.name} of synthroom_1 (1024 x 512) on its SIFT map; " + common.load_line(machine)
              + f"; load before {' / '.join(f'{x:.2f}' for x in load_before)}")
    common.write_json(args.output, result)
    con.print(f"wrote {args.output}")
    return result


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"bench_startup: {time.perf_counter() - t0:.0f} s")
