"""Write a synthetic dataset in the OmniScenes layout (DESIGN.md sections 4 and 7).

For each scene ``<room>_<n>`` (``synthroom_1``, ``synthroom_2``, ...)::

    pcd/<room>_<n>.txt, .ply                    the simulated scan of the unchanged scene
    mesh/<room>_<n>.obj (+ .mtl, .png)          the textured mesh
    gt_lines/<room>_<n>.obj, .txt               ground-truth 3D edges of the mesh
    specs/<room>_<n>.toml                       the spec used (scene_2: the changed scene)
    <split>_pano/<split>_<room>_<n>_scene_<k>/<id>.jpg   query panoramas (JPEG quality 95)
    <split>_pose/<split>_<room>_<n>_scene_<k>/<id>.txt   3x4 [R | t] (R world->camera, t centre)
    dataset.json                                what was generated (no timestamps)

``scene_1`` holds the splits captured in the unchanged scene (robot, handheld, extreme and the
illumination variants ``extreme_intensity``, ``extreme_gamma``, ``extreme_white_balance``, same
poses as ``extreme``); ``scene_2`` the change splits, rendered in ``changed_spec(spec)`` while the
scan stays the unchanged scene.

Everything derives from ``seed`` through independent random streams per scene and per stage
(``np.random.default_rng([seed, spec.seed, scene, stage])``), so the same seed gives byte-identical files
and turning the illumination splits off changes nothing else. The whole folder is built in a
temporary sibling and renamed at the end (:func:`~ldlmap.errors.atomic_dir`).
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ldlmap.errors import InputError, LdlError, atomic_dir
from ldlmap.synth.poses import sample_poses
from ldlmap.synth.render import Renderer, apply_illumination
from ldlmap.synth.spec import MAX_COUNT as MAX_PER_SPLIT
from ldlmap.synth.spec import MAX_WIDTH, MIN_WIDTH, SEED_LIMIT

GENERATOR_VERSION = "1.0"
BASE_SPLITS = ("robot", "handheld", "extreme", "change_robot", "change_handheld")
ILLUMINATION_SPLITS = ("extreme_intensity", "extreme_gamma", "extreme_white_balance")
JPEG_QUALITY = 95
_STREAM = {"scan": 1, "change": 2, "robot": 10, "handheld": 11, "extreme": 12, "change_robot": 13,
           "change_handheld": 14}


@dataclass(frozen=True)
class CaptureSettings:
    """Rendering settings of one scene, resolved from its ``CaptureSpec`` and the overrides."""

    width: int = 1024  # panorama width W
    height: int = 512  # panorama height H = W / 2
    counts: dict[str, int] = field(default_factory=lambda: {s: 3 for s in BASE_SPLITS})
    blur_px: dict[str, float] = field(default_factory=lambda: {"extreme": 8.0})  # max blur at W = 1024
    illumination: dict[str, tuple[str, dict]] = field(default_factory=dict)  # split -> (kind, params)
    supersample: int = 2  # s x s rays per pixel, averaged (anti-aliasing)
    noise_sigma: float = 1.0  # Gaussian sensor noise (intensity levels)


@dataclass
class DatasetSummary:
    """What :func:`generate_dataset` wrote."""

    out: Path
    seed: int
    scenes: list[str]
    splits: dict[str, int]  # split -> number of panoramas over all scenes
    points: dict[str, int]  # scene -> scan points
    width: int
    height: int
    seconds: float = 0.0

    @property
    def images(self) -> int:
        return int(sum(self.splits.values()))


def capture_settings(capture: Any, width: int | None = None, per_split: int | None = None,
                     illumination: bool = True) -> CaptureSettings:
    """Resolve a spec's ``CaptureSpec`` (``None``: defaults) with the command-line overrides."""
    if capture is None:
        from ldlmap.synth.spec import CaptureSpec

        capture = CaptureSpec()
    views = {"robot": capture.robot, "handheld": capture.handheld, "extreme": capture.extreme}
    counts = {s: int(views[s].count) for s in views}
    counts["change_robot"] = counts["change_handheld"] = int(capture.change.count)
    if per_split is not None:
        counts = {s: int(per_split) for s in counts}
    if width is not None:
        W, H = int(width), int(width) // 2
    else:
        W, H = int(capture.width), int(capture.height)
    if W < MIN_WIDTH or W > MAX_WIDTH or W % 2 or H != W // 2:
        raise InputError(f"panorama size must be W x W/2 with an even W in [{MIN_WIDTH}, {MAX_WIDTH}], got {W} x {H}")
    if any(not 0 <= n <= MAX_PER_SPLIT for n in counts.values()):
        raise InputError(f"panorama counts per split must be in [0, {MAX_PER_SPLIT}], got {max(counts.values())}")
    blur = {s: float(v.blur_px) for s, v in views.items()}
    blur.update({f"change_{s}": blur[s] for s in ("robot", "handheld")})
    ill = capture.illumination
    variants: dict[str, tuple[str, dict]] = {}
    if illumination and ill.enabled:
        variants = {"extreme_intensity": ("intensity", {"intensity": float(ill.intensity)}),
                    "extreme_gamma": ("gamma", {"gamma": float(ill.gamma)}),
                    "extreme_white_balance": ("white_balance", {"white_balance": tuple(ill.white_balance)})}
    return CaptureSettings(width=W, height=H, counts=counts, blur_px=blur, illumination=variants)


