"""The ``walk`` capture of ``ldlmap synth --walk tour|video``: a person walking through the scene
with a 360 camera (the path: :mod:`ldlmap.synth.walkplan`).

- ``tour``: a capture tour, a photo every 1-3 m (``--walk-step``, default 2 m: steps of 0.5-1.5 x it), sharp;
- ``video``: a 360 video, a frame every 0.1-0.3 m (default 0.2 m) at 1 m/s (5 frames a second),
  motion blur growing with the turn between frames, also written as ``video/walk_video.mp4`` (PyAV);
  through a building's open doors (``--walk-doors open``) frame by frame, through closed ones in one
  step (``jump: door``: no photo inside a door's panel).

Each walk is a split, ``walk_tour`` / ``walk_video``, in the OmniScenes layout of the other splits:
``walk_<kind>_pano/walk_<kind>_<scene>_scene_1/<stem>.jpg`` with its pose file, the stems numbered
in walk order over the whole walk (``0000``, ``0001``, ...: a walk through a building's floors
continues its numbers from floor to floor), so that ``ldlloc run --root OUT --split walk_tour --walk``
reads each scene's frames in walk order (``--scene-unknown``: the whole walk, all its scenes).
``dataset.json`` holds per walk (``walks``) its frames in order: stem, scene, floor, room (buildings
and multi-room scenes), the frame's time (videos), the step from the previous frame and ``jump``
(:class:`~ldlmap.synth.walkplan.WalkPose`: ``stairs``, ``cut``, ``door`` or null). Each walk has its own
random stream, so asking for one changes nothing else in the dataset.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ldlmap.core.errors import InputError, check_range
from ldlmap.core.geometry import rotation_error_deg
from ldlmap.io.video import write_video
from ldlmap.synth.capture import CaptureSettings, write_jpeg, write_pose
from ldlmap.synth.render import render_through
from ldlmap.synth.walkplan import STEP_RANGE, BuiltRooms, WalkPose, WalkRoom, plan_walk

WALK_KINDS = ("tour", "video")
DOORS = ("closed", "open")  # a building's doors: closed (a panel in each doorway), or open (the next room is seen
# through the doorway): in its scans and panoramas (--doors) and in its walk's frames (--walk-doors)
WALK_STEP_M = {"tour": 2.0, "video": 0.2}  # mean step (m); steps are drawn in walkplan.STEP_RANGE x it
STEP_LIMITS = (0.05, 5.0)  # m, --walk-step
VISITS_PER_FLOOR = 3  # rooms off a building floor's corridor that a walk enters
WALKING_SPEED = 1.0  # m/s: a video's frame rate is WALKING_SPEED / step
VIDEO_FOLDER = "video"
_STREAM = 0x57A1  # the walks' random streams: [seed, _STREAM, kind]


def walk_split(kind: str) -> str:
    """The split of a walk kind: ``walk_tour``, ``walk_video``."""
    return f"walk_{kind}"


def parse_walk(text: str | None) -> tuple[str, ...]:
    """``--walk``'s kinds: ``tour``, ``video`` or both (``tour,video``); one-line error otherwise."""
    if text is None:
        return ()
    kinds = [k.strip() for k in str(text).split(",")]
    bad = [k for k in kinds if k not in WALK_KINDS]
    if bad or not kinds or len(set(kinds)) != len(kinds):
        raise InputError(f"--walk must be tour, video or tour,video, got {text!r}")
    return tuple(k for k in WALK_KINDS if k in kinds)


def _door_value(doors: str, option: str, building: bool, why: str) -> str:
    """``doors`` checked as ``option``'s value: closed or open, open only in a building (``why`` says why)."""
    if doors not in DOORS:
        raise InputError(f"{option} must be closed or open, got {doors!r}")
    if doors == "open" and not building:
        raise InputError(f"{option} open needs a building preset: {why}")
    return doors


def check_doors(doors: str | None, building: bool) -> str:
    """``--doors``: closed (the default) or open, only with a building preset; one-line error otherwise."""
    return "closed" if doors is None else _door_value(doors, "--doors", building,
                                                      "no other preset has doors between its rooms")


def check_walk_doors(doors: str | None, kinds: tuple[str, ...], building: bool, default: str = "closed") -> str:
    """``--walk-doors``: closed or open (default ``default``: as the scans see them), only with ``--walk``
    and a building (the only preset whose walk goes through doors); one-line error otherwise."""
    if doors is None:
        return default
    if doors in DOORS and not kinds:
        raise InputError("--walk-doors goes with --walk")
    return _door_value(doors, "--walk-doors", building, "no other walk goes through a door")


