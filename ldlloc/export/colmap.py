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

import os
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, LdlError
from ldlmap.core.geometry import colmap_cam_from_world
from ldlmap.core.lazy import lazy_module
from ldlmap.core.pictures import GROUP_COLORS_BGR

pycolmap = lazy_module("pycolmap")


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


# The files of a model as pycolmap writes it (``.bin``, or ``.txt`` with --text): the only files of an
# output folder that an export replaces; anything else there (images, a database, notes) is kept.
MODEL_FILES = ("cameras", "images", "points3D", "rigs", "frames")
MODEL_SUFFIXES = (".bin", ".txt")


def model_files(folder: str | Path) -> list[Path]:
    """The model files (:data:`MODEL_FILES`, binary or text) that ``folder`` holds."""
    files = [Path(folder) / f"{n}{s}" for n in MODEL_FILES for s in MODEL_SUFFIXES]
    return [f for f in files if f.exists()]


def check_image_names(names: list[str], text: bool) -> None:
    """One line for an image name a COLMAP model cannot hold as written: not valid UTF-8 (a file
    name of other bytes), or, in a text model (``text``), one with a space, tab, newline or other
    control character (COLMAP's ``images.txt`` reads a name up to its first white space)."""
    for n in names:
        try:
            n.encode("utf-8")
        except UnicodeEncodeError:
            raise InputError(f"image name {n!r} is not valid UTF-8: a COLMAP model cannot hold it (rename the "
                             "file)") from None
        if text and any(c.isspace() or not c.isprintable() for c in n):
            raise InputError(f"image name {n!r} holds white space or a control character, which a COLMAP text "
                             "model cannot hold: export without --text (binary), or rename the file")


def write_colmap_model(folder: str | Path, poses: list, names: list[str], sizes: list[tuple[int, int]],
                       points: np.ndarray | None = None, colors: np.ndarray | None = None,
                       text: bool = False, shown_as: str | Path | None = None) -> Path:
    """Write :func:`build_reconstruction` into the existing folder ``folder`` (``.bin`` files, or
    ``.txt`` with ``text``) and read it back: pycolmap does not report write errors (a full disk
    leaves empty files), so a model that does not read back as written is a one-line error naming
    ``shown_as`` (the output the user named; default ``folder``)."""
    check_image_names(names, text)
    rec = build_reconstruction(poses, names, sizes, points, colors)
    (rec.write_text if text else rec.write_binary)(str(folder))
    check_written_model(folder, rec, text, shown_as or folder)
    return Path(folder)


def check_written_model(folder: str | Path, expected, text: bool, shown_as: str | Path) -> None:
    """Raise a one-line :class:`ldlmap.core.errors.LdlError` unless ``folder`` holds every model
    file, none empty, and reads back with ``expected``'s cameras, image names and point count."""
    suffix = ".txt" if text else ".bin"
    files = [Path(folder) / f"{n}{suffix}" for n in MODEL_FILES]
    bad = [f.name for f in files if not f.is_file() or f.stat().st_size == 0]
    why = f"{', '.join(bad)} missing or empty" if bad else ""
    if not why:
        try:
            back = pycolmap.Reconstruction(str(folder))
            same = (sorted(im.name for im in back.images.values()) == sorted(im.name for im in expected.images.values())
                    and back.num_cameras() == expected.num_cameras()
                    and back.num_points3D() == expected.num_points3D())
            why = "" if same else "it reads back other than written"
        except (ValueError, RuntimeError, OSError) as exc:
            why = f"pycolmap cannot read it back: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
    if why:
        full = _disk_full(folder)
        raise LdlError(f"no space left on device writing {shown_as}" if full else
                       f"could not write the COLMAP model {shown_as}: {why}")


def _disk_full(folder: str | Path) -> bool:
    """Whether the file system of ``folder`` has no free block left for this user."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < 4096
