"""A scanner's own panoramas (an E57 file's spherical images) as a dataset ``ldlloc run`` checks
itself on: the scanner's photos are ground truth for free.

``write_e57_dataset(scan.e57, OUT)`` writes the OmniScenes layout (:mod:`ldlmap.datasets.omniscenes`)::

    OUT/scanner_pano/scanner_<scene>_scene_1/<image>.jpg    the spherical images, as stored (JPEG or PNG)
    OUT/scanner_pose/scanner_<scene>_scene_1/<image>.txt    3x4 [R | t]: R world -> camera, t the centre

with ``<scene>`` the E57 file's stem, so that the map ``ldlmap build scan.e57 -o OUT/maps/<scene>.h5``
serves them (``ldlloc run --root OUT``). Poses are in the E57 file's frame, the map's input frame:
``ldlloc run`` carries them into the map's frame (its ``input_to_map``: a recentring, an up axis).
Pinhole, cylindrical and partial images are listed and skipped.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ldlmap.core.errors import InputError
from ldlmap.datasets.poses import write_pose_txt
from ldlmap.io.e57 import e57_images

SPLIT = "scanner"


@dataclass
class ScannerImages:
    """What :func:`write_e57_dataset` wrote and skipped."""

    root: Path
    scene: str
    written: list[str]
    skipped: list[tuple[str, str]]  # (image name, why)


def _file_stem(name: str, used: set[str]) -> str:
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "image"
    out, k = stem, 1
    while out in used:  # two images of one name keep both
        k += 1
        out = f"{stem}_{k}"
    used.add(out)
    return out


def write_e57_dataset(e57: str | os.PathLike, out: str | os.PathLike, overwrite: bool = False) -> ScannerImages:
    """Write the E57 file's full spherical images with their poses as a dataset (module docstring),
    atomically per folder; refuses a non-empty ``out`` holding the same folders unless ``overwrite``."""
    src, root = Path(e57), Path(out)
    scene = re.sub(r"[^A-Za-z0-9._-]+", "_", src.stem) or "scan"
    images = e57_images(src)
    usable = [im for im in images if not im.note]
    skipped = [(im.name, im.note) for im in images if im.note]
    if not usable:
        why = "; ".join(f"{n}: {w}" for n, w in skipped[:3])
        what = (f"{len(images)} image(s), none a usable spherical panorama ({why})" if images
                else "no images (images2D)")
        raise InputError(f"E57 file {src} has {what}: nothing to write")
    subdirs = [root / f"{SPLIT}_pano", root / f"{SPLIT}_pose"]
    taken = [d for d in subdirs if d.exists()]
    if taken and not overwrite:
        raise InputError(f"{taken[0]} exists: give another folder, or --overwrite to replace the scanner images there")
    if root.exists() and not root.is_dir():
        raise InputError(f"{root} is a file, not a folder")
    root.mkdir(parents=True, exist_ok=True)
    folder = f"{SPLIT}_{scene}_scene_1"
    tmp = Path(tempfile.mkdtemp(prefix=".e57-images-", dir=root))
    try:
        used: set[str] = set()
        written = []
        for im in usable:
            stem = _file_stem(im.name, used)
            pano = tmp / subdirs[0].name / folder / f"{stem}{im.suffix}"
            pano.parent.mkdir(parents=True, exist_ok=True)
            pano.write_bytes(im.data)
            pose = tmp / subdirs[1].name / folder / f"{stem}.txt"
            pose.parent.mkdir(parents=True, exist_ok=True)
            write_pose_txt(pose, im.rot_cam_from_world, im.center)
            written.append(stem)
        for d in subdirs:
            if d.exists():
                shutil.rmtree(d)
            os.replace(tmp / d.name, d)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return ScannerImages(root, scene, written, skipped)
