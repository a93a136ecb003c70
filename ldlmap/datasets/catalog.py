"""Opening a dataset root: its kind from its layout, the reader for it, and the split manifests
shipped under ``datasets/``.
"""

from __future__ import annotations

import sys
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from ldlmap.core.errors import InputError
from ldlmap.datasets.base import (DATASET_KINDS, DEFAULT_ROOTS, Dataset, MANIFEST_DIRS, check_map_level, require_root,
                                  visible_dirs)
from ldlmap.datasets.omniscenes import OmniScenes
from ldlmap.datasets.stanford import Stanford2D3DS
from ldlmap.datasets.zind import ZInD
from ldlmap.io.zind import ZIND_JSON



def detect_kind(root: str | Path) -> str:
    """Guess the layout of ``root``: ``"zind"`` (``<home>/zind_data.json``, or a home folder),
    ``"stanford"`` (``area_*`` folders in ``pano``, ``pcd`` or ``pcd_line``) or ``"omniscenes"``."""
    r = require_root(root, "")
    if (r / ZIND_JSON).is_file() or any((p / ZIND_JSON).is_file() for p in visible_dirs(r)):
        return "zind"
    for sub in ("pano", "pcd", "pcd_line"):
        if (r / sub).is_dir() and any(p.name.startswith("area_") for p in visible_dirs(r / sub)):
            return "stanford"
    if any(p.name.endswith("_pano") for p in visible_dirs(r)) or (r / "pcd").is_dir() or (r / "pcd_line").is_dir():
        return "omniscenes"
    raise InputError(f"no recognisable dataset layout in {r} (expected OmniScenes <split>_pano/, "
                     "Stanford 2D-3D-S pano/area_N/ or ZInD <home>/zind_data.json; see datasets/README.md)")


def open_dataset(root: str | Path | None = None, kind: str | None = "omniscenes", map_level: str = "room") -> Dataset:
    """Open a dataset root of the given kind (``None``: detect it). ``root=None`` uses
    :data:`DEFAULT_ROOTS` for the kind. ``map_level`` (``room`` | ``floor``) picks ZInD's scenes
    (one map per complete room or per floor); other kinds ignore it."""
    if kind is not None and kind not in DATASET_KINDS:
        raise InputError(f"unknown dataset kind {kind!r}; choose one of {', '.join(DATASET_KINDS)}")
    check_map_level(map_level)
    if root is None:
        if kind is None:
            raise InputError("give a dataset root or a dataset kind")
        root = DEFAULT_ROOTS[kind]
    if kind is None:
        kind = detect_kind(root)
    if kind == "zind":
        return ZInD(root, map_level)
    return OmniScenes(root) if kind == "omniscenes" else Stanford2D3DS(root)



def manifest_path(kind: str) -> Path:
    """Location of ``datasets/<dir>/splits.toml`` for a dataset kind.

    The manifests live in the repository's top-level ``datasets/`` folder (data, not code). They
    are found beside the package (source checkout / editable install), or under
    ``<sys.prefix>/share/ldl-toolkit/datasets`` where a wheel install puts them.
    """
    if kind not in MANIFEST_DIRS:
        raise InputError(f"unknown dataset kind {kind!r}; choose one of {', '.join(MANIFEST_DIRS)}")
    rel = Path(MANIFEST_DIRS[kind]) / "splits.toml"
    bases = [Path(__file__).resolve().parents[2] / "datasets", Path(sys.prefix) / "share" / "ldl-toolkit" / "datasets"]
    for base in bases:
        if (base / rel).is_file():
            return base / rel
    raise InputError(f"split manifest datasets/{rel.as_posix()} not found (looked in {', '.join(map(str, bases))})")


def load_manifest(kind: str) -> dict:
    """Parsed split manifest of ``"omniscenes"``, ``"stanford"`` or ``"zind"`` (see ``datasets/README.md``)."""
    path = manifest_path(kind)
    try:
        return tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"cannot read split manifest {path}: {exc}") from None
