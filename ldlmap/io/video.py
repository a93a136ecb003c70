"""Writing videos with PyAV (FFmpeg): the synthetic walks' mp4 (``ldlmap synth --walk video``) and
the test and bench videos that ``ldlloc run --video`` reads (:mod:`ldlloc.walk.video` decodes them)."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Iterable

import numpy as np

from ldlmap.core.errors import atomic_file
from ldlmap.core.lazy import lazy_module

av = lazy_module("av")


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float, codec: str = "libx264") -> Path:
    """Encode RGB frames (H, W, 3) uint8 as a video (mp4: H.264, yuv420p) at ``fps``, atomically."""
    target = Path(path)
    with atomic_file(target) as tmp:
        with av.open(str(tmp), "w") as c:
            s = None
            for img in frames:
                if s is None:
                    s = c.add_stream(codec, rate=Fraction(fps).limit_denominator(1000))
                    s.width, s.height, s.pix_fmt = img.shape[1], img.shape[0], "yuv420p"
                for packet in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")):
                    c.mux(packet)
            if s is not None:
                for packet in s.encode():
                    c.mux(packet)
    return target
