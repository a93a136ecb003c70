"""Thumbnails of the report: each query's panorama with its map's 3D lines drawn at the estimated
pose (coloured by principal group, as in ``--save-vis`` pictures), as JPEG data URIs.

A thumbnail without lines says why (failed query: no pose; map not found or unreadable); a query
whose image cannot be read gets no thumbnail and the reason instead.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ldlloc.batch.results import run_kind
from ldlloc.export.poses import has_pose, map_path_for, resolve_path
from ldlloc.visualize import draw_map_lines
from ldlloc.walk.video import frames_by_index
from ldlmap.core.errors import InputError, LdlError, require_file
from ldlmap.core.lazy import lazy_module
from ldlmap.io.imagefile import image_header_size, read_image
from ldlmap.map.mapfile import read_map

cv2 = lazy_module("cv2")

THUMB_W, THUMB_H = 384, 192  # shown at this size (CSS pixels): 2:1 like the panoramas
JPEG_QUALITY = 85


@dataclass
class Thumbnail:
    data_uri: str | None  # data:image/jpeg;base64,... (None: the image could not be read)
    note: str = ""  # why lines (or the picture) are missing; "" when all is drawn
    href: str | None = None  # the full panorama (a file: URI) that the thumbnail opens


def read_small(path: str | Path) -> np.ndarray:
    """The BGR image at ``path`` resized to THUMB_W x THUMB_H (JPEGs decoded at a reduced scale)."""
    p = require_file(path, "image")
    size = image_header_size(p)
    flag = cv2.IMREAD_COLOR
    for factor, reduced in ((8, cv2.IMREAD_REDUCED_COLOR_8), (4, cv2.IMREAD_REDUCED_COLOR_4),
                            (2, cv2.IMREAD_REDUCED_COLOR_2)):
        if size is not None and size[0] >= factor * THUMB_W:
            flag = reduced
            break
    try:
        img = read_image(p, flag)
    except OSError as exc:
        raise InputError(f"cannot read image ({exc.strerror or exc}): {p}") from None
    if img is None:
        raise InputError(f"cannot decode image: {p}")
    return cv2.resize(img, (THUMB_W, THUMB_H), interpolation=cv2.INTER_AREA)


def data_uri(image_bgr: np.ndarray) -> str:
    """A JPEG data URI of a BGR image."""
    ok, buf = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise LdlError("cannot encode a thumbnail")
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def make_thumbnails(records: list[dict], meta: dict[str, Any],
                    progress: Callable[[], None] | None = None) -> dict[str, Thumbnail]:
    """A :class:`Thumbnail` per record (by name). The map of each record is found as for exports
    (:func:`ldlloc.export.poses.map_path_for`); each map is read once (records grouped by map)."""
    by_map: dict[Path | None, list[dict]] = {}
    looked_for: dict[str, list[Path]] = {}
    for q in records:
        path, looked = map_path_for(q, meta) if has_pose(q) else (None, [])
        by_map.setdefault(path, []).append(q)
        looked_for[q["name"]] = looked
    out: dict[str, Thumbnail] = {}
    for path, group in by_map.items():
        ldl_map, map_note = None, ""
        if path is not None:
            try:
                ldl_map = read_map(path, load_cloud=False)
            except LdlError as exc:
                map_note = f"no lines: {exc}"
        frames = _video_frames(group, meta)
        for q in group:
            image = resolve_path(q["image"], meta)
            read = (lambda p=image: read_small(p)) if frames is None else (lambda q=q: _frame_of(q, image, frames))
            out[q["name"]] = _thumbnail(q, image, read, ldl_map, map_note, looked_for[q["name"]], draw_map_lines,
                                        has_pose(q))
            if progress is not None:
                progress()
    return out


def _video_frames(records: list[dict], meta: dict[str, Any]) -> dict[int, np.ndarray | LdlError] | None:
    """A video run's frames of ``records`` as thumbnails (BGR) by frame index, decoded in one pass
    (an error instead when the video cannot be read); None for a run of images."""
    if run_kind(meta) != "video" or not records:
        return None
    wanted = {_frame_index(q) for q in records}
    frames: dict[int, np.ndarray | LdlError] = {}
    try:
        for i, rgb in frames_by_index(resolve_path(records[0]["image"], meta), wanted):
            frames[i] = cv2.resize(rgb[:, :, ::-1], (THUMB_W, THUMB_H), interpolation=cv2.INTER_AREA)
    except LdlError as exc:
        frames.update({i: exc for i in wanted if i not in frames})  # the frames after a decoding error
    return frames


def _frame_index(q: dict) -> int:
    """A video frame record's index in its video (its name: ``<video stem>/<index>``)."""
    tail = q["name"].rsplit("/", 1)[-1]
    return int(tail) if tail.isdigit() else -1


def _frame_of(q: dict, video: Path, frames: dict[int, np.ndarray | LdlError]) -> np.ndarray:
    got = frames.get(_frame_index(q))
    if got is None:
        raise LdlError(f"frame {q['name']} not found in {video}")
    if isinstance(got, LdlError):
        raise got
    return got


def _thumbnail(q: dict, image: Path, read: Callable[[], np.ndarray], ldl_map, map_note: str, looked: list[Path], draw,
               posed: bool) -> Thumbnail:
    try:
        img = read()
    except LdlError as exc:
        return Thumbnail(None, str(exc))
    href = image.resolve().as_uri()
    if not posed:
        return Thumbnail(data_uri(img), "no pose: no lines drawn", href)
    if ldl_map is None:
        note = map_note or ("no lines: map not found" + (f" ({', '.join(map(str, looked[:3]))})" if looked else ""))
        return Thumbnail(data_uri(img), note, href)
    drawn = draw(img, ldl_map, np.asarray(q["R"], dtype=np.float64), np.asarray(q["t"], dtype=np.float64),
                 thickness=2)
    return Thumbnail(data_uri(drawn), href=href)