def check_walk_step(step: float | None, kinds: tuple[str, ...]) -> None:
    """``--walk-step`` in :data:`STEP_LIMITS` metres, and only with ``--walk``."""
    if step is not None and not kinds:
        raise InputError("--walk-step goes with --walk")
    check_range(step, "--walk-step", *STEP_LIMITS)


def _blur(prev: WalkPose | None, pose: WalkPose, width: int) -> float:
    """A video frame's motion blur (px): 2 px at 1024 wide, plus 1.5 px per degree turned since the
    previous frame, at most 8 px (the extreme split's)."""
    turn = 0.0 if prev is None or pose.jump else rotation_error_deg(prev.R, pose.R)
    return float(np.clip(2.0 + 1.5 * turn, 2.0, 8.0)) * width / 1024.0


def _frames(poses: list[WalkPose], stems: list[str], kind: str, cap: CaptureSettings, built: BuiltRooms,
            spaces: list[list[WalkRoom]], doors_open: bool, rng: np.random.Generator, tmp: Path,
            tick: Callable[[str], None]) -> Iterator[np.ndarray]:
    """Render and write each frame of a walk (photo and pose file); yields the photos in order.
    ``doors_open``: the doors of the walk's ``spaces`` stand open (the next room is seen through them)."""
    split = walk_split(kind)
    space_of = {id(r): space for space in spaces for r in space}
    for k, (pose, stem) in enumerate(zip(poses, stems)):
        room = pose.room
        blur = _blur(poses[k - 1] if k else None, pose, cap.width) if kind == "video" else 0.0
        parts = built.seen_from(room, space_of.get(id(room), [room]), doors_open)
        pano = render_through(parts, pose.R, pose.t, cap.width, cap.height, supersample=cap.supersample,
                              blur_px=blur, blur_angle=float(rng.normal(0.0, 0.1)), noise_sigma=cap.noise_sigma,
                              rng=rng)
        folder = f"{split}_{room.scene}_scene_1"
        write_jpeg(tmp / f"{split}_pano" / folder / f"{stem}.jpg", pano.rgb)
        write_pose(tmp / f"{split}_pose" / folder / f"{stem}.txt", pose.R, pose.t)
        tick(f"{split} {k + 1}/{len(poses)}")
        yield pano.rgb


def _frame_record(pose: WalkPose, prev: WalkPose | None, stem: str, time: float | None) -> dict:
    r = pose.room
    return {"stem": stem, "scene": r.scene, "floor": r.floor, "room": r.id or None, "kind": r.kind,
            "time": None if time is None else round(time, 6),
            "step_m": None if prev is None else round(float(np.linalg.norm(pose.t - prev.t)), 4),
            "jump": pose.jump}


def write_walks(tmp: Path, spaces: list[list[WalkRoom]], kinds: tuple[str, ...], seed: int, cap: CaptureSettings,
                split_counts: dict[str, int], tick: Callable[[str], None], step: float | None = None,
                visits: int = VISITS_PER_FLOOR, doors: str = "closed", built: BuiltRooms | None = None) -> dict:
    """Plan, render and write the walks ``kinds`` through ``spaces`` (in order; each a list of rooms
    joined by doors) into dataset folder ``tmp``; ``split_counts`` grows in place. ``doors``: closed
    or open (:data:`DOORS`); ``built``: the rooms built already (the scans'). Returns the ``walks`` entry
    of ``dataset.json``."""
    built = built or BuiltRooms()
    out = {}
    for kind in kinds:
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, _STREAM, WALK_KINDS.index(kind)])
        st = float(step or WALK_STEP_M[kind])
        poses = plan_walk(spaces, st, rng, built, smooth=kind == "video", visits=visits,
                          doorways=kind == "video" and doors == "open")  # a video walks on through an open door
        digits = max(4, len(str(len(poses) - 1)))
        stems = [f"{k:0{digits}d}" for k in range(len(poses))]
        fps = WALKING_SPEED / st if kind == "video" else None
        frames = _frames(poses, stems, kind, cap, built, spaces, doors == "open", rng, tmp, tick)
        video = None
        if kind == "video":
            video = f"{VIDEO_FOLDER}/{walk_split(kind)}.mp4"
            (tmp / VIDEO_FOLDER).mkdir(exist_ok=True)
            write_video(tmp / video, frames, fps)
        else:
            for _ in frames:
                pass
        split_counts[walk_split(kind)] = len(poses)
        out[walk_split(kind)] = {
            "kind": kind, "doors": doors,
            "step_m": st, "step_range_m": [round(st * STEP_RANGE[0], 6), round(st * STEP_RANGE[1], 6)], "fps": fps,
            "video": video, "width": cap.width, "height": cap.height,
            "frames": [_frame_record(p, poses[k - 1] if k else None, s, None if fps is None else k / fps)
                       for k, (p, s) in enumerate(zip(poses, stems))]}
    return out
