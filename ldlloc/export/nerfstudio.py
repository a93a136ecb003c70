"""Poses as a nerfstudio ``transforms.json`` with ``camera_model: "EQUIRECTANGULAR"``.

Intrinsics as nerfstudio's equirectangular camera reads them (``nerfstudio.cameras.cameras``: "for
equirect, fx = fy = height = width / 2"): ``w``, ``h``, ``fl_x = w / 2``, ``fl_y = h``, ``cx = w / 2``,
``cy = h / 2``; at the top level when every image has the same size, else in each frame. Each frame:
``file_path`` relative to the JSON's folder, and ``transform_matrix``, the 4x4 camera-to-world
matrix in nerfstudio's (OpenGL's) camera frame: x right, y up, z back (the camera looks along -z).

Conversion: our camera frame (docs/method.md) looks along +x with +y left and +z up, so a camera-frame
direction ``p`` is ``OPENGL_FROM_OURS @ p`` in OpenGL's frame (x = -y, y = z, z = -x). With our pose
``p_cam = R (X - c)``, camera-to-world is ``X = R^T OPENGL_FROM_OURS^T p_gl + c``: the matrix's
rotation block is ``(OPENGL_FROM_OURS R)^T`` and its last column ``c``. Nerfstudio's equirectangular
rays (pixel ``(x, y)``: ``theta = -pi (x - cx) / fx``, ``phi = pi (0.5 + (y - cy) / fy)``, direction
``(-sin theta sin phi, cos phi, -cos theta sin phi)``) then meet ours pixel for pixel: the image
centre looks forward, the top row up, x grows to the right. Our world is z up, like nerfstudio's.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

# Our camera frame (forward +x, left +y, up +z) to nerfstudio's OpenGL one (right +x, up +y, back +z):
# p_gl = OPENGL_FROM_OURS @ p_ours.
OPENGL_FROM_OURS = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


def camera_to_world_opengl(rot_cam_from_world: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Nerfstudio's 4x4 ``transform_matrix`` (camera to world, OpenGL camera frame) of our pose."""
    T = np.eye(4)
    T[:3, :3] = (OPENGL_FROM_OURS @ np.asarray(rot_cam_from_world, dtype=np.float64)).T
    T[:3, 3] = np.asarray(center, dtype=np.float64)
    return T


def pose_from_opengl(transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`camera_to_world_opengl`: our ``(R, t)`` from a ``transform_matrix``."""
    T = np.asarray(transform, dtype=np.float64)
    return OPENGL_FROM_OURS.T @ T[:3, :3].T, T[:3, 3].copy()


def intrinsics(width: int, height: int) -> dict[str, float | int]:
    """Nerfstudio's equirectangular intrinsics of a ``width`` x ``height`` panorama."""
    return {"w": int(width), "h": int(height), "fl_x": width / 2.0, "fl_y": float(height),
            "cx": width / 2.0, "cy": height / 2.0}


def transforms(poses: list, json_path: str | Path, sizes: list[tuple[int, int]], extra: dict | None = None) -> dict:
    """The ``transforms.json`` content of ``poses`` (:class:`ldlloc.export.poses.ExportPose`) with
    image sizes ``sizes``; file paths relative to ``json_path``'s folder. ``extra``: more top-level
    keys (nerfstudio ignores keys it does not know)."""
    folder = os.path.abspath(Path(json_path).parent)
    shared = len(set(sizes)) == 1
    frames = []
    for pose, size in zip(poses, sizes):
        frame = {"file_path": Path(os.path.relpath(os.path.abspath(pose.image), folder)).as_posix(),
                 "transform_matrix": camera_to_world_opengl(pose.rot_cam_from_world, pose.center).tolist()}
        if not shared:
            frame.update(intrinsics(*size))
        frame["ldl_name"] = pose.name  # the query's name in the results file (ignored by nerfstudio)
        walk = pose.record.get("walk") or {}
        if walk.get("time") is not None:  # a walk's frame: its time in seconds (a video's timestamp, a capture time)
            frame["time"] = float(walk["time"])
        frames.append(frame)
    out: dict = {"camera_model": "EQUIRECTANGULAR"}
    if shared and sizes:
        out.update(intrinsics(*sizes[0]))
    out["frames"] = frames
    out.update(extra or {})
    return out


def write_transforms(path: str | Path, content: dict) -> None:
    """Write ``content`` as JSON to ``path`` (a temporary file of :func:`ldlmap.core.errors.atomic_file`)."""
    Path(path).write_text(json.dumps(content, indent=1, allow_nan=False) + "\n")
