"""The poses of a results file that an export writes: which queries (:func:`select_queries`), in
which frame (:func:`pose_in_frame`), under which image names (:func:`image_names`), with which
image sizes (:func:`image_size`) and maps (:func:`map_path_for`).

Which queries: ``failed`` ones never (they have no pose). When the file carries verdicts
(``verdict``: confident | ambiguous | failed, from the confidence step), only ``confident`` ones
unless ``include_all``; a file without any verdict (written before verdicts existed) exports every
localized query (status ok or coarse), and the export says so.

Poses follow the toolkit's conventions (docs/method.md): ``R`` rotates world into camera (camera
frame: forward +x, left +y, up +z), ``t`` is the camera centre; ``frame="map"`` is the map's frame (metric, z up), ``frame="input"`` the
frame the map was built from (a record's ``input_frame``; the same as the map's when the map was
built without ``--up`` / ``--scale`` / a recentring shift).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ldlloc.batch.results import load_results, read_results_data
from ldlloc.record import VERDICTS
from ldlmap.core.errors import InputError, require_file
from ldlmap.core.frame import apply, invert, is_identity
from ldlmap.core.lazy import lazy_module
from ldlmap.io.imagefile import image_header_size, read_image
from ldlmap.map.mapfile import read_map, read_map_header

cv2 = lazy_module("cv2")

FRAMES = ("map", "input")


def check_frame(frame: str) -> None:
    """A one-line InputError unless ``frame`` is one of :data:`FRAMES` (``--frame``)."""
    if frame not in FRAMES:
        raise InputError(f"--frame must be {' or '.join(FRAMES)}, got {frame!r}")

@dataclass
class ExportPose:
    """One query's pose as exported."""

    name: str
    scene: str
    image: Path  # the panorama, as the results file names it, relative ones resolved (:func:`resolve_path`)
    rot_cam_from_world: np.ndarray  # (3, 3) world -> camera (our camera frame), in the exported frame
    center: np.ndarray  # (3,) camera centre in the exported frame
    record: dict = field(repr=False)  # the query's record as in the file (verdict, confidence, map, ...)

    @property
    def verdict(self) -> str | None:
        return self.record.get("verdict")

    @property
    def forward(self) -> np.ndarray:
        """The camera's viewing direction (its +x axis, the panorama's centre) in the world."""
        return np.asarray(self.rot_cam_from_world)[0]

    @property
    def up(self) -> np.ndarray:
        """The camera's up axis (+z, the panorama's top row) in the world."""
        return np.asarray(self.rot_cam_from_world)[2]


@dataclass
class Selection:
    """The records an export writes, and why the others were left out."""

    chosen: list[dict]
    failed: int = 0  # no pose (status failed)
    not_confident: int = 0  # a verdict other than confident (kept with include_all)
    other_scenes: int = 0  # left out by ``scene``
    have_verdicts: bool = False  # the file carries verdicts at all

    def describe(self, total: int) -> str:
        """One line: how many were chosen of ``total`` and why the others were not."""
        why = [f"{self.failed} failed"] if self.failed else []
        if self.not_confident:
            why.append(f"{self.not_confident} not confident (--all keeps them)")
        if self.other_scenes:
            why.append(f"{self.other_scenes} of other scenes")
        return f"{len(self.chosen)} of {total} queries" + (f" ({', '.join(why)} left out)" if why else "")


def _check_extra_fields(records: list[dict], source: Path) -> None:
    """One-line errors for the fields other steps add (``verdict``, ``confidence``, ``map``) when
    they are there but malformed (older files lack them: that is fine)."""
    bad = f"not a results file of `ldlloc run`: {source}"
    for i, q in enumerate(records):
        v, c, m = q.get("verdict"), q.get("confidence"), q.get("map")
        if v is not None and v not in VERDICTS:
            raise InputError(f"{bad} (queries[{i}].verdict must be {' | '.join(VERDICTS)} or null, got {v!r:.40})")
        if c is not None and (isinstance(c, bool) or not isinstance(c, (int, float)) or not 0.0 <= c <= 1.0):
            raise InputError(f"{bad} (queries[{i}].confidence must be a number in [0, 1] or null, got {c!r:.40})")
        if m is not None and (not isinstance(m, str) or not m):
            raise InputError(f"{bad} (queries[{i}].map must be a file path or null, got {m!r:.40})")


