"""Colored point clouds: reading ``.ply`` / ``.pcd`` / ``.txt`` (and meshes), writing ``.ply`` / ``.txt``.

Text clouds are rows ``x y z [r g b]`` separated by spaces, tabs or commas, colors 0-255 (the
OmniScenes / Stanford 2D-3D-S ``pcd`` format); colors given as floats in [0, 1] are scaled to
0-255. A first line holding only the point count is skipped. ``#`` starts a comment.
PLY is written as binary little-endian with ``double`` coordinates and ``uchar`` colors, so a
write/read round trip is exact. Meshes (``.obj``, ``.off``, ``.stl`` and ``.ply`` files with
faces) are sampled into a colored cloud by :func:`ldlmap.io.mesh.sample_mesh`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ldlmap.errors import InputError, atomic_file, require_file

POINT_CLOUD_SUFFIXES: tuple[str, ...] = (".ply", ".pcd", ".txt", ".xyz", ".pts")
MESH_SUFFIXES: tuple[str, ...] = (".obj", ".off", ".stl")
SUPPORTED_SUFFIXES: tuple[str, ...] = POINT_CLOUD_SUFFIXES + MESH_SUFFIXES
WRITE_SUFFIXES: tuple[str, ...] = (".ply", ".txt")
DEFAULT_MESH_SAMPLES = 1_000_000  # points sampled from a mesh given where a cloud is expected


@dataclass(frozen=True, eq=False)
class PointCloud:
    """A point cloud in world coordinates (metres) with optional 8-bit RGB colors."""

    points: np.ndarray  # (N, 3) float64
    colors: np.ndarray | None = None  # (N, 3) uint8 RGB, or None

    def __post_init__(self) -> None:
        pts = np.ascontiguousarray(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"point cloud points must have shape (N, 3), got {pts.shape}")
        object.__setattr__(self, "points", pts)
        if self.colors is not None:
            col = np.asarray(self.colors)
            if col.shape != pts.shape:
                raise InputError(f"point cloud colors must have shape {pts.shape}, got {col.shape}")
            if col.dtype != np.uint8:
                if np.issubdtype(col.dtype, np.floating) and not np.all(np.isfinite(col)):
                    raise InputError("point cloud colors contain NaN or inf")
                if col.size and (col.min() < 0 or col.max() > 255):
                    raise InputError("point cloud colors must lie in 0-255")
                col = np.rint(col).astype(np.uint8)
            object.__setattr__(self, "colors", np.ascontiguousarray(col))

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(min (3,), max (3,))``."""
        if len(self) == 0:
            raise InputError("empty point cloud has no bounds")
        return self.points.min(axis=0), self.points.max(axis=0)

    def subsample(self, max_points: int, seed: int = 0) -> "PointCloud":
        """At most ``max_points`` points drawn uniformly without replacement (original order kept)."""
        if max_points <= 0:
            raise ValueError(f"max_points must be positive, got {max_points}")
        if len(self) <= max_points:
            return self
        idx = np.sort(np.random.default_rng(seed).choice(len(self), size=max_points, replace=False))
        return PointCloud(self.points[idx], None if self.colors is None else self.colors[idx])

    def validate(self, source: str | os.PathLike | None = None) -> "PointCloud":
        """Raise :class:`InputError` for an empty cloud or non-finite coordinates; return self."""
        where = f": {source}" if source is not None else ""
        if len(self) == 0:
            raise InputError(f"point cloud is empty{where}")
        bad = ~np.isfinite(self.points).all(axis=1)
        if bad.any():
            raise InputError(f"point cloud has {int(bad.sum())} points with NaN/inf coordinates{where}")
        return self


# ------------------------------------------------------------------------------------- reading


def read_point_cloud(path: str | os.PathLike, mesh_samples: int = DEFAULT_MESH_SAMPLES) -> PointCloud:
    """Read a colored point cloud; meshes are sampled with ``mesh_samples`` points.

    Raises :class:`InputError` for a missing file, an unknown extension, an empty cloud,
    non-finite coordinates or a malformed text file.
    """
    p = require_file(path, "point cloud")
    suffix = p.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise InputError(f"unsupported point cloud format {p.suffix or '(none)'} for {p}; "
                         f"supported: {', '.join(SUPPORTED_SUFFIXES)}")
    if suffix in MESH_SUFFIXES or (suffix == ".ply" and _ply_face_count(p) > 0):
        from ldlmap.io.mesh import sample_mesh

        return sample_mesh(p, mesh_samples)
    if suffix in (".txt", ".xyz", ".pts"):
        pc = _read_text(p)
    elif suffix == ".ply":
        pc = _read_ply(p)
    else:
        pc = _read_open3d(p)
    return pc.validate(p)


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


