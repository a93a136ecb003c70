"""COLMAP models as map inputs: colored sparse points, registered camera centres, dense cloud.

A sparse model folder (``cameras``/``images``/``points3D`` ``.bin`` or ``.txt``, with or without
the newer ``rigs``/``frames`` files) is read with ``pycolmap.Reconstruction``. A dense cloud
``fused.ply`` (COLMAP's ``stereo_fusion`` output) in the model folder, its parent, or the usual
``<workspace>/dense/fused.ply`` / ``dense/0/fused.ply`` next to ``sparse/0`` is used when present:
it is what the map should be built from, the sparse points being too few for rendering.

Without a dense cloud, :func:`read_colmap_views` gives what 3D lines can be reconstructed from
(:mod:`ldlmap.sfm.photo_lines`): each registered image's camera, pose and observations of the sparse
points, and :func:`find_images_dir` the photos, by default ``<workspace>/images`` beside
``sparse/0`` as COLMAP lays a workspace out (``dense/0/images`` for ``dense/0/sparse``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.signals import import_pycolmap
from ldlmap.io.cloud import PointCloud
from ldlmap.io.pointcloud import read_point_cloud

MODEL_FILES: tuple[str, ...] = ("cameras", "images", "points3D")


@dataclass(frozen=True, eq=False)
class ColmapScene:
    """What a COLMAP reconstruction contributes to an LDL map."""

    points: PointCloud  # sparse 3D points with their RGB colors
    camera_centers: np.ndarray  # (M, 3) registered image centres in world coordinates (our t)
    dense: PointCloud | None = None  # fused.ply when found
    image_names: tuple[str, ...] = field(default=())  # names of the registered images, same order
    dense_path: Path | None = None
    camera_down: np.ndarray | None = None  # (M, 3) each image's +y axis (image down) in world coordinates

    @property
    def cloud(self) -> PointCloud:
        """The cloud to build a map from: the dense one when present, else the sparse points."""
        return self.dense if self.dense is not None else self.points


def is_colmap_model(path: str | os.PathLike) -> bool:
    """True when ``path`` is a folder holding a COLMAP sparse model (binary or text)."""
    p = Path(path)
    return p.is_dir() and any(all((p / f"{n}{ext}").is_file() for n in MODEL_FILES) for ext in (".bin", ".txt"))


def find_fused_ply(model_dir: str | os.PathLike) -> Path | None:
    """``fused.ply`` beside a sparse model: in it, its parent, or ``dense[/0]`` of the workspace."""
    p = Path(model_dir)
    candidates = [p / "fused.ply", p.parent / "fused.ply"]
    for root in (p.parent, p.parent.parent):
        candidates += [root / "dense" / "fused.ply", root / "dense" / "0" / "fused.ply"]
    if p.name.isdigit():  # sparse/<k> -> dense/<k>
        candidates.append(p.parent.parent / "dense" / p.name / "fused.ply")
    return next((c for c in candidates if c.is_file()), None)


def resolve_model_dir(path: str | os.PathLike) -> Path | None:
    """The model folder for ``path``: itself, or ``sparse/0`` / ``sparse`` of a COLMAP workspace."""
    p = Path(path)
    for cand in (p, p / "sparse" / "0", p / "sparse"):
        if is_colmap_model(cand):
            return cand
    return None


def read_colmap_model(path: str | os.PathLike, use_dense: bool = True) -> ColmapScene:
    """Read a COLMAP sparse model folder (or a workspace with ``sparse/0``), and ``fused.ply``
    beside it when ``use_dense``.

    Raises :class:`InputError` when the folder is missing, is not a COLMAP model, cannot be
    parsed, or has no 3D points and no dense cloud.
    """
    p, rec = _open_reconstruction(path)
    pts3d = list(rec.points3D.values())
    xyz = np.array([q.xyz for q in pts3d], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([q.color for q in pts3d], dtype=np.uint8).reshape(-1, 3)
    images = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name)
    centers = np.array([im.projection_center() for im in images], dtype=np.float64).reshape(-1, 3)
    # cam_from_world rotation R_c: row 1 is the camera's +y axis (image down, any camera model) in the world.
    down = np.array([im.cam_from_world().rotation.matrix()[1] for im in images], dtype=np.float64).reshape(-1, 3)

    dense, dense_path = None, None
    if use_dense:
        dense_path = find_fused_ply(p)
        if dense_path is not None:
            dense = read_point_cloud(dense_path)
    sparse = PointCloud(xyz, rgb)
    if len(sparse) == 0 and dense is None:
        raise InputError(f"COLMAP model has no 3D points and no fused.ply beside it: {p}")
    if len(sparse):
        sparse.validate(p)
    return ColmapScene(points=sparse, camera_centers=centers, dense=dense,
                       image_names=tuple(im.name for im in images), dense_path=dense_path, camera_down=down)


@dataclass(frozen=True, eq=False)
class ColmapView:
    """One registered image: camera, pose (COLMAP frame: x right, y down, z forward), observations."""

    name: str  # image name, relative to the images folder
    camera: Any  # pycolmap.Camera: projection with its distortion (cam_from_img / img_from_cam)
    rot_cam_from_world: np.ndarray  # (3, 3)
    trans_cam_from_world: np.ndarray  # (3,): x_cam = R X + t
    center: np.ndarray  # (3,) camera centre in world coordinates
    obs_xy: np.ndarray  # (n, 2) pixels of the observed sparse points (first pixel's centre at 0.5)
    obs_point: np.ndarray  # (n,) row of each observed point in ColmapViews.points


@dataclass(frozen=True, eq=False)
class ColmapViews:
    """The registered images of a model (sorted by name) and its sparse points."""

    views: tuple[ColmapView, ...]
    points: np.ndarray  # (P, 3) sparse 3D points
    model_dir: Path
    reconstruction: Any = None  # the pycolmap.Reconstruction the cameras belong to (kept alive)


def _open_reconstruction(path: str | os.PathLike):
    """The model folder found at ``path`` (it or a ``sparse/<n>`` below it) and its pycolmap reconstruction."""
    pycolmap = import_pycolmap()
    p = Path(path)
    if not p.exists():
        raise InputError(f"COLMAP model folder not found: {p}")
    model = resolve_model_dir(p)
    if model is None:
        raise InputError(f"not a COLMAP sparse model (expected cameras, images, points3D .bin or .txt): {p}")
    _check_binary_counts(model)
    try:
        return model, pycolmap.Reconstruction(str(model))
    except (ValueError, RuntimeError, IndexError, MemoryError) as exc:
        detail = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read COLMAP model {model}: {detail}") from None


# Smallest record of each binary model file (COLMAP's layout): a camera (id, model, width, height,
# at least one parameter), an image (id, quaternion, translation, camera id, a name and its NUL,
# its 2D point count), a 3D point (id, xyz, rgb, error, track length).
_MIN_RECORD = {"cameras.bin": 4 + 4 + 8 + 8 + 8, "images.bin": 4 + 32 + 24 + 4 + 2 + 8, "points3D.bin": 8 + 24 + 3 + 8 + 8}


def _check_binary_counts(model: Path) -> None:
    """Refuse a binary model file whose leading record count its size cannot hold: pycolmap would
    try to allocate it (minutes, then std::bad_alloc) or read past the end."""
    for name, size in _MIN_RECORD.items():
        f = model / name
        if not f.is_file():
            continue
        with open(f, "rb") as fh:  # the count alone: the file may be hundreds of MB
            data = fh.read(8)
        count = int(np.frombuffer(data, "<u8")[0]) if len(data) == 8 else -1
        nbytes = f.stat().st_size
        if count < 0 or count * size > nbytes - 8:
            raise InputError(f"cannot read COLMAP model {model}: {name} is truncated or corrupt "
                             f"({'no record count' if count < 0 else f'{count} records declared'}, "
                             f"{nbytes} bytes)")


def read_colmap_views(path: str | os.PathLike) -> ColmapViews:
    """Registered images with their cameras, poses and sparse-point observations."""
    model, rec = _open_reconstruction(path)
    ids = np.array(sorted(rec.point3D_ids()), dtype=np.int64)
    xyz = np.array([rec.points3D[int(i)].xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    views = []
    for im in sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name):
        obs = [p for p in im.points2D if p.has_point3D()]
        pid = np.array([p.point3D_id for p in obs], dtype=np.int64)
        xy = np.array([p.xy for p in obs], dtype=np.float64).reshape(-1, 2)
        row = np.searchsorted(ids, pid)
        ok = (row < len(ids)) & (ids[np.minimum(row, len(ids) - 1)] == pid) if len(ids) else np.zeros(len(pid), bool)
        pose = im.cam_from_world()
        R = np.asarray(pose.rotation.matrix(), dtype=np.float64)
        t = np.asarray(pose.translation, dtype=np.float64).reshape(3)
        views.append(ColmapView(im.name, im.camera, R, t, -R.T @ t, xy[ok], row[ok]))
    return ColmapViews(tuple(views), xyz, model, rec)


def find_images_dir(model_dir: str | os.PathLike, names: tuple[str, ...] | list[str]) -> Path | None:
    """The folder holding the model's photos: ``images`` in the model folder, its parent or the
    workspace above ``sparse/<k>``; the first that holds at least one of ``names``."""
    p = Path(model_dir)
    for cand in (p / "images", p.parent / "images", p.parent.parent / "images"):
        if cand.is_dir() and any((cand / n).is_file() for n in names):
            return cand
    return None
