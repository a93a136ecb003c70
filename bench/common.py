"""Shared helpers of the benchmarks: cached synthetic data, cached maps, query loops, machine info.

Everything generated lands in ``bench/.cache/`` (gitignored) and is reused by later runs; each
name ends with a hash of the code that made it (:func:`synth_tag`, :func:`map_tag`), so a change
of the generator or of the map builder regenerates instead of reusing stale data:

- ``demo_s<seed>/``: the synthetic demo dataset (``generate_dataset(..., 'demo', seed)``,
  OmniScenes layout, 2 scenes, 3 panoramas per split, 1024 x 512);
- ``ablation_s<seed>_n<per>_k<scenes>/``: demo-preset rooms with only an extreme split of
  ``per`` panoramas per scene (the pose-search ablation);
- ``scan_<points>_s<seed>.ply``: a room-sized simulated scan of a "standard"-preset room;
- ``maps/<dataset>/<scene>_<tag>.h5``: maps built from those scans.

The helpers never time anything themselves; the ``bench_*.py`` scripts do.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `python bench/x.py` from anywhere imports the working tree
    sys.path.insert(0, str(ROOT))

CACHE = Path(os.environ.get("LDL_BENCH_CACHE", ROOT / "bench" / ".cache"))

# The paper's runtime table (OmniScenes, seconds per query): stage -> (CPU, GPU).
PAPER_SECONDS: dict[str, tuple[float, float]] = {
    "lines2d": (0.141, 0.141),
    "rotation": (1.124, 0.009),
    "search": (0.052, 0.001),
    "refine": (5.573, 0.587),
    "total": (6.890, 0.738),
}
PAPER_STAGE_NAMES = {
    "lines2d": "line extraction",
    "rotation": "rotation estimation",
    "search": "distance functions",
    "refine": "refinement",
    "total": "total",
}


def console():
    """A Rich console for the tables (wide enough not to wrap them in logs)."""
    from rich.console import Console

    return Console(width=max(150, int(os.environ.get("COLUMNS", 0) or 0)))


# ------------------------------------------------------------------------------------ data


def source_hash(package: str, include: str = "**/*.py", exclude: tuple[str, ...] = ()) -> str:
    """8 hex digits of the SHA-1 of a package's source files: cached data keyed by it is
    regenerated when the code that made it changes (the working tree moves under the cache)."""
    import hashlib

    base = ROOT / package
    h = hashlib.sha1()
    for f in sorted(base.glob(include)):
        rel = f.relative_to(base).as_posix()
        if any(rel.startswith(e) for e in exclude):
            continue
        h.update(rel.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:8]


def synth_tag() -> str:
    """Version tag of the synthetic data generator's code."""
    return source_hash("ldlmap", "synth/*.py")


def map_tag() -> str:
    """Version tag of the map-building code (everything in ``ldlmap`` but the generator and CLI)."""
    return source_hash("ldlmap", exclude=("synth/", "cli"))


def demo_dataset(seed: int = 1) -> Path:
    """The synthetic demo dataset for ``seed`` (generated once, then reused)."""
    from ldlmap.synth.generate import generate_dataset

    out = CACHE / f"demo_s{seed}_{synth_tag()}"
    if not (out / "dataset.json").exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        generate_dataset(out, "demo", [], seed, overwrite=True, progress=False)
    return out


def preset_rooms_dataset(out: Path, spec_dir: Path, preset: str, seed: int, scenes: int, name: str,
                         counts: dict[str, int]) -> Path:
    """A dataset of the preset's random rooms ``random_spec(preset, seed, i)``, ``i = 1..scenes``,
    named ``<name><i>``, with ``counts[split]`` panoramas in the robot / handheld / extreme splits
    (0 for the others), no change or illumination splits. The specs are written as TOML into
    ``spec_dir`` and passed to the generator (so the dataset records the exact specs it used);
    an existing dataset at ``out`` is reused."""
    from ldlmap.synth.generate import generate_dataset
    from ldlmap.synth.spec import dump_spec_toml
    from ldlmap.synth.presets import random_spec

    if (out / "dataset.json").exists():
        return out
    spec_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(1, scenes + 1):
        spec = random_spec(preset, seed, i)
        cap = spec.capture
        cap = replace(cap, robot=replace(cap.robot, count=counts.get("robot", 0)),
                      handheld=replace(cap.handheld, count=counts.get("handheld", 0)),
                      extreme=replace(cap.extreme, count=counts.get("extreme", 0)), change=replace(cap.change, count=0),
                      illumination=replace(cap.illumination, enabled=False))
        spec = replace(spec, name=f"{name}{i:02d}", capture=cap)
        p = spec_dir / f"{name}{i:02d}.toml"
        p.write_text(dump_spec_toml(spec))
        paths.append(p)
    generate_dataset(out, None, paths, seed, overwrite=True, progress=False, illumination=False)
    return out


