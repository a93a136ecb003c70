"""Pictures of a localization: the query's 2D lines by principal group, and the map's 3D lines
projected at the estimated pose (``--save-vis``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ldlmap.core.pictures import draw_arcs, project_lines, write_picture


def localization_picture(image_rgb: np.ndarray, loc, ldl_map) -> np.ndarray:
    """BGR picture: top, the query with its (filtered) 2D lines colored by principal group;
    bottom, the query with the map's 3D lines projected at the estimated pose."""
    import cv2

    bgr = cv2.cvtColor(np.asarray(image_rgb), cv2.COLOR_RGB2BGR)
    top = draw_arcs(bgr, loc.arcs if loc.arcs is not None else np.zeros((0, 2, 3)), loc.arc_groups)
    lines, groups = ldl_map.lines, ldl_map.line_groups
    if getattr(ldl_map, "visibility", None) is not None:  # walls hide the other lines (layout maps)
        seen = ldl_map.visibility[int(ldl_map.nearest_translation(loc.center))]
        lines, groups = lines[seen], groups[seen]
    bottom = draw_arcs(bgr, project_lines(lines, loc.rot_cam_from_world, loc.center), groups)
    h = bgr.shape[0]
    scale = max(1.0, h / 512)
    how = loc.refine_method if getattr(loc, "refined", False) else "coarse"
    for img, text in ((top, f"2D lines ({0 if loc.arcs is None else len(loc.arcs)}) by principal group"),
                      (bottom, f"map lines at the estimated pose ({how})")):
        _title(img, text, scale)
    return np.concatenate([top, bottom], axis=0)


def _title(img: np.ndarray, text: str, scale: float) -> None:
    """White text on a dark banner in the top-left corner (readable on any panorama), in place."""
    import cv2

    font, size, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, max(1, int(round(1.5 * scale)))
    (w, h), base = cv2.getTextSize(text, font, size, thick)
    pad = int(6 * scale)
    cv2.rectangle(img, (0, 0), (w + 2 * pad, h + base + 2 * pad), (30, 30, 30), -1)
    cv2.putText(img, text, (pad, pad + h), font, size, (255, 255, 255), thick, cv2.LINE_AA)


def save_localization_picture(image_rgb: np.ndarray, loc, ldl_map, path: str | Path) -> Path:
    """Write :func:`localization_picture` atomically, in the format of ``path``'s extension."""
    return write_picture(path, localization_picture(image_rgb, loc, ldl_map))


__all__ = ["localization_picture", "save_localization_picture"]
