"""Geometric conventions shared by ``ldlmap`` and ``ldlloc``.

World frame: metric, z up. A pose is ``(R, t)`` where ``R`` (``rot_cam_from_world``) rotates
world into camera and ``t`` is the camera centre in world coordinates::

    p_cam = R (X - t)

Equirectangular image of width ``W`` and height ``H`` (``W = 2 H``). A camera-frame direction
``p = (x, y, z)`` maps to continuous image coordinates::

    u / W = 1 - (atan2(y, x) + pi) / (2 pi)
    v / H = atan2(sqrt(x^2 + y^2), z) / pi

so the top row looks along +z and the image centre looks along +x. ``u, v`` are continuous
coordinates whose integer grid lines are pixel *corners*: the pixel with column index ``c`` and
row index ``r`` covers ``[c, c + 1) x [r, r + 1)`` and its centre is ``(c + 0.5, r + 0.5)``.
:func:`pixel_centers` gives the centres of a whole image.

All functions accept numpy arrays with any leading batch shape.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

# Rotation from our camera frame (forward +x, left +y, up +z) to COLMAP's camera frame for the
# EQUIRECTANGULAR model (forward +z, right +x, down +y): p_colmap = COLMAP_FROM_OURS @ p_ours.
COLMAP_FROM_OURS = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def normalize(v: np.ndarray, axis: int = -1, eps: float = 1e-12) -> np.ndarray:
    """Unit vectors along ``axis`` (zero vectors stay zero)."""
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return v / np.maximum(n, eps)


# ----------------------------------------------------------------------------- sphere <-> image


def bearing_from_pixel(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Unit camera-frame bearings (..., 3) for continuous image coordinates ``uv`` (..., 2)."""
    uv = np.asarray(uv, dtype=np.float64)
    phi = np.pi - 2.0 * np.pi * uv[..., 0] / width  # atan2(y, x)
    theta = np.pi * uv[..., 1] / height  # angle from +z
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def pixel_from_bearing(p: np.ndarray, width: int, height: int) -> np.ndarray:
    """Continuous image coordinates (..., 2) of camera-frame directions ``p`` (..., 3).

    ``u`` lies in ``(0, W]``; the direction exactly behind the camera (atan2 = pi) maps to
    ``u = 0``. Wrap with ``np.mod(u, W)`` where a pixel index is needed.
    """
    p = np.asarray(p, dtype=np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    u = width * (1.0 - (np.arctan2(y, x) + np.pi) / (2.0 * np.pi))
    v = height * np.arctan2(np.hypot(x, y), z) / np.pi
    return np.stack([u, v], axis=-1)


def pixel_centers(width: int, height: int) -> np.ndarray:
    """Continuous coordinates of all pixel centres, shape (H, W, 2) with ``[..., 0] = u``."""
    u = np.arange(width, dtype=np.float64) + 0.5
    v = np.arange(height, dtype=np.float64) + 0.5
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv], axis=-1)


