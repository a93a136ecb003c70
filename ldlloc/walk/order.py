"""The order of a walk's photos: by file name (natural order: ``pano_2`` before ``pano_10``) or by
capture time (EXIF ``DateTimeOriginal`` with its sub-seconds, else XMP; read in :mod:`ldlmap.io.panorama_meta`)."""

from __future__ import annotations

import re
from datetime import timezone
from pathlib import Path

from ldlmap.core.errors import InputError
from ldlmap.io.panorama_meta import panorama_metadata

ORDERS = ("name", "time")


def check_order(order: str, name: str = "order") -> None:
    """A one-line InputError unless ``order`` is one of :data:`ORDERS` (``name``: how the caller calls it)."""
    if order not in ORDERS:
        raise InputError(f"{name} must be {' or '.join(ORDERS)}, got {order!r}")


def natural_key(text: str) -> tuple:
    """A sort key that orders the digit runs of ``text`` as numbers (``a2`` < ``a10``)."""
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", text) if p)


def capture_time(path: str | Path) -> float | None:
    """Seconds (POSIX; a time without a zone taken as UTC) of a photo's recorded capture time (EXIF
    ``DateTimeOriginal`` with its sub-seconds, else XMP: :func:`ldlmap.io.panorama_meta.panorama_metadata`);
    None when the photo records none."""
    t = panorama_metadata(path).time
    if t is None:
        return None
    return (t if t.tzinfo is not None else t.replace(tzinfo=timezone.utc)).timestamp()


def ordered(items: list, order: str, name_of, path_of) -> tuple[list, list[float | None]]:
    """``items`` in walk order and their capture times: ``name`` (natural order of ``name_of(item)``)
    or ``time`` (capture time, ties by name; a one-line error naming a photo without one)."""
    check_order(order)
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
