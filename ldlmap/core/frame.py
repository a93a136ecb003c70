"""The map frame and the input frame (SfM frames are neither z-up nor metric: docs/inputs.md).

A map is metric and z-up. ``ldlmap build`` maps its input (cloud, lines, camera centres) once into
that frame by a similarity ``X_map = s R X_input + t``, stored in the map as the 4x4 matrix
``input_to_map`` (``s``: ``--scale``; ``R``: turns the input's up axis to +z, see
:mod:`ldlmap.sfm.gravity`; ``t``: 0, or the shift that recentres a scan far from the origin, e.g. in
UTM coordinates, :func:`recentring_offset`). Poses found in the map frame are given back in the input frame
with :func:`pose_to_input`; ground-truth poses of the input frame go the other way with
:func:`pose_to_map`. Poses follow docs/formats.md: ``p_cam = R (X - t)``, ``t`` the camera centre.
"""

from __future__ import annotations

import os

import numpy as np

from ldlmap.core.errors import InputError

AXES: dict[str, tuple[float, float, float]] = {
    "x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "-x": (-1, 0, 0), "-y": (0, -1, 0), "-z": (0, 0, -1)}
UP_CHOICES = ("auto", *AXES)


def parse_up(text: str | None) -> np.ndarray | None:
    """The input-frame up axis of ``--up`` (x, y, z, -x, -y, -z) as a unit vector; None for auto."""
    if text is None or str(text).strip().lower() == "auto":
        return None
    key = str(text).strip().lower().replace("+", "")
    if key not in AXES:
        raise InputError(f"--up must be one of {', '.join(UP_CHOICES)}, got {text!r}")
    return np.array(AXES[key], dtype=np.float64)


def similarity(scale: float = 1.0, rotation: np.ndarray | None = None, translation: np.ndarray | None = None) -> np.ndarray:
    """4x4 matrix of ``X -> scale * rotation @ X + translation``."""
    A = np.eye(4)
    A[:3, :3] = float(scale) * (np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64))
    if translation is not None:
        A[:3, 3] = np.asarray(translation, dtype=np.float64)
    return A


