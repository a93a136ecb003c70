"""Ground-truth pose files: OmniScenes ``3x4 [R | t]`` text and Stanford 2D-3D-S JSON, validated on
read (shape, finite values, proper rotation).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.frame import MAX_POSE_COORDINATE
from ldlmap.core.lazy import lazy_module

transform = lazy_module("scipy.spatial.transform")


ROTATION_TOLERANCE = 1e-3  # max |R^T R - I| entry accepted in ground-truth poses (text precision)
_STANFORD_FLIP = np.diag([-1.0, -1.0, 1.0])
def _check_pose(R: np.ndarray, t: np.ndarray, source: Path) -> None:
    """A ground-truth pose: finite, on Earth, its rotation proper (one-line errors naming ``source``)."""
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise InputError(f"pose has non-finite values: {source}")
    if np.abs(t).max() > MAX_POSE_COORDINATE:
        raise InputError(f"pose translation {np.abs(t).max():.3g} is beyond {MAX_POSE_COORDINATE:.0e} from the "
                         f"origin (no place on Earth is): {source}")
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
        raise InputError(f"pose rotation is not a proper rotation (|R^T R - I| = {err:.2g}, "
                         f"det = {np.linalg.det(R):.3g}): {source}")


MAX_POSE_BYTES = 1 << 20  # a pose file is a few hundred bytes; a larger one is not a pose file


def _read_pose_text(p: Path) -> str:
    """The text of pose file ``p``; one-line errors for a missing, unreadable, binary or huge file."""
    try:
        if p.is_dir():
            raise InputError(f"pose file is a folder: {p}")
        if p.stat().st_size > MAX_POSE_BYTES:
            raise InputError(f"not a pose file ({p.stat().st_size} bytes; a pose file is a few hundred): {p}")
        return p.read_text()
    except FileNotFoundError:
        raise InputError(f"pose file not found: {p}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read pose file {p}: {getattr(exc, 'strerror', None) or exc}") from None


def read_pose_txt(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an OmniScenes pose file: a 3x4 ``[R | t]`` (a 4x4 with last row 0 0 0 1 is accepted).

    Returns ``(R, t)`` exactly as stored (R world->camera, t camera centre).
    """
    p = Path(path)
    text = _read_pose_text(p)
    rows = [line.replace(",", " ").split() for line in text.splitlines()]
    rows = [r for r in rows if r and not r[0].startswith("#")]
    try:
        M = np.array([[float(x) for x in r] for r in rows], dtype=np.float64)
    except ValueError:
        raise InputError(f"malformed pose file (expected a 3x4 matrix of numbers): {p}") from None
    if M.shape == (4, 4) and np.allclose(M[3], [0, 0, 0, 1]):
        M = M[:3]
    if M.shape != (3, 4):
        got = "x".join(map(str, M.shape)) if M.ndim == 2 else "empty" if M.size == 0 else "ragged"
        raise InputError(f"malformed pose file (expected a 3x4 [R | t] matrix, got {got}): {p}")
    R, t = M[:, :3].copy(), M[:, 3].copy()
    _check_pose(R, t, p)
    return R, t


def write_pose_txt(path: str | Path, rot_cam_from_world: np.ndarray, center: np.ndarray) -> None:
    """Write a pose in the OmniScenes 3x4 ``[R | t]`` text format (full float precision)."""
    M = np.concatenate([np.asarray(rot_cam_from_world, float), np.asarray(center, float).reshape(3, 1)], 1)
    Path(path).write_text("\n".join(" ".join(repr(float(x)) for x in row) for row in M) + "\n")


def stanford_rotation(final_camera_rotation: Sequence[float]) -> np.ndarray:
    """World->camera rotation from a Stanford 2D-3D-S ``final_camera_rotation`` (Euler 'xyz').

    ``M = Rotation.from_euler('xyz', angles)`` is the Blender camera-to-world rotation (camera
    looks along its -Z, +Y up, +X right). Columns reordered to ``[M[:,2], M[:,0], M[:,1]]``,
    inverted, then left-multiplied by ``diag(-1, -1, 1)`` give our frame: +x forward (image
    centre), +y left, +z up.
    """
    M = transform.Rotation.from_euler("xyz", np.asarray(final_camera_rotation, dtype=np.float64)).as_matrix()
    return _STANFORD_FLIP @ M[:, [2, 0, 1]].T  # inverse of a rotation = transpose


def read_stanford_pose(path: str | Path, alignment: str | Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read a Stanford 2D-3D-S ``*_pose.json`` as ``(R, t)`` in our convention.

    ``alignment``: optional 3x4 ``[A | b]`` text file mapping the pose's world frame to the point
    cloud's (``X_cloud = A (X - b)``), as used by some re-distributions of area 5; then
    ``R' = R A^T`` and ``t' = A (t - b)``.
    """
    p = Path(path)
    try:
        data = json.loads(_read_pose_text(p))
    except (json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"cannot read pose JSON {p}: {exc if isinstance(exc, ValueError) else 'nested too deeply'}") from None
    if not isinstance(data, dict):
        raise InputError(f"pose JSON must be an object with camera_location and final_camera_rotation: {p}")
    try:
        t = np.asarray(data["camera_location"], dtype=np.float64)
        angles = np.asarray(data["final_camera_rotation"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"pose JSON lacks a numeric camera_location / final_camera_rotation ({exc}): {p}") from None
    if t.shape != (3,) or angles.shape != (3,):
        raise InputError(f"pose JSON camera_location and final_camera_rotation must have 3 values each: {p}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(angles))):
        raise InputError(f"pose has non-finite values: {p}")
    R = stanford_rotation(angles)
    if alignment is not None:
        A_b = read_pose_txt(alignment)  # same 3x4 layout and validation
        A, b = A_b
        R, t = R @ A.T, A @ (t - b)
    _check_pose(R, t, p)
    return R, t


def read_pose_file(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A query's known pose ``(R, t)`` from the file format its dataset stores it in: an
    OmniScenes 3x4 ``[R | t]`` ``.txt`` (:func:`read_pose_txt`) or a Stanford 2D-3D-S
    ``*_pose.json`` (:func:`read_stanford_pose`)."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        return read_stanford_pose(p)
    if p.suffix.lower() == ".txt":
        return read_pose_txt(p)
    raise InputError(f"unsupported pose file {p}: use a 3x4 [R | t] .txt (OmniScenes) or a *_pose.json "
                     "(Stanford 2D-3D-S)")
