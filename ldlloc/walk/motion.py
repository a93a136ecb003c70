"""What a walking person can do between two frames: the transition costs of a walk's path.

A step costs nothing up to a free length (a tour: the metres between shots; a video: a walking
speed times the frames' time apart), then its extra length over a step scale, capped at the jump
cost: a jump of 8-12 m between two tour shots (a room skipped) is unlikely, not impossible; frames
close in time (``close_s``: a video's) skip no room: each free length more costs 1, up to ``blocked_cost``. A change
of floor (a height change of :attr:`MotionParams.floor_dz_m` or more) costs more than any jump: floors change only on stairs
or in a lift, rarely. With ``turn_deg`` (videos: the camera turns little between frames) a
rotation costs its angle over it, capped the same way. Costs are negative log-likelihoods
(nats), added to the frames' emission costs (:mod:`ldlloc.walk.hypotheses`).

No step through a wall (:class:`FreeSpace`): where the maps know where a camera can stand (a scan's
stored footprint, when the walk reads it (``WalkParams.scan_walls``, off by default): the columns of
its free space within the camera band; a lattice of candidate translations: a layout's rooms and
doorways), a step whose straight segment leaves that space (a
wall between two rooms, the outside) costs a jump more than its length does (a tour's walker went
round by a door: a detour); between frames close in time (a video's, ``close_s``) it is all but
forbidden (``blocked_cost``): nobody walks through a wall in a fifth of a second. A scan's octree
candidates alone tell no walls (a sample of its free space: their gaps are no walls, and none stand
in doorways narrower than twice the clearance): a scan map built before footprints were stored
has unknown walls.

Floors change on stairs (:func:`stair_points`: the steps' edges in the maps' lines): where the
maps show stairs, a change of floor farther than :data:`STAIR_REACH_M` from them costs
``off_stairs_cost`` more (a lift: rare); maps without stairs say nothing of where floors change.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.map.translations import candidate_spacing
from ldlloc.walk.doors import lived_in, with_doors

ndimage = lazy_module("scipy.ndimage")
spatial = lazy_module("scipy.spatial")


@dataclass(frozen=True)
class MotionParams:
    """The motion model of a walk (defaults: a capture tour of photos)."""

    free_m: float = 5.0  # a step this long or shorter costs nothing (tours: shots 0.6-5 m apart) ...
    speed_mps: float = 1.4  # ... with times (videos): this walking speed times the frames' time apart ...
    min_free_m: float = 0.3  # ... but at least this (a frame's pose error)
    step_m: float = 1.5  # beyond the free length, each step_m more costs 1 ...
    jump_cost: float = 4.0  # ... up to this: a jump (8-12 m between tour shots) stays possible
    floor_dz_m: float = 1.5  # a height change of this or more is a change of floor ...
    floor_cost: float = 8.0  # ... and costs this (stairs or a lift: rare, but a walk may take them)
    turn_deg: float | None = None  # videos: a turn of this many degrees costs 1 (None: turns are free, tours)
    emission_weight: float = 20.0  # a frame's pose that explains no line costs this (the best pose 0)
    anchor_cost: float = 6.0  # a pose distinct from a frame's own confident pose costs this more (less than two jumps:
    # a confident pose in the wrong copy of a room, reached and left by jumps, still gives way)
    own_cost: float = 0.5  # ... or this when it was not, unless the image named that pose as its competitor (a copy
    # of a room it cannot tell from its own pose costs nothing more: the motion decides)
    close_s: float = 2.0  # frames at most this far apart in time cannot stand on two sides of a wall ...
    blocked_cost: float = 100.0  # ... a step through one costs this more (all but forbidden; tours: a jump more)
    off_stairs_cost: float = 16.0  # a change of floor away from the maps' stairs costs this more (a lift, or a
    # floor taken for another: more than two floor changes by the stairs)


def free_length(params: MotionParams, dt: float | None) -> float:
    """Metres a step may cover for free: ``free_m``, or with a time gap ``dt`` (s) the walking speed times it."""
    if dt is None or not np.isfinite(dt) or dt <= 0:
        return params.free_m
    return max(params.min_free_m, params.speed_mps * float(dt))


def transition_costs(prev, cur, params: MotionParams, dt: float | None = None,
                     free: "FreeSpace | None" = None) -> np.ndarray:
    """(H_prev, H_cur) costs of moving from each pose of ``prev`` to each of ``cur`` (both
    :class:`ldlloc.walk.hypotheses.Hypotheses`); ``dt``: their time apart in seconds (None: unknown);
    ``free``: where the maps let a camera stand (None: no walls known)."""
    d = prev.center[:, None, :] - cur.center[None, :, :]
    dist = np.linalg.norm(d, axis=2)
    close = dt is not None and np.isfinite(dt) and 0 <= dt <= params.close_s
    free_m = free_length(params, dt)
    # frames close in time skip no room: no jump; each free length more than a walker covers costs 1
    cap, scale = (params.blocked_cost, min(free_m, params.step_m)) if close else (params.jump_cost, params.step_m)
    cost = np.clip((dist - free_m) / scale, 0.0, cap)
    if params.turn_deg is not None:
        c = np.einsum("aij,bij->ab", prev.rot_cam_from_world, cur.rot_cam_from_world)  # trace(Ra^T Rb)
        ang = np.degrees(np.arccos(np.clip((c - 1.0) / 2.0, -1.0, 1.0)))
        cost = np.minimum(cost + ang / params.turn_deg, cap)
    if free is not None and free.masks is not None:  # through a wall: a jump more (the way round by a door),
        wall = params.blocked_cost if close else params.jump_cost  # between close frames forbidden
        cost = np.where(free.blocked(prev.center, prev.map_index, cur.center, cur.map_index),
                        cost + wall, cost)
    floor = np.abs(d[:, :, 2]) >= params.floor_dz_m
    cost = np.where(floor, np.maximum(cost, params.floor_cost), cost)
    if free is not None and floor.any():  # floors change on the stairs
        cost = np.where(floor & free.off_stairs(prev.center, prev.map_index, cur.center, cur.map_index),
                        cost + params.off_stairs_cost, cost)
    return cost


def straight_walk_costs(last, cur, frames: int, params: MotionParams, dt: float | None = None,
                        free: "FreeSpace | None" = None) -> np.ndarray:
    """(H,) what a walk pays at least from the one pose of ``last`` to each pose of ``cur`` (both
    :class:`ldlloc.walk.hypotheses.Hypotheses`) over ``frames`` steps of ``dt`` seconds each through frames
    that placed nothing (a video's lost frames): :func:`transition_costs` summed along the straight line,
    the turn and the change of floor on the first step, the ground covered evenly. One step of the whole
    distance would let a video's walker run 9 m in a second and a half for a few nats."""
    k = max(int(frames), 1)
    start = np.asarray(last.center, float).reshape(1, 3)
    total = np.zeros(len(cur))
    prev = replace(last, map_index=np.repeat(last.map_index[:1], len(cur)),
                   rot_cam_from_world=np.repeat(last.rot_cam_from_world[:1], len(cur), 0),
                   center=np.repeat(start, len(cur), 0))
    for i in range(1, k + 1):  # a few frames (the walk's lookback): not a hot loop
        at = start + (np.asarray(cur.center, float) - start) * (i / k)
        at[:, 2] = cur.center[:, 2]
        step = replace(cur, center=at)
        total += np.diagonal(transition_costs(prev, step, params, dt, free))
        prev = step
    return total


REACH = 1.0  # a point within this many candidate spacings of a candidate is free space: a gap of two spacings is
# bridged (a doorway narrower than the spacing may hold no candidate), a wider one is a wall (a scan's wall and the
# clearance on both sides of it: 0.2 m + 2 x 0.25 m at a 0.3 m spacing)
CELLS_PER_SPACING = 4  # the grid's cell: a quarter of the smallest candidate spacing ...
CELLS_PER_FOOTPRINT = 2  # ... or half the smallest footprint cell (a step crossing a wall one cell thick meets it)
MAX_CELLS = 40_000_000  # the grid's cells over all maps (coarser cells beyond: memory bounded)
MAX_SAMPLES = 4_000_000  # segment points looked up at once


class FreeSpace:
    """Where a camera can stand on each map of a walk, in the maps' common frame, on one grid: a
    scan's stored footprint (:class:`ldlmap.map.contents.Footprint`: the columns free within the camera
    band, open doors included), else the xy of a lattice's candidate translations each grown by
    ``REACH`` times its spacing; ``CELLS_PER_SPACING`` cells to the smallest spacing,
    ``CELLS_PER_FOOTPRINT`` to the smallest footprint cell. :meth:`blocked` tells the steps that leave
    it. A map with neither (``translations`` None, or its spacing and footprint None) has unknown walls:
    a step on it is never blocked (``masks`` None when no map's walls are known). ``stairs``: each
    map's stairs (:func:`stair_points`, None: none known); :meth:`off_stairs` tells the floor changes
    away from them."""

    def __init__(self, translations: list[np.ndarray] | None, stairs: list[np.ndarray] | None = None,
                 spacings: list[float | None] | None = None, footprints: list | None = None):
        self.stairs = None if stairs is None or not any(len(s) for s in stairs) else \
            [np.asarray(s, dtype=np.float64).reshape(-1, 2) for s in stairs]
        self.masks = None
        if translations is None:
            return
        M = len(translations)
        footprints = list(footprints) if footprints is not None else [None] * M
        T = [np.unique(np.asarray(t, dtype=np.float64).reshape(-1, 3)[:, :2].round(4), axis=0)
             for t in translations]  # their xy (a scan's candidates stand at several heights)
        spacing = spacings or [candidate_spacing(np.asarray(t, dtype=np.float64).reshape(-1, 3))
                               for t in translations]
        lattice = [f is None and s is not None and len(t) >= 2 for t, s, f in zip(T, spacing, footprints)]
        self.known = np.array([f is not None or k for f, k in zip(footprints, lattice)])
        if not self.known.any():
            return
        self.reach = [REACH * max(s, 1e-3) if k else 0.0 for s, k in zip(spacing, lattice)]
        self.end_margin = max([f.cell for f in footprints if f is not None], default=0.0)  # a pose beside a wall
        # may stand in the wall's footprint cell: the points of a step this close to its ends are not judged
        lo, hi = self._extent(T, lattice, footprints)
        self.lo, span = lo, hi - lo
        cells = [r / (REACH * CELLS_PER_SPACING) for r, k in zip(self.reach, lattice) if k]
        cells += [f.cell / CELLS_PER_FOOTPRINT for f in footprints if f is not None]
        cell = max(min(cells), 0.01, float(np.sqrt(np.prod(span) * M / MAX_CELLS)))
        self.cell, self.shape = cell, tuple(int(v) for v in np.ceil(span / cell).astype(int) + 1)
        self.masks = np.stack([self._sampled(f) if f is not None else self._mask(t, r) if k
                               else np.zeros(self.shape, dtype=bool)
                               for t, r, k, f in zip(T, self.reach, lattice, footprints)])  # (M, X, Y) bool

    def _extent(self, T: list[np.ndarray], lattice: list[bool], footprints: list) -> tuple[np.ndarray, np.ndarray]:
        """The grid's xy box: every lattice's candidates grown by the largest reach, every footprint's grid."""
        lo, hi, reach = [], [], max(self.reach)
        for t, k, f in zip(T, lattice, footprints):
            if f is not None:
                lo.append(np.asarray(f.origin, float))
                hi.append(np.asarray(f.origin, float) + np.array(f.mask.shape) * f.cell)
            elif k:
                lo.append(t.min(0) - reach)
                hi.append(t.max(0) + reach)
        return np.min(lo, 0) - 1e-6, np.max(hi, 0) + 1e-6

    def _sampled(self, footprint) -> np.ndarray:
        """A footprint on this grid: each cell takes the footprint cell its centre falls in (separable: axis-aligned grids)."""
        axes = []
        for k in range(2):
            c = self.lo[k] + (np.arange(self.shape[k]) + 0.5) * self.cell
            axes.append(np.floor((c - footprint.origin[k]) / footprint.cell).astype(np.int64))
        ok_i, ok_j = [(a >= 0) & (a < n) for a, n in zip(axes, footprint.mask.shape)]
        out = np.zeros(self.shape, dtype=bool)
        out[np.ix_(ok_i, ok_j)] = np.asarray(footprint.mask, bool)[np.ix_(axes[0][ok_i], axes[1][ok_j])]
        return out

    @classmethod
    def of_maps(cls, maps: list, read_footprints: bool = True) -> "FreeSpace | None":
        """The free space of these maps (:class:`ldlmap.map.contents.LdlMap`): walls from a map's stored
        footprint (a scan's, where its candidates stand, its closed doors opened: :mod:`ldlloc.walk.doors`), else where its candidates are a lattice (:func:`lattice_spacing`), unknown on
        the other maps (``read_footprints`` False: a footprint is not read); stairs from their lines; None when
        neither walls nor stairs are known."""
        T = [np.asarray(m.translations, dtype=np.float64).reshape(-1, 3) for m in maps]
        spacings = [lattice_spacing(m) for m in maps]
        footprints = [None if not read_footprints or getattr(m, "footprint", None) is None else
                      with_doors(lived_in(m.footprint, t), getattr(m, "lines_raw", m.lines), map_floors(m))
                      for m, t in zip(maps, T)]
        walls = any(f is not None or (s is not None and len(t) >= 2) for t, s, f in zip(T, spacings, footprints))
        stairs = [stair_points(m.lines) for m in maps]
        if not walls and not any(len(s) for s in stairs):
            return None
        return cls(T if walls else None, stairs, spacings, footprints)

    def off_stairs(self, a: np.ndarray, map_a: np.ndarray, b: np.ndarray, map_b: np.ndarray) -> np.ndarray:
        """(P, Q) whether neither end of the step from each ``a`` (P, 3) on map ``map_a`` (P,) to each
        ``b`` (Q, 3) on ``map_b`` stands within :data:`STAIR_REACH_M` (xy) of a stair of either map
        (all False when no map shows stairs)."""
        P, Q = len(a), len(b)
        if self.stairs is None:
            return np.zeros((P, Q), dtype=bool)
        near_a = np.stack([near_any(a, s) for s in self.stairs], 1)  # (P, M): a within reach of map m's stairs
        near_b = np.stack([near_any(b, s) for s in self.stairs], 1)  # (Q, M)
        ma, mb = np.asarray(map_a)[:, None], np.asarray(map_b)[None, :]
        at = (near_a[np.arange(P)[:, None], ma] | near_a[np.arange(P)[:, None], mb]
              | near_b[np.arange(Q)[None, :], ma] | near_b[np.arange(Q)[None, :], mb])
        return ~at

    def _mask(self, xy: np.ndarray, reach: float) -> np.ndarray:
        marked = np.zeros(self.shape, dtype=bool)
        ij = np.floor((xy - self.lo) / self.cell).astype(int)
        marked[ij[:, 0], ij[:, 1]] = True
        return ndimage.distance_transform_edt(~marked) * self.cell <= reach + self.cell * 0.71  # + a cell's half diagonal

    def blocked(self, a: np.ndarray, map_a: np.ndarray, b: np.ndarray, map_b: np.ndarray) -> np.ndarray:
        """(P, Q) whether the straight step from each ``a`` (P, 3) on map ``map_a`` (P,) to each ``b``
        (Q, 3) on ``map_b`` leaves the free space of both maps somewhere between its ends (its points
        a cell apart; the ends themselves are where the poses are: not judged, nor with footprints the
        points within ``end_margin`` of them); all False when the walls are not known (on either map:
        no step of it is blocked)."""
        a, b = np.asarray(a, float)[:, :2], np.asarray(b, float)[:, :2]
        P, Q = len(a), len(b)
        if self.masks is None:
            return np.zeros((P, Q), dtype=bool)
        longest = float(np.max(np.linalg.norm(a[:, None] - b[None], axis=2))) if P and Q else 0.0
        n = int(np.ceil(longest / self.cell))
        if n < 2:
            return np.zeros((P, Q), dtype=bool)
        f = np.arange(1, n) / n  # interior points
        out = np.zeros((P, Q), dtype=bool)
        rows = max(1, MAX_SAMPLES // max(1, Q * len(f)))
        for s in range(0, P, rows):  # chunks of the previous frame's poses: memory bounded
            pts = a[s:s + rows, None, None] + f[None, None, :, None] * (b[None, :, None] - a[s:s + rows, None, None])
            ij = np.floor((pts - self.lo) / self.cell).astype(int)
            inside = np.all((ij >= 0) & (ij < np.array(self.shape)), axis=-1)
            ij = np.where(inside[..., None], ij, 0)
            ma = np.asarray(map_a)[s:s + rows, None, None]
            mb = np.asarray(map_b)[None, :, None]
            free = inside & (self.masks[ma, ij[..., 0], ij[..., 1]] | self.masks[mb, ij[..., 0], ij[..., 1]])
            free |= ~self.known[ma] | ~self.known[mb]  # a map whose walls are not known blocks nothing
            if self.end_margin:
                length = np.linalg.norm(b[None, :] - a[s:s + rows, None], axis=-1)[..., None]
                free |= (f * length < self.end_margin) | ((1 - f) * length < self.end_margin)
            out[s:s + rows] = ~free.all(-1)
        return out


def map_floors(m) -> np.ndarray:
    """The floors' heights (z) map ``m`` was built with (its config), else its lines' lowest end."""
    how = (m.config.get("translations") or {}) if isinstance(getattr(m, "config", None), dict) else {}
    floors = np.asarray(how.get("floors") or [], dtype=np.float64).reshape(-1)
    L = np.asarray(getattr(m, "lines_raw", m.lines), dtype=np.float64).reshape(-1, 2, 3)
    return floors if len(floors) or not len(L) else np.array([L[..., 2].min()])


def lattice_spacing(m) -> float | None:
    """The spacing (m) of map ``m``'s candidate translations when they are a lattice (``spacing``
    translations: a layout's rooms and doorways, a line map's free space), else None: a scan's octree
    candidates sample its free space unevenly (gaps of a metre in open space, none in doorways its
    scan saw closed), so their gaps tell no walls."""
    how = (m.config.get("translations") or {}) if isinstance(getattr(m, "config", None), dict) else {}
    if how.get("method") != "spacing" or not how.get("spacing"):
        return None
    return float(how["spacing"])


RISE_M = (0.1, 0.25)  # a stair's step: this much higher than the one before ...
RUN_M = (0.15, 0.45)  # ... and this far on (across its edge): shelves stand straight above each other
MIN_STEPS = 5  # steps in a run (fewer: furniture)
STEP_WIDTH_M = (0.5, 3.0)  # a step's edge: as long as a flight is wide
PARALLEL_DEG = 5.0
STAIR_REACH_M = 3.0  # a floor change within this of a stair's steps (xy) is on the stairs: its landings


def stair_points(lines: np.ndarray) -> np.ndarray:
    """(S, 2) xy of the stairs in 3D segments (N, 2, 3): the midpoints of the horizontal segments
    (:data:`STEP_WIDTH_M` long: a step's edge) that end a run of at least :data:`MIN_STEPS` parallel ones, each
    ``RISE_M`` above and ``RUN_M`` on from the one before (and overlapping it along its length). The
    pairs compared are the midpoints within one step of each other (memory bounded in the map's size)."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    d = L[:, 1] - L[:, 0]
    n = np.linalg.norm(d, axis=1)
    keep = (n >= STEP_WIDTH_M[0]) & (n <= STEP_WIDTH_M[1]) & (np.abs(d[:, 2]) < 0.05 * n)
    L, d, n = L[keep], d[keep], n[keep]
    if len(L) < MIN_STEPS:
        return np.zeros((0, 2))
    u = d[:, :2] / np.linalg.norm(d[:, :2], axis=1, keepdims=True)
    mid = L.mean(1)
    pairs = spatial.cKDTree(mid).query_pairs(float(np.hypot(RISE_M[1], RUN_M[1])) + 0.5 * float(n.max()),
                                             output_type="ndarray")
    i, j = np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]]  # both ways: i below j
    off, dz = mid[j, :2] - mid[i, :2], mid[j, 2] - mid[i, 2]
    along = np.abs(np.einsum("ek,ek->e", u[i], off))
    across = np.abs(np.einsum("ek,ek->e", u[i, ::-1] * np.array([1.0, -1.0]), off))
    step = ((np.abs(np.einsum("ek,ek->e", u[i], u[j])) > np.cos(np.radians(PARALLEL_DEG)))
            & (dz >= RISE_M[0]) & (dz <= RISE_M[1]) & (across >= RUN_M[0]) & (across <= RUN_M[1])
            & (along < 0.5 * n[i]))
    i, j = i[step], j[step]
    run = np.ones(len(L))  # steps in the longest run ending at each segment
    for _ in range(MIN_STEPS):
        nxt = run.copy()
        np.maximum.at(nxt, j, run[i] + 1)
        run = nxt
    return mid[run >= MIN_STEPS, :2]


def near_any(p: np.ndarray, q: np.ndarray, reach: float = STAIR_REACH_M) -> np.ndarray:
    """(P,) whether each point ``p`` (P, >= 2) stands within ``reach`` (xy) of any of ``q`` (S, 2)."""
    if not len(q):
        return np.zeros(len(p), dtype=bool)
    return np.linalg.norm(np.asarray(p, float)[:, None, :2] - q[None], axis=2).min(1) <= reach
