"""Where a synthetic walk goes (``ldlmap synth --walk``): a person carrying a 360 camera.

A *walk space* is rooms joined by doors (a building's floor; elsewhere one room). Its free space
is a 0.1 m grid of the floor plan (:func:`free_grid`): cells inside a room or a door's passage
through the wall, :data:`CLEARANCE` from every surface at hip and eye height (walls, door jambs,
sloped ceilings) and :data:`OBJECT_MARGIN` outside every object's footprint (furniture, stair
steps). Between waypoints the path is the shortest one on that grid, weighted to keep away from
the walls, then pulled straight wherever the grid has a line of sight (:func:`grid_path`), so it
goes through doors and down corridors and never through a wall. It is sampled with steps drawn in
[0.5, 1.5] x the walk's step (:func:`sample_path`); where a step's chord would leave the free space
(a corner), the corner itself becomes a frame. No frame stands in a doorway (a closed door's panel
is there) unless the walk is a video whose doors stand open: it walks on through them frame by frame.
Heights: one eye height per walk in :data:`EYE_HEIGHT` with a 2 cm bounce; tilts of :data:`TILT_DEG`;
the camera's yaw follows the walking direction (a video's turning at most :data:`MAX_TURN_DEG` a frame).
A building's stairwell is climbed as far as its ceiling lets the camera go
(:func:`stair_climb`), then the walk goes on in the next floor's stairwell where the flight from
below arrives (:func:`stair_arrival`): the floors are closed solids, so that stretch is a jump,
marked in the ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import rotation_from_axis_angle
from ldlmap.core.lazy import lazy_module
from ldlmap.core.polygon import distance_to_boundary, points_in_polygon
from ldlmap.synth.poses import clear_of_objects, object_hulls
from ldlmap.synth.render import Renderer
from ldlmap.synth.scene import build_scene
from ldlmap.synth.spec import SceneSpec
from ldlmap.synth.types import SceneMesh

sparse = lazy_module("scipy.sparse")
csgraph = lazy_module("scipy.sparse.csgraph")

GRID_M = 0.1  # free-space grid cell, m
CLEARANCE = 0.3  # m from every surface (at hip and eye height)
OBJECT_MARGIN = 0.15  # m outside every object's footprint
HIP_M = 1.0  # m above the floor: the lower height the clearance is checked at
EYE_HEIGHT = (1.5, 1.7)  # m, the walk's camera height above the floor (one draw per walk)
BOUNCE_M = 0.02  # m, the walking bounce of the camera
TILT_DEG = (1.0, 3.0)  # tilt of the camera's up axis from the vertical
MAX_TURN_DEG = 30.0  # a video's camera turns at most this per frame (150 deg/s at 5 frames a second: a walker
# turns round in a second and more; the walking direction reverses in one frame at a room's far end)
STEP_RANGE = (0.5, 1.5)  # a step is drawn in this range times the walk's step
WALL_WEIGHT = 0.3  # m: grid edges cost length x (1 + WALL_WEIGHT / clearance): paths keep off walls


@dataclass(frozen=True, eq=False)
class WalkRoom:
    """One room a walk may enter: its spec as rendered (own frame, floor at z = 0) and where it stands."""

    id: str
    scene: str  # the OmniScenes scene whose folders its frames go to
    spec: SceneSpec
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world position of the spec's origin
    floor: int | None = None  # buildings: the floor
    kind: str | None = None  # buildings: office, hotel, room, corridor, stairwell
    passages: tuple[np.ndarray, ...] = ()  # (4, 2) world xy rectangles through its doors to rooms of its space
    doors: tuple[int, ...] = ()  # its openings that are those doors: open in the frames of a walk whose doors are ...
    reveal_m: float = 0.0  # ... their reveal this deep into the wall (half the wall between two rooms)

    def footprint(self) -> np.ndarray:
        """The footprint in world xy."""
        return np.asarray(self.spec.footprint, dtype=np.float64) + np.asarray(self.offset[:2], dtype=np.float64)

    @property
    def z(self) -> float:
        return float(self.offset[2])


class BuiltRooms:
    """Meshes and renderers of walk rooms, built once per spec (identical rooms share them)."""

    def __init__(self) -> None:
        self._built: dict[SceneSpec, tuple[SceneMesh, Renderer]] = {}
        self._open: dict[tuple, Renderer] = {}  # (spec, doors, reveal): the room with its doors open

    def get(self, spec: SceneSpec) -> tuple[SceneMesh, Renderer]:
        if spec not in self._built:
            mesh = build_scene(spec)
            self._built[spec] = (mesh, Renderer(mesh))
        return self._built[spec]

    def opened(self, room: WalkRoom) -> Renderer:
        """The renderer of ``room`` with its doors open (:attr:`WalkRoom.doors`)."""
        key = (room.spec, room.doors, room.reveal_m)
        if key not in self._open:
            self._open[key] = Renderer(build_scene(room.spec, open_doors=room.doors, reveal_m=room.reveal_m))
        return self._open[key]

    def seen_from(self, room: WalkRoom, space: list[WalkRoom], doors_open: bool) -> list[tuple[Renderer, np.ndarray]]:
        """What a frame in ``room`` renders (each renderer with the world position of its mesh's origin):
        with ``doors_open``, the room and through its doors the rooms of its ``space`` that have doors;
        else, or where it has no door, the room alone as the scans see it."""
        if not (doors_open and room.doors):
            return [(self.get(room.spec)[1], np.asarray(room.offset, dtype=np.float64))]
        return [(self.opened(r), np.asarray(r.offset, dtype=np.float64))
                for r in [room] + [r for r in space if r is not room and r.doors]]


@dataclass
class FreeGrid:
    """A walk space's free floor cells: ``free[i, j]`` at world xy ``origin + (j, i) * GRID_M``."""

    origin: np.ndarray  # (2,)
    free: np.ndarray  # (ny, nx) bool
    clearance: np.ndarray  # (ny, nx) distance (m) to the nearest surface (inf outside)
    z: float  # the space's floor level
    touch: np.ndarray | None = None  # (ny, nx) inside a room or passage and outside every object (chords)
    walls: tuple = ()  # (P (E, 2), Q (E, 2), doors (D, 3): edge, start, end along it): :func:`crosses_wall`
    doorway: np.ndarray | None = None  # (ny, nx) free only as a door's passage (no photo there)
    labels: np.ndarray | None = None  # (ny, nx) connected component of each free cell (-1: not free)
    graph: object = None  # scipy CSR graph of the free cells (:func:`_graph`)
    index: np.ndarray | None = None  # (ny, nx) node of each free cell (-1: not free)

    def cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.rint((np.atleast_2d(xy)[:, :2] - self.origin) / GRID_M).astype(np.int64)
        ny, nx = self.free.shape
        return np.clip(ij[:, 1], 0, ny - 1), np.clip(ij[:, 0], 0, nx - 1)

    def xy(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return self.origin + np.column_stack([cols, rows]) * GRID_M

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        r, c = self.cell(xy)
        return self.free[r, c]

    def in_doorway(self, xy: np.ndarray) -> np.ndarray:
        r, c = self.cell(xy)
        return self.doorway[r, c]

    def nearest_free(self, xy: np.ndarray, component: int | None = None) -> np.ndarray:
        """The free cell centre nearest to ``xy`` (in ``component`` when given)."""
        ok = (self.free if component is None else self.labels == component) & ~self.doorway
        rows, cols = np.nonzero(ok)
        if not len(rows):
            raise InputError("a walk found no free floor: the rooms are too small or too cluttered to walk through")
        pts = self.xy(rows, cols)
        return pts[int(np.argmin(np.linalg.norm(pts - np.asarray(xy)[:2], axis=1)))]


def free_grid(rooms: list[WalkRoom], built: BuiltRooms) -> FreeGrid:
    """The free space of a walk space (see the module docstring), with its connected components.
    A door is a closed panel in a closed room: the cells of its passage are free however near the
    panel (``doorway``: the walk goes through, but takes no photo there)."""
    fps = [r.footprint() for r in rooms]
    allp = np.concatenate(fps)
    lo, hi = allp.min(0) - GRID_M, allp.max(0) + GRID_M
    xs, ys = np.arange(lo[0], hi[0], GRID_M), np.arange(lo[1], hi[1], GRID_M)
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    inside, passage = np.zeros(len(xy), dtype=bool), np.zeros(len(xy), dtype=bool)
    for poly in fps:
        inside |= points_in_polygon(xy, poly)
    for poly in (p for r in rooms for p in r.passages):
        passage |= points_in_polygon(xy, poly)
    ok, dist = inside | passage, np.full(len(xy), np.inf)
    touch = ok.copy()  # clear of the objects themselves (no margin): what a step's chord may cross
    for r, fp in zip(rooms, fps):
        mesh, rend = built.get(r.spec)
        sel = ok & np.all((xy > fp.min(0) - CLEARANCE - GRID_M) & (xy < fp.max(0) + CLEARANCE + GRID_M), axis=1)
        local = xy[sel] - np.asarray(r.offset[:2])
        hulls = object_hulls(mesh)
        touch[sel] &= clear_of_objects(local, hulls, 0.0)
        ok[sel] &= clear_of_objects(local, hulls, OBJECT_MARGIN)
        for h in (HIP_M, EYE_HEIGHT[1] + BOUNCE_M):
            d = rend.distance(np.column_stack([local, np.full(len(local), h)]))
            dist[sel] = np.minimum(dist[sel], d)
    shape = (len(ys), len(xs))
    roomy = ok & inside & (dist >= CLEARANCE)
    grid = FreeGrid(origin=lo.copy(), free=(roomy | (ok & passage)).reshape(shape),
                    clearance=np.maximum(dist, CLEARANCE).reshape(shape), z=min(r.z for r in rooms),
                    doorway=(ok & passage & ~roomy).reshape(shape),
                    touch=(touch & (inside | passage)).reshape(shape), walls=_walls(rooms))
    grid.graph, grid.index = _graph(grid)
    labels = np.full(shape, -1)
    if grid.graph.shape[0]:
        labels[grid.free] = csgraph.connected_components(grid.graph, directed=False)[1]
    grid.labels = labels
    return grid


def _walls(rooms: list[WalkRoom]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rooms' walls (footprint edges, world xy) and their doors' spans along them."""
    P, Q, doors = [], [], []
    for r in rooms:
        fp = r.footprint()
        base = sum(len(p) for p in P)
        P.append(fp)
        Q.append(np.roll(fp, -1, axis=0))
        doors += [(base + o.wall, o.offset, o.offset + o.width) for o in r.spec.openings if o.kind == "door"]
    return np.concatenate(P), np.concatenate(Q), np.asarray(doors, dtype=np.float64).reshape(-1, 3)


def crosses_wall(walls: tuple, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the xy segment ``a``-``b`` crosses a wall of ``walls`` (:func:`_walls`) outside its doors."""
    P, Q, doors = walls
    d1, d2 = np.asarray(b, dtype=np.float64)[:2] - np.asarray(a, dtype=np.float64)[:2], Q - P
    w = P - np.asarray(a, dtype=np.float64)[:2]
    den = d1[0] * d2[:, 1] - d1[1] * d2[:, 0]
    par = np.abs(den) < 1e-12
    den = np.where(par, 1.0, den)
    t = (w[:, 0] * d2[:, 1] - w[:, 1] * d2[:, 0]) / den
    u = (w[:, 0] * d1[1] - w[:, 1] * d1[0]) / den
    for e in np.nonzero(~par & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1))[0]:
        along = u[e] * np.linalg.norm(d2[e])
        mine = doors[doors[:, 0] == e]
        if not np.any((mine[:, 1] <= along) & (along <= mine[:, 2])):
            return True
    return False


def _graph(grid: FreeGrid):
    """The 8-connected graph of the free cells, edges weighted to keep off the walls; and the cell -> node index."""
    index = np.full(grid.free.shape, -1, dtype=np.int64)
    index[grid.free] = np.arange(int(grid.free.sum()))
    ny, nx = grid.free.shape
    rows, cols, weights = [], [], []
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):  # each undirected edge once
        sa = (slice(0, ny - di), slice(max(0, -dj), nx - max(0, dj)))
        sb = (slice(di, ny), slice(max(0, dj), nx - max(0, -dj)))
        a, b = index[sa], index[sb]
        both = (a >= 0) & (b >= 0)
        near = np.minimum(grid.clearance[sa][both], grid.clearance[sb][both])
        rows.append(a[both])
        cols.append(b[both])
        weights.append(GRID_M * math.hypot(di, dj) * (1.0 + WALL_WEIGHT / near))
    n = int(grid.free.sum())
    g = sparse.coo_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    return g.tocsr(), index


# ------------------------------------------------------------------------------------ paths


def line_of_sight(grid: FreeGrid, a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> bool:
    """Whether the straight xy segment from ``a`` to ``b`` stays on ``mask``'s cells (default: the free
    ones), sampled every half cell."""
    a, b = np.asarray(a, dtype=np.float64)[:2], np.asarray(b, dtype=np.float64)[:2]
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / (GRID_M / 2))) + 1)
    r, c = grid.cell(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    return bool((grid.free if mask is None else mask)[r, c].all())


def grid_path(grid: FreeGrid, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The walk from free point ``a`` to free point ``b`` (xy, on one component): the cheapest grid
    path (:func:`_graph`), pulled straight where the grid has a line of sight; (M, 2) xy."""
    (ra,), (ca,) = grid.cell(a)
    (rb,), (cb,) = grid.cell(b)
    na, nb = int(grid.index[ra, ca]), int(grid.index[rb, cb])
    if na < 0 or nb < 0:
        raise InputError("a walk's waypoint is not on the free floor")
    _, pred = csgraph.dijkstra(grid.graph, directed=False, indices=na, return_predecessors=True)
    nodes = [nb]
    while nodes[-1] != na:
        if pred[nodes[-1]] < 0:
            raise InputError("a walk cannot get from one of its waypoints to the next: no free path through the doors")
        nodes.append(int(pred[nodes[-1]]))
    rows, cols = np.nonzero(grid.free)
    pts = grid.xy(rows[nodes[::-1]], cols[nodes[::-1]])
    keep, i = [0], 0
    while i < len(pts) - 1:  # string pulling: the farthest point still in sight
        j = i + 1
        while j + 1 < len(pts) and line_of_sight(grid, pts[i], pts[j + 1]):
            j += 1
        keep.append(j)
        i = j
    return pts[keep]


def _along(poly: np.ndarray, cum: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points at arc lengths ``s`` along the polyline (cumulative lengths ``cum``) and their segments."""
    seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(poly) - 2)
    frac = (s - cum[seg]) / np.maximum(cum[seg + 1] - cum[seg], 1e-12)
    return poly[seg] + frac[:, None] * (poly[seg + 1] - poly[seg]), seg


def _past_doorway(nxt: float, last: float, hi: float, blocked: np.ndarray, fine: np.ndarray) -> tuple[float, bool]:
    """A frame drawn at arc length ``nxt`` in a doorway moves past it when the step stays within ``hi``,
    else stops before it; when neither can be, it moves past it in one longer step (flagged)."""
    k = int(np.searchsorted(fine, nxt))
    if k >= len(blocked) or not blocked[k]:
        return nxt, False
    after = float(fine[k + int(np.argmin(blocked[k:]))])
    before = fine[:k][~blocked[:k]]
    before = float(before[-1]) if len(before) else last
    if after - last <= hi:
        return after, False
    if before > last + 1e-6:
        return before, False
    return after, True


def sample_path(poly: np.ndarray, step: float, rng: np.random.Generator, grid: FreeGrid,
                objects: bool = True, doorways: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Frames (N, 3) along the 3D polyline ``poly``, its ends the first and last, steps of
    ``STEP_RANGE`` x ``step`` along it, none in a doorway (:func:`_past_doorway`) unless ``doorways``
    (its doors stand open), and whether each was reached across a doorway longer than a step. A step
    whose straight chord would cross a wall outside a door, or (``objects``: a video's) an object, ends
    at the farthest point of the path it can see instead (a tour's photographer walks round the
    furniture between two photos)."""
    poly = np.asarray(poly, dtype=np.float64)
    if len(poly) == 1:
        return poly.copy(), np.zeros(1, dtype=bool)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])
    total = float(cum[-1])
    fine = np.arange(0.0, total + 0.05, 0.05)
    # where no frame may stand: a doorway, unless its doors stand open
    blocked = np.zeros(len(fine), dtype=bool) if doorways else grid.in_doorway(_along(poly, cum, fine)[0][:, :2])
    corner_ok = np.ones(len(poly), dtype=bool) if doorways else ~grid.in_doorway(poly[:, :2])
    floor_z = float(poly[0, 2]) + 1e-6

    def clear(a: float, b: float) -> bool:  # a stair climb is straight
        (pa, pb), _ = _along(poly, cum, np.array([a, b]))
        return max(pa[2], pb[2]) > floor_z or ((not objects or line_of_sight(grid, pa, pb, grid.touch))
                                                and not crosses_wall(grid.walls, pa, pb))

    s, door = [0.0], [False]
    while s[-1] < total - 1e-6:
        nxt = min(total, s[-1] + step * rng.uniform(*STEP_RANGE))
        nxt, flag = _past_doorway(nxt, s[-1], step * STEP_RANGE[1], blocked, fine)
        if not clear(s[-1], nxt):  # the farthest point it sees (else the nearest)
            corner = cum[(cum > s[-1] + 1e-6) & (cum < nxt) & corner_ok]
            cands = np.sort(np.concatenate([fine[(fine > s[-1] + 1e-6) & (fine < nxt) & ~blocked], corner]))[::-1]
            nxt = next((float(c) for c in cands if clear(s[-1], c)), float(cands[-1]) if len(cands) else nxt)
            flag = False
        s.append(nxt)
        door.append(flag)
    return _along(poly, cum, np.asarray(s))[0], np.asarray(door)


def turn_limited(angle: np.ndarray, most: float) -> np.ndarray:
    """Angles (radians, unwrapped) turning at most ``most`` per frame: limited forwards and backwards, the
    two averaged (a turn starts a little before the corner and ends a little after it)."""
    def limited(a: np.ndarray) -> np.ndarray:
        out = a.copy()
        for k in range(1, len(a)):  # a walk's frames: hundreds, once per walk
            out[k] = out[k - 1] + np.clip(a[k] - out[k - 1], -most, most)
        return out

    return 0.5 * (limited(angle) + limited(angle[::-1])[::-1])


def walk_rotations(pos: np.ndarray, rng: np.random.Generator, smooth: bool) -> np.ndarray:
    """World->camera rotations (N, 3, 3) of one leg of a walk: the yaw follows the walking direction
    (``smooth``, a video: averaged over about 1 m, turning at most :data:`MAX_TURN_DEG` a frame, slowly
    wandering; else with 10 deg of noise), the up axis tilted by ``TILT_DEG`` (a video: drifting
    smoothly; a tour: drawn per frame)."""
    n = len(pos)
    d = np.gradient(pos[:, :2], axis=0) if n > 1 else np.array([[1.0, 0.0]])
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    k = np.arange(n)
    heading = np.arctan2(u[:, 1], u[:, 0])
    if smooth:
        heading = np.convolve(np.pad(np.unwrap(heading), 2, mode="edge"), np.ones(5) / 5.0, "valid")
        heading = turn_limited(heading, np.radians(MAX_TURN_DEG))
        noise = np.radians(3.0) * np.sin(0.21 * k + rng.uniform(0, 2 * np.pi))
        tilt = np.radians(2.0 + np.sin(0.13 * k + rng.uniform(0, 2 * np.pi)))
        azimuth = rng.uniform(0, 2 * np.pi) + 0.05 * k
    else:
        noise = np.radians(rng.normal(0.0, 10.0, n))
        tilt = np.radians(rng.uniform(*TILT_DEG, n))
        azimuth = rng.uniform(0, 2 * np.pi, n)
    yaw = heading + rng.uniform(0, 2 * np.pi) + noise
    z = np.array([0.0, 0.0, 1.0])
    return np.stack([(rotation_from_axis_angle(z, float(y))
                      @ rotation_from_axis_angle(np.array([np.cos(a), np.sin(a), 0.0]), float(t))).T
                     for y, t, a in zip(yaw, tilt, azimuth)])


# ----------------------------------------------------------------------------------- stairs


def _flights(room: WalkRoom) -> tuple[list, list]:
    """A stairwell's steps (world x, y, top): the flight up from its floor (east, by x) and the
    flight further up (the other side: its highest step is where the flight from below arrives)."""
    boxes = [o for o in room.spec.objects if o.kind == "box"]
    if not boxes:
        return [], []
    lowest = min(boxes, key=lambda o: o.size[2])
    cy = float(np.mean(np.asarray(room.spec.footprint, dtype=np.float64)[:, 1]))
    ox, oy = float(room.offset[0]), float(room.offset[1])
    up = sorted((o.center[0] + ox, o.center[1] + oy, o.size[2], o.size[0]) for o in boxes
                if abs(o.center[1] - lowest.center[1]) < 1e-6)
    other = [(o.center[0] + ox, o.center[1] + oy, o.size[2], o.size[0]) for o in boxes
             if (o.center[1] - cy) * (lowest.center[1] - cy) < 0 and abs(o.center[1] - cy) > 0.5]
    return up, other


def stair_climb(room: WalkRoom, grid: FreeGrid, eye: float) -> np.ndarray:
    """The climb (K, 3) in a stairwell: from the foot of its flight up, step by step, as high as its
    ceiling lets the camera go (``CLEARANCE`` below it); the foot alone when there are no steps."""
    up, _ = _flights(room)
    if not up:
        foot = grid.nearest_free(room.footprint().mean(0))
        return np.array([[foot[0], foot[1], room.z + eye]])
    x0, y, _, depth = up[0]
    foot = grid.nearest_free(np.array([x0 - depth / 2 - 0.45, y]))
    pts = [[foot[0], foot[1], room.z + eye], [x0 - depth / 2 - 0.05, y, room.z + eye]]
    for x, yy, top, _ in up:
        if top + eye + CLEARANCE > room.spec.ceiling_height:
            break
        pts.append([x, yy, room.z + top + eye])
    return np.asarray(pts)


def stair_arrival(room: WalkRoom, grid: FreeGrid) -> np.ndarray:
    """Where the flight from the floor below arrives in stairwell ``room`` (xy, a free cell): west of
    the highest step of its second flight, on the floor (the centre when it has no steps)."""
    _, other = _flights(room)
    if not other:
        return grid.nearest_free(room.footprint().mean(0))
    x, y, _, depth = max(other, key=lambda s: s[2])
    return grid.nearest_free(np.array([x - depth / 2 - 0.5, y]))


# ----------------------------------------------------------------------------------- routes


def _room_cells(grid: FreeGrid, room: WalkRoom, component: int) -> np.ndarray:
    """Free cells (xy) of ``component`` inside ``room``'s footprint."""
    rows, cols = np.nonzero(grid.labels == component)
    pts = grid.xy(rows, cols)
    return pts[points_in_polygon(pts, room.footprint())]


def loop_route(room: WalkRoom, grid: FreeGrid, rng: np.random.Generator) -> list[np.ndarray]:
    """Waypoints of a loop around one room: 3-6 well-spread free points (one per 5 m^2 of free floor)
    in the largest free component, in order around their middle, back to the first."""
    comps = grid.labels[grid.labels >= 0]
    if not len(comps):
        raise InputError(f"a walk found no free floor in {room.id}: the room is too small or too cluttered")
    cells = _room_cells(grid, room, int(np.bincount(comps).argmax()))
    k = int(np.clip(round(len(cells) * GRID_M ** 2 / 5.0), 3, 6))
    chosen = [int(rng.integers(len(cells)))]
    dist = np.linalg.norm(cells - cells[chosen[0]], axis=1)
    for _ in range(k - 1):  # farthest points
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(cells - cells[chosen[-1]], axis=1))
    pts = cells[chosen]
    mid = pts.mean(0)
    order = np.argsort(np.arctan2(pts[:, 1] - mid[1], pts[:, 0] - mid[0]))
    order = np.roll(order, -int(rng.integers(len(order))))
    return [pts[i] for i in order] + [pts[order[0]]]


def visited_rooms(rooms: list[WalkRoom], rng: np.random.Generator, visits: int,
                  near: np.ndarray | None = None) -> list[WalkRoom]:
    """The rooms off a floor's corridor that its walk enters: one of each kind first (office, hotel
    room, room of its own), then others, ``visits`` in all; with ``near`` (xy: a floor the walk
    crosses from stairwell to stairwell) each drawn from the two of its kind nearest to it."""
    pool = [r for r in rooms if r.kind not in ("corridor", "stairwell")]
    if near is not None:
        pool.sort(key=lambda r: float(np.linalg.norm(r.footprint().mean(0) - near)))
    chosen: list[WalkRoom] = []
    for kind in ("office", "hotel", "room"):
        of_kind = [r for r in pool if r.kind == kind and r not in chosen][:2 if near is not None else None]
        if of_kind and len(chosen) < visits:
            chosen.append(of_kind[int(rng.integers(len(of_kind)))])
    rest = [r for r in pool if r not in chosen][:2 * visits if near is not None else None]
    extra = rng.permutation(len(rest))[:max(0, visits - len(chosen))]
    return chosen + [rest[int(i)] for i in extra]


def floor_route(rooms: list[WalkRoom], grid: FreeGrid, rng: np.random.Generator, visits: int,
                start: np.ndarray | None, through: bool = False) -> list[np.ndarray]:
    """Waypoints of a floor's walk: from ``start`` (default: the corridor's west end) into each visited
    room (two points in it: near its middle, then another at least 1 m away) and back out, nearest
    first; ``through`` (the walk arrived by the stairs and leaves by them): rooms near ``start``."""
    corridor = next(r for r in rooms if r.kind == "corridor")
    if start is None:
        fp = corridor.footprint()
        start = grid.nearest_free(np.array([fp[:, 0].min() + 0.6, fp[:, 1].mean()]))
    (r0,), (c0,) = grid.cell(start)
    comp = int(grid.labels[r0, c0])
    route = [np.asarray(start, dtype=np.float64)]
    picked = visited_rooms(rooms, rng, visits, np.asarray(start) if through else None)
    chosen = sorted(picked, key=lambda r: abs(r.footprint()[:, 0].mean() - start[0]))
    for room in chosen:
        cells = _room_cells(grid, room, comp)
        if not len(cells):
            continue  # no free way in: the walk passes it by
        a = cells[int(np.argmin(np.linalg.norm(cells - room.footprint().mean(0), axis=1)))]
        far = cells[np.linalg.norm(cells - a, axis=1) >= 1.0]
        route += [a] + ([far[int(rng.integers(len(far)))]] if len(far) else [])
    return route


# ------------------------------------------------------------------------------------ walks


@dataclass(frozen=True, eq=False)
class WalkPose:
    """One frame of a walk: pose (R world->camera, t the centre, world), where it stands, and
    ``jump``: how the walk got here from the previous frame when it did not walk (``stairs``: up a
    stairwell the renderer cannot show; ``cut``: into a room no door leads to; ``door``: through a
    doorway longer than a step, where the closed door's panel leaves no photo to take), else None."""

    R: np.ndarray
    t: np.ndarray
    room: WalkRoom
    jump: str | None = None


def room_of(rooms: list[WalkRoom], xyz: np.ndarray) -> WalkRoom:
    """The room holding point ``xyz`` (its footprint, floor to ceiling), else the nearest on its level
    (a camera in a doorway, between two rooms' walls)."""
    p = np.asarray(xyz, dtype=np.float64)
    level = [r for r in rooms if r.z - 1e-6 <= p[2] <= r.z + r.spec.ceiling_height + 1e-6] or rooms
    for r in level:
        if points_in_polygon(p[None, :2], r.footprint())[0]:
            return r
    return min(level, key=lambda r: float(distance_to_boundary(p[None, :2], r.footprint())[0]))


def plan_walk(spaces: list[list[WalkRoom]], step: float, rng: np.random.Generator, built: BuiltRooms,
              smooth: bool = False, visits: int = 3, doorways: bool = False) -> list[WalkPose]:
    """A walk through ``spaces`` in order (each a list of rooms joined by doors): a loop in a room
    alone, a floor's tour (:func:`floor_route`) in a space with a corridor, up its stairwell when the
    next space is the floor above (:func:`stair_climb`); frames every ``step`` metres on average
    (``smooth``: a video's orientations; ``doorways``: frames may stand in its open doorways)."""
    if not spaces or not all(spaces):
        raise InputError("a walk needs at least one room")
    eye = float(rng.uniform(*EYE_HEIGHT))
    out: list[WalkPose] = []
    start, jump = None, None
    grids = [free_grid(rooms, built) for rooms in spaces]
    for si, (rooms, grid) in enumerate(zip(spaces, grids)):
        corridor = any(r.kind == "corridor" for r in rooms)
        nxt = spaces[si + 1] if si + 1 < len(spaces) else []
        stairs = [r for r in rooms if r.kind == "stairwell"]
        climb = bool(corridor and stairs and any(r.kind == "stairwell" for r in nxt))
        if corridor:
            route = floor_route(rooms, grid, rng, visits, start, through=climb and start is not None)
        else:
            route = loop_route(rooms[0], grid, rng)
        tail = stair_climb(stairs[0], grid, eye) if climb else np.zeros((0, 3))
        if len(tail):
            route.append(tail[0, :2])
        legs = [grid_path(grid, a, b) for a, b in zip(route[:-1], route[1:])] or [np.asarray(route[:1])]
        xy = np.concatenate([legs[0]] + [g[1:] for g in legs[1:]])
        poly = np.column_stack([xy, np.full(len(xy), grid.z + eye)])
        poly = np.concatenate([poly, tail[1:]]) if len(tail) else poly
        pos, door = sample_path(poly, step, rng, grid, objects=smooth, doorways=doorways)
        pos[:, 2] += BOUNCE_M * np.sin(rng.uniform(0, 2 * np.pi) + np.arange(len(pos)) * 2.1)
        for k, (R, t) in enumerate(zip(walk_rotations(pos, rng, smooth), pos)):
            out.append(WalkPose(R=R, t=t, room=room_of(rooms, t), jump=jump if k == 0 else ("door" if door[k] else None)))
        start, jump = (stair_arrival(next(r for r in nxt if r.kind == "stairwell"), grids[si + 1]), "stairs") \
            if climb else (None, "cut")
    return out
