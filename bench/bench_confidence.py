"""Confidence of a localization, measured: synthetic data and the real ZInD home.

Run: ``python bench/bench_confidence.py [--data ../shared/data] [--real-maps DIR] [--fit]``.

Sets (each run once and cached under ``bench/.cache/confidence/``; ``--rerun`` runs again):

- ``synthetic rooms``: the demo-preset dataset of ``ldlmap synth`` of seed 11 (2 rooms, every
  split, 3 panoramas per split and room: 48 queries) with SIFT maps (``ldlmap prepare``),
  localized twice: ``--refine auto`` (features) and ``--refine geometric`` (lines alone, as the
  real layout maps are); ``synthetic rooms wrong map``: the first panorama of each split and room
  against the other room's map (16 queries, every pose wrong), both refinements;
- ``synthetic multiroom``: ``--preset multiroom --per-split 2`` of seed 11 (4 demo rooms in one
  map, a synthetic floor map: 64 queries), both refinements;
- ``held-out multiroom``: ``--preset multiroom`` of seed 12 (64 queries, both refinements), never
  fitted on: the synthetic check of the fit;
- ``real room`` and ``real floor``: the 19 panoramas of the shared ZInD home against its room
  maps and its floor map (maps from ``--real-maps`` (folders ``room_*``/``floor_*`` as
  ``bench/bench_real.py`` caches them), else built by bench_real's :func:`build_maps`).

Printed per set: the verdict counts, the precision of the confident poses (within 0.25 m / 5 deg
and 0.1 m / 5 deg), their coverage and the risk-coverage table (accuracy within 0.25 m / 5 deg of
the x % most confident queries, x = 50, 70, 80, 90, 100). The confidence is recomputed from each
record's ``confidence_signals`` with the current :data:`ldlloc.confidence.MODEL`, so cached runs
stay valid when the model is refitted. ``--fit`` fits the logistic on the ``synthetic`` sets (256
poses) and prints the constants to put into ``ldlloc/confidence.py``; the real home is never
fitted on, only checked. Results: ``bench/confidence.json``.
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

SEEDS = (11,)  # demo-preset datasets (2 rooms each)
MULTIROOM_SEED = 11
HELD_OUT_SEED = 12  # a second multiroom dataset, never fitted on: the synthetic check of the fit
COVERAGES = (50, 70, 80, 90, 100)
OK_T, OK_R = 0.25, 5.0  # the confidence target: confident poses within 0.25 m / 5 deg
TIGHT_T, TIGHT_R = 0.1, 5.0
TARGET_PRECISION = 0.98  # --fit: the threshold keeps >= 98 % of synthetic confident poses right (the confidence's target)
L2 = 0.1  # --fit: ridge weight on the standardized signals (the logistic must not chase a few queries)


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
        if all(r.status == "failed" or (r.confidence_signals and "features" in r.confidence_signals)
               for r in results):
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


def synthetic_results(rerun: bool, held_out: bool = True) -> dict[str, list]:
    from dataclasses import replace

    from ldlmap.datasets import open_dataset
    from ldlloc.pipeline import LocalizeParams

    out: dict[str, list] = {}
    roots = [synthetic_dataset(seed) for seed in SEEDS] + [multiroom_dataset(MULTIROOM_SEED)]
    if held_out:
        roots.append(multiroom_dataset(HELD_OUT_SEED))
    for root in roots:
        queries = open_dataset(root, "omniscenes").queries()
        runs = [(root.name, queries)]
        if len({q.scene for q in queries}) > 1:
            runs.append((f"{root.name}_wrong_map", wrong_map_queries(queries)))
        for name, qs in runs:
            for mode, kind in (("auto", "features"), ("geometric", "geometric")):
                label = "synthetic multiroom" if name.startswith("multiroom") else "synthetic rooms"
                if root.name.endswith(f"_s{HELD_OUT_SEED}") and name.startswith("multiroom"):
                    label = "held-out multiroom"  # not "synthetic ...": left out of the fit
                key = f"{label}{' wrong map' * name.endswith('wrong_map')} {kind}"
                out.setdefault(key, []).extend(cached_run(f"{name}_{mode}", qs, root / "maps",
                                                          replace(LocalizeParams(), refine_mode=mode), rerun))
    return out


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
    """Per query: the signals, the confidence and verdict of the current model, right or not."""
    from ldlloc.confidence import MODEL, RIVAL_SHARE, verdict_for

    out = []
    for r in results:
        ok = r.status != "failed" and r.t_error_m is not None
        sig = r.confidence_signals or {}
        conf = MODEL.confidence(sig) if ok and sig else 0.0
        out.append({"name": f"{r.scene}/{r.split}/{r.name}", "signals": sig, "confidence": conf,
                    "verdict": verdict_for(conf, r.competitors, rival=max(
                        sig.get("pnp_rival", 0.0), sig.get("map_rival", 0.0)) >= RIVAL_SHARE) if ok else "failed",
                    "competitors": [c["why"] for c in r.competitors],
                    "good": bool(ok and r.t_error_m < OK_T and r.r_error_deg < OK_R),
                    "tight": bool(ok and r.t_error_m < TIGHT_T and r.r_error_deg < TIGHT_R),
                    "t_error_m": r.t_error_m, "r_error_deg": r.r_error_deg})
    return out


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


def fit(rs: list[dict], signals: tuple[str, ...]) -> dict:
    """L2-regularized logistic with non-negative weights on the standardized ``signals`` (scipy),
    folded back to raw weights, and the smallest threshold at which the confident poses are >=
    TARGET_PRECISION right."""
    from scipy.optimize import minimize

    rs = [r for r in rs if r["signals"]]
    X = np.array([[r["signals"].get(k, 0.0) for k in signals] for r in rs], float)
    y = np.array([r["good"] for r in rs], float)
    mu, sd = X.mean(0), X.std(0).clip(1e-6)
    Z = (X - mu) / sd

    def nll(w):
        z = w[0] + Z @ w[1:]
        return float(np.sum(np.logaddexp(0, z) - y * z) + L2 * np.sum(w[1:] ** 2))

    # monotone: no signal may lower the confidence as it grows (an explainable model, and one that
    # cannot learn a synthetic quirk backwards)
    bounds = [(None, None)] + [(0.0, None)] * X.shape[1]
    w = minimize(nll, np.zeros(X.shape[1] + 1), method="L-BFGS-B", bounds=bounds).x
    weights = w[1:] / sd
    bias = w[0] - float(np.sum(w[1:] * mu / sd))
    p = 1 / (1 + np.exp(-(bias + X @ weights)))
    threshold = 1.0
    for t in np.unique(p)[::-1]:  # lower the threshold while the confident ones stay right enough
        sel = p >= t
        if np.mean(y[sel]) >= TARGET_PRECISION:
            threshold = float(t)
        elif sel.sum() >= 10:
            break
    return {"bias": round(float(bias), 3), "weights": {k: round(float(v), 3) for k, v in zip(signals, weights)},
            "confident_at": round(threshold, 3), "n": int(len(y)), "right": int(y.sum())}


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
    ap.add_argument("--fit", action="store_true", help="fit the logistic on the synthetic sets and print it")
    ap.add_argument("--rerun", action="store_true", help="localize again instead of reading cached runs")
    ap.add_argument("--no-held-out", action="store_true", help="skip the held-out multiroom dataset (seed 12)")
    ap.add_argument("--threads", type=int, default=1, help="torch and OpenCV threads (default 1)")
    ap.add_argument("--output", default=str(HERE / "confidence.json"))
    args = ap.parse_args(argv)
    import cv2
    import torch

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    sets = synthetic_results(args.rerun, not args.no_held_out)
    sets.update(real_results(real_data_root(args.data), Path(args.real_maps) if args.real_maps else None, args.rerun))
    table = {name: rows(rs) for name, rs in sets.items()}
    out: dict = {}
    synthetic = [r for name, rs in table.items() if name.startswith("synthetic") for r in rs]
    if args.fit:
        from ldlloc.confidence import SIGNALS

        out["fit"] = fit(synthetic, SIGNALS)
        console().print(f"fitted on synthetic: {out['fit']}")
    summaries = {name: set_summary(rs) for name, rs in table.items()}
    if synthetic:
        summaries["synthetic, all"] = set_summary(synthetic)
    print_sets(summaries)
    for name in ("real room", "real floor"):
        if name in table:
            print_queries(name, table[name])
    from dataclasses import asdict

    from ldlloc.confidence import MODEL

    out.update(model=asdict(MODEL),
               sets=summaries, queries=table)
    Path(args.output).write_text(json.dumps(out, indent=1))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
