"""Equirectangular videos as walks: ``ldlloc run --video FILE|DIR|GLOB [--video ...] [--fps F | --every N]``.

Several videos (``--video`` repeated, a folder of videos or a quoted glob: :func:`find_videos`)
are one walk each.

Decoded in-process with PyAV (FFmpeg) frame by frame, never written to disk: the first pass
(:func:`ldlloc.walk.localize.localize_walk`) reads the kept frames in order from one decoder
(:func:`decoded_frames`); a frame the walk must look at again (a pose it moved) is read again by
seeking (:func:`frame_at`). Each kept frame is named ``<video stem>/<index>`` with its timestamp
(seconds, the stream's presentation time). A video that is not 2:1, does not decode, or is asked
for more frames a second than it has is a one-line error.
"""

from __future__ import annotations

import glob
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ldlloc.pipeline import WORK_WIDTH
from ldlmap.core.errors import InputError, require_file
from ldlmap.io.video import write_video  # noqa: F401  (moved to ldlmap: the generator writes videos too)
from ldlmap.core.lazy import lazy_module
from ldlloc.walk.order import natural_key

av = lazy_module("av")
cv2 = lazy_module("cv2")


VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm")  # what a folder or a glob of videos takes


def find_videos(specs: list[str | Path], warn=None) -> list[Path]:
    """The videos of ``--video`` (each a file, a folder of videos or a quoted glob), in natural name
    order, each once. One-line errors: a value that names nothing, a folder or glob without videos
    (:data:`VIDEO_SUFFIXES`), two videos of one name (a frame's record is ``<stem>/<frame>``); a
    video that does not decode is refused where it is opened (:func:`video_info`). A folder's other
    files are left out (``warn`` says how many; hidden files silently)."""
    found: list[Path] = []
    for spec in specs:
        text = str(spec)
        p = Path(text)
        if p.is_file():
            found.append(p)
            continue
        if p.is_dir():
            files = [f for f in p.iterdir() if f.is_file() and not f.name.startswith(".")]
            where = f"in the folder {p}"
        elif glob.has_magic(text):
            files = [Path(f) for f in glob.glob(text, recursive=True) if Path(f).is_file()]
            where = f"matching {text}"
        else:
            raise InputError(f"--video not found: {text} (a video, a folder of videos or a quoted glob)")
        videos = [f for f in files if f.suffix.lower() in VIDEO_SUFFIXES]
        if not videos:
            raise InputError(f"no video ({', '.join(s[1:] for s in VIDEO_SUFFIXES)}) {where}")
        if len(videos) < len(files) and warn is not None:
            warn(f"warning: {len(files) - len(videos)} file(s) {where} left out (not {'/'.join(VIDEO_SUFFIXES)})")
        found += videos
    unique = {f.resolve(): f for f in sorted(found, key=lambda f: natural_key(str(f)))}
    stems: dict[str, Path] = {}
    for f in unique.values():
        if f.stem in stems:
            raise InputError(f"two videos named {f.stem}: {stems[f.stem]} and {f} (a frame's record is named "
                             "<video name>/<frame>: rename one)")
        stems[f.stem] = f
    return list(unique.values())


@dataclass(frozen=True)
class VideoFrame:
    """One kept frame: its index among the video's frames, its time (s) and presentation time stamp."""

    index: int
    time: float
    pts: int | None


@dataclass(frozen=True)
class VideoInfo:
    """The video stream: size, frame rate (frames a second), duration (s, None: unknown)."""

    path: Path
    width: int
    height: int
    rate: float
    duration: float | None


def _open(path: Path):
    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError, ValueError) as exc:
        raise InputError(f"cannot decode video {path}: {exc}") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"no video stream in {path}")
    return container


def video_info(path: str | Path) -> VideoInfo:
    """The video's stream properties; one-line errors for a missing, undecodable or non-2:1 video."""
    p = require_file(path, "video")
    with _open(p) as c:
        s = c.streams.video[0]
        w, h = int(s.codec_context.width), int(s.codec_context.height)
        rate = float(s.average_rate or s.guessed_rate or 0)
        dur = float(s.duration * s.time_base) if s.duration is not None and s.time_base else None
    if w <= 0 or h <= 0:
        raise InputError(f"cannot decode video {p}: no frame size")
    check_equirectangular(p, w, h)
    if rate <= 0:
        raise InputError(f"cannot decode video {p}: no frame rate")
    return VideoInfo(p, w, h, rate, dur)


