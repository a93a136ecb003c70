"""Pictures of a localization: the query's 2D lines by principal group, and the map's 3D lines
projected at the estimated pose (``--save-vis``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ldlmap.pictures import draw_arcs, project_lines, write_png


def localization_picture(image_rgb: np.ndarray, loc, ldl_map) -> np.ndarray:
    """BGR picture: top, the query with its (filtered) 2D lines colored by principal group;
    bottom, the query with the map's 3D lines projected at the estimated pose."""
    import cv2

    bgr = cv2.cvtColor(np.asarray(image_rgb), cv2.COLOR_RGB2BGR)
    top = draw_arcs(bgr, loc.arcs if loc.arcs is not None else np.zeros((0, 2, 3)), loc.arc_groups)
    arcs3d = project_lines(ldl_map.lines, loc.rot_cam_from_world, loc.center)
    bottom = draw_arcs(bgr, arcs3d, ldl_map.line_groups)
    h = bgr.shape[0]
    scale = max(1.0, h / 512)
    for img, text in ((top, f"2D lines ({0 if loc.arcs is None else len(loc.arcs)}) by principal group"),
                      (bottom, f"map lines at the estimated pose ({'refined' if loc.refined else 'coarse'})")):
        cv2.putText(img, text, (10, int(24 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, (255, 255, 255), 3, cv2.LINE_AA)
        cv2.putText(img, text, (10, int(24 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, (20, 20, 20), 1, cv2.LINE_AA)
    return np.concatenate([top, bottom], axis=0)


def save_localization_picture(image_rgb: np.ndarray, loc, ldl_map, path: str | Path) -> Path:
    """Write :func:`localization_picture` (PNG, or JPEG when ``path`` ends in .jpg) atomically."""
    import cv2

    from ldlmap.errors import InputError, atomic_file

    pic = localization_picture(image_rgb, loc, ldl_map)
    path = Path(path)
    if path.suffix.lower() == ".png":
        return write_png(path, pic)
    with atomic_file(path, suffix=".jpg") as tmp:
        if not cv2.imwrite(str(tmp), pic, [cv2.IMWRITE_JPEG_QUALITY, 90]):
            raise InputError(f"could not write {path}")
    return path


__all__ = ["localization_picture", "save_localization_picture"]
