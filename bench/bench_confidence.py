"""Confidence of a localization, measured: synthetic data, the layout benchmark, the building and the
real ZInD home, judged leave-one-kind-out.

Run: ``python bench/bench_confidence.py [--data ../shared/data] [--real-maps DIR] [--building
bench/building.json] [--results SET=RESULTS.json ...] [--skip synthetic,layout,real] [--fit]``.

Sets (each run once and cached under ``bench/.cache/confidence/``; ``--rerun`` runs again), by kind:

- ``demo`` rooms: the demo-preset dataset of ``ldlmap synth`` of seed 11 (2 rooms, every split, 3
  panoramas per split and room: 48 queries) with SIFT maps (``ldlmap prepare``), localized twice:
  ``--refine auto`` (features) and ``--refine geometric`` (lines alone, as the real layout maps
  are); and the first panorama of each split and room against the other room's map (16 queries,
  every pose wrong), both refinements;
- ``multiroom``: ``--preset multiroom --per-split 2`` of seeds 11 and 12 (4 demo rooms in one map,
  a synthetic floor map: 64 queries each), both refinements;
- ``layout <shape>``: the furnished rooms of ``bench/bench_layout.py`` (24 rooms of seed 39, one
  robot and one handheld panorama each), maps from their layout line files alone built with
  ``--up z --camera-height 0.3:2.2``, ``--max-tilt 10``; one kind per shape (box, sloped, stepped,
  arched, curved, apartment: 8 queries each);
- ``building``: the rows of a ``bench/bench_building.py`` run (``--building``: its results json,
  single images, the floor not given; skipped when absent);
- ``real room`` and ``real floor``: the 19 panoramas of the shared ZInD home against its room
  maps and its floor map (maps from ``--real-maps`` (folders ``room_*``/``floor_*`` as
  ``bench/bench_real.py`` caches them), else built by bench_real's :func:`build_maps`): never
  fitted, only checked.

Printed per set: the verdict counts, the precision of the confident poses (within 0.25 m / 5 deg
and 0.1 m / 5 deg), their coverage and the risk-coverage table (accuracy within 0.25 m / 5 deg of
the x % most confident queries, x = 50, 70, 80, 90, 100). The confidence and verdict are recomputed
from each record's ``confidence_signals`` and competitors with the current
:data:`ldlloc.confidence.MODEL` (:func:`ldlloc.confidence.judge`), so cached runs stay valid when
the model is refitted. Then the calibration judged leave-one-kind-out (:func:`ldlloc.confidence_fit.leave_one_kind_out`):
for each fitted kind, the logistic fitted on the other kinds and tested on it (poses, confident,
confident right, precision), for every signal set of ``SIGNAL_SETS``; the real home with the fit
on every kind. ``--fit`` prints the model fitted on all kinds (what goes into
``ldlloc/confidence.py``). Each leave-one-kind-out table is given twice: as judged, and without the
copies of identical rooms (``copies`` and the copies named, :func:`without_copies`: the code before
that check, from the same runs). Results: ``bench/confidence.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import CACHE, console  # noqa: E402
from ldlloc.confidence import COPY_WHY  # noqa: E402
from ldlloc.confidence_fit import fit, judged, leave_one_kind_out  # noqa: E402

SEEDS = (11,)  # demo-preset datasets (2 rooms each)
MULTIROOM_SEEDS = (11, 12)  # multiroom datasets (4 demo rooms in one map each)
LAYOUT_SEED, LAYOUT_ROOMS = 39, 24  # bench_layout's defaults
LAYOUT_BAND, LAYOUT_UP = (0.3, 2.2), "z"  # its maps as the map defaults will build them
COVERAGES = (50, 70, 80, 90, 100)
OK_T, OK_R = 0.25, 5.0  # the confidence target: confident poses within 0.25 m / 5 deg
TIGHT_T, TIGHT_R = 0.1, 5.0
CHECK_ONLY = ("real",)  # kinds never fitted on, only checked
SIGNAL_SETS = {"all signals": ("gap", "support", "support_gap", "margin", "features", "refined"),
               "without support": ("gap", "margin", "features", "refined")}


def synthetic_dataset(seed: int) -> Path:
    """A demo-preset dataset with SIFT maps (generated and prepared once)."""
    from ldlmap.batch.prepare import default_params, prepare_dataset
    from ldlmap.synth.generate import generate_dataset

    out = CACHE / "confidence" / f"synth_s{seed}"
    if not (out / "dataset.json").exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        generate_dataset(out, "demo", [], seed, overwrite=True, progress=False)
    if not (out / "maps" / "synthroom_2.h5").exists():
        prepare_dataset(out, "omniscenes", out / "maps", default_params("omniscenes"))  # SIFT maps, as `ldlmap prepare`
    return out


def multiroom_dataset(seed: int) -> Path:
    """``ldlmap synth --preset multiroom --per-split 2`` (4 demo rooms in one map: 64 queries) with its SIFT map."""
    from ldlmap.batch.prepare import default_params, prepare_dataset
    from ldlmap.synth.generate import generate_dataset

    out = CACHE / "confidence" / f"multiroom_s{seed}"
    if not (out / "dataset.json").exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        generate_dataset(out, "multiroom", [], seed, overwrite=True, progress=False, per_split=2)
    if not (out / "maps" / "multiroom_1.h5").exists():
        prepare_dataset(out, "omniscenes", out / "maps", default_params("omniscenes"))
    return out


def cached_run(name: str, queries: list, maps: Path, params, rerun: bool) -> list:
    """The results of ``queries`` (run once, then read from ``bench/.cache/confidence/<name>.json``)."""
    from ldlloc.batch.results import load_results
    from ldlloc.batch.run import run_queries

    path = CACHE / "confidence" / f"{name}.json"
    if path.exists() and not rerun:
        results, _ = load_results(path)
        if all(r.status == "failed" or (r.confidence_signals and "physical" in r.confidence_signals)
               for r in results):  # runs of the code before the physical check are redone
            return results
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    console().print(f"running {name}: {len(queries)} queries")
    return run_queries(queries, maps, path, params, "cpu")


def wrong_map_queries(queries: list) -> list:
    """The first panorama of each split and scene, given the other room's map (two-room datasets):
    every pose is wrong, and the confidence must say so (a user who picked the wrong map)."""
    from dataclasses import replace

    scenes = sorted({q.scene for q in queries})
    other = {a: b for a, b in zip(scenes, scenes[1:] + scenes[:1])}
    first: dict[tuple[str, str], object] = {}
    for q in sorted(queries, key=lambda q: q.name):
        first.setdefault((q.scene, q.split), q)
    return [replace(q, scene=other[q.scene]) for q in first.values()]


def synthetic_results(rerun: bool, multiroom_seeds: tuple[int, ...] = MULTIROOM_SEEDS) -> dict[str, list]:
    """Kind ``demo`` (the demo rooms and their wrong-map queries) and ``multiroom``, both refinements:
    ``{set name: results}``, each set name starting with its kind."""
    from dataclasses import replace

    from ldlmap.datasets import open_dataset
    from ldlloc.pipeline import LocalizeParams

    out: dict[str, list] = {}
    roots = [synthetic_dataset(seed) for seed in SEEDS] + [multiroom_dataset(seed) for seed in multiroom_seeds]
    for root in roots:
        queries = open_dataset(root, "omniscenes").queries()
        runs = [(root.name, queries)]
        if len({q.scene for q in queries}) > 1:
            runs.append((f"{root.name}_wrong_map", wrong_map_queries(queries)))
        for name, qs in runs:
            for mode, refine in (("auto", "features"), ("geometric", "geometric")):
                kind = "multiroom" if name.startswith("multiroom") else "demo"
                key = f"{kind} {root.name.split('_')[-1]}{' wrong map' * name.endswith('wrong_map')} {refine}"
                out[key] = cached_run(f"{name}_{mode}", qs, root / "maps", replace(LocalizeParams(), refine_mode=mode),
                                      rerun)
    return out


def layout_results(rerun: bool) -> dict[str, list]:
    """Kinds ``layout <shape>``: bench_layout's furnished rooms on their layout-only maps (``--up z
    --camera-height 0.3:2.2``), ``--max-tilt 10``."""
    from bench.bench_layout import MAX_TILT, SPLITS, build_maps, furnished_dataset
    from ldlmap.datasets import open_dataset
    from ldlloc.pipeline import LocalizeParams

    root = furnished_dataset(LAYOUT_ROOMS, LAYOUT_SEED, None)
    maps, _ = build_maps(root, LAYOUT_BAND, LAYOUT_UP)
    queries = open_dataset(root, "omniscenes").queries(list(SPLITS))
    results = cached_run(f"layout_s{LAYOUT_SEED}", queries, maps, LocalizeParams(max_tilt_deg=MAX_TILT), rerun)
    shape = {s["name"]: s["shape"] for s in json.loads((root / "dataset.json").read_text())["scenes"]}
    out: dict[str, list] = {}
    for r in results:
        out.setdefault(f"layout {shape[r.scene]}", []).append(r)
    return dict(sorted(out.items()))


def real_results(data: Path, real_maps: Path | None, rerun: bool) -> dict[str, list]:
    from ldlmap.datasets import open_dataset
    from ldlloc.pipeline import LocalizeParams

    zind = data / "zind"
    if not zind.is_dir():
        console().print(f"no real data at {zind}: the real home is skipped")
        return {}
    out = {}
    for level in ("room", "floor"):
        maps = None
        if real_maps is not None:
            found = sorted(real_maps.glob(f"{level}_default_*"))
            maps = found[-1] if found else None
        if maps is None:
            from bench.bench_real import build_maps

            maps = build_maps(zind, level, None)
        queries = open_dataset(zind, "zind", map_level=level).queries()
        out[f"real {level}"] = cached_run(f"real_{level}", queries, maps, LocalizeParams(), rerun)
    return out


def rows(results: list) -> list[dict]:
    """Per query: its signals and competitors, and whether it is right (within 0.25 m / 5 deg, and
    within 0.1 m / 5 deg); :func:`ldlloc.confidence_fit.judged` adds a model's confidence and verdict."""
    out = []
    for r in results:
        ok = r.status != "failed" and r.t_error_m is not None
        out.append({"name": f"{r.scene}/{r.split}/{r.name}", "signals": (r.confidence_signals or {}) if ok else {},
                    "competitors": [c["why"] for c in r.competitors],
                    "good": bool(ok and r.t_error_m < OK_T and r.r_error_deg < OK_R),
                    "tight": bool(ok and r.t_error_m < TIGHT_T and r.r_error_deg < TIGHT_R),
                    "t_error_m": r.t_error_m, "r_error_deg": r.r_error_deg})
    return out


