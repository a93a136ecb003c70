"""3D line segment files (docs/formats.md, "3D line files").

All readers return, and all writers take, float64 arrays of shape (N, 2, 3): (start, end).

Formats:

* our ``.txt``: first line ``# ldl lines v1``, then one ``x1 y1 z1 x2 y2 z2`` row per segment;
* ``.obj`` (ours and Line3D++): ``v x y z`` vertices and ``l i j`` (1-based; a polyline
  ``l i j k`` gives consecutive segments); other records are ignored;
* Line3D++ ``.txt``: one 3D line per row, ``n P1x P1y P1z Q1x Q1y Q1z ... m camID segID px py
  qx qy ...`` (n segments, then m 2D observations of 6 numbers); all segments are returned;
* 3DLineDetection ``.txt`` (the OmniScenes / Stanford ``pcd_line`` files): rows
  ``x y z ... line_id``: points along each line, the first and last point of an id are its
  ends; extra columns are ignored and ids need not be sorted or contiguous.

Both other ``.txt`` flavours are told apart by content: our header, else Line3D++ when every
row has ``1 + 6 n + 1 + 6 m`` columns with integer ``n`` and ``m``, else 3DLineDetection.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, atomic_file, require_file

HEADER = "# ldl lines v1"


def check_segments(segs: np.ndarray, what: str) -> np.ndarray:
    """Segments as float64 (L, 2, 3) (also from (L, 6) rows); refuses (one line, naming ``what``) other shapes or bad values."""
    arr = np.asarray(segs, dtype=np.float64)
    if arr.ndim == 2 and arr.shape[1] == 6:
        arr = arr.reshape(-1, 2, 3)
    if arr.ndim != 3 or arr.shape[1:] != (2, 3):
        raise InputError(f"{what}: line segments must have shape (N, 2, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what}: line segments contain NaN or infinite values")
    return arr


def _read_text(path: str | os.PathLike, what: str, allow_empty: bool = False) -> tuple[Path, list[str]]:
    p = require_file(path, what)
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {what} {p}: {exc}") from None
    lines = text.splitlines()
    if not allow_empty and not any(line.strip() and not line.lstrip().startswith("#") for line in lines):
        raise InputError(f"{what} is empty: {p}")
    return p, lines


def _numeric_rows(p: Path, lines: list[str], what: str) -> list[np.ndarray]:
    rows = []
    for no, line in enumerate(lines, start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            vals = np.array([float(x) for x in s.replace(",", " ").split()], dtype=np.float64)
        except ValueError:
            raise InputError(f"{what} {p}, line {no}: non-numeric value in {s[:60]!r}") from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{what} {p}, line {no}: NaN or infinite value")
        rows.append(vals)
    return rows


def read_ldl_txt(path: str | os.PathLike) -> np.ndarray:
    """Our ``.txt`` format (header ``# ldl lines v1``, rows ``x1 y1 z1 x2 y2 z2``)."""
    what = "line file"
    p, lines = _read_text(path, what, allow_empty=True)
    if not lines or lines[0].strip() != HEADER:
        raise InputError(f"{what} {p}: missing header {HEADER!r}")
    rows = _numeric_rows(p, lines[1:], what)
    if not rows:
        return np.zeros((0, 2, 3))
    bad = [i for i, r in enumerate(rows) if len(r) != 6]
    if bad:
        raise InputError(f"{what} {p}: data row {bad[0] + 1} has {len(rows[bad[0]])} columns, expected 6")
    return np.stack(rows).reshape(-1, 2, 3)


def read_3dlinedetection_txt(path: str | os.PathLike) -> np.ndarray:
    """3DLineDetection rows ``x y z ... line_id``: one segment per id (its first and last point)."""
    what = "3DLineDetection line file"
    p, lines = _read_text(path, what)
    rows = _numeric_rows(p, lines, what)
    counts = {len(r) for r in rows}
    if len(counts) != 1:
        raise InputError(f"{what} {p}: rows have different column counts {sorted(counts)}")
    ncol = counts.pop()
    if ncol < 4:
        raise InputError(f"{what} {p}: expected at least 4 columns (x y z ... line_id), got {ncol}")
    data = np.stack(rows)
    ids = data[:, -1]
    if not np.all((ids == np.round(ids)) & (np.abs(ids) < 2.0 ** 53)):
        raise InputError(f"{what} {p}: the last column (line id) must hold integers")
    ids = ids.astype(np.int64)
    _, first = np.unique(ids, return_index=True)
    _, last_rev = np.unique(ids[::-1], return_index=True)
    last = len(ids) - 1 - last_rev
    order = np.argsort(first)  # segments in file order of first appearance
    return np.stack([data[first[order], :3], data[last[order], :3]], axis=1)


def read_line3dpp_txt(path: str | os.PathLike) -> np.ndarray:
    """Line3D++ ``.txt``: per row n segments (6 numbers each), then m observations (6 numbers each)."""
    what = "Line3D++ line file"
    p, lines = _read_text(path, what)
    rows = _numeric_rows(p, lines, what)
    segs = []
    for i, r in enumerate(rows, start=1):
        problem = _line3dpp_row_problem(r)
        if problem:
            raise InputError(f"{what} {p}: row {i} {problem}")
        n = int(r[0])
        segs.append(r[1:1 + 6 * n].reshape(n, 2, 3))
    return np.concatenate(segs) if segs else np.zeros((0, 2, 3))


def _line3dpp_row_problem(r: np.ndarray) -> str | None:
    if len(r) < 2 or r[0] != round(r[0]) or r[0] < 1:
        return "does not start with a positive integer segment count"
    n = int(r[0])
    if len(r) < 1 + 6 * n + 1:
        return f"has {len(r)} columns, too few for {n} segments"
    m = r[1 + 6 * n]
    if m != round(m) or m < 0:
        return "has a non-integer observation count"
    if len(r) != 1 + 6 * n + 1 + 6 * int(m):
        return f"has {len(r)} columns, expected 1 + 6*{n} + 1 + 6*{int(m)} = {2 + 6 * n + 6 * int(m)}"
    return None


def read_lines_obj(path: str | os.PathLike) -> np.ndarray:
    """``.obj`` with ``v`` and ``l`` records (1-based, negative = relative); polylines become segments."""
    what = "line OBJ file"
    p, lines = _read_text(path, what)
    verts: list[list[float]] = []
    segs: list[tuple[int, int]] = []
    for no, line in enumerate(lines, start=1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        try:
            if parts[0] == "v":
                if len(parts) < 4:
                    raise InputError(f"{what} {p}, line {no}: a vertex needs 3 coordinates")
                xyz = [float(x) for x in parts[1:4]]
                if not all(np.isfinite(xyz)):
                    raise InputError(f"{what} {p}, line {no}: NaN or infinite vertex")
                verts.append(xyz)
            elif parts[0] == "l":
                idx = [int(x.split("/")[0]) for x in parts[1:]]
                if len(idx) < 2:
                    raise InputError(f"{what} {p}, line {no}: a line needs at least 2 vertex indices")
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                segs.extend(zip(idx[:-1], idx[1:]))
        except ValueError:
            raise InputError(f"{what} {p}, line {no}: non-numeric value in {line.strip()[:60]!r}") from None
    if not segs:
        raise InputError(f"{what} {p}: no 'l' records")
    ij = np.asarray(segs, dtype=np.int64)
    if ij.min() < 0 or ij.max() >= len(verts):
        raise InputError(f"{what} {p}: line refers to a vertex index out of range (1..{len(verts)})")
    V = np.asarray(verts, dtype=np.float64)
    return np.stack([V[ij[:, 0]], V[ij[:, 1]]], axis=1)


read_line3dpp_obj = read_lines_obj


def detect_txt_format(path: str | os.PathLike) -> str:
    """``"ldl"``, ``"line3dpp"`` or ``"3dlinedetection"`` for a ``.txt`` line file (by content)."""
    p, lines = _read_text(path, "line file", allow_empty=True)
    if lines and lines[0].strip() == HEADER:
        return "ldl"
    rows = _numeric_rows(p, lines, "line file")
    if rows and all(_line3dpp_row_problem(r) is None for r in rows):
        return "line3dpp"
    return "3dlinedetection"


# Names of the formats that :func:`sniff_line_file` recognises, for messages.
LINE_FORMAT_NAMES = {"ldl": "LDL lines .txt", "line3dpp": "Line3D++ .txt", "3dlinedetection": "3DLineDetection .txt",
                     "obj": "Line3D++ / LDL .obj"}
_OBJ_RECORD = re.compile(rb"^([lf])[ \t]", re.MULTILINE)


def sniff_line_file(path: str | os.PathLike, max_rows: int = 200) -> str | None:
    """The line-file format of ``path`` judged from its content (a key of :data:`LINE_FORMAT_NAMES`),
    or None when it looks like anything else (a point cloud, a mesh, unreadable).

    Cheap and never raising for content: a ``.txt`` is judged by its first ``max_rows`` data rows
    (our header; Line3D++ rows; 3DLineDetection rows of a column count a point cloud cannot have
    (not 3 or 6, at least 4) ending in an integer line id), an ``.obj`` by having ``l`` records and
    no ``f`` record.
    """
    p = Path(path)
    ext = p.suffix.lower()
    try:
        if ext == ".obj":
            return "obj" if _obj_has_lines_only(p) else None
        if ext != ".txt":
            return None
        with open(p, encoding="utf-8") as f:
            head = [line for _, line in zip(range(max_rows + 50), f)]
    except (OSError, UnicodeDecodeError):
        return None
    data = [ln for ln in head if ln.strip() and not ln.lstrip().startswith("#")][:max_rows]
    if head and head[0].strip() == HEADER:
        return "ldl"
    try:
        rows = [np.array([float(x) for x in ln.replace(",", " ").split()]) for ln in data]
    except ValueError:
        return None
    if not rows or not all(np.all(np.isfinite(r)) for r in rows):
        return None
    if all(_line3dpp_row_problem(r) is None for r in rows):
        return "line3dpp"
    ncols = {len(r) for r in rows}
    if len(ncols) == 1 and min(ncols) >= 4 and min(ncols) != 6 and all(r[-1] == round(r[-1]) for r in rows):
        return "3dlinedetection"
    return None


def _obj_has_lines_only(p: Path, chunk: int = 1 << 23) -> bool:
    """Whether an OBJ file has ``l`` records and no ``f`` record (stops at the first ``f``)."""
    has_lines, carry = False, b""
    with open(p, "rb") as f:
        while True:
            block = f.read(chunk)
            text = carry + block
            cut = text.rfind(b"\n") + 1 if block else len(text)  # whole lines; the rest goes with the next block
            text, carry = text[:cut], text[cut:]
            for m in _OBJ_RECORD.finditer(text):
                if m.group(1) == b"f":
                    return False
                has_lines = True
            if not block:
                return has_lines


def read_lines(path: str | os.PathLike) -> np.ndarray:
    """Read any supported line file, choosing the reader by extension and content."""
    p = require_file(path, "line file")
    ext = p.suffix.lower()
    if ext == ".obj":
        return read_lines_obj(p)
    if ext != ".txt":
        raise InputError(f"unsupported line file extension {p.suffix!r} (use .txt or .obj): {p}")
    fmt = detect_txt_format(p)
    if fmt == "ldl":
        return read_ldl_txt(p)
    if fmt == "line3dpp":
        return read_line3dpp_txt(p)
    return read_3dlinedetection_txt(p)


def write_lines_txt(path: str | os.PathLike, segs: np.ndarray) -> Path:
    """Our ``.txt`` format, atomically."""
    arr = check_segments(segs, str(path)).reshape(-1, 6)
    body = "\n".join(" ".join(r) for r in np.char.mod("%.6f", arr)) if len(arr) else ""
    with atomic_file(path) as tmp:
        tmp.write_text(f"{HEADER}\n# {len(arr)} segments: x1 y1 z1 x2 y2 z2 (metres)\n{body}{chr(10) if body else ''}")
    return Path(path)


def write_lines_obj(path: str | os.PathLike, segs: np.ndarray) -> Path:
    """``.obj`` with two ``v`` records and one ``l`` record per segment, atomically."""
    arr = check_segments(segs, str(path))
    V = arr.reshape(-1, 3)
    v_txt = "".join("v " + " ".join(r) + "\n" for r in np.char.mod("%.6f", V)) if len(V) else ""
    k = np.arange(len(arr)) * 2 + 1
    l_txt = "".join(f"l {a} {a + 1}\n" for a in k)
    with atomic_file(path) as tmp:
        tmp.write_text(f"# ldl lines: {len(arr)} segments\n{v_txt}{l_txt}")
    return Path(path)


def write_lines(path: str | os.PathLike, segs: np.ndarray) -> Path:
    """Write ``segs`` as ``.obj`` or our ``.txt`` depending on the extension."""
    ext = Path(path).suffix.lower()
    if ext == ".obj":
        return write_lines_obj(path, segs)
    if ext == ".txt":
        return write_lines_txt(path, segs)
    raise InputError(f"unsupported line file extension {Path(path).suffix!r} (use .txt or .obj): {path}")