def extreme_dataset(seed: int = 7, per_split: int = 10, scenes: int = 3) -> Path:
    """Demo-preset rooms whose only split is ``extreme`` with ``per_split`` panoramas each
    (:func:`preset_rooms_dataset`)."""
    return preset_rooms_dataset(CACHE / f"ablation_s{seed}_n{per_split}_k{scenes}_{synth_tag()}",
                                CACHE / f"ablation_specs_s{seed}_n{per_split}_k{scenes}", "demo", seed, scenes, "abl",
                                {"extreme": per_split})


def room_scan(points: int = 1_000_000, seed: int = 0) -> tuple[Path, dict[str, Any]]:
    """A simulated scan of about ``points`` points of a "standard"-preset room, as a PLY.

    The preset's scanner settings (stations, noise, holes) are kept and the density raised so
    that the room's surface yields ``points`` samples (the scanner simulation then drops unseen
    and grazing returns, hence the 1.25 margin; the cap keeps it at most ``points``).
    Returns the path and a small description (points, room extent).
    """
    from ldlmap.synth.scan import mesh_area, sample_scan, scan_params, write_ply
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.presets import random_spec

    out = CACHE / f"scan_{points}_s{seed}_{synth_tag()}.ply"
    meta_path = out.with_suffix(".json")
    if out.exists() and meta_path.exists():
        return out, json.loads(meta_path.read_text())
    spec = random_spec("standard", seed, 1)
    mesh = build_scene(spec)
    params = replace(scan_params(spec.scan), density=1.25 * points / mesh_area(mesh), max_points=points)
    P, C = sample_scan(mesh, params, np.random.default_rng(seed))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_ply(out, P, C)
    ext = P.max(0) - P.min(0)
    meta = {"points": int(len(P)), "extent_m": [round(float(x), 2) for x in ext], "preset": "standard",
            "seed": seed}
    meta_path.write_text(json.dumps(meta))
    return out, meta


def cached_map(dataset: Path, scene: str, num_views: int = 40, features: str = "sift",
               **params: Any) -> Path:
    """The map of ``scene`` of ``dataset`` built with ``num_views`` views (built once, reused; the
    build's seconds beside it, :func:`build_seconds`)."""
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.datasets import open_dataset

    tag = f"{features}_v{num_views}" + "".join(f"_{k}{v}" for k, v in sorted(params.items())) + f"_{map_tag()}"
    out = CACHE / "maps" / dataset.name / f"{scene}_{tag}.h5"
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        ds = open_dataset(dataset, "omniscenes")
        t0 = time.perf_counter()
        build_map(ds.point_cloud(scene), out, params=BuildParams().replaced(num_views=num_views, features=features, **params),
                  name=scene)
        out.with_suffix(".json").write_text(json.dumps({"build_seconds": time.perf_counter() - t0}))
    return out


def build_seconds(map_path: Path) -> float | None:
    """Seconds :func:`cached_map` took to build ``map_path`` (None: not recorded)."""
    meta = Path(map_path).with_suffix(".json")
    return float(json.loads(meta.read_text())["build_seconds"]) if meta.exists() else None


def subset_views(ldl_map, num_views: int):
    """A copy of ``ldl_map`` keeping only its first ``num_views`` rendered views.

    Views are chosen by farthest-point sampling from a fixed start, so the first ``k`` views of
    a map built with ``V >= k`` views are exactly the views a ``k``-view build renders; each
    candidate translation is re-served by its nearest kept view, as ``build_map`` does.
    """
    from ldlmap.map.contents import MapFeatures

    f = ldl_map.features
    k = min(int(num_views), f.num_views)
    end = int(f.offsets[k])
    centers = f.view_centers[:k]
    d = np.linalg.norm(ldl_map.translations[:, None, :] - centers[None, :, :], axis=2)
    feats = MapFeatures(backend=f.backend, view_centers=centers, offsets=f.offsets[: k + 1].copy(),
                        xyz=f.xyz[:end], keypoints=f.keypoints[:end], scores=f.scores[:end],
                        descriptors=f.descriptors[:end], translation_view=d.argmin(1).astype(np.int32),
                        width=f.width, height=f.height)
    return replace(ldl_map, features=feats)


# ------------------------------------------------------------------------------- localization