def given_results(specs: list[str]) -> dict[str, list[dict]]:
    """``--results SET=PATH``: each results file's rows (:func:`rows`) under its set name."""
    from ldlloc.batch.results import load_results

    out = {}
    for spec in specs:
        name, _, path = spec.partition("=")
        if not path:
            raise SystemExit(f"--results {spec}: expected SET=PATH")
        out[name] = rows(load_results(Path(path))[0])
    return out


def building_rows(path: Path) -> list[dict]:
    """The rows of a ``bench_building.py`` run (its results json), as :func:`rows` makes them, with
    ``wrong_copy``: the pose landed in another copy of an identical room."""
    data = json.loads(Path(path).read_text())
    out = []
    for r in data["rows"]:
        ok = r["t_err"] is not None
        out.append({"name": r["name"], "signals": (r.get("signals") or {}) if ok else {},
                    "competitors": list(r.get("competitors") or []),
                    "good": bool(ok and r["t_err"] < OK_T and r["r_err"] < OK_R),
                    "tight": bool(ok and r["t_err"] < TIGHT_T and r["r_err"] < TIGHT_R),
                    "t_error_m": r["t_err"], "r_error_deg": r["r_err"],
                    "wrong_copy": bool(ok and r["group"] is not None and not r["right_room"])})
    return out


