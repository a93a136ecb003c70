"""The in-memory point cloud every reader returns, and the file suffixes the readers take."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ldlmap.core.errors import InputError


POINT_CLOUD_SUFFIXES: tuple[str, ...] = (".ply", ".pcd", ".txt", ".xyz", ".pts")
MESH_SUFFIXES: tuple[str, ...] = (".obj", ".off", ".stl")
SUPPORTED_SUFFIXES: tuple[str, ...] = POINT_CLOUD_SUFFIXES + MESH_SUFFIXES
WRITE_SUFFIXES: tuple[str, ...] = (".ply", ".txt")
DEFAULT_MESH_SAMPLES = 1_000_000  # points sampled from a mesh given where a cloud is expected


@dataclass(frozen=True, eq=False)
class PointCloud:
    """A point cloud in world coordinates (metres) with optional 8-bit RGB colors."""

    points: np.ndarray  # (N, 3) float64
    colors: np.ndarray | None = None  # (N, 3) uint8 RGB, or None

    def __post_init__(self) -> None:
        pts = np.ascontiguousarray(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"point cloud points must have shape (N, 3), got {pts.shape}")
        object.__setattr__(self, "points", pts)
        if self.colors is not None:
            col = np.asarray(self.colors)
            if col.shape != pts.shape:
                raise InputError(f"point cloud colors must have shape {pts.shape}, got {col.shape}")
            if col.dtype != np.uint8:
                if np.issubdtype(col.dtype, np.floating) and not np.all(np.isfinite(col)):
                    raise InputError("point cloud colors contain NaN or inf")
                if col.size and (col.min() < 0 or col.max() > 255):
                    raise InputError("point cloud colors must lie in 0-255")
                col = np.rint(col).astype(np.uint8)
            object.__setattr__(self, "colors", np.ascontiguousarray(col))

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(min (3,), max (3,))``."""
        if len(self) == 0:
            raise InputError("empty point cloud has no bounds")
        return self.points.min(axis=0), self.points.max(axis=0)

    def subsample(self, max_points: int, seed: int = 0) -> "PointCloud":
        """At most ``max_points`` points drawn uniformly without replacement (original order kept)."""
        if max_points <= 0:
            raise ValueError(f"max_points must be positive, got {max_points}")
        if len(self) <= max_points:
            return self
        idx = np.sort(np.random.default_rng(seed).choice(len(self), size=max_points, replace=False))
        return PointCloud(self.points[idx], None if self.colors is None else self.colors[idx])

    def validate(self, source: str | os.PathLike | None = None) -> "PointCloud":
        """Raise :class:`InputError` for an empty cloud or non-finite coordinates; return self."""
        where = f": {source}" if source is not None else ""
        if len(self) == 0:
            raise InputError(f"point cloud is empty{where}")
        bad = ~np.isfinite(self.points).all(axis=1)
        if bad.any():
            raise InputError(f"point cloud has {int(bad.sum())} points with NaN/inf coordinates{where}")
        return self
