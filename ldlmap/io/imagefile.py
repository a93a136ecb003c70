"""Image files read and written through Python's own file I/O, decoded and encoded by OpenCV in memory.

OpenCV's ``imread`` / ``imwrite`` take the path as a C string: a file name that is not valid
UTF-8 (``b"z\\xff.jpg"``, which Python holds as ``"z\\udcff.jpg"``) crashes them (SIGSEGV), and
their failures say nothing about why. Here the bytes go through ``open()`` (any name the file
system holds, ``OSError`` with the reason) and OpenCV only sees buffers (``imdecode``, ``imencode``).

A written JPEG or PNG can carry a short text (``comment``): a JPEG COM segment after the start
marker, a PNG ``tEXt`` chunk (keyword ``Comment``) after ``IHDR``; :func:`image_comment` reads it
back from the file's first bytes (it is how a command recognizes its own pictures).
:func:`image_header_size` reads a PNG's or JPEG's size from its header, before decoding it.

libjpeg reports damaged data (a file cut short, its end marker kept) only as a warning on the
process's stderr and returns a grey-filled image: :func:`read_image` catches the decoder's stderr,
and such a warning makes the file corrupt (:class:`InputError`), never a line leaked to the terminal.
"""

from __future__ import annotations

import contextlib
import os
import struct
import sys
import tempfile
import zlib
from pathlib import Path
from typing import Iterator

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module

cv2 = lazy_module("cv2")

JPEG_SUFFIXES = (".jpg", ".jpeg")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_KEYWORD = b"Comment"
_HEAD_BYTES = 512  # where image_comment looks: the comment sits right after the header
# What libjpeg says of data it could not decode in full (its JWRN_* warnings): the image is damaged.
CORRUPT_DATA_WARNINGS = ("Corrupt JPEG data", "Premature end of JPEG file")


def printable(text: str) -> str:
    """``text`` (a file name, or a caption holding one) with the bytes that are not UTF-8 (Python
    holds them as lone surrogates, ``"z\\udcff"``) written ``\\xff``: text that OpenCV can draw
    (a surrogate crashes ``cv2.putText``) and that UTF-8 outputs (pages, JSON) can hold."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def read_image(path: str | os.PathLike, flags: int | None = None) -> np.ndarray | None:
    """The decoded image at ``path`` (``cv2.imdecode`` with ``flags``, default ``IMREAD_COLOR``;
    the ``IMREAD_REDUCED_*`` flags work too), None when it cannot be decoded (what the decoder said
    of it is not printed); ``OSError`` when the file cannot be read; :class:`InputError` when the
    decoder reports damaged data."""
    with open(path, "rb") as f:
        data = np.frombuffer(f.read(), dtype=np.uint8)
    if data.size == 0:
        return None
    with _native_stderr() as said:
        img = cv2.imdecode(data, cv2.IMREAD_COLOR if flags is None else flags)
    text = said()
    damaged = [line for line in text.splitlines() if line.startswith(CORRUPT_DATA_WARNINGS)]
    if damaged:
        raise InputError(f"corrupt image data ({damaged[0].strip()}): {printable(os.fspath(path))}")
    if text and img is not None:  # anything else said meanwhile goes where it was going; for a file that
        sys.stderr.write(text)     # cannot be decoded, the caller's one-line error says it all
    return img


@contextlib.contextmanager
def _native_stderr() -> Iterator:
    """Catch what is written to file descriptor 2 (C libraries' stderr) inside the block; yields a
    function returning it as text ("" when the descriptor cannot be redirected)."""
    caught: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        yield lambda: ""
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lambda: "".join(caught)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            caught.append(tmp.read().decode("utf-8", "replace"))


def encode_image(image: np.ndarray, suffix: str, quality: int = 90, comment: str | None = None) -> bytes:
    """``image`` (BGR or grey) encoded in the format ``suffix`` names (``.jpg``: JPEG at ``quality``,
    ``.webp`` likewise); ``comment`` (ASCII) is embedded in a JPEG or PNG. ``ValueError`` when
    OpenCV cannot encode it."""
    ext = suffix.lower()
    params = {".jpg": [cv2.IMWRITE_JPEG_QUALITY, quality], ".jpeg": [cv2.IMWRITE_JPEG_QUALITY, quality],
              ".webp": [cv2.IMWRITE_WEBP_QUALITY, quality]}.get(ext, [])
    ok, buf = cv2.imencode(ext, np.ascontiguousarray(image), params)
    if not ok:
        raise ValueError(f"OpenCV cannot encode a {ext} image")
    data = buf.tobytes()
    if comment is None:
        return data
    text = comment.encode("ascii")
    if ext in JPEG_SUFFIXES and data.startswith(b"\xff\xd8"):
        return data[:2] + b"\xff\xfe" + struct.pack(">H", len(text) + 2) + text + data[2:]
    if ext == ".png" and data.startswith(_PNG_SIGNATURE):
        end_ihdr = 8 + 8 + 13 + 4  # signature, IHDR's length and type, its 13 bytes, its CRC
        body = b"tEXt" + _PNG_KEYWORD + b"\x00" + text
        chunk = struct.pack(">I", len(body) - 4) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
        return data[:end_ihdr] + chunk + data[end_ihdr:]
    return data


def write_image(path: str | os.PathLike, image: np.ndarray, quality: int = 90, comment: str | None = None,
                suffix: str | None = None) -> None:
    """Write ``image`` to ``path`` in the format its extension (or ``suffix``) names
    (:func:`encode_image`); ``OSError`` (no space left, ...) from the write itself."""
    data = encode_image(image, suffix or Path(path).suffix, quality, comment)
    with open(path, "wb") as f:
        f.write(data)


def image_comment(path: str | os.PathLike) -> str | None:
    """The comment :func:`write_image` embedded in a JPEG or PNG at ``path`` (None: none, another
    format, or unreadable)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_HEAD_BYTES)
    except OSError:
        return None
    if head.startswith(b"\xff\xd8\xff\xfe") and len(head) >= 6:
        n = struct.unpack(">H", head[4:6])[0] - 2
        return head[6:6 + n].decode("ascii", "replace") if 6 + n <= len(head) else None
    if head.startswith(_PNG_SIGNATURE):
        at = 8 + 8 + 13 + 4
        if head[at + 4:at + 8] == b"tEXt":
            n = struct.unpack(">I", head[at:at + 4])[0]
            body = head[at + 8:at + 8 + n]
            key, _, text = body.partition(b"\x00")
            if key == _PNG_KEYWORD:
                return text.decode("ascii", "replace")
    return None


def image_header_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) from a PNG or JPEG header, read before decoding (None: another format, or
    no size found); raises :class:`InputError` for a JPEG without its end marker (truncated)."""
    p = Path(path)
    with open(p, "rb") as f:
        head = f.read(1 << 16)
        if head.startswith(_PNG_SIGNATURE) and len(head) >= 24 and head[12:16] == b"IHDR":
            return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        if not head.startswith(b"\xff\xd8"):
            return None
        f.seek(max(0, p.stat().st_size - 4096))
        if b"\xff\xd9" not in f.read():
            raise InputError(f"truncated JPEG (no end marker): {p}")
    i = 2
    while i + 9 <= len(head) and head[i] == 0xFF:  # JPEG segments up to the frame header (SOFn)
        marker, length = head[i + 1], int.from_bytes(head[i + 2:i + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return int.from_bytes(head[i + 7:i + 9], "big"), int.from_bytes(head[i + 5:i + 7], "big")
        i += 2 + length
    return None


__all__ = ["encode_image", "image_comment", "image_header_size", "printable", "read_image", "write_image"]
