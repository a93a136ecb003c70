"""Poses as a COLMAP model (``cameras``, ``images``, ``points3D``, and pycolmap's ``rigs`` and
``frames``), written by pycolmap itself, that ``pycolmap.Reconstruction(folder)`` and COLMAP read.

Cameras: one ``EQUIRECTANGULAR`` camera (params ``[W, H]``) per image size. Images: one per query,
named by its path under the image root, its ``cam_from_world`` our pose turned into COLMAP's camera
frame (:func:`ldlmap.core.geometry.colmap_cam_from_world`: COLMAP's equirectangular camera looks
along +z with +x right and +y down, ours along +x with +y left and +z up, so ``R_colmap =
COLMAP_FROM_OURS R`` and ``t_colmap = -R_colmap c``), no 2D points. Points3D: both end points of
every kept 3D line of the maps (colour: the line's principal group), without tracks: the scene's
structure for COLMAP's viewer and a seed for splatting pipelines that start from points3D.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ldlmap.core.geometry import colmap_cam_from_world
from ldlmap.core.pictures import GROUP_COLORS_BGR


def line_points(lines: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both end points (2L, 3) of lines (L, 2, 3) and their RGB colours (2L, 3) by principal group."""
    segs = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    rgb = np.array([GROUP_COLORS_BGR.get(int(g), GROUP_COLORS_BGR[-1])[::-1] for g in groups],
                   dtype=np.uint8).reshape(-1, 3)
    return segs.reshape(-1, 3), np.repeat(rgb, 2, axis=0)


def build_reconstruction(poses: list, names: list[str], sizes: list[tuple[int, int]],
                         points: np.ndarray | None = None, colors: np.ndarray | None = None):
    """A ``pycolmap.Reconstruction`` of ``poses`` (:class:`ldlloc.export.poses.ExportPose`) named
    ``names``, with image sizes ``sizes`` ((W, H) each) and track-less ``points`` (N, 3) coloured
    ``colors`` (N, 3) uint8."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    camera_of: dict[tuple[int, int], int] = {}
    for w, h in sizes:
        if (w, h) not in camera_of:
            cam_id = len(camera_of) + 1
            cam = pycolmap.Camera.create_from_model_id(cam_id, pycolmap.CameraModelId.EQUIRECTANGULAR, 0.0, w, h)
            cam.params = [w, h]  # EQUIRECTANGULAR's params are the image size
            rec.add_camera_with_trivial_rig(cam)
            camera_of[(w, h)] = cam_id
    for i, (pose, name, size) in enumerate(zip(poses, names, sizes), start=1):
        R_c, t_c = colmap_cam_from_world(pose.rot_cam_from_world, pose.center)
        image = pycolmap.Image(name=name, camera_id=camera_of[size], image_id=i)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R_c), t_c))
    if points is not None:
        for xyz, rgb in zip(np.asarray(points, dtype=np.float64), np.asarray(colors, dtype=np.uint8)):
            rec.add_point3D(xyz, pycolmap.Track(), rgb)
    return rec


def write_colmap_model(folder: str | Path, poses: list, names: list[str], sizes: list[tuple[int, int]],
                       points: np.ndarray | None = None, colors: np.ndarray | None = None,
                       text: bool = False) -> Path:
    """Write :func:`build_reconstruction` into the existing folder ``folder`` (``.bin`` files, or
    ``.txt`` with ``text``)."""
    rec = build_reconstruction(poses, names, sizes, points, colors)
    (rec.write_text if text else rec.write_binary)(str(folder))
    return Path(folder)
