"""Maps from what scanners, phones and architects hand over: one synthetic room written
as .ply, .e57 (its scanner panoramas embedded), .las, .laz, .glb (y-up) and .ifc; a map built from
each with `ldlmap build` (each build in its own process: wall seconds and peak memory, RSS of the
process); the room's queries localized against each map (final pose within 0.1 m / 5 deg; the IFC
map is lines-only and refined geometrically); the E57's own panoramas written by `ldlmap e57
--images` and checked with `ldlloc run`; and a 3-storey building written as IFC: one map per storey,
its queries against the folder of storey maps, the storey not given.

Run: ``python bench/bench_inputs.py [--views 12] [--num-trans 400] [--density 2000] [--output bench/inputs.json]``.
Inputs and maps go to ``bench/.cache/inputs/`` (rebuilt each run). About 10 min of 2 busy cores.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import CACHE, console  # noqa: E402

OUT = CACHE / "inputs"
# query poses in the L-shaped room: centre, yaw (deg), tilt (deg)
QUERIES = (((1.5, 3.8, 1.4), 60.0, 2.0), ((5.9, 0.7, 1.2), 200.0, 1.0), ((2.0, 1.5, 1.5), 300.0, 4.0),
           ((6.2, 2.2, 1.3), 120.0, 2.0))


def _child_build(argv: list[str]) -> None:
    """In a child process: run `ldlmap build ARGV`, then print wall seconds and peak RSS as JSON."""
    import resource

    from typer.testing import CliRunner

    from ldlmap.cli import app

    tick = time.perf_counter()
    res = CliRunner().invoke(app, ["build", *argv])
    secs = time.perf_counter() - tick
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB -> MB (Linux)
    print(json.dumps({"ok": res.exit_code == 0, "seconds": secs, "peak_mb": rss, "output": res.output[-600:]}))


def _build(argv: list[str]) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, __file__, "--child", json.dumps(argv)], capture_output=True, text=True,
                         env=env, cwd=ROOT)
    last = [line for line in out.stdout.splitlines() if line.startswith("{")]
    if not last:
        raise RuntimeError(out.stderr[-2000:])
    return json.loads(last[-1])


def _queries(mesh, dz: float = 0.0, poses=QUERIES):
    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlmap.synth.render import Renderer

    render = Renderer(mesh)
    for c, yaw, tilt in poses:
        R = rotation_from_axis_angle(np.array([1.0, 0, 0]), np.radians(tilt)) @ \
            rotation_from_axis_angle(np.array([0, 0, 1.0]), np.radians(yaw))
        yield render.render(R, np.array(c), 1024).rgb, R, np.array(c) + [0.0, 0.0, dz]


def _localize(map_path: Path, mesh, utm: bool) -> list[tuple[float, float]]:
    from ldlloc.pipeline import LocalizeParams, Localizer
    from ldlmap.core.frame import pose_to_map
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.map.mapfile import read_map

    m = read_map(map_path)
    loc = Localizer(m, LocalizeParams())
    errs = []
    for img, R, c in _queries(mesh):
        if utm:  # the LAS scan lies at UTM coordinates: the truth in the map's (recentred) frame
            from ldlmap.synth.formats import UTM_OFFSET

            R, c = pose_to_map(R, c + UTM_OFFSET, m.input_to_map)
        try:
            r = loc.localize(img)
            errs.append((float(np.linalg.norm(r.center - c)), float(rotation_error_deg(r.rot_cam_from_world, R))))
        except Exception as exc:  # noqa: BLE001 - a failed query is a measurement
            errs.append((float("inf"), float("inf")))
            console().print(f"{map_path.name}: query failed: {exc}")
    return errs


def _room_formats(args) -> list[dict]:
    from tests.test_inputs_formats import ROOM
    from ldlmap.synth.formats import ROOM_FORMATS, room_capture, write_room

    cap = room_capture(ROOM, density=args.density, pano_width=1024)
    rows = []
    for fmt in ROOM_FORMATS:
        src = OUT / f"room.{fmt}"
        write_room(fmt, src, cap)
        opts = ["--num-views", str(args.views), "--num-trans", str(args.num_trans)] if fmt != "ifc" else \
            ["--trans-spacing", "0.3"]
        b = _build([str(src), "-o", str(OUT / f"room_{fmt}.h5"), "--overwrite", *opts])
        if not b["ok"]:
            console().print(f"{fmt}: build failed: {b['output']}")
            rows.append({"format": fmt, "ok": False})
            continue
        errs = _localize(OUT / f"room_{fmt}.h5", cap.mesh, fmt in ("las", "laz"))
        good = sum(t < 0.1 and r < 5.0 for t, r in errs)
        rows.append({"format": fmt, "ok": True, "file_mb": src.stat().st_size / 1e6, "build_s": b["seconds"],
                     "peak_mb": b["peak_mb"], "within_10cm_5deg": f"{good}/{len(errs)}",
                     "median_t_m": float(np.median([t for t, _ in errs])),
                     "median_r_deg": float(np.median([r for _, r in errs]))})
    return rows


def _e57_own_panoramas() -> dict:
    from typer.testing import CliRunner

    from ldlloc.cli import app as loc_app
    from ldlmap.cli import app as map_app

    root = OUT / "e57_check"
    run = CliRunner()
    r = run.invoke(map_app, ["e57", str(OUT / "room.e57"), "--images", str(root), "--overwrite"])
    assert r.exit_code == 0, r.output
    (root / "maps").mkdir(exist_ok=True)
    os.replace(OUT / "room_e57.h5", root / "maps" / "room.h5")
    r = run.invoke(loc_app, ["run", "--root", str(root), "--split", "scanner", "-o", str(OUT / "e57_check.json"),
                             "--overwrite"])
    assert r.exit_code == 0, r.output
    qs = json.loads((OUT / "e57_check.json").read_text())["queries"]
    return {"panoramas": len(qs), "errors": [(q["t_error_m"], q["r_error_deg"]) for q in qs]}


def _building() -> dict:
    from tests.test_inputs_ifc import BUILDING, _write
    from ldlloc.batch.which_map import MapSet, localize_on_maps
    from ldlloc.pipeline import LocalizeParams
    from ldlmap.core.geometry import rotation_error_deg
    from ldlmap.synth.scene import build_scene

    model = _write(OUT / "house.ifc", "foot")
    b = _build([str(model), "-o", str(OUT / "storeys"), "--trans-spacing", "0.3", "--overwrite"])
    maps = MapSet.load(OUT / "storeys", LocalizeParams(), "cpu")
    out = []
    for name, z, room, _ in BUILDING:
        pose = {"ground": (((4.0, 1.6, 1.5), 30.0, 3.0), ((2.0, 1.0, 1.2), 250.0, 1.0)),
                "first": (((1.5, 3.6, 1.4), 60.0, 2.0), ((5.5, 1.5, 1.3), 170.0, 2.0)),
                "second": (((2.0, 2.2, 1.3), 200.0, 1.0), ((4.5, 3.0, 1.5), 20.0, 3.0))}[name]
        for img, R, c in _queries(build_scene(room), z, pose):
            loc, choice = localize_on_maps(img, maps, None)
            out.append({"storey": name, "chosen": choice.chosen.entry.scene, "t_m": float(np.linalg.norm(loc.center - c)),
                        "r_deg": float(rotation_error_deg(loc.rot_cam_from_world, R))})
    return {"build_s": b["seconds"], "peak_mb": b["peak_mb"], "queries": out}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--num-trans", type=int, default=400)
    ap.add_argument("--density", type=float, default=2000.0)
    ap.add_argument("--output", type=Path, default=ROOT / "bench" / "inputs.json")
    args = ap.parse_args()
    if args.child:
        return _child_build(json.loads(args.child))
    OUT.mkdir(parents=True, exist_ok=True)
    from rich.table import Table

    rows = _room_formats(args)
    t = Table(title="one room, six formats: build (own process) and 4 queries localized")
    for col in ("format", "file MB", "build s", "peak MB", "within 0.1 m / 5 deg", "median m", "median deg"):
        t.add_column(col)
    for r in rows:
        if r["ok"]:
            t.add_row(r["format"], f"{r['file_mb']:.1f}", f"{r['build_s']:.1f}", f"{r['peak_mb']:.0f}",
                      r["within_10cm_5deg"], f"{r['median_t_m']:.3f}", f"{r['median_r_deg']:.2f}")
        else:
            t.add_row(r["format"], "-", "failed", "-", "-", "-", "-")
    console().print(t)
    e57 = _e57_own_panoramas()
    console().print(f"E57's own panoramas with ldlloc run: {e57['errors']}")
    bld = _building()
    ok = sum(q["chosen"] == q["storey"] and q["t_m"] < 0.1 and q["r_deg"] < 5 for q in bld["queries"])
    console().print(f"3-storey IFC (feet): maps in {bld['build_s']:.1f} s, peak {bld['peak_mb']:.0f} MB; "
                    f"{ok}/{len(bld['queries'])} queries on the right storey within 0.1 m / 5 deg: {bld['queries']}")
    load = os.getloadavg()
    args.output.write_text(json.dumps({"room": rows, "e57_own_panoramas": e57, "building": bld,
                                       "load": load}, indent=1))
    console().print(f"load {load[0]:.1f}; wrote {args.output}")


if __name__ == "__main__":
    main()