def decompose(A: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(scale, rotation, translation)`` of a similarity; InputError when ``A`` is not one."""
    A = np.asarray(A, dtype=np.float64)
    if A.shape != (4, 4) or not np.all(np.isfinite(A)) or not np.allclose(A[3], [0, 0, 0, 1]):
        raise InputError(f"input_to_map must be a finite 4x4 similarity, got shape {A.shape}")
    M = A[:3, :3]
    s = float(np.cbrt(np.linalg.det(M)))
    if not s > 0 or not np.allclose((M / s) @ (M / s).T, np.eye(3), atol=1e-6):
        raise InputError("input_to_map is not a similarity (scale times a proper rotation)")
    return s, M / s, A[:3, 3].copy()


def is_identity(A: np.ndarray | None, tol: float = 1e-9) -> bool:
    """True for None or the identity transform."""
    return A is None or bool(np.allclose(np.asarray(A, dtype=np.float64), np.eye(4), atol=tol))


def apply(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Points ``X`` (..., 3) mapped by the 4x4 transform ``A``."""
    A = np.asarray(A, dtype=np.float64)
    return np.asarray(X, dtype=np.float64) @ A[:3, :3].T + A[:3, 3]


def invert(A: np.ndarray) -> np.ndarray:
    """Inverse of a similarity."""
    s, R, t = decompose(A)
    return similarity(1.0 / s, R.T, -(R.T @ t) / s)


def pose_to_input(rot_cam_from_map: np.ndarray, center_map: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A map-frame pose ``(R, t)`` in the input frame of ``A`` (``input_to_map``).

    With ``X_map = s R_a X_in + t_a``: ``p_cam = R (X_map - t) = s R R_a (X_in - A^-1 t)``, a camera
    with rotation ``R R_a`` at ``A^-1 t`` (the scale only scales depths).
    """
    _, Ra, _ = decompose(A)
    return np.asarray(rot_cam_from_map, dtype=np.float64) @ Ra, apply(invert(A), center_map)


def pose_to_map(rot_cam_from_input: np.ndarray, center_input: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pose_to_input`: an input-frame pose in the map frame."""
    _, Ra, _ = decompose(A)
    return np.asarray(rot_cam_from_input, dtype=np.float64) @ Ra.T, apply(A, center_input)


def rotation_to_z(up: np.ndarray, horizontal: np.ndarray | None = None) -> np.ndarray:
    """A rotation taking the unit vector ``up`` to +z and, when given, ``horizontal`` (projected
    on the plane normal to ``up``) to +x; without it the smallest rotation doing the first."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    if horizontal is not None:
        h = np.asarray(horizontal, dtype=np.float64)
        h = h - (h @ u) * u
        if np.linalg.norm(h) > 1e-6:
            h = h / np.linalg.norm(h)
            return np.stack([h, np.cross(u, h), u])  # rows: the input's directions of map x, y, z
    c = float(u[2])
    if c < -1 + 1e-12:  # upside down: half a turn about x
        return np.diag([1.0, -1.0, -1.0])
    v = np.array([u[1], -u[0], 0.0])  # u x z
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


RECENTRE_BEYOND = 1000.0  # metres: farther from the origin, float32 map storage loses millimetres
# Metres: no coordinate of a map lies farther from its origin. A build recentres inputs farther than
# RECENTRE_BEYOND and refuses extents over MAX_EXTENT, so its maps stay within a few km; at 1e6 m
# float32 coordinates are 6 cm apart, coarser than the 5 cm accuracy threshold (a damaged map).
MAX_MAP_COORDINATE = 1e6
# Metres (or input units): no ground-truth pose lies farther from its frame's origin. Input frames may
# be geographic (UTM northings reach 1e7 m); beyond 1e8 m nothing on Earth is (a corrupt pose).
MAX_POSE_COORDINATE = 1e8
MAX_EXTENT = 1000.0  # units: a scan whose robust extent (mean side) is larger is refused (millimetres?)


def recentring_offset(points: np.ndarray) -> np.ndarray | None:
    """The origin (3,) that the map frame moves to, or None when the points are near enough the
    origin. Maps store float32 coordinates (spacing 0.5 m at 4e6 m, UTM northings): a scan farther
    than :data:`RECENTRE_BEYOND` from the origin is recentred on its median, rounded to whole
    metres; ``input_to_map`` records the shift, so poses are still reported in the input frame."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(P) == 0 or np.abs(P).max() <= RECENTRE_BEYOND:
        return None
    centre = np.round(np.median(P, axis=0))
    return centre if np.abs(centre).max() > 0 else None


def check_extent(extent_sides: np.ndarray) -> None:
    """Refuse (one line) a scan whose robust extent looks like another unit than metres: every
    grid of the build (voxels, plane images, translation lattices) is sized in metres."""
    sides = np.asarray(extent_sides, dtype=np.float64)
    mean = float(np.mean(sides))
    if not np.isfinite(mean) or mean > MAX_EXTENT:
        dims = " x ".join(f"{x:.0f}" for x in sides)
        hint = "0.001 (millimetres)" if mean < 1e5 else "S (metres per input unit)"
        raise InputError(f"the input spans {dims} units (robust extent): far too large for metres (millimetres?). "
                         f"A map must be in metres: pass --scale {hint}")


def check_memory(what: str, nbytes: float, hint: str) -> None:
    """Refuse (one line, with the estimate) to allocate ``nbytes`` for ``what`` when that exceeds
    half of this machine's available memory; called before grids sized by the input are built."""
    try:
        available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        available = 8 << 30
    if not nbytes <= 0.5 * available:
        raise InputError(f"{what} would need about {nbytes / 2**30:.3g} GiB, more than half of the "
                         f"{available / 2**30:.1f} GiB available: {hint}")


def scale_warning(extent: float) -> str | None:
    """One line when a map's robust extent (mean of its three sides) suggests the wrong unit."""
    if extent > 200.0:
        return (f"the map spans {extent:.0f} units (robust extent): millimetres? A map must be in metres: "
                f"pass --scale 0.001 (or the right metres per unit)")
    if extent < 0.5:
        return (f"the map spans only {extent:.3g} units (robust extent): an unscaled SfM frame? A map must be in "
                f"metres: pass --scale S (metres per unit)")
    return None
