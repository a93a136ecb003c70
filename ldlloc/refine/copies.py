"""Identical rooms, found from the maps' lines: whether the place a pose stands in exists elsewhere.

A building repeats its rooms (offices along a corridor, hotel rooms, the same office on every
floor): one image cannot tell the copies apart, whatever its score. No fitting is needed to see it:

1. the **seen lines** (:func:`seen_lines`): the map lines the image confirms at the pose (a share
   of their points on a query arc, :func:`ldlloc.refine.geometric.seen_line_points`): what the
   image shows of its room;
2. the **motions** that carry them onto another place (:func:`copy_motions`): a turn about the
   up axis by a multiple of 90 degrees and a translation, voted for by pairs of lines of the same
   length and direction (one vote per seen line and motion), then kept where the moved seen lines
   lie on the target map's lines (``cover``: the share of their points within :data:`COPY_TOL` of
   a map line, after the translation is refined on them: :func:`fitted_offset`) for
   :data:`COPY_COVER` or more. The pose's own place (no motion) and a symmetric
   room's twin within itself (the moved lines land on the seen lines again, or, on a map that
   stores visibility, the moved camera sees mostly the same lines: :func:`room_twins` finds those
   and the refined rivals' tie judges them) are not copies, nor is the pose's own place on another
   map (maps that share a frame);
3. the **copy's pose** (the pose moved the same way) must stand where a camera can
   (:func:`ldlloc.refine.geometric.physical_poses` on its map) and explain the image about as well,
   both ways: its map-line support (:func:`ldlloc.refine.geometric.map_line_support`: the map's lines
   the image confirms) within :data:`COPY_NOISE` of the pose's own, and the share of the image's
   lines its map explains (:func:`explained_share`) at least :data:`EXPLAINED_SHARE` of the pose's
   (a wall of shelves only one copy has tells them apart).

:func:`find_copies` runs the three on the pose's map and on other maps (a folder of floor maps);
:func:`ldlloc.confidence.add_copies` names them and makes the verdict at most ``ambiguous``.
A map's line samples and their k-d tree are built once per map (:func:`line_index`).
"""

from __future__ import annotations

import weakref
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlloc.refine.geometric import arc_planes, map_line_support, physical_poses, seen_line_points

spatial = lazy_module("scipy.spatial")

SEEN_SHARE = 0.5  # a map line is seen when this share of its points lies on a query arc
SEEN_RADIUS_M = 8.0  # ... and it passes within this of the camera (maps without visibility: what lies
# behind walls far off and happens to project onto an arc is not the room)
MIN_SEEN_LINES = 6  # fewer seen lines do not describe a room (no copy is looked for)
MIN_LINE_M = 0.3  # lines shorter than this neither vote nor are sampled (clutter, fragments)
SAMPLE_M = 0.05  # spacing of the points sampled along the lines
PARALLEL_DEG = 3.0  # two lines vote for a motion when parallel within this after its turn ...
LENGTH_TOL = 0.15  # ... and of the same length within this share (or 0.2 m)
VOTE_CELL_M = 0.25  # translations voted for are binned in cells of this size
MIN_VOTES = 4  # a motion needs this many seen lines voting for it
MAX_MOTIONS = 12  # the best-voted motions checked per map and turn
COPY_TOL = 0.15  # m: a moved seen-line point lies on a target line within this
COPY_COVER = 0.6  # a motion is a copy when this share of the seen lines' points lie on the target's lines
FIT_RADIUS_M = 0.3  # the voted translation is refined on the points within this of a target line
SELF_SHARE = 0.5  # a motion that lands this share on the seen lines themselves is the room's own symmetry
COPY_NOISE = 0.05  # a copy's map-line support within this of the pose's explains the image as well (the tie's noise)
EXPLAINED_SHARE = 0.6  # ... and the share of the image its map explains at least this much of the pose's (two scans of
# one room differ: the copy of a synthetic office explains 0.23 of the image where the pose explains 0.32)
MAX_COPIES = 3


@dataclass(frozen=True)
class LineIndex:
    """A map's grouped lines of :data:`MIN_LINE_M` or more: their points every :data:`SAMPLE_M`
    (``points``, with ``owner``: each point's line) in a k-d tree, midpoints, unit directions and lengths."""

    lines: np.ndarray  # (L, 2, 3)
    mid: np.ndarray
    unit: np.ndarray
    length: np.ndarray
    points: np.ndarray
    owner: np.ndarray
    tree: object