def check_equirectangular(path: Path, w: int, h: int, index: int | None = None) -> None:
    """A one-line error for a video (or its frame ``index``: the size may change mid-stream) that is not 2:1."""
    if w != 2 * h:
        where = "" if index is None else f" from frame {index} on"
        raise InputError(f"not an equirectangular video (width must be 2 x height): {path} is {w}x{h}{where}")


def check_sampling(info: VideoInfo, fps: float | None, every: int | None) -> None:
    """``--fps`` in (0, the video's rate] or ``--every`` >= 1, not both."""
    if fps is not None and every is not None:
        raise InputError("--fps and --every are two ways to say the same: give one")
    if fps is not None and not (0 < fps <= info.rate + 1e-6):
        raise InputError(f"--fps must be in (0, {info.rate:g}] (the video's frame rate), got {fps:g}")
    if every is not None and every < 1:
        raise InputError(f"--every must be at least 1, got {every}")


def _rgb(frame) -> np.ndarray:
    """A decoded frame as RGB uint8 at the working width (as :func:`ldlloc.pipeline.load_image`)."""
    img = frame.to_ndarray(format="rgb24")
    if img.shape[1] > WORK_WIDTH:
        img = cv2.resize(img, (WORK_WIDTH, WORK_WIDTH // 2), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img)


def _kept(index: int, time: float, fps: float | None, every: int | None, next_time: float) -> bool:
    if fps is not None:
        return time >= next_time - 1e-6
    return index % (every or 1) == 0


def decoded_frames(info: VideoInfo, fps: float | None = None, every: int | None = None
                   ) -> Iterator[tuple[VideoFrame, np.ndarray]]:
    """The kept frames in order with their images: every ``every``-th, or the first at or after
    each multiple of ``1 / fps`` seconds (neither: every frame)."""
    with _open(info.path) as c:
        s = c.streams.video[0]
        s.thread_type = "AUTO"
        next_time, index = 0.0, 0
        try:
            for frame in c.decode(s):
                check_equirectangular(info.path, frame.width, frame.height, index)
                time = float(frame.time) if frame.time is not None else index / info.rate
                if _kept(index, time, fps, every, next_time):
                    yield VideoFrame(index, time, frame.pts), _rgb(frame)
                    next_time = (np.floor(time * fps + 1e-6) + 1) / fps if fps else next_time
                index += 1
        except av.error.FFmpegError as exc:
            raise InputError(f"cannot decode video {info.path} at frame {index}: {exc}") from None


def frame_at(info: VideoInfo, vf: VideoFrame) -> np.ndarray:
    """One kept frame's image again: seek to the key frame before it, decode up to it."""
    with _open(info.path) as c:
        s = c.streams.video[0]
        if vf.pts is not None:
            c.seek(int(vf.pts), stream=s, backward=True, any_frame=False)
        for frame in c.decode(s):
            if vf.pts is None or frame.pts is None or frame.pts >= vf.pts:
                return _rgb(frame)
    raise InputError(f"cannot decode video {info.path}: frame {vf.index} not found again")


def frames_by_index(path: str | Path, indices: set[int]) -> Iterator[tuple[int, np.ndarray]]:
    """The frames of the video at ``path`` whose index is in ``indices`` (RGB at the working width),
    in one decoding pass (a report's thumbnails of a video run)."""
    info = video_info(path)
    last = max(indices, default=-1)
    with _open(info.path) as c:
        s = c.streams.video[0]
        s.thread_type = "AUTO"
        index = 0
        try:
            for frame in c.decode(s):
                if index > last:
                    return
                if index in indices:
                    yield index, _rgb(frame)
                index += 1
        except av.error.FFmpegError as exc:
            raise InputError(f"cannot decode video {info.path} at frame {index}: {exc}") from None