def read_records(path: str | Path) -> tuple[list[dict], dict[str, Any]]:
    """The query records (as plain dicts, every field kept) and ``meta`` of a results file, after
    :func:`ldlloc.batch.results.load_results` has validated it (one-line errors for bad files)."""
    results, meta = load_results(path)
    records = read_results_data(path)["queries"]  # with the journal of a run that did not finish
    _check_extra_fields(records, Path(path))
    return records, meta


def resolve_path(path: str | Path, meta: dict[str, Any]) -> Path:
    """A path of a results file (a record's ``image`` or ``map``, the run's ``maps``) as seen from
    here: a relative one starts from the run's working folder (``meta["base_dir"]``), or, in files
    written before it was recorded or when it is not there, from the current folder."""
    p = Path(path)
    base = meta.get("base_dir")
    if p.is_absolute() or not isinstance(base, str) or not base:
        return p
    there = Path(base) / p
    return p if not there.exists() and p.exists() else there


def has_pose(record: dict) -> bool:
    return record.get("status", "ok") != "failed" and record.get("R") is not None and record.get("t") is not None


def select_queries(records: list[dict], include_all: bool = False, scene: str | None = None) -> Selection:
    """The records to export (see the module docstring), in file order."""
    sel = Selection(chosen=[], have_verdicts=any(q.get("verdict") is not None for q in records))
    for q in records:
        if scene is not None and q["scene"] != scene:
            sel.other_scenes += 1
        elif not has_pose(q):
            sel.failed += 1
        elif sel.have_verdicts and q.get("verdict") != "confident" and not include_all:
            sel.not_confident += 1
        else:
            sel.chosen.append(q)
    return sel


def map_path_for(record: dict, meta: dict[str, Any], given: Path | None = None) -> tuple[Path | None, list[Path]]:
    """The map of a record, the first that exists of: the record's ``map``, ``given`` (``--map``),
    the run's maps folder (``meta["maps"]``, else ``meta["root"]/maps``) + ``<scene>.h5``; and
    every place looked at (for a message when none exists)."""
    looked: list[Path] = []
    if record.get("map"):
        looked.append(resolve_path(record["map"], meta))
    if given is not None:
        looked.append(Path(given))
    folder = meta.get("maps") or (Path(meta["root"]) / "maps" if isinstance(meta.get("root"), str) else None)
    if folder:
        looked.append(resolve_path(Path(folder) / f"{record['scene']}.h5", meta))
    return next((p for p in looked if p.is_file()), None), looked


def input_to_map_of(map_path: Path) -> np.ndarray | None:
    """The map's ``input_to_map`` (None: the identity), read from its header only."""
    A = read_map_header(map_path)["input_to_map"]
    return None if A is None or is_identity(np.asarray(A)) else np.asarray(A, dtype=np.float64)


