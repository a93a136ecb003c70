"""Doors a scan saw closed: where a walk passes through the walls of a scan's footprint.

A scan's footprint (:class:`ldlmap.map.contents.Footprint`) is free where its columns hold empty
space, so an open door is a gap in the wall, but a closed one (a scanned door leaf: the synthetic
building's doors are all closed panels) is wall. Its frame is still in the map's lines: each jamb a
vertical edge from the floor up (:data:`JAMB_MIN_M` long or more, its foot within
:data:`JAMB_FLOOR_M` of a floor: a window's edges start at its sill), two jambs a door's width apart
(:data:`DOOR_WIDTH_M`), standing at a wall of the footprint no thicker than :data:`MAX_WALL_M` with
free space on both sides, at their middle and at both feet (a cabinet or a shelf against a wall
makes the wall thicker; a room's corner, where another wall runs on along the normal, is no door),
and without a pair like it standing in front of the wall (:func:`fronted`: the front and back edges
of a cabinet lower than the camera band, which the footprint does not see).
:func:`with_doors` opens each door so found: the cells between its jambs through the wall. The
footprint's hollows (the insides of closed furniture and of double walls: free columns, but no
candidate translation stands in them) are taken out first (:func:`lived_in`): a cabinet's hollow
against a wall would otherwise make the wall look thin.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.map.contents import Footprint

csgraph = lazy_module("scipy.sparse.csgraph")
ndimage = lazy_module("scipy.ndimage")
sparse = lazy_module("scipy.sparse")
spatial = lazy_module("scipy.spatial")

DOOR_WIDTH_M = (0.6, 1.25)  # jambs this far apart (xy) make a door
JAMB_MIN_M = 1.5  # a jamb: vertical edges reaching at least this high ...
JAMB_FLOOR_M = 0.4  # ... from within this of a floor ...
JAMB_TOP_M = 2.35  # ... and no higher than this above it: a door's height (1.9-2.3 m), not a ceiling's (a room's corner)
JAMB_GAP_M = 0.05  # the pieces of one jamb: vertical segments this close in xy ...
PIECE_MIN_M = 0.25  # ... and this long or more
VERTICAL_COS = 0.98  # a segment's direction within 11.5 deg of the vertical
MAX_WALL_M = 0.5  # a door's wall: at most this thick in the footprint (its cells), free on both sides
FRONT_M = 1.0  # a pair of jambs with a pair like it this far in front of its wall: a piece of furniture's edges ...
ALIGN_M = 0.15  # ... like it: at most this far apart along the wall, their widths as close, their directions parallel
PARALLEL_COS = 0.985


def jambs(lines: np.ndarray, floors: np.ndarray) -> np.ndarray:
    """(J, 2) xy of the jambs in the segments ``lines`` (N, 2, 3): vertical pieces (a line detector
    breaks an edge into several) standing within :data:`JAMB_GAP_M` of each other in xy, taken together,
    that reach from within :data:`JAMB_FLOOR_M` of one of ``floors`` (z) :data:`JAMB_MIN_M` up or more,
    but not past :data:`JAMB_TOP_M` (a door's top, under the ceiling)."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    d = L[:, 1] - L[:, 0]
    n = np.linalg.norm(d, axis=1)
    L = L[(n >= PIECE_MIN_M) & (np.abs(d[:, 2]) >= VERTICAL_COS * n)]
    z = np.asarray(floors, dtype=np.float64).reshape(-1)
    if not len(z) or len(L) < 2:
        return np.zeros((0, 2))
    xy = L[:, :, :2].mean(1)
    pairs = spatial.cKDTree(xy).query_pairs(JAMB_GAP_M, output_type="ndarray")
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(L), len(L)))
    _, label = csgraph.connected_components(graph, directed=False)
    bottom, top = np.full(label.max() + 1, np.inf), np.full(label.max() + 1, -np.inf)
    np.minimum.at(bottom, label, L[:, :, 2].min(1))
    np.maximum.at(top, label, L[:, :, 2].max(1))
    centre = np.stack([np.bincount(label, xy[:, k]) for k in range(2)], 1) / np.bincount(label)[:, None]
    floor = z[np.abs(bottom[:, None] - z[None]).argmin(1)]
    ok = (np.abs(bottom - floor) <= JAMB_FLOOR_M) & (top - floor >= JAMB_MIN_M) & (top - floor <= JAMB_TOP_M)
    return centre[ok]


