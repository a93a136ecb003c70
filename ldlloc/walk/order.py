"""The order of a walk's photos: by file name (natural order: ``pano_2`` before ``pano_10``) or by
capture time (EXIF ``DateTimeOriginal``, with its sub-seconds when present)."""

from __future__ import annotations

import re
import struct
from datetime import datetime, timezone
from pathlib import Path

from ldlmap.core.errors import InputError

ORDERS = ("name", "time")
DATETIME_ORIGINAL, SUBSEC_ORIGINAL, EXIF_IFD = 0x9003, 0x9291, 0x8769


def natural_key(text: str) -> tuple:
    """A sort key that orders the digit runs of ``text`` as numbers (``a2`` < ``a10``)."""
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", text) if p)


def capture_time(path: str | Path) -> float | None:
    """Seconds (POSIX, the camera's clock taken as UTC) of a JPEG's EXIF ``DateTimeOriginal`` plus
    ``SubSecTimeOriginal``; None when the file carries none (another format, no EXIF, no such tag)."""
    with open(path, "rb") as f:
        head = f.read(1 << 17)
    if not head.startswith(b"\xff\xd8"):
        return None
    i = 2
    while i + 4 <= len(head) and head[i] == 0xFF:
        marker, length = head[i + 1], int.from_bytes(head[i + 2:i + 4], "big")
        if marker == 0xE1 and head[i + 4:i + 10] == b"Exif\0\0":
            return _exif_time(head[i + 10:i + 2 + length])
        if marker == 0xDA:  # image data: no EXIF before it
            return None
        i += 2 + length
    return None


def _exif_time(tiff: bytes) -> float | None:
    """The capture time in a TIFF-structured EXIF block (None: absent or malformed)."""
    try:
        end = {b"II": "<", b"MM": ">"}[tiff[:2]]
        tags = _ifd(tiff, struct.unpack(end + "I", tiff[4:8])[0], end)
        if EXIF_IFD not in tags:
            return None
        exif = _ifd(tiff, tags[EXIF_IFD][1], end)
        if DATETIME_ORIGINAL not in exif:
            return None
        text = _ascii(tiff, exif[DATETIME_ORIGINAL], end)
        stamp = datetime.strptime(text[:19], "%Y:%m:%d %H:%M:%S").replace(tzinfo=timezone.utc).timestamp()
        sub = _ascii(tiff, exif[SUBSEC_ORIGINAL], end) if SUBSEC_ORIGINAL in exif else ""
        return stamp + (float(f"0.{sub}") if sub.isdigit() else 0.0)
    except (KeyError, struct.error, ValueError, IndexError):
        return None


def _ifd(tiff: bytes, offset: int, end: str) -> dict[int, tuple[int, int]]:
    """``tag -> (count, value or offset)`` of the IFD at ``offset``."""
    n = struct.unpack(end + "H", tiff[offset:offset + 2])[0]
    out = {}
    for k in range(n):
        tag, _kind, count, value = struct.unpack(end + "HHII", tiff[offset + 2 + 12 * k:offset + 14 + 12 * k])
        out[tag] = (count, value)
    return out


def _ascii(tiff: bytes, entry: tuple[int, int], end: str) -> str:
    """An ASCII tag's text (inline when 4 bytes or fewer)."""
    count, value = entry
    raw = struct.pack(end + "I", value)[:count] if count <= 4 else tiff[value:value + count]
    return raw.split(b"\0")[0].decode("ascii", "replace").strip()


def ordered(items: list, order: str, name_of, path_of) -> tuple[list, list[float | None]]:
    """``items`` in walk order and their capture times: ``name`` (natural order of ``name_of(item)``)
    or ``time`` (capture time, ties by name; a one-line error naming a photo without one)."""
    if order not in ORDERS:
        raise InputError(f"--order must be {' or '.join(ORDERS)}, got {order!r}")
    items = sorted(items, key=lambda q: natural_key(name_of(q)))
    times = [capture_time(path_of(q)) for q in items]
    if order == "name":
        return items, times
    missing = [name_of(q) for q, t in zip(items, times) if t is None]
    if missing:
        raise InputError(f"--order time: {len(missing)} photo(s) carry no capture time (EXIF DateTimeOriginal), "
                         f"e.g. {missing[0]}; use --order name")
    pairs = sorted(zip(times, range(len(items))))
    return [items[i] for _, i in pairs], [t for t, _ in pairs]
