"""Candidate translations for pose search (paper supp. "Hyperparameter Setup").

Both methods first build the *free space* of the scan on a voxel grid:

* inside: the voxel's column lies in the scan's 2D footprint (xy occupancy, closed and
  hole-filled) and its height lies between the floor and the ceiling (robust z percentiles);
* clear: the voxel centre is at least ``clearance`` from every occupied voxel (Euclidean
  distance transform);
* connected: it belongs to one of the large connected components of such voxels, so that the
  closed interiors of furniture (free of points but walled in) are not used.

Then

* ``grid`` (Stanford 2D-3D-S): a regular lattice whose spacing is found by bisection so that the
  number of free lattice points is close to ``num``;
* ``octree`` (OmniScenes; Rodenberg et al. 2016 represent free space by octree cells of the
  cloud): an octree over the voxel grid is refined level by level, largest cells first and cells
  that touch occupied space first (where views change fastest), until ``num`` leaves hold free
  space; each leaf gives the centroid of its free voxels (snapped to the nearest free voxel
  when the centroid is not free).

Every candidate is finally checked against the raw points with a KD-tree (distance >=
``clearance``). Optional ``prior_centers`` (e.g. COLMAP camera centres) are appended unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.frame import check_memory
from ldlmap.core.lazy import lazy_module
from ldlmap.core.polygon import distance_to_boundary, points_in_polygon
from ldlmap.map.contents import Footprint
from ldlmap.map.floors import band_ranges, in_band
from ldlmap.lines3d import robust_bounds

ndimage = lazy_module("scipy.ndimage")
spatial = lazy_module("scipy.spatial")


@dataclass(frozen=True)
class TranslationParams:
    """Parameters of :func:`candidate_translations`."""

    voxel: float = 0.1  # free-space voxel size (grown for large scenes, see max_cells)
    max_cells: int = 128  # at most this many voxels along the longest side
    footprint_close: int = 3  # closing radius (voxels) of the xy footprint
    z_percentiles: tuple[float, float] = (0.5, 99.5)  # floor / ceiling from the z distribution
    min_component: float = 0.2  # keep free components with at least this fraction of the largest
    band_above_floor: tuple[float, float] | None = None  # keep only free space this many metres above
    # a floor, e.g. (0.3, 2.2) where a camera stands: the N_t candidates of a floor map spread over the
    # cameras' heights only (docs/measurements.md#building-bench)
    height_spacing: float | None = None  # maps without a scan: levels in band_above_floor at most this far apart in
    # height (None: the lattice's spacing; known camera heights always use the lattice's)
    floors: tuple[float, ...] | None = None  # the floors' heights (ldlmap.map.floors.find_floors); None: the
    # robust lowest z of the points (z_percentiles)


def _free_space(P: np.ndarray, clearance: float, params: TranslationParams):
    """Free voxel mask (X, Y, Z) bool, grid origin (3,), voxel size and the (X, Y) columns a walker passes
    (:func:`_passable`: no clearance, open doors too)."""
    lo, hi = robust_bounds(P)  # far outliers neither stretch the grid nor occupy it
    P = P[np.all((P >= lo) & (P <= hi), axis=1)]  # the box's own points: all of them unless outliers
    extent = float((hi - lo).max())
    h = max(params.voxel, extent / params.max_cells)
    dims = np.maximum(np.ceil((hi - lo) / h).astype(np.int64), 1) + 1
    idx = np.minimum(np.floor((P - lo) / h).astype(np.int64), dims - 1)
    occ = np.zeros(dims, bool)
    occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    # Footprint in xy: occupied columns, closed and hole-filled.
    r = params.footprint_close
    foot = occ.any(axis=2)
    foot = np.pad(foot, r)
    st = np.ones((2 * r + 1, 2 * r + 1), bool)
    foot = ndimage.binary_closing(foot, structure=st)[r:-r, r:-r]
    foot = ndimage.binary_fill_holes(foot)
    z0, z1 = np.percentile(P[:, 2], params.z_percentiles)
    zc = lo[2] + (np.arange(dims[2]) + 0.5) * h
    zok = (zc >= z0 + clearance) & (zc <= z1 - clearance)
    if params.band_above_floor is not None:
        zok &= in_band(zc, np.asarray(params.floors if params.floors is not None else [z0]), params.band_above_floor)
    dist = ndimage.distance_transform_edt(~occ) * h
    # The occupied voxel may hold a point anywhere inside it: subtract half a diagonal.
    free = foot[:, :, None] & zok[None, None, :] & (dist - 0.87 * h >= clearance)
    passable = _passable(occ, foot, zc, params.floors if params.floors is not None else [z0])
    lab, n = ndimage.label(free)
    if n > 1:
        sizes = np.bincount(lab.ravel())[1:]
        keep = np.concatenate([[False], sizes >= params.min_component * sizes.max()])
        free = keep[lab]
    return free, lo, h, passable


HEAD_M = (1.2, 1.8)  # a walker passes a column empty at these heights above a floor: over tables, sofas and low
# cabinets, through open doors (2 m and more), not through walls (a wall hidden behind low furniture shows above it)


def _passable(occ: np.ndarray, foot: np.ndarray, zc: np.ndarray, floors) -> np.ndarray:
    """(X, Y) the footprint's columns without an occupied voxel :data:`HEAD_M` above one of ``floors``
    (the voxel nearest the band's middle when none has its centre in it)."""
    out = np.zeros(foot.shape, dtype=bool)
    for f in np.asarray(floors, dtype=np.float64).reshape(-1):  # a few floors
        k = np.flatnonzero((zc >= f + HEAD_M[0]) & (zc <= f + HEAD_M[1]))
        if not len(k):
            k = np.array([int(np.argmin(np.abs(zc - f - 0.5 * sum(HEAD_M))))])
        out |= ~occ[:, :, k].any(axis=2)
    return out & foot


def points_along_lines(lines: np.ndarray, step: float = 0.05) -> np.ndarray:
    """Points every ``step`` metres along segments (L, 2, 3): stand in for a cloud when only lines are given."""
    v = lines[:, 1] - lines[:, 0]
    per_line = np.ceil(np.linalg.norm(v, axis=1) / step)
    check_memory(f"{per_line.sum():.3g} points every {step:g} m along the lines", float(per_line.sum()) * 24 * 6,
                 "check the input's unit (--scale)")
    n = np.maximum(per_line.astype(np.int64), 1) + 1
    seg = np.repeat(np.arange(len(lines)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n - 1, n)
    return lines[seg, 0] + t[:, None] * v[seg]


def _check_clear(C: np.ndarray, P: np.ndarray, clearance: float) -> np.ndarray:
    if len(C) == 0:
        return C
    d, _ = spatial.cKDTree(P).query(C, k=1, workers=-1)
    return C[d >= clearance]


def _grid(free: np.ndarray, lo: np.ndarray, h: float, num: int) -> np.ndarray:
    shape = np.array(free.shape)
    size = shape * h

    def lattice(s: float) -> np.ndarray:
        axes = [np.arange(s / 2, size[i], s) for i in range(3)]
        G = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        ij = np.minimum((G / h).astype(np.int64), shape - 1)
        return lo + G[free[ij[:, 0], ij[:, 1], ij[:, 2]]]

    vol = free.sum() * h ** 3
    s_lo, s_hi = h * 0.5, max(float(size.max()), h)
    s = (vol / max(num, 1)) ** (1 / 3)
    best = lattice(s)
    for _ in range(30):  # bisection on the spacing: the count decreases with it (roughly)
        n = len(best)
        if n > num:
            s_lo = s
        else:
            s_hi = s
        if abs(n - num) <= max(1, 0.02 * num) or s_hi - s_lo < 1e-4:
            break
        s = 0.5 * (s_lo + s_hi)
        cur = lattice(s)
        if abs(len(cur) - num) < abs(len(best) - num) or len(best) == 0:
            best = cur
    return best


def _octree(free: np.ndarray, lo: np.ndarray, h: float, num: int) -> np.ndarray:
    depth = int(np.ceil(np.log2(max(free.shape))))
    n = 2 ** depth
    cube = np.zeros((n, n, n), bool)
    cube[: free.shape[0], : free.shape[1], : free.shape[2]] = free
    occupied = np.zeros((n, n, n), bool)  # non-free space inside the bounding box of the scan
    occupied[: free.shape[0], : free.shape[1], : free.shape[2]] = ~free
    ii = np.indices((n, n, n)).reshape(3, -1).T.astype(np.float64)
    f = cube.reshape(-1).astype(np.float64)
    # Pyramids per level: free voxel count, non-free count, sums of free voxel coordinates.
    pyr = []
    for lev in range(depth + 1):
        c = n >> lev  # cells per side at this level
        b = n // c  # voxels per cell side

        def red(a: np.ndarray) -> np.ndarray:
            return a.reshape(c, b, c, b, c, b).sum(axis=(1, 3, 5)).reshape(-1)

        fc = red(cube.astype(np.int64))
        oc = red(occupied.astype(np.int64))
        sums = np.stack([red((ii[:, k] * f).reshape(n, n, n)) for k in range(3)], 1)
        pyr.append((c, fc, oc, sums))
    pyr = pyr[::-1]  # pyr[l]: level l, 2**l cells per side (l = 0 root)
    # Best-first refinement, level by level.
    leaves: list[tuple[int, np.ndarray]] = []  # (level, flat cell ids)
    active = np.array([0]) if pyr[0][1][0] > 0 else np.zeros(0, np.int64)
    count = len(active)
    for lev in range(depth):
        c, fc, oc, _ = pyr[lev]
        c2, fc2, _, _ = pyr[lev + 1]
        x, y, z = np.unravel_index(active, (c, c, c))
        kids = np.stack([np.ravel_multi_index((2 * x + dx, 2 * y + dy, 2 * z + dz), (c2, c2, c2))
                         for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], 1)  # (A, 8)
        gain = (fc2[kids] > 0).sum(1) - 1  # leaves added by splitting
        # Mixed cells (free and occupied) first, then the cells with most free space.
        order = np.lexsort((-fc[active], -(oc[active] > 0).astype(np.int64)))
        budget = num - count
        cum = np.cumsum(gain[order])
        nsplit = int(np.searchsorted(cum, budget, side="right")) if budget > 0 else 0
        below = cum[nsplit - 1] if nsplit else 0
        if budget > 0 and nsplit < len(order) and cum[nsplit] - budget < budget - below:
            nsplit += 1  # overshooting by one split lands closer to num
        split = order[:nsplit]
        stay = np.setdiff1d(np.arange(len(active)), split)
        leaves.append((lev, active[stay]))
        new = kids[split].ravel()
        active = new[fc2[new] > 0]
        count = sum(len(a) for _, a in leaves) + len(active)
        if nsplit == 0:
            active = np.zeros(0, np.int64)
            break
    leaves.append((depth, active))
    cents = []
    for lev, cells in leaves:
        if len(cells):
            _, fc, _, sums = pyr[lev]
            cents.append(sums[cells] / fc[cells][:, None])
    if not cents:
        return np.zeros((0, 3))
    C = np.concatenate(cents)  # voxel index coordinates
    fidx = np.argwhere(free)
    ci = np.round(C).astype(np.int64)
    ok = np.all((ci >= 0) & (ci < free.shape), axis=1)
    ok[ok] = free[ci[ok, 0], ci[ok, 1], ci[ok, 2]]
    if (~ok).any():
        _, j = spatial.cKDTree(fidx).query(C[~ok], k=1)
        C[~ok] = fidx[j]
    return lo + (C + 0.5) * h


def candidate_translations(points: np.ndarray, num: int = 800, method: Literal["octree", "grid"] = "octree",
                           clearance: float = 0.25, prior_centers: np.ndarray | None = None,
                           params: TranslationParams = TranslationParams()) -> np.ndarray:
    """Candidate camera centres (N_t, 3) in the free space of a scan (N_t ~ ``num``).

    ``num`` is N_t of the paper (800 OmniScenes with ``octree``, 1700 Stanford 2D-3D-S with
    ``grid``). ``clearance`` (metres) is the minimum distance to any scan point.
    """
    return translations_and_footprint(points, num, method, clearance, prior_centers, params)[0]


def translations_and_footprint(points: np.ndarray, num: int = 800, method: Literal["octree", "grid"] = "octree",
                               clearance: float = 0.25, prior_centers: np.ndarray | None = None,
                               params: TranslationParams = TranslationParams()) -> tuple[np.ndarray, Footprint]:
    """:func:`candidate_translations` and the scan's :class:`ldlmap.map.contents.Footprint`: the xy
    columns of the free-space grid, inside the scan's outline, without points :data:`HEAD_M` above a
    floor (no clearance: an open 0.9 m door is a column or more of a floor's 0.21-0.31 m voxels)."""
    P = np.asarray(points)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise InputError(f"point cloud must be a non-empty (N, 3) array, got shape {P.shape}")
    P = P.astype(np.float64, copy=False)
    if not np.all(np.isfinite(P)):
        raise InputError("point cloud contains NaN or infinite coordinates")
    if num < 1:
        raise InputError(f"number of translations must be >= 1, got {num}")
    if method not in ("octree", "grid"):
        raise InputError(f"unknown translation method {method!r}: use 'octree' or 'grid'")
    free, lo, h, passable = _free_space(P, clearance, params)
    if not free.any():
        C = np.zeros((0, 3))
    elif method == "grid":
        C = _grid(free, lo, h, num)
    else:
        C = _octree(free, lo, h, num)
    C = _check_clear(C, P, clearance)
    if prior_centers is not None:
        pc = np.asarray(prior_centers, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(pc)):
            raise InputError("prior camera centres contain NaN or infinite values")
        C = np.concatenate([C, pc])
    if len(C) == 0:
        band = params.band_above_floor
        within = f" within {band[0]:g}-{band[1]:g} m above the floor" if band is not None else ""
        raise InputError(f"no free space found for candidate translations{within} (clearance {clearance} m)")
    return C, Footprint(passable, np.asarray(lo[:2], dtype=np.float64), float(h))


SPARSE_SPACING_M = 0.45  # median spacing of a scan's candidates above which the build warns: the building's
# floors at N_t 800 stood 0.54 m apart and lost their corridors, at 1600 in the camera band 0.34 m (a room: 0.2 m)


def candidate_spacing(translations: np.ndarray) -> float:
    """Median distance (metres) from each candidate translation to its nearest other one (0 for fewer than 2)."""
    T = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    if len(T) < 2:
        return 0.0
    d, _ = spatial.cKDTree(T).query(T, k=2)
    return float(np.median(d[:, 1]))


# ------------------------------------------------------------------ maps without a scan


@dataclass(frozen=True)
class Walkable:
    """Where a camera can stand in a map that has no scan (a room layout or an SfM line map).

    ``polygons``: (V, 2) xy outlines in metres (rooms of a floor plan). ``portals``: (P, 2, 2)
    door and opening segments (xy ends): cameras may also stand in a rectangle ``portal_depth``
    deep on both sides of each, so that a closet photographed from its doorway is covered.
    ``z_range``: the camera-height band (world z, metres) when it is known. ``walls``: (W, 4, 3)
    wall quads (corner by corner, door and opening holes left out) that hide lines from cameras
    (:mod:`ldlmap.map.visibility`), when known; ``ceiling_heights``: each polygon's ceiling (metres),
    with the walls they close the rooms (floor and ceiling surfaces for coverage).
    """

    polygons: tuple[np.ndarray, ...] = ()
    portals: np.ndarray | None = None
    z_range: tuple[float, float] | None = None
    walls: np.ndarray | None = None
    ceiling_heights: tuple[float, ...] = ()


def portal_rectangles(portals: np.ndarray, depth: float, widen: float = 0.0) -> list[np.ndarray]:
    """(4, 2) rectangles spanning each portal segment (P, 2, 2), ``depth`` to both sides of it."""
    P = np.asarray(portals, dtype=np.float64).reshape(-1, 2, 2)
    a, b = P[:, 0], P[:, 1]
    d = b - a
    length = np.linalg.norm(d, axis=1, keepdims=True)
    ok = length[:, 0] > 1e-9
    a, b, d, length = a[ok], b[ok], d[ok], length[ok]
    u = d / length
    n = np.stack([-u[:, 1], u[:, 0]], 1) * depth
    a, b = a - u * widen, b + u * widen
    return list(np.stack([a - n, b - n, b + n, a + n], 1))


def _z_levels(z_range: tuple[float, float], spacing: float) -> np.ndarray:
    """Heights spaced by at most ``spacing`` over the band, centred (one level for a thin band)."""
    lo, hi = float(min(z_range)), float(max(z_range))
    n = max(1, int(np.ceil((hi - lo) / spacing - 1e-9)))
    if hi - lo < 1e-9:
        return np.array([lo])
    return lo + (np.arange(n) + 0.5) * (hi - lo) / n


def _centred_lattice(lo: np.ndarray, hi: np.ndarray, spacing: float) -> np.ndarray:
    """(N, 2) square lattice of ``spacing`` over the box [lo, hi], with equal margins on both sides."""
    count = float(np.prod(np.floor((np.asarray(hi) - np.asarray(lo)) / spacing) + 1))
    check_memory(f"a lattice of {count:.3g} candidate translations {spacing:g} m apart", count * 16 * 4,
                 "raise --trans-spacing, or check the input's unit (--scale)")
    axes = []
    for a, b in zip(lo, hi):
        n = max(1, int(np.floor((b - a) / spacing)) + 1)
        start = a + 0.5 * ((b - a) - (n - 1) * spacing)
        axes.append(start + spacing * np.arange(n))
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)


def _region_interior_point(poly: np.ndarray) -> np.ndarray:
    """A point well inside a polygon: the centroid when inside, else the deepest point of a fine grid."""
    c = poly.mean(0)
    if points_in_polygon(c[None], poly)[0]:
        return c
    lo, hi = poly.min(0), poly.max(0)
    g = np.stack(np.meshgrid(*[np.linspace(lo[i], hi[i], 41) for i in range(2)], indexing="ij"), -1).reshape(-1, 2)
    g = g[points_in_polygon(g, poly)]
    if len(g) == 0:
        return c
    return g[np.argmax(distance_to_boundary(g, poly))]


def band_heights(lines: np.ndarray, params: TranslationParams, clearance: float) -> list[tuple[float, float]] | None:
    """The world-z ranges of ``params.band_above_floor`` above each floor (``params.floors``, else the
    lowest line end), under the highest line end less ``clearance``; None without a band. One-line
    error when every band lies above the lines."""
    if params.band_above_floor is None:
        return None
    z = lines[..., 2]
    floors = np.asarray(params.floors if params.floors is not None else [z.min()], dtype=np.float64)
    ranges = band_ranges(floors, params.band_above_floor, float(z.max()) - clearance)
    if not ranges:
        b0, b1 = params.band_above_floor
        raise InputError(f"--camera-height {b0:g}:{b1:g} m lies above the ceiling: the floor is at z = {floors[0]:.2f}, "
                         f"the lines reach z = {float(z.max()):.2f} m, so no candidate translation is left")
    return ranges


def spaced_translations(lines: np.ndarray, spacing: float = 0.3, walkable: Walkable | None = None,
                        z_range: tuple[float, float] | None = None, portal_depth: float = 1.0, portal_widen: float = 0.3,
                        clearance: float = 0.05, params: TranslationParams = TranslationParams()) -> np.ndarray:
    """Candidate camera centres for a map without a scan, on a lattice of ``spacing`` metres.

    Where cameras can stand: the ``walkable`` polygons (and ``portal_depth`` on both sides of
    each portal, widened by ``portal_widen`` at both ends) when given, else the free space of the lines (the footprint their points
    enclose, as for scans). Heights: ``z_range`` (or ``walkable.z_range``) when known, else
    ``params.band_above_floor`` above each of ``params.floors`` (:func:`band_heights`), else the free
    space's floor-to-ceiling band; levels at most ``spacing`` apart. Lattice points
    closer than ``clearance`` to a 3D line are dropped. Never empty: a region that no lattice
    point falls in (a room smaller than the spacing) gets its interior point.
    """
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    if len(L) == 0 or not np.all(np.isfinite(L)):
        raise InputError("candidate translations need finite 3D lines")
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError(f"translation spacing must be > 0 m, got {spacing}")
    zr = z_range if z_range is not None else (walkable.z_range if walkable is not None else None)
    if zr is not None and not (len(zr) == 2 and np.all(np.isfinite(zr))):
        raise InputError(f"camera-height band must be two finite heights, got {zr}")
    ranges = [zr] if zr is not None else band_heights(L, params, clearance)
    banded = zr is None and ranges is not None  # levels in the band above the floors (known heights: the lattice's)
    dz = params.height_spacing if banded and params.height_spacing else spacing
    regions: list[np.ndarray] = []
    if walkable is not None and walkable.polygons:
        regions = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in walkable.polygons]
        if walkable.portals is not None and len(walkable.portals):
            regions += portal_rectangles(walkable.portals, portal_depth, portal_widen)
        if zr is None:
            zs = L[..., 2]
            zr = (float(zs.min()) + clearance, float(zs.max()) - clearance)
        lo = np.min([r.min(0) for r in regions], axis=0)
        hi = np.max([r.max(0) for r in regions], axis=0)
        G = _centred_lattice(lo, hi, spacing)
        inside = np.zeros((len(regions), len(G)), bool)
        for k, r in enumerate(regions):  # one vectorized test per region (rooms: tens)
            inside[k] = points_in_polygon(G, r)
        xy = G[inside.any(0)]
        missing = [r for k, r in enumerate(regions[: len(walkable.polygons)]) if not inside[k].any()]
        if missing:
            xy = np.concatenate([xy, np.stack([_region_interior_point(r) for r in missing])])
    else:
        P = points_along_lines(L)
        free, lo3, h, _ = _free_space(P, clearance, params)
        foot = free.any(axis=2) if free.any() else _free_space(P, 0.0, params)[0].any(axis=2)
        if zr is None:
            zs = lo3[2] + (np.nonzero(free.any(axis=(0, 1)))[0] + 0.5) * h if free.any() else P[:, 2]
            zr = (float(zs.min()), float(zs.max()))
        G = _centred_lattice(np.zeros(2), np.array(foot.shape) * h, spacing)
        ij = np.minimum((G / h).astype(np.int64), np.array(foot.shape) - 1)
        xy = lo3[:2] + G[foot[ij[:, 0], ij[:, 1]]]
        if len(xy) == 0:
            xy = (P[:, :2].min(0) + P[:, :2].max(0))[None] / 2
    levels = np.concatenate([_z_levels(r, dz) for r in (ranges if ranges is not None else [zr])])
    C = np.concatenate([np.column_stack([xy, np.full(len(xy), z)]) for z in levels])
    if clearance <= 0:
        return C
    # Away from the lines (sampled every clearance / 2: a point's distance is off by at most a quarter).
    clear = _check_clear(C, points_along_lines(L, step=clearance / 2), 0.9 * clearance)
    return clear if len(clear) else C
