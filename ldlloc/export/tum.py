"""A walk's trajectory as TUM text: one line per pose, ``timestamp tx ty tz qx qy qz qw``.

The pose is the camera's in the world (camera to world: ``t`` the camera centre, ``q`` the unit
quaternion of ``R^T``, our camera frame); ``timestamp``: the frame's time in seconds (a video's
timestamp, a photo's capture time), else its index in the walk, else its rank in name order.
Lines are in walk order (frame index, then name), after a ``#`` header naming the convention.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.errors import InputError


def quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    """The unit quaternion ``(x, y, z, w)`` of rotation matrix ``R`` (w >= 0)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i], q[j], q[k] = s / 4, (R[j, i] + R[i, j]) / s, (R[k, i] + R[i, k]) / s
    q = np.asarray(q) / np.linalg.norm(q)
    return -q if q[3] < 0 else q


def walk_key(pose) -> tuple:
    """A pose's place in its walk: its frame index (records of ``--walk`` runs), then its name."""
    walk = pose.record.get("walk") or {}
    return (0, int(walk["frame"])) if isinstance(walk.get("frame"), int) else (1, 0), pose.name


def check_one_walk(poses: list, results) -> None:
    """One-line error when ``poses`` come from several walks (a dataset run's, one per scene): a TUM
    file is one trajectory, and walks interleaved by frame index are none."""
    walks = sorted({str((p.record.get("walk") or {}).get("name")) for p in poses if p.record.get("walk")})
    if len(walks) > 1:
        shown = ", ".join(walks[:4]) + (f" and {len(walks) - 4} more" if len(walks) > 4 else "")
        raise InputError(f"{results} holds {len(walks)} walks ({shown}): a TUM file is one trajectory; "
                         "export one walk's scene with --scene NAME")


def tum_text(poses: list, frame: str = "map") -> str:
    """The TUM file of ``poses`` (:class:`ldlloc.export.poses.ExportPose`), in walk order."""
    lines = [f"# ldlloc trajectory ({frame} frame): timestamp tx ty tz qx qy qz qw; camera to world, "
             "t the camera centre; timestamp: the frame's time (s), else its index in the walk"]
    for rank, p in enumerate(sorted(poses, key=walk_key)):
        walk = p.record.get("walk") or {}
        stamp = walk.get("time")
        if stamp is None:
            stamp = walk.get("frame", rank)
        t = np.asarray(p.center, float)
        q = quaternion_xyzw(np.asarray(p.rot_cam_from_world, float).T)
        lines.append(" ".join(f"{v:.6f}" for v in (float(stamp), *t, *q)))
    return "\n".join(lines) + "\n"
