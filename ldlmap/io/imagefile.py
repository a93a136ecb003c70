"""Image files read without giving their path to OpenCV.

OpenCV's ``imread`` takes a C string: a file name that is not UTF-8 (``z\\xff.jpg``, which Python
holds with surrogate escapes) crashes it with SIGSEGV. :func:`read_image_file` reads the bytes in
Python and decodes them with ``cv2.imdecode``. libjpeg reports damaged data (a file cut short, its
end marker kept) only as a warning on the process's stderr and returns a grey-filled image: the
decoder's stderr is caught, and such a warning makes the file corrupt (:class:`InputError`), never
a line leaked to the terminal.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np

from ldlmap.core.errors import InputError

# What libjpeg says of data it could not decode in full (its JWRN_* warnings): the image is damaged.
CORRUPT_DATA_WARNINGS = ("Corrupt JPEG data", "Premature end of JPEG file")


def read_image_file(path: str | os.PathLike, flags: int | None = None) -> np.ndarray | None:
    """The decoded image of file ``path`` (``cv2.imdecode``; ``flags``: default ``IMREAD_COLOR``),
    None when OpenCV cannot decode it (what the decoder said of it is not printed); :class:`InputError`
    when the decoder reports damaged data."""
    import cv2

    data = np.frombuffer(Path(path).read_bytes(), np.uint8)
    with _native_stderr() as said:
        img = cv2.imdecode(data, cv2.IMREAD_COLOR if flags is None else flags)
    text = said()
    damaged = [line for line in text.splitlines() if line.startswith(CORRUPT_DATA_WARNINGS)]
    if damaged:
        raise InputError(f"corrupt image data ({damaged[0].strip()}): {path}")
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