def without_copies(rs: list[dict]) -> list[dict]:
    """The rows as the code before the copies check judged them (:mod:`ldlloc.refine.copies`): without
    the ``copies`` signal and the copies named among the competitors."""
    return [{**r, "signals": {k: v for k, v in r["signals"].items() if k != "copies"},
             "competitors": [c for c in r["competitors"] if not str(c).startswith(COPY_WHY)]} for r in rs]


def set_summary(rs: list[dict]) -> dict:
    n = len(rs)
    conf = [r for r in rs if r["verdict"] == "confident"]
    order = sorted(rs, key=lambda r: -r["confidence"])
    risk = {}
    for x in COVERAGES:
        top = order[:max(1, int(np.ceil(n * x / 100)))] if n else []
        risk[x] = float(np.mean([r["good"] for r in top])) if top else None
    return {"count": n, **{v: sum(r["verdict"] == v for r in rs) for v in ("confident", "ambiguous", "failed")},
            "coverage": len(conf) / n if n else None,
            "accuracy_0.25m_5deg": float(np.mean([r["good"] for r in rs])) if n else None,
            "precision_0.25m_5deg": float(np.mean([r["good"] for r in conf])) if conf else None,
            "precision_0.1m_5deg": float(np.mean([r["tight"] for r in conf])) if conf else None,
            "risk_coverage_0.25m_5deg": risk,
            "ambiguous_with_competitors": sum(bool(r["competitors"]) for r in rs if r["verdict"] == "ambiguous")}