def _room_name(spec: Any) -> str:
    name = re.sub(r"[^A-Za-z0-9]", "", str(getattr(spec, "name", "") or ""))
    return name or "synthroom"


def _rng(seed: int, spec: Any, scene: int, stage: str) -> np.random.Generator:
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, int(spec.seed) & 0xFFFFFFFF, int(scene), _STREAM[stage]])


def _write_jpeg(path: Path, rgb: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
        raise OSError(f"cannot write image {path}")


def _write_pose(path: Path, R: np.ndarray, t: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.hstack([np.asarray(R, np.float64), np.asarray(t, np.float64).reshape(3, 1)]))


def write_split_panoramas(tmp: Path, name: str, spec: Any, idx: int, cap: CaptureSettings, seed: int,
                          renderer: Renderer, changed_renderer: Renderer, split_counts: dict[str, int],
                          tick: Callable[[str], None] = lambda description="": None,
                          first_stem: Mapping[str, int] | None = None) -> dict[str, list[str]]:
    """Render and write the panoramas of every split of one room under the scene ``name``.

    ``idx`` is the room's index in the random streams (:func:`_rng`); ``renderer`` draws the
    unchanged room and ``changed_renderer`` the changed one (``change_*`` splits, ``scene_2``).
    Images of a split are numbered (``%04d``) from ``first_stem[split]`` (default 0; the
    illumination variants share the extreme split's numbers), so that several rooms can share
    one scene folder. ``split_counts`` is increased in place; returns split -> stems written.
    """
    written: dict[str, list[str]] = {}
    first = dict(first_stem or {})
    W, H = cap.width, cap.height
    for split in BASE_SPLITS:
        n = cap.counts[split]
        if n == 0:
            continue
        rng = _rng(seed, spec, idx, split)
        rend = changed_renderer if split.startswith("change_") else renderer
        state = "scene_2" if split.startswith("change_") else "scene_1"
        folder = f"{split}_{name}_{state}"
        poses = sample_poses(rend.mesh, split, n, rng, spec.capture, renderer=rend)
        for k, (R, t) in enumerate(poses):
            blur = angle = 0.0
            if cap.blur_px.get(split, 0.0) > 0:  # length in [max / 2, max], scaled with W
                blur = rng.uniform(0.5, 1.0) * cap.blur_px[split] * W / 1024.0
                angle = rng.uniform(0.0, np.pi)
            pano = rend.render(R, t, W, H, supersample=cap.supersample, blur_px=blur, blur_angle=angle,
                               noise_sigma=cap.noise_sigma, rng=rng)
            stem = f"{first.get(split, 0) + k:04d}"
            _write_jpeg(tmp / f"{split}_pano" / folder / f"{stem}.jpg", pano.rgb)
            _write_pose(tmp / f"{split}_pose" / folder / f"{stem}.txt", R, t)
            split_counts[split] += 1
            written.setdefault(split, []).append(stem)
            if split == "extreme":
                for var, (kind, params) in cap.illumination.items():
                    vfolder = f"{var}_{name}_{state}"
                    _write_jpeg(tmp / f"{var}_pano" / vfolder / f"{stem}.jpg",
                                apply_illumination(pano.rgb, kind, **params))
                    _write_pose(tmp / f"{var}_pose" / vfolder / f"{stem}.txt", R, t)
                    split_counts[var] += 1
                    written.setdefault(var, []).append(stem)
            tick(f"{name}: {split} {k + 1}/{n}")
    return written


def check_dataset_seed(seed: int) -> None:
    """A dataset seed in ``[0, 2**32)`` (the random streams take it as one 32-bit word)."""
    if not 0 <= int(seed) < SEED_LIMIT:
        raise InputError(f"--seed must be in [0, 2**32), got {seed}")


def is_synth_dataset(folder: Path) -> bool:
    """Whether ``folder`` holds a dataset written by :func:`generate_dataset` (its ``dataset.json``)."""
    try:
        return json.loads((Path(folder) / "dataset.json").read_text()).get("generator") == "ldlmap.synth"
    except (OSError, ValueError, AttributeError):
        return False


def refuse_replacing_other_dataset(out: Path, overwrite: bool) -> None:
    """``--overwrite`` replaces a synthetic dataset written before, never another non-empty folder
    (a typo in OUT must not delete a user's files)."""
    out = Path(out)
    if overwrite and out.is_dir() and any(out.iterdir()) and not is_synth_dataset(out):
        raise LdlError(f"output folder {out} is not a dataset written by `ldlmap synth` (no dataset.json of ours): "
                       "--overwrite does not replace it; remove it yourself or choose another folder")


def load_specs(preset: str | None, spec_paths: Sequence[Path], seed: int) -> list[tuple[str, Any]]:
    """``(room name, spec)`` pairs: the spec files when given (room = the spec's name), else
    ``random_spec(preset, seed, i)`` for the preset's scenes (room ``synthroom``)."""
    from ldlmap.synth import spec as spec_mod

    if spec_paths:
        return [(_room_name(s), s) for s in (spec_mod.load_spec(Path(p)) for p in spec_paths)]
    preset = preset or "demo"
    count = int(spec_mod.get_preset(preset).get("scenes", 2))
    return [("synthroom", spec_mod.random_spec(preset, seed, i)) for i in range(1, count + 1)]


def generate_dataset(out: Path, preset: str | None = "demo", spec_paths: Sequence[Path] = (), seed: int = 0,
                     overwrite: bool = False, progress: bool = True, illumination: bool = True,
                     width: int | None = None, per_split: int | None = None) -> DatasetSummary:
    """Generate the dataset into ``out`` (atomically) and return a :class:`DatasetSummary`.

    ``width`` and ``per_split`` override the specs' panorama width and panoramas per split.
    A multi-room preset (``multiroom``: several rooms in one scan, one scene) is generated by
    :func:`ldlmap.synth.multiroom.generate_multiroom`.
    """
    from ldlmap.synth.multiroom import generate_multiroom, is_multiroom_preset

    check_dataset_seed(seed)
    if not spec_paths and is_multiroom_preset(preset):
        return generate_multiroom(out, preset, seed, overwrite=overwrite, progress=progress,
                                  illumination=illumination, width=width, per_split=per_split)
    from ldlmap.synth.edges import mesh_edges
    from ldlmap.synth.meshio import write_textured_obj
    from ldlmap.synth.scan import sample_scan, write_ply, write_txt
    from ldlmap.synth.scene import build_scene
    from ldlmap.synth.spec import changed_spec, dump_spec_toml
    from ldlmap.io.linefiles import write_lines

    start = time.perf_counter()
    out = Path(out)
    named = load_specs(preset, list(spec_paths), seed)  # bad specs fail before anything is written
    specs = [s for _, s in named]
    names = [f"{room}_{i}" for i, (room, _) in enumerate(named, start=1)]
    settings = [capture_settings(s.capture, width, per_split, illumination) for s in specs]
    splits = list(BASE_SPLITS) + [v for v in ILLUMINATION_SPLITS if any(v in c.illumination for c in settings)]
    split_counts = {s: 0 for s in splits}
    points: dict[str, int] = {}
    scene_info = []
    total = sum(4 + sum(c.counts.values()) for c in settings)

    with atomic_dir(out, overwrite=overwrite) as tmp, _progress(progress, total) as tick:
        for idx, (spec, cap, name) in enumerate(zip(specs, settings, names), start=1):
            W, H = cap.width, cap.height
            mesh = build_scene(spec)
            renderer = Renderer(mesh)
            (tmp / "specs").mkdir(parents=True, exist_ok=True)
            (tmp / "specs" / f"{name}.toml").write_text(dump_spec_toml(spec))
            tick(f"{name}: mesh")
            (tmp / "mesh").mkdir(exist_ok=True)
            write_textured_obj(mesh, tmp / "mesh" / f"{name}.obj")
            segs = mesh_edges(mesh)
            (tmp / "gt_lines").mkdir(exist_ok=True)
            write_lines(tmp / "gt_lines" / f"{name}.obj", segs)
            write_lines(tmp / "gt_lines" / f"{name}.txt", segs)
            tick(f"{name}: scan")
            pts, cols = sample_scan(mesh, spec.scan, _rng(seed, spec, idx, "scan"), renderer=renderer)
            (tmp / "pcd").mkdir(exist_ok=True)
            write_ply(tmp / "pcd" / f"{name}.ply", pts, cols)
            write_txt(tmp / "pcd" / f"{name}.txt", pts, cols)
            points[name] = int(len(pts))
            tick(f"{name}: changed scene")
            changed = changed_spec(spec, _rng(seed, spec, idx, "change"))
            (tmp / "specs" / f"{name}_scene_2.toml").write_text(dump_spec_toml(changed))
            changed_renderer = Renderer(build_scene(changed))
            tick(f"{name}: panoramas")

            write_split_panoramas(tmp, name, spec, idx, cap, seed, renderer, changed_renderer, split_counts,
                                  tick)
            scene_info.append({"name": name, "spec": f"specs/{name}.toml", "changed_spec": f"specs/{name}_scene_2.toml",
                               "points": points[name], "triangles": int(mesh.num_triangles),
                               "gt_lines": int(len(segs)), "width": W, "height": H})
        meta = {"generator": "ldlmap.synth", "version": GENERATOR_VERSION, "seed": int(seed),
                "preset": None if spec_paths else (preset or "demo"),
                "illumination": sorted({v for c in settings for v in c.illumination}),
                "layout": "omniscenes", "scenes": scene_info,
                "splits": {s: {"images": split_counts[s]} for s in splits}}
        (tmp / "dataset.json").write_text(json.dumps(meta, indent=2) + "\n")

    return DatasetSummary(out=out, seed=int(seed), scenes=names, splits=split_counts, points=points,
                          width=settings[0].width if settings else 0,
                          height=settings[0].height if settings else 0,
                          seconds=time.perf_counter() - start)


class _progress:
    """Context manager yielding ``tick(description)``; a Rich bar only when ``enabled``."""

    def __init__(self, enabled: bool, total: int) -> None:
        self.enabled, self.total = enabled, total
        self._bar = None

    def __enter__(self):
        if not self.enabled:
            return lambda description="": None
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from ldlmap.cli_common import err_console

        self._bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                             TimeElapsedColumn(), console=err_console, transient=True)
        self._bar.__enter__()
        task = self._bar.add_task("synth", total=self.total)

        def tick(description: str = "") -> None:
            self._bar.update(task, advance=1, description=description)

        return tick

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.__exit__(*exc)
