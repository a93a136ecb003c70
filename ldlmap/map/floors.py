"""Where a camera can stand in height: the map's floors, and the camera-height band above each.

A floor is where vertical structure begins: wall corners, door jambs, stair and furniture sides
start on it, so the bottom ends of the (near-)vertical 3D lines, weighted by length, pile up at
each floor's height, whatever the frame's origin (a layout in a building's frame has its floor at
z = -3.5). Every map has lines, so one rule serves scans, meshes, layouts, line files and SfM.
A level is a floor when it holds :data:`FLOOR_SHARE` of that length and stands at least
:data:`MIN_STOREY_M` above the floor below it (upper kitchen cabinets and window sills start
lower than that); without vertical lines the lowest line ends are the floor.
"""

from __future__ import annotations

import numpy as np

from ldlmap.lines3d.principal import HORIZONTAL_DEG, line_directions

DEFAULT_CAMERA_HEIGHT = (0.3, 2.2)  # metres above a floor: a person's or a robot's camera, by default
BAND_LEVEL_SPACING_M = 0.65  # maps without a scan: lattice levels in a band at most this far apart in height (three
# over the default band: 0.62, 1.25, 1.88 m); measured against 0.3 and 0.5 in docs/benchmarks.md (layout maps)
LEVEL_BIN_M = 0.1  # bottom ends are histogrammed in bins of this height (a level: a bin and its neighbours)
FLOOR_SHARE = 0.15  # a floor holds at least this share of the vertical lines' bottom-end length
MIN_STOREY_M = 2.0  # a second floor stands at least this far above the one below it
LOW_PERCENTILE = 0.5  # without vertical lines: the floor is this percentile of the line ends' heights


def find_floors(lines: np.ndarray) -> np.ndarray:
    """The floors' heights (z, ascending, at least one) of 3D segments (N, 2, 3) in a z-up frame."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    d, length = line_directions(L)
    vertical = (np.abs(d[:, 2]) >= np.cos(np.radians(HORIZONTAL_DEG))) & (length > 0)  # the same tolerance
    if not vertical.any():
        return np.array([float(np.percentile(L[..., 2], LOW_PERCENTILE))])
    bottoms, w = L[vertical, :, 2].min(1), length[vertical]
    lo = float(bottoms.min())
    idx = np.floor((bottoms - lo) / LEVEL_BIN_M).astype(np.int64)
    hist = np.bincount(idx, weights=w)
    padded = np.pad(hist, 1)
    level = padded[:-2] + padded[1:-1] + padded[2:]  # a bin with its two neighbours
    around = np.pad(level, 1)
    peak = (level >= around[:-2]) & (level >= around[2:])
    strong = np.flatnonzero(peak & (level >= FLOOR_SHARE * w.sum()))
    floors: list[float] = []
    for b in strong if len(strong) else [int(np.argmax(level))]:
        near = np.abs(idx - b) <= 1
        z = weighted_median(bottoms[near], w[near])
        if not floors or z - floors[-1] >= MIN_STOREY_M:
            floors.append(z)
    return np.asarray(floors)


def weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The value below which half the weight lies."""
    order = np.argsort(x, kind="stable")
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def height_above_floor(z: np.ndarray, floors: np.ndarray) -> np.ndarray:
    """Height of each ``z`` above the highest floor at or below it (negative below the lowest floor)."""
    z = np.asarray(z, dtype=np.float64)
    f = np.asarray(floors, dtype=np.float64)
    k = np.maximum(np.searchsorted(f, z, side="right") - 1, 0)
    return z - f[k]


def in_band(z: np.ndarray, floors: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """Whether each height ``z`` lies ``band`` (MIN, MAX metres) above the floor under it."""
    h = height_above_floor(z, floors)
    return (h >= band[0]) & (h <= band[1])


def band_ranges(floors: np.ndarray, band: tuple[float, float], top: float) -> list[tuple[float, float]]:
    """The world-z ranges of the band above each floor, each ending below the next floor and ``top``
    (the highest line end); bands wholly above ``top`` are dropped."""
    f = np.asarray(floors, dtype=np.float64)
    ceilings = np.append(f[1:], top)
    out = []
    for z0, z1 in zip(f, ceilings):
        lo, hi = z0 + band[0], min(z0 + band[1], z1)
        if hi >= lo:
            out.append((float(lo), float(hi)))
    return out