def pose_in_frame(record: dict, frame: str, meta: dict[str, Any], given_map: Path | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of a record in ``frame`` (map | input). The input-frame pose is the record's
    ``input_frame``; a record without it is in the input frame already when its map was built in
    its input's frame (identity ``input_to_map``), which the map's header says; otherwise (or
    without the map) a one-line error."""
    check_frame(frame)
    if frame == "input" and record.get("input_frame") is not None:
        pose = record["input_frame"]
        return np.asarray(pose["R"], dtype=np.float64), np.asarray(pose["t"], dtype=np.float64)
    if frame == "input":
        found, looked = map_path_for(record, meta, given_map)
        if found is None:
            raise InputError(f"--frame input: query {record['name']} has no input_frame pose and its map is not "
                             f"found (looked at {', '.join(map(str, looked)) or 'nothing'}); give it with --map")
        if input_to_map_of(found) is not None:
            raise InputError(f"--frame input: query {record['name']} has no input_frame pose but its map {found} "
                             "was built from another frame (results written before input_frame existed?): run "
                             "the query again, or export in the map frame")
    return np.asarray(record["R"], dtype=np.float64), np.asarray(record["t"], dtype=np.float64)


ROTATION_TOL = 1e-4  # largest |R R^T - I| entry and |det R - 1| of a rotation as the pipeline writes it (~1e-15)


def check_rotation(R: np.ndarray, name: str) -> None:
    """One-line error when ``R`` (3x3) is not a rotation (a hand-edited pose: a reflection, det -1,
    or a scaled matrix): COLMAP, nerfstudio and viewers would take it as a camera and go wrong."""
    R = np.asarray(R, dtype=np.float64)
    off = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if off > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise InputError(f"query {name}: R is not a rotation (det {det:.4g}, |R R^T - I| up to {off:.2g}): "
                         "was the results file edited? Fix or drop that query")


def export_poses(records: list[dict], frame: str, meta: dict[str, Any], given_map: Path | None = None
                 ) -> list[ExportPose]:
    """The :class:`ExportPose` of each chosen record in ``frame``."""
    out = []
    for q in records:
        R, t = pose_in_frame(q, frame, meta, given_map)
        check_rotation(R, q["name"])
        out.append(ExportPose(name=q["name"], scene=q["scene"], image=resolve_path(q["image"], meta),
                              rot_cam_from_world=R, center=t, record=q))
    return out


def image_names(images: list[Path], root: Path | None = None) -> tuple[Path, list[str]]:
    """The folder image names are relative to (``root``, else the deepest folder that holds every
    image) and each image's name under it (``/``-separated). One-line errors for an image outside
    ``root`` and for two queries of the same image."""
    absolute = [Path(os.path.abspath(p)) for p in images]
    if root is None:
        root = Path(os.path.commonpath([str(p.parent) for p in absolute])) if absolute else Path.cwd()
    root = Path(os.path.abspath(root))
    names = []
    for p in absolute:
        try:
            names.append(p.relative_to(root).as_posix())
        except ValueError:
            raise InputError(f"image {p} is not under --image-root {root}") from None
    seen: dict[str, int] = {}
    for i, n in enumerate(names):
        if n in seen:
            raise InputError(f"two exported queries share the image {images[i]}: export one of them "
                             "(--scene) so that each image has one pose")
        seen[n] = i
    return root, names


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image: from its PNG or JPEG header, else by decoding it."""
    p = require_file(path, "image")
    size = image_header_size(p)
    if size is None:
        img = read_image(p, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"cannot decode image (corrupt or unsupported format): {p}")
        size = (int(img.shape[1]), int(img.shape[0]))
    if min(size) <= 0:
        raise InputError(f"image {p} has no pixels ({size[0]}x{size[1]})")
    return int(size[0]), int(size[1])


@dataclass
class MapLines:
    """The kept 3D lines of the maps of the exported queries, in the exported frame."""

    lines: np.ndarray  # (L, 2, 3)
    groups: np.ndarray  # (L,) principal group of each line (-1: none)
    maps: list[Path]  # the maps they come from
    missing: list[str]  # scenes whose map was not found (their lines are not there)


def map_lines(poses: list[ExportPose], frame: str, meta: dict[str, Any], given_map: Path | None = None) -> MapLines:
    """The kept lines of every map the ``poses`` were found in (each map read once), moved into
    the input frame for ``frame="input"``."""
    found: dict[Path, None] = {}
    missing: dict[str, None] = {}
    for p in poses:
        path, _ = map_path_for(p.record, meta, given_map)
        if path is None:
            missing[p.scene] = None
        else:
            found[Path(os.path.abspath(path))] = None
    lines, groups = [np.zeros((0, 2, 3))], [np.zeros(0, dtype=np.int64)]
    for path in found:
        m = read_map(path, load_cloud=False)
        segs = np.asarray(m.lines, dtype=np.float64).reshape(-1, 2, 3)
        if frame == "input" and not is_identity(m.input_to_map):
            segs = apply(invert(m.input_to_map), segs)
        lines.append(segs)
        groups.append(np.asarray(m.line_groups, dtype=np.int64))
    return MapLines(np.concatenate(lines), np.concatenate(groups), list(found), list(missing))
