"""What the ``ldlmap lines`` command writes: line files and a top-view picture."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.core.pictures import write_picture
from ldlmap.io.linefiles import write_lines
from ldlmap.lines3d.params import check_lines
from ldlmap.lines3d.principal import assign_line_groups

cv2 = lazy_module("cv2")


def write_line_files(path: str, lines: np.ndarray) -> list:
    """Write ``lines`` as ``.obj`` and ``.txt`` (same stem as ``path``, via
    :func:`ldlmap.io.linefiles.write_lines`, atomically); returns the two paths."""
    L = check_lines(lines)
    base = Path(path)
    targets = [base.with_suffix(".obj"), base.with_suffix(".txt")]
    for t in targets:
        write_lines(t, L)
    return targets


def top_view_image(lines: np.ndarray, size: int = 1000, principal: np.ndarray | None = None,
                   dropped: np.ndarray | None = None) -> np.ndarray:
    """Top view (x right, y up) of 3D lines as a BGR image (size, size, 3), colored by group.

    Lines of the three principal groups are red, green and blue, others grey; ``dropped`` lines
    (e.g. removed by the length filter) are drawn thin and light.
    """
    L = check_lines(lines)
    D = check_lines(dropped) if dropped is not None else np.zeros((0, 2, 3))
    allp = np.concatenate([L, D]).reshape(-1, 3)
    img = np.full((size, size, 3), 255, np.uint8)
    if len(allp):
        lo, hi = allp[:, :2].min(0), allp[:, :2].max(0)
        margin = 20
        scale = (size - 2 * margin) / max(float((hi - lo).max()), 1e-6)

        def px(X: np.ndarray) -> np.ndarray:
            xy = (X[..., :2] - lo) * scale + margin
            return np.stack([xy[..., 0], size - 1 - xy[..., 1]], -1).round().astype(np.int32)

        for a, b in px(D):
            cv2.line(img, tuple(map(int, a)), tuple(map(int, b)), (200, 200, 200), 1, cv2.LINE_AA)
        groups = np.full(len(L), -1)
        if principal is not None and len(L):
            v = L[:, 1] - L[:, 0]
            groups = assign_line_groups(v, principal)
        colors = {0: (40, 40, 220), 1: (40, 170, 40), 2: (220, 80, 40), 3: (30, 200, 230), 4: (200, 60, 200),
                  5: (200, 200, 40), 6: (20, 110, 240), -1: (90, 90, 90)}  # BGR; 3-6: Atlanta frames of more
        for (a, b), g in zip(px(L), groups):
            cv2.line(img, tuple(map(int, a)), tuple(map(int, b)), colors.get(int(g), (90, 90, 90)), 2, cv2.LINE_AA)
    return img


def draw_top_view(lines: np.ndarray, path: str, size: int = 1000, principal: np.ndarray | None = None,
                  dropped: np.ndarray | None = None) -> None:
    """Write :func:`top_view_image` atomically, in the format of ``path``'s extension."""
    write_picture(path, top_view_image(lines, size, principal, dropped))
