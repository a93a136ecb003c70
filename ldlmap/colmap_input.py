"""What a COLMAP model builds a map from: ``colmap_scene_input(model, lines, images) -> SceneInput``.

In order of preference:

1. a 3D line file (``--lines``): those lines, with the dense cloud (or the sparse points) for
   features and translations;
2. the dense cloud ``fused.ply`` beside the model (:func:`ldlmap.io.colmap.find_fused_ply`);
3. 3D lines reconstructed from the model's photos (:mod:`ldlmap.sfm_lines`): ``images`` or the
   workspace's ``images`` folder beside ``sparse/0``; a lines-only map whose candidate
   translations include the registered camera centres;
4. otherwise an :class:`InputError` naming the three ways to give the model something to map.

Sparse points alone are never mapped: with their outliers and no surfaces they carry no lines.
"""

from __future__ import annotations

from pathlib import Path

from ldlmap.errors import InputError


def colmap_scene_input(model_dir: str | Path, lines=None, images: str | Path | None = None, params=None):
    """The :class:`ldlmap.build.SceneInput` of a COLMAP model folder (see the module docstring)."""
    from ldlmap.build import SceneInput
    from ldlmap.io.colmap import find_images_dir, read_colmap_model, read_colmap_views
    from ldlmap.sfm_lines import SfmLinesParams, reconstruct_lines

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