def pixel_index_from_bearing(p: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer (row, col) of the pixel that contains each direction (wrapped, clipped)."""
    uv = pixel_from_bearing(p, width, height)
    col = np.mod(np.floor(uv[..., 0]).astype(np.int64), width)
    row = np.clip(np.floor(uv[..., 1]).astype(np.int64), 0, height - 1)
    return row, col


# ------------------------------------------------------------------------------- world <-> camera


def cam_from_world(points_world: np.ndarray, rot_cam_from_world: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Camera-frame coordinates ``R (X - t)`` of world points (..., 3)."""
    X = np.asarray(points_world, dtype=np.float64)
    return (X - np.asarray(center, dtype=np.float64)) @ np.asarray(rot_cam_from_world).T


def world_from_cam(points_cam: np.ndarray, rot_cam_from_world: np.ndarray, center: np.ndarray) -> np.ndarray:
    """World coordinates ``R^T p + t`` of camera-frame points (..., 3)."""
    p = np.asarray(points_cam, dtype=np.float64)
    return p @ np.asarray(rot_cam_from_world) + np.asarray(center, dtype=np.float64)


def project_to_pixels(points_world: np.ndarray, rot_cam_from_world: np.ndarray, center: np.ndarray,
                      width: int, height: int) -> np.ndarray:
    """Continuous image coordinates (..., 2) of world points seen from pose ``(R, t)``."""
    return pixel_from_bearing(cam_from_world(points_world, rot_cam_from_world, center), width, height)


# --------------------------------------------------------------------------------------- errors


def translation_error(t_est: np.ndarray, t_true: np.ndarray) -> float:
    """Euclidean distance between two camera centres, in metres."""
    return float(np.linalg.norm(np.asarray(t_est, float) - np.asarray(t_true, float)))


def angle_from_trace_deg(trace: np.ndarray | float) -> np.ndarray:
    """Angle in degrees of rotations with these traces: ``arccos((trace - 1) / 2)`` (the one formula of
    a rotation's angle; ``trace(A^T B) = sum(A * B)`` gives the angle between two rotations)."""
    c = (np.asarray(trace, dtype=np.float64) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def rotation_error_deg(r_est: np.ndarray, r_true: np.ndarray) -> float:
    """Angle of ``R_est^T R_true`` in degrees (:func:`angle_from_trace_deg`)."""
    return float(angle_from_trace_deg(np.trace(np.asarray(r_est, float).T @ np.asarray(r_true, float))))


# ------------------------------------------------------------------------------------ rotations


def rotation_from_axis_angle(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix (Rodrigues) for a rotation of ``angle_rad`` about ``axis``."""
    k = normalize(np.asarray(axis, dtype=np.float64))
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def is_rotation(R: np.ndarray, atol: float = 1e-6) -> bool:
    """True when ``R`` is a proper 3x3 rotation matrix."""
    R = np.asarray(R, dtype=np.float64)
    return R.shape == (3, 3) and np.allclose(R.T @ R, np.eye(3), atol=atol) and np.linalg.det(R) > 0


# ------------------------------------------------------------------------------------ icosphere


@lru_cache(maxsize=8)
def _icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    t = (1.0 + 5.0 ** 0.5) / 2.0
    verts = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
             [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    faces = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
             [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
             [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    V = normalize(np.array(verts, dtype=np.float64))
    F = np.array(faces, dtype=np.int64)
    for _ in range(level):
        # Midpoints of every edge, shared between the two faces that use the edge.
        edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        edges.sort(axis=1)
        uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
        mids = normalize(V[uniq[:, 0]] + V[uniq[:, 1]])
        mid_idx = len(V) + inverse.reshape(3, -1).T  # (F, 3): mid of edge 01, 12, 20
        V = np.concatenate([V, mids])
        a, b, c = F[:, 0], F[:, 1], F[:, 2]
        ab, bc, ca = mid_idx[:, 0], mid_idx[:, 1], mid_idx[:, 2]
        F = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1),
                            np.stack([c, ca, bc], 1), np.stack([ab, bc, ca], 1)])
    V.setflags(write=False)
    F.setflags(write=False)
    return V, F


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) on the unit sphere and faces (M, 3) of an icosphere.

    ``level`` 0..5 gives 12, 42, 162, 642, 2562, 10242 vertices (``10 * 4**level + 2``).
    The returned arrays are read-only and cached.
    """
    if not 0 <= int(level) <= 7:
        raise ValueError(f"icosphere level must be in 0..7, got {level}")
    return _icosphere(int(level))


def icosphere_points(level: int) -> np.ndarray:
    """The vertices of :func:`icosphere` (unit vectors, read-only)."""
    return icosphere(level)[0]


def half_icosphere_points(level: int) -> np.ndarray:
    """Icosphere vertices with antipodal duplicates removed (one of each ``+d``/``-d`` pair)."""
    V = icosphere_points(level)
    # Keep the representative whose first non-zero coordinate is positive.
    key = np.where(np.abs(V[:, 2]) > 1e-9, V[:, 2],
                   np.where(np.abs(V[:, 1]) > 1e-9, V[:, 1], V[:, 0]))
    return V[key > 0]


# --------------------------------------------------------------------------------------- COLMAP


def colmap_cam_from_world(rot_cam_from_world: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Our pose ``(R, t)`` as COLMAP's ``cam_from_world`` rotation and translation.

    COLMAP maps ``p_colmap = R_c X + t_c``; with ``p_colmap = A R (X - t)`` (``A`` =
    :data:`COLMAP_FROM_OURS`) this is ``R_c = A R`` and ``t_c = -A R t``.
    """
    R_c = COLMAP_FROM_OURS @ np.asarray(rot_cam_from_world, dtype=np.float64)
    t_c = -R_c @ np.asarray(center, dtype=np.float64)
    return R_c, t_c


def pose_from_colmap(rot_colmap: np.ndarray, trans_colmap: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`colmap_cam_from_world`: our ``(R, t)`` from COLMAP ``cam_from_world``."""
    R_c = np.asarray(rot_colmap, dtype=np.float64)
    R = COLMAP_FROM_OURS.T @ R_c
    t = -R_c.T @ np.asarray(trans_colmap, dtype=np.float64)
    return R, t

