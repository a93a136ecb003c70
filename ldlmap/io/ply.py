"""PLY headers: element counts and property types, checked against the file's size before reading."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


@dataclass(frozen=True)
class PlyHeader:
    """A PLY file's header: its format, elements with their properties, and where the data starts."""

    fmt: str  # ascii | binary_little_endian | binary_big_endian
    elements: list  # [(name, count, [(prop, type or 'list')])]
    data_offset: int  # bytes before the data


def ply_header(path: Path) -> PlyHeader:
    """The header of the PLY file at ``path``, its counts checked against the file's size (one-line errors)."""
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
    header = PlyHeader(fmt, elements, m.end())
    _check_ply_counts(header, path)
    return header


def _check_ply_counts(h: PlyHeader, path: Path) -> None:
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


def ply_face_count(path: Path) -> int:
    """Number of faces declared in a PLY header (0 for point clouds)."""
    return sum(count for name, count, _ in ply_header(path).elements if name == "face")
