"""What a map is built from: ``load_input(path, ...) -> SceneInput`` for a cloud, a mesh, a scanner
or phone file (E57, LAS/LAZ, glTF: :func:`read_scanner_file`, docs/inputs.md), a COLMAP model or a
3D line file alone (IFC models: :mod:`ldlmap.map.ifc_maps`).

A COLMAP model (``colmap_scene_input``) gives, in order of preference:
1. a 3D line file (``--lines``): those lines, with the dense cloud (or the sparse points) for
   features and translations;
2. the dense cloud ``fused.ply`` beside the model (:func:`ldlmap.io.colmap.find_fused_ply`);
3. 3D lines reconstructed from the model's photos (:mod:`ldlmap.sfm.photo_lines`): ``images`` or the
   workspace's ``images`` folder beside ``sparse/0``; a lines-only map whose candidate
   translations include the registered camera centres;
4. otherwise an :class:`InputError` naming the three ways to give the model something to map.

Sparse points alone are never mapped: with their outliers and no surfaces they carry no lines.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.io.cloud import PointCloud, SUPPORTED_SUFFIXES
from ldlmap.io.colmap import find_images_dir, is_colmap_model, read_colmap_model, read_colmap_views, resolve_model_dir
from ldlmap.io.e57 import read_e57
from ldlmap.io.gltf import read_gltf
from ldlmap.io.las import read_las
from ldlmap.io.linefiles import LINE_FORMAT_NAMES, read_lines, sniff_line_file
from ldlmap.io.pointcloud import read_point_cloud
from ldlmap.sfm.photo_lines import SfmLinesParams, reconstruct_lines


@dataclass
class SceneInput:
    """The loaded input of a map: a cloud (maybe None), lines (maybe None), translation priors."""

    points: np.ndarray | None
    colors: np.ndarray | None
    lines: np.ndarray | None
    prior_centers: np.ndarray | None
    source: str
    walkable: Any = None  # ldlmap.map.translations.Walkable: where cameras stand (maps without a scan)
    note: str = ""  # how the input was turned into a cloud or lines, when worth telling (COLMAP models)
    camera_down: np.ndarray | None = None  # (M, 3) registered cameras' image-down axes (gravity)


def load_input(path: str | Path, lines_path: str | Path | None, mesh_samples: int,
               images: str | Path | None = None, stations: tuple[str, ...] | list[str] = ()) -> SceneInput:
    """Read any supported input (cloud, mesh, scanner/phone format, COLMAP model, or a line file
    alone); ``images``: a COLMAP model's photos (:mod:`ldlmap.map.inputs`); ``stations``: an E57's
    stations to use (names or indices; all when empty)."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"input not found: {p}")
    lines = read_lines(lines_path) if lines_path is not None else None
    model_dir = resolve_model_dir(p) if p.is_dir() else None
    if model_dir is not None and is_colmap_model(model_dir):
        return colmap_scene_input(model_dir, lines, images)
    if images is not None:
        raise InputError(f"--images goes with a COLMAP model folder, not {p}")
    if p.is_dir():
        raise InputError(f"{p} is a folder but not a COLMAP model (cameras/images/points3D .bin or .txt)")
    suffix = p.suffix.lower()
    if stations and suffix != ".e57":
        raise InputError(f"--stations goes with an E57 scan, not {p.name}")
    if suffix in SCANNER_SUFFIXES:
        cloud, note = read_scanner_file(p, mesh_samples, stations)
        return SceneInput(cloud.points, cloud.colors, lines, None, str(p), note=note)
    kind = sniff_line_file(p)  # by content: a line file's rows could pass for a small point cloud
    if kind is not None and lines is not None:
        raise InputError(f"{p} is a 3D line file ({LINE_FORMAT_NAMES[kind]}), not a scan: give it alone "
                         f"(`ldlmap build {p}`), or a scan with --lines")
    if kind is not None:
        return SceneInput(None, None, read_lines(p), None, f"lines:{p}")
    if suffix in SUPPORTED_SUFFIXES:  # not a line file by its content: the cloud's own error, if any
        cloud = read_point_cloud(p, mesh_samples=mesh_samples)
        return SceneInput(cloud.points, cloud.colors, lines, None, str(p))
    if suffix == ".ifc":
        raise InputError(f"{p.name} is an IFC (BIM) model: its maps are lines-only, one per storey: `ldlmap build {p}` "
                         "(from Python: ldlmap.map.ifc_maps.build_ifc_maps)")
    raise InputError(f"unsupported input {p.name}: use a point cloud, mesh, scanner or phone file, IFC model, COLMAP "
                     f"model folder or line file ({', '.join(SUPPORTED_SUFFIXES + SCANNER_SUFFIXES)}, .ifc)")


SCANNER_SUFFIXES: tuple[str, ...] = (".e57", ".las", ".laz", ".glb", ".gltf")  # docs/inputs.md


def read_scanner_file(path: Path, mesh_samples: int, stations=()):
    """``(PointCloud, note)`` of an E57 scan, a LAS/LAZ cloud or a glTF/GLB mesh (sampled, z-up)."""
    suffix = path.suffix.lower()
    if suffix == ".e57":
        scan = read_e57(path, list(stations) or None)
        return PointCloud(scan.points, scan.colors), "; ".join(scan.notes)
    if suffix in (".las", ".laz"):
        return read_las(path)
    return read_gltf(path, mesh_samples)


def colmap_scene_input(model_dir: str | Path, lines=None, images: str | Path | None = None, params=None):
    """The :class:`SceneInput` of a COLMAP model folder (see the module docstring)."""
    model_dir = Path(model_dir)
    scene = read_colmap_model(model_dir)
    source = f"colmap:{model_dir}"
    if lines is not None or scene.dense is not None:
        cloud = scene.cloud
        note = f"dense cloud {scene.dense_path}" if scene.dense is not None else ""
        return SceneInput(cloud.points, cloud.colors, lines, scene.camera_centers, source, note=note,
                          camera_down=scene.camera_down)
    if images is not None:
        images = Path(images)
        if not images.is_dir():
            raise InputError(f"--images folder not found: {images}")
        if not any((images / n).is_file() for n in scene.image_names):
            raise InputError(f"none of the model's {len(scene.image_names)} registered photos "
                             f"({', '.join(scene.image_names[:2])}, ...) is in {images}")
    else:
        images = find_images_dir(model_dir, scene.image_names)
    if images is None:
        raise InputError(f"COLMAP model {model_dir} has no fused.ply and its photos are not in an images folder "
                         "beside it: run COLMAP's dense stereo (image_undistorter, patch_match_stereo, stereo_fusion) "
                         "for a fused.ply, pass --images DIR with the model's photos, or give a 3D line file with --lines")
    rec = reconstruct_lines(read_colmap_views(model_dir), images, params or SfmLinesParams())
    note = (f"no fused.ply: {rec.counts['lines']} 3D lines reconstructed from {rec.counts['photos']} photos in "
            f"{images} ({sum(rec.seconds.values()):.1f} s)")
    return SceneInput(None, None, rec.lines, scene.camera_centers, f"colmap-lines:{model_dir}", note=note,
                      camera_down=scene.camera_down)