@dataclass(frozen=True)
class _PlyHeader:
    fmt: str  # ascii | binary_little_endian | binary_big_endian
    elements: list  # [(name, count, [(prop, type or 'list')])]
    data_offset: int  # bytes before the data


def _ply_header(path: Path) -> _PlyHeader:
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if not head.startswith(b"ply"):
        raise InputError(f"not a PLY file (missing 'ply' magic): {path}")
    m = re.search(rb"end_header\r?\n", head)
    if m is None:
        raise InputError(f"corrupt PLY header (no end_header): {path}")
    fmt, elements = "", []
    for raw in head[: m.start()].decode("ascii", "replace").splitlines()[1:]:
        w = raw.split()
        if not w or w[0] in ("comment", "obj_info"):
            continue
        try:
            if w[0] == "format":
                fmt = w[1]
            elif w[0] == "element":
                elements.append((w[1], int(w[2]), []))
                if elements[-1][1] < 0:
                    raise InputError(f"corrupt PLY header: element {w[1]} has a negative count {w[2]}: {path}")
            elif w[0] == "property" and elements:
                elements[-1][2].append((w[-1], "list" if w[1] == "list" else _PLY_TYPES[w[1]]))
        except (IndexError, KeyError, ValueError):
            raise InputError(f"corrupt PLY header line {raw.strip()!r}: {path}") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"unsupported PLY format {fmt or '(none)'}: {path}")
    header = _PlyHeader(fmt, elements, m.end())
    _check_ply_counts(header, path)
    return header


def _check_ply_counts(h: _PlyHeader, path: Path) -> None:
    """Refuse element counts that the file's size cannot hold (before anything is allocated):
    a binary row needs its fixed-size properties (a list at least its 1-byte length), an ASCII
    row at least 2 bytes (a digit and a separator) per property."""
    available = path.stat().st_size - h.data_offset
    need = 0
    for _, count, props in h.elements:
        if h.fmt == "ascii":
            row = 2 * max(len(props), 1)
        else:
            row = sum(1 if t == "list" else np.dtype(t).itemsize for _, t in props)
        need += count * row
    if need > available:
        what = ", ".join(f"{count} {name}" for name, count, _ in h.elements)
        raise InputError(f"corrupt or truncated PLY: its header declares {what}, which need at least {need} bytes, "
                         f"the file holds {available}: {path}")


def _ply_face_count(path: Path) -> int:
    """Number of faces declared in a PLY header (0 for point clouds)."""
    return sum(count for name, count, _ in _ply_header(path).elements if name == "face")