def kind_of(set_name: str) -> str:
    """The kind a set belongs to: ``demo``, ``multiroom``, ``layout <shape>``, ``building``, ``real``."""
    words = set_name.split()
    return " ".join(words[:2]) if words[0] == "layout" else words[0]


def print_loko(table: dict[str, dict[str, dict]]) -> None:
    from rich.table import Table

    t = Table(title="confidence judged leave-one-kind-out: fitted without the kind, tested on it (0.25 m / 5 deg)")
    for col in ("signals", "held-out kind", "poses", "right", "confident", "confident right", "precision",
                "wrong copy", "threshold"):
        t.add_column(col, justify="right")
    for name, per in table.items():
        for kind, c in per.items():
            t.add_row(name, kind, str(c["poses"]), str(c["right"]), str(c["confident"]), str(c["confident_right"]),
                      "-" if c["precision"] is None else f"{c['precision']:.3f}", str(c["confident_wrong_copy"]),
                      f"{c['confident_at']:.3f}")
    console().print(t)


def print_sets(summaries: dict[str, dict]) -> None:
    from rich.table import Table

    t = Table(title="confidence: verdicts, precision of the confident poses, risk-coverage (within 0.25 m / 5 deg)")
    for col in ("set", "n", "conf", "amb", "fail", "coverage", "all ok", "prec 0.25m", "prec 0.1m",
                *[f"top {x}%" for x in COVERAGES]):
        t.add_column(col, justify="right")
    f = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    for name, s in summaries.items():
        t.add_row(name, str(s["count"]), str(s["confident"]), str(s["ambiguous"]), str(s["failed"]), f(s["coverage"]),
                  f(s["accuracy_0.25m_5deg"]), f(s["precision_0.25m_5deg"]), f(s["precision_0.1m_5deg"]),
                  *[f(s["risk_coverage_0.25m_5deg"][x]) for x in COVERAGES])
    console().print(t)


def print_queries(name: str, rs: list[dict]) -> None:
    """The real queries one by one: signals, confidence, verdict, errors."""
    from rich.table import Table

    t = Table(title=f"{name}: per query")
    from ldlloc.confidence import SIGNALS as names

    for col in ("query", *names, "conf", "verdict", "competitors", "t err m", "r err deg"):
        t.add_column(col)
    for r in sorted(rs, key=lambda r: -r["confidence"]):
        s = r["signals"]
        t.add_row(r["name"].split("/")[-1], *[f"{s.get(k, float('nan')):.3f}" for k in names],
                  f"{r['confidence']:.3f}", r["verdict"], ", ".join(r["competitors"][:2]),
                  "-" if r["t_error_m"] is None else f"{r['t_error_m']:.3f}",
                  "-" if r["r_error_deg"] is None else f"{r['r_error_deg']:.1f}")
    console().print(t)


