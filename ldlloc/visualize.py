"""Pictures of a localization: the query's 2D lines by principal group, and the map's 3D lines
projected at the estimated pose (``--save-vis``, ``--vis``), with a caption band under them: the
panorama's name and its pose error (or status), and the legend of the colours."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ldlloc.batch.accuracy import THRESHOLDS, within_threshold
from ldlmap.core.lazy import lazy_module
from ldlmap.core.pictures import draw_arcs, drawable_text, group_legend, project_lines, with_caption, write_picture

cv2 = lazy_module("cv2")


def localization_caption(name: str, loc, errors: tuple[float, float] | None = None) -> str:
    """``name`` and its pose error against ground truth (``errors``: metres, degrees) with the
    verdict at the headline threshold, or without ground truth its status; and how it was refined."""
    how = f"refined by {loc.refine_method}" if getattr(loc, "refined", False) else "not refined"
    if errors is not None:
        _, t_max, r_max = THRESHOLDS[1]
        verdict = "localized" if within_threshold(*errors) else "not localized"
        return (f"{name}: error {errors[0]:.3f} m, {errors[1]:.2f} deg: {verdict} (within {t_max:g} m / "
                f"{r_max:g} deg), {how}")
    return f"{name}: {loc.status}, {how}, no ground truth" + (f" ({loc.message})" if loc.message else "")


def localization_picture(image_rgb: np.ndarray, loc, ldl_map, caption: str = "") -> np.ndarray:
    """BGR picture: top, the query with its (filtered) 2D lines colored by principal group;
    bottom, the query with the map's 3D lines projected at the estimated pose; under them a band
    with ``caption`` and the colours' legend."""
    bgr = cv2.cvtColor(np.asarray(image_rgb), cv2.COLOR_RGB2BGR)
    top = draw_arcs(bgr, loc.arcs if loc.arcs is not None else np.zeros((0, 2, 3)), loc.arc_groups)
    bottom = draw_map_lines(bgr, ldl_map, loc.rot_cam_from_world, loc.center)
    h = bgr.shape[0]
    scale = max(1.0, h / 512)
    how = loc.refine_method if getattr(loc, "refined", False) else "coarse"
    for img, text in ((top, f"detected: 2D lines of the panorama ({0 if loc.arcs is None else len(loc.arcs)})"),
                      (bottom, f"map: its 3D lines at the estimated pose ({how})")):
        _title(img, text, scale)
    return with_caption(np.concatenate([top, bottom], axis=0), caption,
                        group_legend(getattr(ldl_map, "principal_directions", None)),
                        "colour: the map's principal direction of each line")


def draw_map_lines(image_bgr: np.ndarray, ldl_map, rot_cam_from_world: np.ndarray, center: np.ndarray,
                   thickness: int = 2) -> np.ndarray:
    """A copy of a BGR panorama with the map's 3D lines projected at pose ``(R, t)``, coloured by
    principal group; on maps that record line visibility (layout maps), only the lines seen from
    the candidate translation nearest to ``t`` (walls hide the others)."""
    lines, groups = ldl_map.lines, ldl_map.line_groups
    if getattr(ldl_map, "visibility", None) is not None:
        seen = ldl_map.visibility[int(ldl_map.nearest_translation(center))]
        lines, groups = lines[seen], groups[seen]
    return draw_arcs(image_bgr, project_lines(lines, rot_cam_from_world, center), groups, thickness)


def _title(img: np.ndarray, text: str, scale: float) -> None:
    """White text on a dark banner in the top-left corner (readable on any panorama), in place."""
    text = drawable_text(text)
    font, size, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, max(1, int(round(1.5 * scale)))
    (w, h), base = cv2.getTextSize(text, font, size, thick)
    pad = int(6 * scale)
    cv2.rectangle(img, (0, 0), (w + 2 * pad, h + base + 2 * pad), (30, 30, 30), -1)
    cv2.putText(img, text, (pad, pad + h), font, size, (255, 255, 255), thick, cv2.LINE_AA)


def save_localization_picture(image_rgb: np.ndarray, loc, ldl_map, path: str | Path, caption: str = "") -> Path:
    """Write :func:`localization_picture` atomically, in the format of ``path``'s extension."""
    return write_picture(path, localization_picture(image_rgb, loc, ldl_map, caption))


__all__ = ["draw_map_lines", "localization_caption", "localization_picture", "save_localization_picture"]