@dataclass
class QueryOutcome:
    """One localized query: the evaluate record plus the pose-search candidates (for recall)."""

    result: Any  # ldlloc.batch.accuracy.QueryResult
    loc: Any  # ldlloc.pipeline.Localization or None when it failed


def localize_queries(localizer, queries: Sequence[Any], on_done: Callable[[int, int], None] | None = None,
                     transform: Callable[[np.ndarray, Any], np.ndarray] | None = None) -> list[QueryOutcome]:
    """Localize ``queries`` (``ldlmap.datasets.Query``) with ``localizer``; failures are recorded.
    ``transform(image, query)``: what each panorama goes through first (e.g. an appearance change)."""
    from ldlloc.batch.accuracy import QueryResult
    from ldlloc.pipeline import load_image
    from ldlmap.core.errors import InputError
    from ldlmap.core.geometry import rotation_error_deg, translation_error

    out = []
    for i, q in enumerate(queries):
        rec = QueryResult(image=str(q.image), scene=q.scene, split=q.split, name=q.name)
        loc = None
        try:
            img = load_image(q.image)
            loc = localizer.localize(img if transform is None else transform(img, q))
        except InputError as exc:
            rec.status, rec.message = "failed", str(exc)
        if loc is not None:
            rec.R, rec.t = loc.rot_cam_from_world.tolist(), loc.center.tolist()
            rec.t_error_m = translation_error(loc.center, q.center)
            rec.r_error_deg = rotation_error_deg(loc.rot_cam_from_world, q.rot_cam_from_world)
            rec.seconds = dict(loc.seconds)
            rec.num_rotations, rec.num_matches, rec.num_inliers = loc.num_rotations, loc.num_matches, loc.num_inliers
            rec.refined, rec.status, rec.message = loc.refined, loc.status, loc.message
        out.append(QueryOutcome(rec, loc))
        if on_done:
            on_done(i + 1, len(queries))
    return out


def candidate_errors(loc, query) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) errors of every top-K candidate of a localization."""
    from ldlmap.core.geometry import rotation_error_deg

    terr = np.linalg.norm(loc.candidates_center - query.center[None], axis=1)
    rerr = np.array([rotation_error_deg(R, query.rot_cam_from_world) for R in loc.candidates_rot])
    return terr, rerr


# ---------------------------------------------------------------------------------- machine


def machine_info(device: str = "cpu") -> dict[str, Any]:
    """CPU count, torch threads, load average and versions: the context of a timing."""
    import torch

    info: dict[str, Any] = {
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "platform": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "device": device,
    }
    if device.startswith("cuda") and torch.cuda.is_available():
        info["cuda_device"] = torch.cuda.get_device_name(0)
    return info


def set_threads(threads: int | None) -> None:
    """Threads as the product sets them (:func:`ldlmap.core.cli_common.set_threads`: torch, OpenCV and
    the BLAS pools) when ``threads`` is given (> 0); else keep the libraries' defaults.

    On a shared, oversubscribed machine torch's OpenMP workers spin at every barrier while
    their cores run other processes: the many small ops of the pose search then slow down
    by an order of magnitude, which is why ``ldlloc`` and the benchmarks default to 1 thread.
    """
    if threads:
        from ldlmap.core.cli_common import set_threads as product_set_threads

        product_set_threads(int(threads))


def load_line(info: dict[str, Any]) -> str:
    """A one-line description of the machine and its load, printed under each table."""
    la = info.get("load_average", [])
    return (f"{info.get('cpu_count')} CPUs, torch threads {info.get('torch_threads')}, "
            f"load average {' / '.join(f'{x:.2f}' for x in la)} (1/5/15 min), device {info.get('device')}")


def parse_field(template: Any, value: str) -> Any:
    """A ``field=value`` experiment option's ``value`` as the type of ``template`` (the dataclass
    field's default); booleans from true/false/1/0/yes/no."""
    if isinstance(template, bool):
        if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise SystemExit(f"not a boolean: {value!r} (true or false)")
        return value.lower() in ("true", "1", "yes")
    return type(template)(value)


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` to ``path`` atomically (through ``ldlmap.core.errors.atomic_file``)."""
    from ldlmap.core.errors import atomic_file

    with atomic_file(path) as tmp:
        Path(tmp).write_text(json.dumps(data, indent=1) + "\n")


def fmt(x: float | None, spec: str = ".3f") -> str:
    """Format a number for a table cell; ``-`` for missing or non-finite values."""
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


class Stopwatch:
    """``with Stopwatch() as sw: ...`` then ``sw.seconds``."""

    def __enter__(self) -> "Stopwatch":
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self.t0