_INDEX: dict[int, LineIndex] = {}


def line_samples(lines: np.ndarray, step: float = SAMPLE_M) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` along each line (both ends included) and the index of each point's line."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    n = np.maximum(2, np.ceil(np.linalg.norm(L[:, 1] - L[:, 0], axis=1) / step).astype(int) + 1)
    owner = np.repeat(np.arange(len(L)), n)
    f = (np.arange(len(owner)) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n - 1, n)
    return L[owner, 0] + f[:, None] * (L[owner, 1] - L[owner, 0]), owner


def make_index(lines: np.ndarray) -> LineIndex:
    """The :class:`LineIndex` of lines (L, 2, 3) (those under :data:`MIN_LINE_M` left out)."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    L, length = L[length >= MIN_LINE_M], length[length >= MIN_LINE_M]
    points, owner = line_samples(L)
    return LineIndex(L, L.mean(1), (L[:, 1] - L[:, 0]) / length.clip(1e-12)[:, None], length, points, owner,
                     spatial.cKDTree(points if len(points) else np.zeros((1, 3))))


def line_index(ldl_map) -> LineIndex:
    """The map's :class:`LineIndex` of its grouped lines, built on first use and kept while the map lives."""
    key = id(ldl_map)
    if key in _INDEX:
        return _INDEX[key]
    index = make_index(np.asarray(ldl_map.lines)[np.asarray(ldl_map.line_groups) >= 0])
    try:
        weakref.finalize(ldl_map, _INDEX.pop, key, None)
    except TypeError:  # an object without weak references (a stand-in): not kept
        return index
    _INDEX[key] = index
    return index


def seen_lines(arcs: np.ndarray, R: np.ndarray, center: np.ndarray, ldl_map, tol_deg: float = 1.0) -> np.ndarray:
    """The map's grouped lines (M, 2, 3) the image confirms at the pose: :data:`SEEN_SHARE` of their
    shown points on a query arc, within :data:`SEEN_RADIUS_M` of the camera (and seen from the pose's
    candidate translation, when the map stores visibility)."""
    L = grouped_lines_seen_from(ldl_map, center)
    L = L[segment_distance(L, np.asarray(center, np.float64)) <= SEEN_RADIUS_M]
    if len(arcs) == 0 or len(L) == 0:
        return L[:0]
    near, shown = seen_line_points(arc_planes(arcs), R, center, L, tol_deg)
    share = near.sum(1) / np.maximum(shown.sum(1), 1)
    return L[(share >= SEEN_SHARE) & (shown.sum(1) >= shown.shape[1] // 4)]


def visible_at(ldl_map, center: np.ndarray) -> np.ndarray | None:
    """(1, L) the map's lines seen from the candidate translation nearest ``center`` (None: the map
    stores no visibility)."""
    if getattr(ldl_map, "visibility", None) is None:
        return None
    return np.asarray(ldl_map.visibility[ldl_map.nearest_translation(np.asarray(center, float)[None])], bool)


def grouped_lines_seen_from(ldl_map, center: np.ndarray) -> np.ndarray:
    """(M, 2, 3) the map's grouped lines, those seen from the candidate translation nearest ``center``
    when the map stores visibility."""
    keep = np.asarray(ldl_map.line_groups) >= 0
    vis = visible_at(ldl_map, center)
    if vis is not None:
        keep &= vis[0]
    return np.asarray(ldl_map.lines, dtype=np.float64)[keep]


def same_room(ldl_map, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two places of a map that stores visibility see mostly the same lines (:data:`SELF_SHARE`
    of the fewer: one room, a symmetric twin within it, not a copy); False without visibility."""
    va, vb = visible_at(ldl_map, a), visible_at(ldl_map, b)
    if va is None:
        return False
    return bool((va & vb).sum() >= SELF_SHARE * max(min(va.sum(), vb.sum()), 1))


def explained_share(arcs: np.ndarray, R: np.ndarray, center: np.ndarray, ldl_map, tol_deg: float = 1.0) -> float:
    """Share of the image's arc points (within the horizon band) that lie on one of the map's grouped
    lines seen from the pose: :func:`ldlloc.refine.geometric.seen_line_points` with the roles swapped
    (the map's lines projected as arcs, the query's arcs as the lines sampled). What the inlier loss
    counts, exactly at the pose (no distance field of a nearby candidate)."""
    L = grouped_lines_seen_from(ldl_map, center)
    if len(arcs) == 0 or len(L) == 0:
        return 0.0
    d = (L - np.asarray(center, np.float64)) @ np.asarray(R, np.float64).T
    d /= np.linalg.norm(d, axis=2, keepdims=True).clip(1e-12)
    near, shown = seen_line_points(arc_planes(d), np.eye(3), np.zeros(3), arcs, tol_deg)
    return float(near[shown].mean()) if shown.any() else 0.0


def segment_distance(lines: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(L,) distance of ``point`` to each segment (L, 2, 3)."""
    a, d = lines[:, 0], lines[:, 1] - lines[:, 0]
    f = np.clip(np.einsum("li,li->l", point - a, d) / np.einsum("li,li->l", d, d).clip(1e-12), 0.0, 1.0)
    return np.linalg.norm(a + f[:, None] * d - point, axis=1)


def turn(k: int) -> np.ndarray:
    """The rotation about the world's up axis by ``k`` x 90 degrees (exact)."""
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][k % 4]
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)


def voted_offsets(seen: LineIndex, target: LineIndex, Q: np.ndarray) -> np.ndarray:
    """Translations (M, 3) that carry the seen lines, turned by ``Q``, onto target lines, most voted
    first: each pair of a seen and a target line of the same direction and length votes for the
    offset of their midpoints, once per seen line and cell (:data:`VOTE_CELL_M`); cells with
    :data:`MIN_VOTES` or more give the mean offset of their votes, at most :data:`MAX_MOTIONS`."""
    u = seen.unit @ Q.T
    parallel = np.abs(u @ target.unit.T) >= np.cos(np.radians(PARALLEL_DEG))
    dl = np.abs(seen.length[:, None] - target.length[None])
    same = parallel & (dl <= np.maximum(LENGTH_TOL * seen.length[:, None], 0.2))
    a, b = np.nonzero(same)
    if len(a) == 0:
        return np.zeros((0, 3))
    off = target.mid[b] - seen.mid[a] @ Q.T
    cell = np.floor(off / VOTE_CELL_M).astype(np.int64)
    keys, first = np.unique(np.column_stack([cell, a]), axis=0, return_index=True)  # one vote per seen line and cell
    cells, inv, votes = np.unique(keys[:, :3], axis=0, return_inverse=True, return_counts=True)
    order = np.argsort(-votes, kind="stable")
    order = order[votes[order] >= MIN_VOTES][:MAX_MOTIONS]
    inv = inv.reshape(-1)
    return np.array([off[first[inv == c]].mean(0) for c in order]).reshape(-1, 3)


def cover(points: np.ndarray, tree, tol: float = COPY_TOL) -> float:
    """Share of ``points`` within ``tol`` of a point of ``tree``."""
    if len(points) == 0:
        return 0.0
    d, _ = tree.query(points, distance_upper_bound=tol)
    return float(np.mean(np.isfinite(d)))


def fitted_offset(points: np.ndarray, target: LineIndex, offset: np.ndarray, steps: int = 2) -> np.ndarray:
    """The voted translation refined on the points (seen lines' points, turned): moved by the median
    of each point's step to its nearest target point within :data:`FIT_RADIUS_M` (lines of two copies
    extracted from two scans differ by centimetres; the vote's cell is coarser)."""
    off = np.asarray(offset, np.float64)
    for _ in range(steps):
        d, i = target.tree.query(points + off, distance_upper_bound=FIT_RADIUS_M)
        ok = np.isfinite(d)
        if ok.sum() < 3:
            break
        off = off + np.median(target.points[i[ok]] - (points[ok] + off), axis=0)
    return off


def copy_motions(seen: LineIndex, target: LineIndex, same_map: bool) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The motions ``(Q, offset, cover)`` (``x -> Q x + offset``) that carry the seen lines onto the
    target map's lines (module docstring, step 2), best cover first; on the pose's own map the
    identity and the room's own symmetries are left out."""
    out = []
    for k, Q, off, moved in fitted_motions(seen, target, range(4)):
        if same_map and (k == 0 and np.linalg.norm(off) < VOTE_CELL_M or cover(moved, seen.tree) >= SELF_SHARE):
            continue
        c = cover(moved, target.tree)
        if c >= COPY_COVER:
            out.append((Q, off, c))
    out.sort(key=lambda m: -m[2])
    return out


def fitted_motions(seen: LineIndex, target: LineIndex, turns) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """For each turn ``k`` (by k x 90 degrees) of ``turns``, the offsets the line pairs vote for, fitted:
    ``(k, Q, offset, the seen points moved)``; shared by the copies and the twins."""
    for k in turns:
        Q = turn(k)
        rotated = seen.points @ Q.T
        for off in voted_offsets(seen, target, Q):
            off = fitted_offset(rotated, target, off)
            yield k, Q, off, rotated + off


def room_twins(arcs: np.ndarray, R: np.ndarray, center: np.ndarray, ldl_map,
               tol_deg: float = 1.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """The pose's twins within its own room: the pose moved by each turn of 90, 180 or 270 degrees
    and translation that carries the lines the image confirms there (:func:`seen_lines`) onto the
    map's lines (:data:`COPY_COVER` of their points) and keeps the camera in the same room and where
    a camera can stand: ``(R, t)`` each. A symmetric layout shows the image the same lines from
    there; what tells the twin apart (doors, windows, a sloped side) is left to its score."""
    R, center = np.asarray(R, np.float64), np.asarray(center, np.float64)
    seen = make_index(seen_lines(arcs, R, center, ldl_map, tol_deg))
    if len(seen.lines) < MIN_VOTES:  # a motion needs this many: a layout's few creases may be all there is
        return []
    target, out = line_index(ldl_map), []
    for _, Q, off, moved in fitted_motions(seen, target, (1, 2, 3)):
        tc = Q @ center + off
        if (cover(moved, target.tree) < COPY_COVER or not physical_poses(tc[None], ldl_map)[0]
                or any(np.linalg.norm(tc - t) < 2 * VOTE_CELL_M for _, t in out)):
            continue
        if not same_room(ldl_map, center, tc) and getattr(ldl_map, "visibility", None) is not None:
            continue  # another room of the map: a copy (find_copies), not a twin
        out.append((R @ Q.T, tc))
    return out


def find_copies(arcs: np.ndarray, R: np.ndarray, center: np.ndarray, own_map, maps: list[tuple[str | None, object]],
                own_support: float, tol_deg: float = 1.0, limit: int | None = MAX_COPIES) -> list[dict]:
    """The copies of the pose's place (module docstring) in ``maps`` (``(name, map)``; name None: the
    pose's own map ``own_map``): ``{"map", "R", "t", "support", "cover", "turn_deg"}``, best support
    first, at most ``limit`` (None: all). ``own_support``: the pose's map-line support."""
    R, center = np.asarray(R, np.float64), np.asarray(center, np.float64)
    seen = make_index(seen_lines(arcs, R, center, own_map, tol_deg))
    if len(seen.lines) < MIN_SEEN_LINES:
        return []
    found, own_share = [], None
    for name, m in maps:
        same = m is own_map
        for Q, off, c in copy_motions(seen, line_index(m), same):
            Rc, tc = R @ Q.T, Q @ center + off
            if np.linalg.norm(tc - center) < 2 * VOTE_CELL_M or not physical_poses(tc[None], m)[0]:
                continue  # the pose itself (maps sharing a frame: the same room on another room's map), or no camera
            if physical_poses(tc[None], own_map)[0] and same_room(own_map, center, tc):
                continue  # within the pose's own room: a twin
            if any(f["map"] == name and np.linalg.norm(np.asarray(f["t"]) - tc) < 2 * VOTE_CELL_M for f in found):
                continue  # the same copy voted twice
            s = float(map_line_support(arcs, Rc[None], tc[None], m.lines, m.line_groups, visible_at(m, tc), tol_deg)[0])
            if s < own_support - COPY_NOISE:
                continue
            if own_share is None:
                own_share = explained_share(arcs, R, center, own_map, tol_deg)
            share = explained_share(arcs, Rc, tc, m, tol_deg)
            if share >= EXPLAINED_SHARE * own_share:
                found.append({"map": name, "R": Rc, "t": tc, "support": s, "explained": share, "cover": c,
                              "turn_deg": int(round(np.degrees(np.arctan2(Q[1, 0], Q[0, 0])))) % 360})
    found.sort(key=lambda f: -f["support"])
    return found if limit is None else found[:limit]
