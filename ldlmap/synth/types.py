"""Data types passed between the synthetic-scene stages."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SceneMesh:
    """A textured triangle mesh of one room, in world coordinates (metres, z up).

    Every triangle samples its color from ``atlas`` through per-corner texture coordinates.
    Texture coordinates follow OBJ: ``(s, t)`` in [0, 1], ``s`` to the right, ``t`` *up* (row
    ``(1 - t) * atlas_height`` of the image).
    """

    vertices: np.ndarray  # (V, 3) float64, world coordinates
    triangles: np.ndarray  # (F, 3) int64 (int32 accepted), counter-clockwise seen from outside the solid
    tri_uvs: np.ndarray  # (F, 3, 2) float32 texture coordinates of each triangle corner
    atlas: np.ndarray  # (Ha, Wa, 3) uint8 texture atlas (RGB)
    tri_object: np.ndarray  # (F,) int32: -1 for room shell (floor, ceiling, walls, frames, posters), else object index
    footprint: np.ndarray  # (K, 2) float64 room polygon, counter-clockwise, metres
    ceiling_height: float  # metres; the floor is at z = 0
    name: str = "room"
    object_boxes: list[np.ndarray] = field(default_factory=list)  # per object: (8, 3) oriented box corners
    # (F,) int32 or None: index of the planar-faced part (closed solid, or flat quad for panels and
    # posters) each triangle belongs to; the room shell (floor, ceiling, walls) is part 0.
    tri_part: np.ndarray | None = None

    @property
    def num_triangles(self) -> int:
        return int(len(self.triangles))
