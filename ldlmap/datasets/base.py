"""What every dataset reader shares: the dataset kinds and their default roots, a :class:`Query`, the
:class:`Dataset` protocol, and the folder helpers of the readers.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Protocol, Sequence, runtime_checkable

import numpy as np

from ldlmap.core.errors import InputError, check_choice


DEFAULT_ROOTS: dict[str, Path] = {"omniscenes": Path("data/omniscenes"), "stanford": Path("data/stanford2d3ds"),
                                  "zind": Path("data/zind")}
DATASET_KINDS: tuple[str, ...] = ("omniscenes", "stanford", "zind")
# Folder under ``datasets/`` holding each kind's split manifest.
MANIFEST_DIRS: dict[str, str] = {"omniscenes": "omniscenes", "stanford": "stanford2d3ds", "zind": "zind"}
MAP_LEVELS: tuple[str, ...] = ("room", "floor")  # ZInD: one map per complete room, or per floor


def check_map_level(level: str, name: str = "map level") -> None:
    """A one-line InputError unless ``level`` is one of :data:`MAP_LEVELS` (``name``: how the caller calls it)."""
    check_choice(level, MAP_LEVELS, name)

# Split order used for listing and sorting (other ``<name>_pano`` splits follow alphabetically).
OMNISCENES_SPLITS: tuple[str, ...] = ("robot", "handheld", "extreme", "change_robot", "change_handheld")
STANFORD_AREAS: tuple[str, ...] = ("area_1", "area_2", "area_3", "area_4", "area_5a", "area_5b", "area_6")

IMAGE_EXTENSIONS: tuple[str, ...] = (".jpg", ".jpeg", ".png")
POINT_CLOUD_EXTENSIONS: tuple[str, ...] = (".ply", ".txt", ".pcd")  # preference order
@dataclass(frozen=True, eq=False)
class Query:
    """One query panorama with its ground-truth pose (``p_cam = R (X - t)``).

    Compared by identity (it holds arrays); compare ``name`` to match queries."""

    image: Path
    scene: str  # point-cloud name: ``room_1`` (OmniScenes) or ``area_3/office_1`` (Stanford)
    split: str  # ``extreme``, ``change_robot``, ... or the Stanford area
    rot_cam_from_world: np.ndarray = field(repr=False)  # (3, 3) R, world -> camera
    center: np.ndarray = field(repr=False)  # (3,) t, camera centre in world coordinates
    name: str = ""  # stable id, e.g. ``extreme/room_1_scene_2/00012``
    scene_state: str = ""  # ``scene_2`` (OmniScenes capture session), the Stanford area or the ZInD home
    upright: bool = False  # captured upright (ZInD): localization may use an upright rotation prior
    pose_file: Path | None = None  # where the ground truth was read (never to be written over)
    floor: int | None = None  # synthetic buildings: the floor the camera is on (0 = ground floor)
    room: str | None = None  # synthetic multi-room scenes and buildings: id of the room holding the camera


@runtime_checkable
class Dataset(Protocol):
    """What the batch tools need from a dataset root."""

    kind: str
    root: Path

    def splits(self) -> list[str]: ...

    def scenes(self) -> list[str]: ...

    def queries(self, split: str | Sequence[str] | None = None, scene: str | None = None) -> list[Query]: ...

    def point_cloud(self, scene: str) -> Path: ...

    def line_file(self, scene: str) -> Path | None: ...



def natural_key(text: str) -> tuple:
    """Sort key that orders embedded integers numerically (``img_2`` before ``img_10``)."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text))


def as_split_list(split: str | Sequence[str] | None, available: list[str], what: str) -> list[str]:
    if split is None:
        return list(available)
    wanted = [split] if isinstance(split, str) else list(split)
    unknown = [s for s in wanted if s not in available]
    if unknown:
        raise InputError(f"unknown {what} {', '.join(unknown)}; available: {', '.join(available) or 'none'}")
    return wanted


def find_file(folder: Path, stems: Iterable[str], extensions: Iterable[str]) -> Path | None:
    for stem in stems:
        for ext in extensions:
            candidate = folder / f"{stem}{ext}"
            if candidate.is_file():
                return candidate
    return None


def line_file_scenes(folder: Path) -> set[str]:
    """Scene names of the 3D line files in ``folder``: ``<scene>lines.txt``, ``<scene>_lines.txt``
    or ``<scene>.txt`` / ``.obj`` (what ``line_file`` looks for)."""
    if not folder.is_dir():
        return set()
    out = set()
    for p in folder.iterdir():
        if p.is_file() and p.suffix.lower() in (".txt", ".obj") and not p.name.startswith("."):
            stem = p.stem
            for suffix in ("_lines", "lines"):
                if stem.endswith(suffix) and len(stem) > len(suffix):
                    stem = stem[: -len(suffix)]
                    break
            out.add(stem)
    return out


def visible_dirs(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))


def require_root(root: str | Path, kind: str) -> Path:
    r = Path(root).expanduser()
    what = f"{kind} dataset root" if kind else "dataset root"
    if not r.exists():
        raise InputError(f"{what} not found: {r} (see datasets/README.md)")
    if not r.is_dir():
        raise InputError(f"{what} is not a folder: {r}")
    return r
