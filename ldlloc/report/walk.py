"""The HTML report's top view of a walk: the map's lines seen from above (grey), the path through
the frames in walk order, each frame a dot coloured by its verdict, a ring around the frames that
the walk (not their image) decided. Plain SVG, as :mod:`ldlloc.report.plots`."""

from __future__ import annotations

from html import escape
from pathlib import Path

import numpy as np

from ldlmap.core.errors import LdlError
from ldlmap.map.mapfile import read_map

SIZE = 560  # the view's width and height in CSS pixels
PAD = 24
MAX_MAP_LINES = 4000


def walk_records(records: list[dict]) -> list[dict]:
    """The records of a walk's frames that hold a pose, in walk order (frame index, then name)."""
    walk = [r for r in records if r.get("walk") and r.get("t") is not None]
    return sorted(walk, key=lambda r: (str(r["walk"].get("name")), int(r["walk"].get("frame", 0)), r["name"]))


def map_lines_xy(records: list[dict]) -> np.ndarray:
    """(L, 2, 2) the x, y of the lines of the maps the records name (those that can be read)."""
    out = []
    for path in sorted({r["map"] for r in records if r.get("map")}):
        if Path(path).is_file():
            try:
                out.append(np.asarray(read_map(path, load_cloud=False).lines, float)[:, :, :2])
            except (LdlError, OSError):
                continue
    return np.concatenate(out)[:MAX_MAP_LINES] if out else np.zeros((0, 2, 2))


def walk_svg(records: list[dict], colors: dict[str, str], lines_xy: np.ndarray | None = None) -> str | None:
    """The top view (module docstring) of the walk records among ``records``; None when there are none."""
    walk = walk_records(records)
    if not walk:
        return None
    xy = np.array([r["t"][:2] for r in walk], float)
    lines = np.zeros((0, 2, 2)) if lines_xy is None else np.asarray(lines_xy, float)
    pts = np.concatenate([xy, lines.reshape(-1, 2)])
    lo, hi = pts.min(0), pts.max(0)
    scale = (SIZE - 2 * PAD) / max(float((hi - lo).max()), 1e-6)

    def px(p: np.ndarray) -> np.ndarray:  # world x right, y up -> SVG x right, y down
        return np.stack([PAD + (p[..., 0] - lo[0]) * scale, SIZE - PAD - (p[..., 1] - lo[1]) * scale], -1)

    body = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{SIZE}" height="{SIZE}" viewBox="0 0 {SIZE} {SIZE}" '
            f'role="img" aria-label="top view of the walk">']
    for (x0, y0), (x1, y1) in px(lines):
        body.append(f'<line x1="{x0:.1f}" y1="{y0:.1f}" x2="{x1:.1f}" y2="{y1:.1f}" stroke="#bbb" stroke-width="1"/>')
    path = px(xy)
    body.append('<polyline fill="none" stroke="#555" stroke-width="1.2" points="'
                + " ".join(f"{x:.1f},{y:.1f}" for x, y in path) + '"/>')
    for r, (x, y) in zip(walk, path):
        color = colors.get(r.get("verdict") or "none", colors.get("none", "#888"))
        decided = ", decided by the walk" if r["walk"].get("walk_decided") else ""
        tip = escape(f"{r['name']}: {r.get('verdict')}{decided}")
        body.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="4" fill="{color}"><title>{tip}</title></circle>')
        if r["walk"].get("walk_decided"):
            body.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="7.5" fill="none" stroke="{color}" stroke-width="1.5"/>')
    body.append(f'<text x="{PAD}" y="{SIZE - 6}" font-size="11">{len(walk)} frames; ring: decided by the walk; '
                f'{1 / scale:.3f} m a pixel</text></svg>')
    return "\n".join(body)
