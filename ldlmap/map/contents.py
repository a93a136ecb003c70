"""An LDL map in memory (:class:`LdlMap`, :class:`MapFeatures`): what :mod:`.mapfile` reads and writes."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class MapFeatures:
    """Local features of the rendered views, stored as one ragged (CSR) table."""

    backend: str
    view_centers: np.ndarray  # (V, 3)
    offsets: np.ndarray  # (V + 1,)
    xyz: np.ndarray  # (K, 3)
    keypoints: np.ndarray  # (K, 2)
    scores: np.ndarray  # (K,)
    descriptors: np.ndarray  # (K, D)
    translation_view: np.ndarray  # (N_t,) view serving each candidate translation
    width: int = 1024
    height: int = 512
    extraction: str = "equirect"  # equirect | cube (ldlmap.features.sphere.PANORAMA_EXTRACTIONS)

    @property
    def num_views(self) -> int:
        return int(len(self.view_centers))

    def view_slice(self, view: int) -> slice:
        """Rows of view ``view`` in ``xyz``, ``keypoints``, ``scores``, ``descriptors``."""
        return slice(int(self.offsets[view]), int(self.offsets[view + 1]))


@dataclass(frozen=True)
class Footprint:
    """Where a camera can stand on a scan, seen from above: the xy cells (``cell`` metres square, cell
    (0, 0)'s corner at ``origin``) whose column holds free space (no scan point) within the camera
    band; walls, full-height furniture and the outside are not free, an open door is."""

    mask: np.ndarray  # (X, Y) bool
    origin: np.ndarray  # (2,) world xy of cell (0, 0)'s lower corner
    cell: float

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cell (..., 2) of each point ``xy`` (..., >= 2), (0, 0) outside the grid, and whether it is inside."""
        ij = np.floor((np.asarray(xy, dtype=np.float64)[..., :2] - self.origin) / self.cell).astype(np.int64)
        inside = np.all((ij >= 0) & (ij < np.array(self.mask.shape)), axis=-1)
        return np.where(inside[..., None], ij, 0), inside

    def free_at(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point ``xy`` (..., >= 2) stands in a free cell (False outside the grid)."""
        ij, inside = self.cells(xy)
        return inside & self.mask[ij[..., 0], ij[..., 1]]


@dataclass
class LdlMap:
    """Everything localization needs for one scene (see the module docstring for units)."""

    name: str
    bounds_min: np.ndarray
    bounds_max: np.ndarray
    lines_raw: np.ndarray
    lines: np.ndarray
    line_groups: np.ndarray
    length_threshold: float
    kept_ratio: float
    principal_directions: np.ndarray
    translations: np.ndarray
    cloud_points: np.ndarray | None = None
    cloud_colors: np.ndarray | None = None
    features: MapFeatures | None = None
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    fields_attrs: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    line_lambda: float = 0.1
    visibility: np.ndarray | None = None  # (N_t, L) bool: kept lines seen from each translation (None: all)
    coverage: np.ndarray | None = None  # (N_t, G + 1, 2G) bool: directions meeting a mapped surface
    input_to_map: np.ndarray | None = None  # (4, 4) similarity from the build's input frame (None: identity)
    footprint: Footprint | None = None  # a scan's free space seen from above (None: walls not known)

    @property
    def lines_only(self) -> bool:
        return self.features is None

    @property
    def camera_height_band(self) -> tuple[float, float] | None:
        """(min, max) world z of the camera: the camera-height band above the map's floors (``camera_z``),
        else (maps built before floors were found) the lines-only map's ``camera_height``; None when unknown."""
        how = (self.config.get("translations") or {}) if isinstance(self.config, dict) else {}
        try:
            ranges = np.asarray(how["camera_z"], dtype=np.float64).reshape(-1, 2) if "camera_z" in how else None
            lo, hi = (ranges[:, 0].min(), ranges[:, 1].max()) if ranges is not None else (
                float(z) for z in how.get("camera_height"))
        except (TypeError, ValueError, IndexError):
            return None
        return (lo, hi) if np.isfinite(lo) and np.isfinite(hi) and lo <= hi else None

    def nearest_translation(self, points: np.ndarray) -> np.ndarray:
        """Index of the candidate translation nearest to each point ((..., 3) -> (...,))."""
        P = np.asarray(points, dtype=np.float64)
        return np.linalg.norm(P[..., None, :] - self.translations, axis=-1).argmin(-1)
