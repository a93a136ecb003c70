"""Camera poses for the synthetic query splits (OmniScenes-like capture styles).

A pose is ``(R, t)`` in the convention of :mod:`ldlmap.core.geometry`: ``R`` rotates world into
camera (``p_cam = R (X - t)``), ``t`` is the camera centre. "Upright" means the camera's +z axis
(the top row of the panorama) is the world +z, i.e. ``R = I`` up to a yaw about z.

Centres are drawn uniformly inside the room footprint, rejected when closer than a clearance to
any surface (open3d ``compute_distance``) or when above / inside an object's box footprint.
Rotations per split (:data:`SPLIT_POSES`):

* ``robot``: height about 1.0 m, up axis tilted at most 2 degrees (so roll, pitch <= 2), any yaw;
* ``handheld``: height about 1.5 m, tilted at most 10 degrees, any yaw;
* ``extreme``: height 0.8-1.8 m, rotation uniform on SO(3) (the split also gets motion blur);
* ``change_robot`` / ``change_handheld``: as robot / handheld (rendered in the changed scene).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import rotation_from_axis_angle
from ldlmap.core.lazy import lazy_module
from ldlmap.core.polygon import points_in_polygon
from ldlmap.synth.render import Renderer
from ldlmap.synth.types import SceneMesh

spatial = lazy_module("scipy.spatial")

SPLITS = ("robot", "handheld", "extreme", "change_robot", "change_handheld")


@dataclass(frozen=True)
class PoseParams:
    """How one split places and orients its cameras."""

    height_min: float  # metres above the floor (camera centre)
    height_max: float
    max_tilt_deg: float  # bound on the tilt of the camera's up axis; ignored when any_rotation
    any_rotation: bool = False  # uniform on SO(3)
    clearance: float = 0.3  # metres from any surface
    object_margin: float = 0.15  # metres around an object's box footprint that stay free


SPLIT_POSES: dict[str, PoseParams] = {
    "robot": PoseParams(0.95, 1.05, 2.0),
    "handheld": PoseParams(1.35, 1.65, 10.0),
    "extreme": PoseParams(0.8, 1.8, 180.0, any_rotation=True),
}


def split_pose_params(split: str, capture: Any = None) -> PoseParams:
    """Pose parameters of ``split`` (``change_*`` share their base split).

    ``capture`` (a :class:`~ldlmap.synth.spec.CaptureSpec`) overrides the defaults: its view of
    the base split gives ``camera_height +- height_jitter`` and ``max_tilt_deg`` (180 = any
    rotation), and ``min_clearance`` the clearance.
    """
    base = split.removeprefix("change_")
    if base not in SPLIT_POSES:
        raise InputError(f"unknown split {split!r}; valid: {', '.join(SPLITS)}")
    p = SPLIT_POSES[base]
    if capture is None:
        return p
    view = getattr(capture, base, None)
    if view is not None:
        h, jitter, tilt = float(view.camera_height), float(view.height_jitter), float(view.max_tilt_deg)
        p = replace(p, height_min=h - jitter, height_max=h + jitter, max_tilt_deg=min(tilt, 180.0),
                    any_rotation=tilt >= 180.0)
    clearance = getattr(capture, "min_clearance", None)
    if clearance is not None:
        p = replace(p, clearance=float(clearance))
    if not (p.height_min > 0 and p.height_max >= p.height_min and p.clearance >= 0 and p.max_tilt_deg >= 0):
        raise InputError(f"invalid pose parameters for split {split!r}: {p}")
    return p


def object_hulls(mesh: SceneMesh) -> list[np.ndarray]:
    """Half-plane equations (E, 3) of the xy convex hull of each object box."""
    hulls = []
    for box in mesh.object_boxes:
        xy = np.asarray(box, dtype=np.float64).reshape(-1, 3)[:, :2]
        try:
            hulls.append(spatial.ConvexHull(xy).equations)
        except Exception:  # degenerate (flat) box footprint: ignore, the distance test remains
            continue
    return hulls


def clear_of_objects(xy: np.ndarray, hulls: list[np.ndarray], margin: float) -> np.ndarray:
    """Whether points (N, 2) stand more than ``margin`` metres outside every object hull (:func:`object_hulls`)."""
    ok = np.ones(len(xy), dtype=bool)
    for eq in hulls:
        ok &= ~np.all(xy @ eq[:, :2].T + eq[:, 2] <= margin, axis=1)
    return ok


def sample_positions(mesh: SceneMesh, n: int, rng: np.random.Generator, height_min: float,
                     height_max: float, clearance: float, object_margin: float = 0.15,
                     renderer: Renderer | None = None, max_batches: int = 200) -> np.ndarray:
    """``n`` free positions (n, 3) inside the footprint, ``clearance`` from every surface."""
    renderer = renderer or Renderer(mesh)
    fp = np.asarray(mesh.footprint, dtype=np.float64)
    lo, hi = fp.min(axis=0), fp.max(axis=0)
    z_hi = min(height_max, float(mesh.ceiling_height) - clearance)
    z_lo = min(height_min, z_hi)
    hulls = object_hulls(mesh)
    out: list[np.ndarray] = []
    count = 0
    for _ in range(max_batches):
        cand = np.column_stack([rng.uniform(lo[0], hi[0], 256), rng.uniform(lo[1], hi[1], 256),
                                rng.uniform(z_lo, z_hi, 256)])
        ok = points_in_polygon(cand[:, :2], fp) & clear_of_objects(cand[:, :2], hulls, object_margin)
        if np.any(ok):
            ok[ok] = renderer.distance(cand[ok]) >= clearance
        good = cand[ok]
        out.append(good)
        count += len(good)
        if count >= n:
            break
    pts = np.concatenate(out)[:n] if out else np.zeros((0, 3))
    if len(pts) < n:
        raise InputError(f"cannot place {n} cameras in room {mesh.name!r} with {clearance} m clearance "
                         f"(found {len(pts)}): the room is too small or too cluttered")
    return pts


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix uniform on SO(3) (normalised Gaussian quaternion)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def tilted_rotation(rng: np.random.Generator, max_tilt_deg: float) -> np.ndarray:
    """World->camera rotation with any yaw whose up axis (camera +z) is tilted from world +z by
    at most ``max_tilt_deg`` (tilt direction uniform, uniform over the spherical cap)."""
    yaw = rng.uniform(0.0, 2.0 * np.pi)
    cos_tilt = rng.uniform(np.cos(np.radians(max_tilt_deg)), 1.0)
    azimuth = rng.uniform(0.0, 2.0 * np.pi)
    tilt = rotation_from_axis_angle(np.array([np.cos(azimuth), np.sin(azimuth), 0.0]), float(np.arccos(cos_tilt)))
    world_from_cam = _rot_z(yaw) @ tilt
    return world_from_cam.T


def sample_poses(mesh: SceneMesh, split: str, n: int, rng: np.random.Generator, capture: Any = None,
                 renderer: Renderer | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` poses ``(R, t)`` (R world->camera, t the centre) for ``split`` in ``mesh``."""
    p = split_pose_params(split, capture)
    centers = sample_positions(mesh, n, rng, p.height_min, p.height_max, p.clearance, p.object_margin,
                               renderer=renderer)
    poses = []
    for c in centers:
        R = random_rotation(rng) if p.any_rotation else tilted_rotation(rng, p.max_tilt_deg)
        poses.append((R, c.copy()))
    return poses
