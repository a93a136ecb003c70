"""A picture of a map (``ldlmap info --png``, ``ldlmap build --png``): its top view beside a panorama
of the stored cloud with the map's lines projected, and a caption band under them (the map's name
and counts, the legend of the colours)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.core.pictures import draw_arcs, group_legend, project_lines, with_caption, write_picture
from ldlmap.lines3d import top_view_image
from ldlmap.map.render import render_points_panorama

cv2 = lazy_module("cv2")

DROPPED_BGR = (200, 200, 200)  # top_view_image's colour of the lines the length filter dropped


def map_caption(ldl_map, name: str) -> str:
    """``name`` and what the picture shows of the map: its kept and extracted lines, its translations."""
    return (f"{name}: {len(ldl_map.lines)} of {len(ldl_map.lines_raw)} 3D lines kept, "
            f"{len(ldl_map.translations)} candidate translations")


def map_picture(ldl_map, path: str | Path, width: int = 1024, name: str | None = None) -> Path:
    """A picture of a map: its top view beside a panorama of the stored cloud with projected lines,
    over a band with the map's ``name`` (default: its scene name) and counts, and the legend.

    The panorama is rendered at the candidate translation closest to the cloud's centre.
    """
    height = width // 2
    centre = (ldl_map.bounds_min + ldl_map.bounds_max) / 2
    t = ldl_map.translations[int(ldl_map.nearest_translation(centre))]
    if ldl_map.cloud_points is not None and ldl_map.cloud_colors is not None:
        rgb, _, _ = render_points_panorama(ldl_map.cloud_points, ldl_map.cloud_colors, np.eye(3), t, width, height)
        pano = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    else:
        pano = np.full((height, width, 3), 255, np.uint8)
    pano = draw_arcs(pano, project_lines(ldl_map.lines, np.eye(3), t), ldl_map.line_groups)
    top = top_view_image(ldl_map.lines, size=height, principal=ldl_map.principal_directions,
                         dropped=ldl_map.lines_raw)
    legend = [*group_legend(ldl_map.principal_directions), (DROPPED_BGR, "dropped by the length filter")]
    picture = with_caption(np.concatenate([top, pano], axis=1),
                           map_caption(ldl_map, name or ldl_map.name), legend,
                           "left: top view; right: the lines seen from the central candidate translation")
    return write_picture(path, picture)
