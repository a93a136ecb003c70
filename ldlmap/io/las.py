"""LAS and LAZ point clouds (``laspy``; LAZ decompressed by ``lazrs``).

Coordinates are the header's ``scale * X + offset`` in float64 (``laspy``'s ``x, y, z``), so
large projected coordinates (UTM eastings and northings) keep their millimetres; the map build
recentres them and stores the shift (:func:`ldlmap.core.frame.recentring_offset`). Colour: the
RGB of point formats 2, 3, 5, 7, 8 and 10. The specification stores 16-bit colour; files whose
colours all fit in 0-255 (many writers store 8-bit values unscaled) are read as 8-bit, the others
divided by 257. A file without RGB gives a cloud without colour (intensity is not colour).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, atomic_file, require_file
from ldlmap.core.lazy import lazy_module
from ldlmap.io.cloud import PointCloud

laspy = lazy_module("laspy")

LAS_SUFFIXES: tuple[str, ...] = (".las", ".laz")


def read_las(path: str | os.PathLike) -> tuple[PointCloud, str]:
    """The cloud of a LAS/LAZ file and a one-line note (points, colour, CRS units when stated)."""
    p = require_file(path, "LAS file")
    try:
        las = laspy.read(str(p))
    except Exception as exc:  # laspy raises LaspyException, lazrs its own, numpy ValueError on short data
        text = str(exc).strip().splitlines()
        raise InputError(f"cannot read LAS/LAZ file {p}: {text[0] if text else type(exc).__name__}") from None
    n = len(las.points)
    if n == 0:
        raise InputError(f"LAS file holds no points: {p}")
    pts = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1).astype(np.float64)
    names = set(las.point_format.dimension_names)
    colors, how = None, "no RGB in this point format (a cloud without colour)"
    if {"red", "green", "blue"} <= names:
        rgb = np.stack([np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)], axis=1).astype(np.float64)
        if rgb.max() > 255:
            colors, how = np.rint(rgb / 257.0).astype(np.uint8), "16-bit RGB scaled to 8 bits"
        else:
            colors, how = rgb.astype(np.uint8), "RGB stored as 8-bit values"
    h = las.header
    note = (f"LAS {h.version} point format {las.point_format.id}: {n} points (scale {', '.join(f'{s:g}' for s in h.scales)}, "
            f"offset {', '.join(f'{o:.0f}' for o in h.offsets)}), {how}")
    return PointCloud(pts, colors).validate(p), note


def write_las(path: str | os.PathLike, cloud: PointCloud, scale: float = 0.001,
              offset: np.ndarray | None = None, sixteen_bit: bool = True) -> Path:
    """Write ``cloud`` as LAS 1.2 (point format 2 with colour, 0 without); ``.laz`` is compressed.
    ``offset``: the header offset (default: the cloud's minimum, rounded to metres)."""
    target = Path(path)
    if target.suffix.lower() not in LAS_SUFFIXES:
        raise InputError(f"cannot write {target.suffix or '(none)'} as LAS: use .las or .laz")
    pts = cloud.points
    header = laspy.LasHeader(point_format=2 if cloud.colors is not None else 0, version="1.2")
    header.offsets = np.floor(pts.min(axis=0)) if offset is None else np.asarray(offset, dtype=np.float64)
    header.scales = np.full(3, float(scale))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    if cloud.colors is not None:
        rgb = cloud.colors.astype(np.uint16) * (257 if sixteen_bit else 1)
        las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    with atomic_file(target) as tmp:
        las.write(str(tmp), do_compress=target.suffix.lower() == ".laz")
    return target
