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
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, atomic_file, require_file
from ldlmap.core.lazy import lazy_module
from ldlmap.io.cloud import DEFAULT_MESH_SAMPLES, MESH_SUFFIXES, SUPPORTED_SUFFIXES, WRITE_SUFFIXES, PointCloud
from ldlmap.io.mesh import sample_mesh
from ldlmap.io.ply import ply_face_count, ply_header

o3d = lazy_module("open3d")


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
    if suffix in MESH_SUFFIXES or (suffix == ".ply" and ply_face_count(p) > 0):
        return sample_mesh(p, mesh_samples)
    if suffix in (".txt", ".xyz", ".pts"):
        pc = _read_text(p)
    elif suffix == ".ply":
        pc = _read_ply(p)
    else:
        if suffix == ".pcd":
            _check_pcd_complete(p)
        pc = _read_open3d(p)
    return pc.validate(p)


def _check_pcd_complete(path: Path) -> None:
    """Refuse a PCD file that holds fewer points than its header's ``POINTS`` (a truncated file, which
    open3d reads with the missing points at the origin): ASCII rows are counted, binary sizes checked."""
    with open(path, "rb") as fh:
        header: dict[str, list[str]] = {}
        for _ in range(64):  # the header is a dozen lines; DATA ends it
            words = fh.readline().decode("ascii", "replace").split()
            if not words or words[0].startswith("#"):
                continue
            header[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                break
        else:
            return  # no DATA line: open3d says what is wrong
        try:
            points = int(header["POINTS"][0]) if "POINTS" in header else \
                int(header["WIDTH"][0]) * int(header["HEIGHT"][0])
            sizes = [int(x) for x in header.get("SIZE", [])]
            counts = [int(x) for x in header.get("COUNT", ["1"] * len(sizes))]
        except (KeyError, IndexError, ValueError):
            return
        kind = (header["DATA"] or ["?"])[0].lower()
        if kind == "ascii":
            got = sum(1 for line in fh if line.strip())
        elif kind == "binary" and sizes and len(counts) == len(sizes):
            got = (path.stat().st_size - fh.tell()) // sum(s * c for s, c in zip(sizes, counts))
        else:
            return  # binary_compressed: its own size field, checked by open3d
    if got < points:
        raise InputError(f"truncated PCD file: its header says {points} points, it holds {got}: {path}")


def _read_ply(path: Path) -> PointCloud:
    """Vertex-only PLY (ascii or binary) read with numpy; size checked against the header."""
    h = ply_header(path)
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
    """A cloud read by open3d (``.pcd`` and unusual PLY layouts); one line when it holds no points."""
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
