"""Capturing a synthetic dataset's query panoramas and poses, shared by the one-room and multi-room
generators: the splits, random streams, per-split capture settings, the files of a split, and the
safety checks before a dataset folder is replaced.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ldlmap.core.cli_common import err_console
from ldlmap.core.errors import InputError, LdlError, atomic_dir
from ldlmap.datasets.omniscenes import written_by_synth
from ldlmap.io.imagefile import write_image
from ldlmap.synth.poses import sample_poses
from ldlmap.synth.render import Renderer, apply_illumination, render_through
from ldlmap.synth.spec import MAX_COUNT as MAX_PER_SPLIT
from ldlmap.synth.spec import MAX_WIDTH, MIN_WIDTH, SEED_LIMIT, CaptureSpec, SceneSpec


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


def capture_settings(capture: CaptureSpec | None, width: int | None = None, per_split: int | None = None,
                     illumination: bool = True) -> CaptureSettings:
    """Resolve a spec's ``CaptureSpec`` (``None``: defaults) with the command-line overrides."""
    if capture is None:
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


def stream_rng(seed: int, spec: SceneSpec, scene: int, stage: str) -> np.random.Generator:
    """The random stream of one stage (scan, change or a split) of room ``scene`` of a dataset."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, int(spec.seed) & 0xFFFFFFFF, int(scene), _STREAM[stage]])


def write_jpeg(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, rgb[..., ::-1], quality=JPEG_QUALITY)


def write_pose(path: Path, R: np.ndarray, t: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.hstack([np.asarray(R, np.float64), np.asarray(t, np.float64).reshape(3, 1)]))


def write_split_panoramas(tmp: Path, name: str, spec: SceneSpec, idx: int, cap: CaptureSettings, seed: int,
                          renderer: Renderer, changed_renderer: Renderer, split_counts: dict[str, int],
                          tick: Callable[[str], None] = lambda description="": None,
                          first_stem: Mapping[str, int] | None = None,
                          offset: np.ndarray | None = None,
                          through: Sequence[tuple[Renderer, np.ndarray]] = ()) -> dict[str, list[str]]:
    """Render and write the panoramas of every split of one room under the scene ``name``.

    ``idx`` is the room's index in the random streams (:func:`stream_rng`); ``renderer`` draws the
    unchanged room and ``changed_renderer`` the changed one (``change_*`` splits, ``scene_2``).
    Images of a split are numbered (``%04d``) from ``first_stem[split]`` (default 0; the
    illumination variants share the extreme split's numbers), so that several rooms can share
    one scene folder. ``offset`` (3,) moves the written camera centres from the renderers' frame
    into the world frame (a room rendered where its spec puts it, floor at z = 0, then placed in
    a building). ``through``: the rooms seen through the room's open doors (renderers with their
    meshes' origins in the room's frame). ``split_counts`` is increased in place; returns split ->
    stems written.
    """
    written: dict[str, list[str]] = {}
    first = dict(first_stem or {})
    W, H = cap.width, cap.height
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64).reshape(3)
    for split in BASE_SPLITS:
        n = cap.counts[split]
        if n == 0:
            continue
        rng = stream_rng(seed, spec, idx, split)
        rend = changed_renderer if split.startswith("change_") else renderer
        state = "scene_2" if split.startswith("change_") else "scene_1"
        folder = f"{split}_{name}_{state}"
        poses = sample_poses(rend.mesh, split, n, rng, spec.capture, renderer=rend)
        for k, (R, t) in enumerate(poses):
            blur = angle = 0.0
            if cap.blur_px.get(split, 0.0) > 0:  # length in [max / 2, max], scaled with W
                blur = rng.uniform(0.5, 1.0) * cap.blur_px[split] * W / 1024.0
                angle = rng.uniform(0.0, np.pi)
            pano = render_through([(rend, np.zeros(3)), *through], R, t, W, H, supersample=cap.supersample,
                                  blur_px=blur, blur_angle=angle, noise_sigma=cap.noise_sigma, rng=rng)
            stem = f"{first.get(split, 0) + k:04d}"
            write_jpeg(tmp / f"{split}_pano" / folder / f"{stem}.jpg", pano.rgb)
            write_pose(tmp / f"{split}_pose" / folder / f"{stem}.txt", R, t + shift)
            split_counts[split] += 1
            written.setdefault(split, []).append(stem)
            if split == "extreme":
                for var, (kind, params) in cap.illumination.items():
                    vfolder = f"{var}_{name}_{state}"
                    write_jpeg(tmp / f"{var}_pano" / vfolder / f"{stem}.jpg",
                                apply_illumination(pano.rgb, kind, **params))
                    write_pose(tmp / f"{var}_pose" / vfolder / f"{stem}.txt", R, t + shift)
                    split_counts[var] += 1
                    written.setdefault(var, []).append(stem)
            tick(f"{name}: {split} {k + 1}/{n}")
    return written


def check_dataset_seed(seed: int) -> None:
    """A dataset seed in ``[0, 2**32)`` (the random streams take it as one 32-bit word)."""
    if not 0 <= int(seed) < SEED_LIMIT:
        raise InputError(f"--seed must be in [0, 2**32), got {seed}")


def refuse_replacing_other_dataset(out: Path, overwrite: bool) -> None:
    """``--overwrite`` replaces a synthetic dataset written before, never another non-empty folder
    (a typo in OUT must not delete a user's files)."""
    out = Path(out)
    if overwrite and out.is_dir() and any(out.iterdir()) and not written_by_synth(out):
        raise LdlError(f"output folder {out} is not a dataset written by `ldlmap synth` (no dataset.json of ours): "
                       "--overwrite does not replace it; remove it yourself or choose another folder")


GENERATED_TOP = ("dataset.json", "specs", "mesh", "gt_lines", "pcd")  # and <split>_pano, <split>_pose folders


def generated_files(root: Path) -> set[str]:
    """Paths (relative, posix) of the files `ldlmap synth` wrote in dataset ``root``: its
    ``dataset.json`` lists them (``files``); a dataset written before that list, every file under
    the generator's own top-level names."""
    root = Path(root)
    try:
        listed = json.loads((root / "dataset.json").read_text()).get("files")
    except (OSError, ValueError, AttributeError):
        listed = None
    if isinstance(listed, list) and all(isinstance(f, str) for f in listed):
        return {*listed, "dataset.json"}
    ours = lambda top: top in GENERATED_TOP or top.endswith(("_pano", "_pose"))  # noqa: E731
    return {p.relative_to(root).as_posix() for p in root.rglob("*")
            if p.is_file() and ours(p.relative_to(root).parts[0])}


def files_not_generated(root: Path) -> list[str]:
    """The files (and empty folders) under synthetic dataset ``root`` that `ldlmap synth` did not
    write (a user's notes, results, maps): ``synth --overwrite`` keeps them."""
    root = Path(root)
    ours = generated_files(root)
    extra = [p.relative_to(root).as_posix() for p in sorted(root.rglob("*"))
             if (p.is_symlink() or not p.is_dir() or not any(p.iterdir())) and p.relative_to(root).as_posix() not in ours]
    return extra


def read_dataset_meta(root: str | Path) -> dict:
    """The ``dataset.json`` of a generated dataset; one-line errors when it is missing or unreadable."""
    path = Path(root) / "dataset.json"
    if not path.is_file():
        raise InputError(f"not a generated synthetic dataset (no dataset.json): {root}")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read {path}: {exc}") from None


def list_generated(tmp: Path, meta: dict) -> dict:
    """``meta`` with ``files``: every file written under ``tmp`` so far (before ``dataset.json``)."""
    return {**meta, "files": sorted(p.relative_to(tmp).as_posix() for p in tmp.rglob("*") if p.is_file())}


def dataset_output(out: Path, overwrite: bool):
    """The :func:`atomic_dir` of a generated dataset: a new folder, or with ``overwrite`` one that
    replaces only the files the generator wrote before, keeping any other (:func:`files_not_generated`)."""
    out = Path(out)
    if not (overwrite and out.is_dir() and written_by_synth(out) and files_not_generated(out)):
        return atomic_dir(out, overwrite=overwrite)
    return atomic_dir(out, overwrite=True, commit=lambda tmp, target: _replace_generated(tmp, target))


def _replace_generated(tmp: Path, out: Path) -> None:
    """Move the new dataset in ``tmp`` into ``out`` file by file: the old generated files go, the
    others stay. ``dataset.json`` is replaced last, so a run killed midway leaves the old list (the
    next ``--overwrite`` still knows what it wrote). A user's file where a new one would go is
    refused before anything moves."""
    old = generated_files(out)
    new = sorted(p.relative_to(tmp).as_posix() for p in tmp.rglob("*") if p.is_file())
    clash = [f for f in new if f not in old and (out / f).exists()]
    if clash:
        raise LdlError(f"the new dataset would replace {len(clash)} file(s) in {out} that `ldlmap synth` did not "
                       f"write (first: {clash[0]}); move them away and run again")
    for rel in sorted(old - {"dataset.json"}):
        (out / rel).unlink(missing_ok=True)
    for rel in new:
        if rel != "dataset.json":
            (out / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp / rel, out / rel)
    os.replace(tmp / "dataset.json", out / "dataset.json")
    folders = {(out / rel).parent for rel in old} - {out}
    for folder in sorted(folders, key=lambda p: len(p.parts), reverse=True):  # emptied folders of ours
        while folder != out and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
            folder = folder.parent
    shutil.rmtree(tmp, ignore_errors=True)


class ProgressTicks:
    """Context manager yielding ``tick(description)``; a Rich bar only when ``enabled``."""

    def __init__(self, enabled: bool, total: int) -> None:
        self.enabled, self.total = enabled, total
        self._bar = None

    def __enter__(self):
        if not self.enabled:
            return lambda description="": None
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