def main(argv: list[str] | None = None) -> int:
    from bench.bench_real import real_data_root

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="real data folder (default $LDL_REAL_DATA or ../shared/data)")
    ap.add_argument("--real-maps", default=None, help="folder of cached real maps (room_*/, floor_*/), e.g. "
                    "another checkout's bench/.cache/real (default: build them like bench_real.py)")
    ap.add_argument("--building", action="append", metavar="[KIND=]PATH",
                    help="a bench_building.py results json (its rows: the kind KIND, default building), repeatable")
    ap.add_argument("--fit", action="store_true", help="fit the logistic on every fitted kind and print it")
    ap.add_argument("--rerun", action="store_true", help="localize again instead of reading cached runs")
    ap.add_argument("--no-layout", action="store_true", help="skip the layout benchmark's rooms")
    ap.add_argument("--multiroom-seeds", default=",".join(map(str, MULTIROOM_SEEDS)),
                    help="multiroom datasets to run (comma-separated seeds; default 11,12)")
    ap.add_argument("--results", action="append", metavar="SET=PATH", help="an `ldlloc run` results file with ground "
                    "truth as a set (its kind: the set name's first word; 'real ...' is checked only), repeatable")
    ap.add_argument("--skip", default="", help="comma-separated: synthetic, layout, real (sets not run)")
    ap.add_argument("--threads", type=int, default=1, help="torch and OpenCV threads (default 1)")
    ap.add_argument("--output", default=str(HERE / "confidence.json"))
    args = ap.parse_args(argv)
    import cv2
    import torch

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    seeds = tuple(int(x) for x in args.multiroom_seeds.split(",") if x.strip())
    skip = {x.strip() for x in args.skip.split(",") if x.strip()}
    sets = {} if "synthetic" in skip else {name: rows(rs) for name, rs in synthetic_results(args.rerun, seeds).items()}
    if not args.no_layout and "layout" not in skip:
        sets.update({name: rows(rs) for name, rs in layout_results(args.rerun).items()})
    for spec in args.building or []:  # [KIND=]PATH
        kind, _, path = spec.rpartition("=")
        if Path(path).exists():
            sets[kind or "building"] = building_rows(Path(path))
    sets.update(given_results(args.results or []))
    if "real" not in skip:
        real = real_results(real_data_root(args.data), Path(args.real_maps) if args.real_maps else None, args.rerun)
        sets.update({name: rows(rs) for name, rs in real.items()})
    kinds: dict[str, list[dict]] = {}
    for name, rs in sets.items():
        kinds.setdefault(kind_of(name), []).extend(rs)
    out: dict = {}
    if args.fit:
        from ldlloc.confidence import SIGNALS

        out["fit"] = fit([{**r, "kind": k} for k, rs in kinds.items() if not k.startswith(CHECK_ONLY) for r in rs],
                         SIGNALS)
        console().print(f"fitted on every fitted kind: {out['fit']}")
    table = {name: judged(rs) for name, rs in sets.items()}
    summaries = {name: set_summary(rs) for name, rs in table.items()}
    for kind, rs in kinds.items():
        if sum(kind_of(n) == kind for n in sets) > 1:
            summaries[f"{kind}, all"] = set_summary(judged(rs))
    print_sets(summaries)
    out["leave_one_kind_out"] = {name: leave_one_kind_out(kinds, sig, CHECK_ONLY) for name, sig in SIGNAL_SETS.items()}
    before = {kind: without_copies(rs) for kind, rs in kinds.items()}
    out["leave_one_kind_out"].update({f"{name}, no copies (before)": leave_one_kind_out(before, sig, CHECK_ONLY)
                                      for name, sig in SIGNAL_SETS.items()})
    print_loko(out["leave_one_kind_out"])
    for name in ("real room", "real floor"):
        if name in table:
            print_queries(name, table[name])
    from dataclasses import asdict

    from ldlloc.confidence import MODEL

    out.update(model=asdict(MODEL), sets=summaries, queries=table)
    Path(args.output).write_text(json.dumps(out, indent=1))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