def jamb_pairs(lines: np.ndarray, floors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of :func:`jambs` a door's width (:data:`DOOR_WIDTH_M`) apart: (K, 2) xy of each
    pair's middle and (K, 2) its vector from one jamb to the other."""
    foot = jambs(lines, floors)
    if len(foot) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    i, j = spatial.cKDTree(foot).query_pairs(DOOR_WIDTH_M[1], output_type="ndarray").T
    v = foot[j] - foot[i]
    keep = np.linalg.norm(v, axis=1) >= DOOR_WIDTH_M[0]
    return (foot[i] + foot[j])[keep] / 2, v[keep]


def wall_runs(footprint: Footprint, at: np.ndarray, normal: np.ndarray,
              longest: float = MAX_WALL_M) -> tuple[np.ndarray, np.ndarray]:
    """Along ``normal`` (K, 2) through each point ``at`` (K, 2): the ends (offsets, m) of the wall that
    stands there (the run of cells not free nearest the point, within a cell of it), NaN where no
    wall stands there, or where it runs on past :data:`MAX_WALL_M` or leads to no free space."""
    cell = float(footprint.cell)
    step = cell / 4
    s = np.arange(-longest - 2 * cell, longest + 2 * cell + step, step)
    free = footprint.free_at(at[:, None, :] + s[None, :, None] * normal[:, None, :])  # (K, S)
    near = ~free & (np.abs(s) <= cell)[None]
    start = np.where(near.any(1), np.argmin(np.where(near, np.abs(s)[None], np.inf), axis=1), -1)
    idx = np.arange(len(s))[None]
    hi = np.where(free & (idx > start[:, None]), idx, len(s)).min(1)  # the first free sample past the wall
    lo = np.where(free & (idx < start[:, None]), idx, -1).max(1)  # the last free one before it
    ok = (start >= 0) & (hi < len(s)) & (lo >= 0)
    ok &= np.where(ok, s[np.minimum(hi, len(s) - 1)] - s[np.maximum(lo, 0)], np.inf) <= longest + 2 * step
    return np.where(ok, s[np.maximum(lo, 0)], np.nan), np.where(ok, s[np.minimum(hi, len(s) - 1)], np.nan)


def door_passages(footprint: Footprint, lines: np.ndarray, floors: np.ndarray) -> np.ndarray:
    """The doors of ``lines`` (:func:`jamb_pairs`) in ``footprint``'s walls: pairs of jambs whose
    middle and feet all stand at a wall no thicker than :data:`MAX_WALL_M` with free space on both sides
    (a cabinet or a shelf against a wall is thicker; a corner's wall runs on). (D, 6): centre xy, unit
    vector along the door, half its width, and the wall's two ends along the door's normal."""
    mid, v = jamb_pairs(lines, floors)
    if not len(mid):
        return np.zeros((0, 6))
    width = np.linalg.norm(v, axis=1)
    u = v / width[:, None]
    normal = np.stack([-u[:, 1], u[:, 0]], 1)
    lo, hi = wall_runs(footprint, mid, normal)
    # at the feet the door's frame may stand out of the wall into one more cell
    flo, fhi = wall_runs(footprint, np.concatenate([mid - 0.5 * v, mid + 0.5 * v]), np.concatenate([normal] * 2),
                         MAX_WALL_M + footprint.cell)
    ok = np.isfinite(lo) & np.isfinite(flo.reshape(2, -1)).all(0) & ~fronted(mid, u, width, lo, hi, footprint.cell)
    return np.column_stack([mid, u, 0.5 * width, lo, hi])[ok]


def fronted(mid: np.ndarray, u: np.ndarray, width: np.ndarray, lo: np.ndarray, hi: np.ndarray,
            cell: float) -> np.ndarray:
    """(K,) whether each jamb pair (middles ``mid``, directions ``u``, ``width``; its wall from ``lo`` to
    ``hi`` along its normal) has a pair like it (as wide, parallel, at the same place along the wall)
    standing in front of its wall, up to :data:`FRONT_M` away: a piece of furniture's front and back
    edges (a door's other pair stands in its wall's other face)."""
    normal = np.stack([-u[:, 1], u[:, 0]], 1)
    off = mid[None] - mid[:, None]  # (K, K): from pair a to pair b
    across = np.einsum("abk,ak->ab", off, normal)
    like = ((np.abs(np.einsum("abk,ak->ab", off, u)) <= ALIGN_M) & (np.abs(width[:, None] - width[None]) <= ALIGN_M)
            & (np.abs(np.einsum("ak,bk->ab", u, u)) >= PARALLEL_COS))
    lo, hi = np.nan_to_num(lo)[:, None], np.nan_to_num(hi)[:, None]
    out = ((across < lo - cell) & (across >= -FRONT_M)) | ((across > hi + cell) & (across <= FRONT_M))
    return (like & out).any(1)


def lived_in(footprint: Footprint, translations: np.ndarray) -> Footprint:
    """``footprint`` less its free regions (4-connected cells) that hold none of the map's candidate
    ``translations`` (N, >= 2): the hollow insides of furniture and of walls, where nobody stands."""
    label, _ = ndimage.label(footprint.mask)
    ij, inside = footprint.cells(np.asarray(translations, dtype=np.float64).reshape(len(translations), -1))
    ij = ij[inside]
    keep = np.zeros(label.max() + 1, dtype=bool)
    keep[label[ij[:, 0], ij[:, 1]]] = True
    keep[0] = False
    return Footprint(keep[label], footprint.origin, footprint.cell)


def with_doors(footprint: Footprint, lines: np.ndarray, floors: np.ndarray) -> Footprint:
    """``footprint`` with the doors of ``lines`` (:func:`door_passages`) open: the cells whose centres
    lie between a door's jambs, from one side's pair to the other's and a cell beyond each."""
    doors = door_passages(footprint, lines, floors)
    if not len(doors):
        return footprint
    mask, cell = np.array(footprint.mask, dtype=bool), float(footprint.cell)
    for c, u, half, s0, s1 in zip(doors[:, :2], doors[:, 2:4], doors[:, 4], doors[:, 5], doors[:, 6]):
        # a few tens of doors a floor, each a small box of cells
        normal = np.array([-u[1], u[0]])
        corners = np.array([c + a * half * u + s * normal for a in (-1, 1) for s in (s0, s1)])
        lo = np.maximum(np.floor((corners.min(0) - footprint.origin) / cell).astype(int), 0)
        hi = np.minimum(np.ceil((corners.max(0) - footprint.origin) / cell).astype(int), np.array(mask.shape))
        if np.any(hi <= lo):
            continue
        ii, jj = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]), indexing="ij")
        p = footprint.origin + (np.stack([ii, jj], -1) + 0.5) * cell - c
        inside = (np.abs(p @ u) <= half) & (p @ normal >= s0) & (p @ normal <= s1)
        mask[ii[inside], jj[inside]] = True
    return Footprint(mask, footprint.origin, footprint.cell)