def _read_ply(path: Path) -> PointCloud:
    """Vertex-only PLY (ascii or binary) read with numpy; size checked against the header."""
    h = _ply_header(path)
    if not h.elements or h.elements[0][0] != "vertex" or any(t == "list" for _, t in h.elements[0][2]):
        return _read_open3d(path)  # unusual layouts: let open3d try
    _, count, props = h.elements[0]
    names = [n for n, _ in props]
    if not {"x", "y", "z"} <= set(names):
        raise InputError(f"PLY vertices lack x, y, z properties: {path}")
    endian = ">" if h.fmt == "binary_big_endian" else "<"
    dtype = np.dtype([(n, endian + t) for n, t in props])
    if h.fmt == "ascii":
        with open(path, "rb") as f:
            f.seek(h.data_offset)
            try:
                table = np.loadtxt(f, dtype=np.float64, max_rows=count, ndmin=2)
            except ValueError as exc:
                raise InputError(f"corrupt PLY data ({str(exc).split(';')[0]}): {path}") from None
        if table.shape != (count, len(props)):
            raise InputError(f"corrupt PLY: expected {count} vertices with {len(props)} values, read {table.shape[0]}: {path}")
        cols = {n: table[:, i] for i, n in enumerate(names)}
    else:
        data = np.fromfile(path, dtype=np.uint8, offset=h.data_offset)
        if data.size < count * dtype.itemsize:
            raise InputError(f"corrupt or truncated PLY: {count} vertices need {count * dtype.itemsize} bytes, "
                             f"found {data.size}: {path}")
        rec = data[: count * dtype.itemsize].view(dtype)
        cols = {n: rec[n] for n in names}
    pts = np.stack([cols["x"], cols["y"], cols["z"]], axis=1).astype(np.float64)
    colors = None
    for keys in (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue")):
        if set(keys) <= set(names):
            rgb = np.stack([cols[k] for k in keys], axis=1)
            kind = dict(props)[keys[0]]
            if kind.startswith("f"):
                rgb = np.clip(rgb.astype(np.float64), 0.0, 1.0) * 255.0
            elif kind in ("u2", "i2"):
                rgb = rgb.astype(np.float64) / 257.0
            colors = np.rint(np.clip(rgb, 0, 255)).astype(np.uint8)
            break
    if count == 0:
        raise InputError(f"point cloud is empty: {path}")
    return PointCloud(pts, colors)


def _read_open3d(path: Path) -> PointCloud:
    import open3d as o3d

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.io.read_point_cloud(str(path))
    pts = np.asarray(cloud.points, dtype=np.float64)
    if len(pts) == 0:
        raise InputError(f"no points could be read (empty or corrupt file): {path}")
    colors = None
    if cloud.has_colors():
        colors = np.rint(np.clip(np.asarray(cloud.colors), 0.0, 1.0) * 255.0).astype(np.uint8)
    return PointCloud(pts, colors)


def _first_data_lines(path: Path, n: int = 2) -> list[str]:
    lines: list[str] = []
    with open(path, "r", errors="replace") as f:
        for line in f:
            s = line.split("#", 1)[0].strip()
            if s:
                lines.append(s)
                if len(lines) == n:
                    break
    return lines


def _read_text(path: Path) -> PointCloud:
    head = _first_data_lines(path)
    if not head:
        raise InputError(f"point cloud is empty: {path}")
    delimiter = "," if "," in head[0] else None
    ncols0 = len(head[0].split(delimiter))
    skiprows = 0
    if ncols0 == 1 and len(head) > 1:  # a leading point-count line
        skiprows, ncols0 = 1, len(head[1].split(delimiter))
    if ncols0 not in (3, 6):
        raise InputError(f"point cloud text rows must have 3 (x y z) or 6 (x y z r g b) columns, "
                         f"found {ncols0}: {path}")
    try:
        data = np.loadtxt(path, dtype=np.float64, delimiter=delimiter, comments="#", skiprows=skiprows, ndmin=2)
    except ValueError as exc:
        msg = str(exc).split(";")[0]
        raise InputError(f"malformed point cloud text ({msg}): {path}") from None
    except UnicodeDecodeError:
        raise InputError(f"point cloud text is not readable as text: {path}") from None
    if data.shape[0] == 0:
        raise InputError(f"point cloud is empty: {path}")
    colors = None
    if data.shape[1] == 6:
        rgb = data[:, 3:]
        if not np.all(np.isfinite(rgb)):
            raise InputError(f"point cloud colors contain NaN or inf: {path}")
        if rgb.max() <= 1.0 and np.any(rgb != np.rint(rgb)):
            rgb = rgb * 255.0  # colors given as floats in [0, 1]
        if rgb.min() < 0 or rgb.max() > 255:
            raise InputError(f"point cloud colors must lie in 0-255 (found {rgb.min():g}..{rgb.max():g}): {path}")
        colors = np.rint(rgb).astype(np.uint8)
    return PointCloud(data[:, :3], colors)


# ------------------------------------------------------------------------------------- writing


def write_point_cloud(path: str | os.PathLike, pc: PointCloud) -> Path:
    """Write ``pc`` as binary PLY (``.ply``) or text rows ``x y z [r g b]`` (``.txt``), atomically."""
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in WRITE_SUFFIXES:
        raise InputError(f"cannot write point cloud format {target.suffix or '(none)'}; "
                         f"supported: {', '.join(WRITE_SUFFIXES)}")
    with atomic_file(target) as tmp:
        if suffix == ".ply":
            _write_ply(tmp, pc)
        else:
            _write_text(tmp, pc)
    return target


def _write_ply(path: Path, pc: PointCloud) -> None:
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    props = ["property double x", "property double y", "property double z"]
    if pc.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    rec = np.empty(len(pc), dtype=fields)
    rec["x"], rec["y"], rec["z"] = pc.points.T
    if pc.colors is not None:
        rec["red"], rec["green"], rec["blue"] = pc.colors.T
    header = "\n".join(["ply", "format binary_little_endian 1.0", "comment written by ldlmap",
                        f"element vertex {len(pc)}", *props, "end_header"]) + "\n"
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(rec.tobytes())


def _write_text(path: Path, pc: PointCloud) -> None:
    with open(path, "w") as f:
        if pc.colors is None:
            np.savetxt(f, pc.points, fmt="%.17g")
        else:
            table = np.concatenate([pc.points, pc.colors.astype(np.float64)], axis=1)
            np.savetxt(f, table, fmt=["%.17g"] * 3 + ["%d"] * 3)
