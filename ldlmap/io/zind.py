"""Zillow Indoor Dataset (ZInD) homes: ground-truth poses and line maps from room layouts.

A home as distributed (``<root>/<home>/zind_data.json`` and ``<root>/<home>/panos/*.jpg``)::

    merger -> floor_XX -> complete_room_YY -> partial_room_ZZ -> pano_N -> {
        layout_raw | layout_complete | layout_visible: {vertices, doors, windows, openings, internal},
        floor_plan_transformation: {translation [2], rotation (deg), scale},
        camera_height (= 1: the unit of the local frame), ceiling_height, is_primary, is_inside,
        is_ceiling_flat, image_path, label, ...}
    scale_meters_per_coordinate: {floor_XX: metres per floor-plan unit}

**Local frame of a panorama.** Camera at the origin, lengths in units of the camera height
``c`` (``camera_height``, 1 in practice): the floor at ``z = -c``, the ceiling at
``z = ceiling_height - c``. ``vertices`` is the (V, 2) wall polygon; ``doors``, ``windows`` and
``openings`` are flat lists whose consecutive triples are one element
``[left_xy, right_xy, [z_bottom, z_top]]``. ZInD's pixel of a local point ``p``: azimuth
``atan2(-x, y)`` at ``u = (azimuth + pi) / (2 pi) W``, elevation ``asin(z / |p|)`` at
``v = (1 - (elevation + pi / 2) / pi) H``.

**Floor plan.** ``g = s (p_xy @ M) + T`` with ``M = [[cos a, sin a], [-sin a, cos a]]``
(``a`` = rotation in radians, ``s`` = scale, ``T`` = translation), i.e. ``g = s Rz(a) p + T``
with ``Rz`` the counter-clockwise rotation; metres = ``g * m`` with ``m`` the floor's
``scale_meters_per_coordinate``.

**Our world frame (the mirror).** Equating ZInD's pixel with ours (``ldlmap.core.geometry``: image
centre along camera +x, ``u / W = 1 - (atan2(y, x) + pi) / (2 pi)``) gives the camera-frame
direction of a local point as ``(y, x, z)``: a swap of x and y, a reflection. The local frame
(and the floor plan built from it by rotations) is therefore left-handed with respect to a
camera frame, so the world frame mirrors the floor plan's y axis::

    X = (m g_x, -m g_y, m s (z + c))          metres, z up, floor at z = 0
    R = P Rz(a)^T F,   t = (m T_x, -m T_y, m s c)

with ``P`` the swap of x and y and ``F = diag(1, -1, 1)``: ``det R = (-1)(+1)(-1) = +1``, a
proper rotation, and ``p_cam = R (X - t)`` is proportional to ``P p`` for every local point
``p``. The camera stands ``m s c`` metres above the floor (about 1.4 m in ZInD).

**Rooms.** Several panoramas (partial rooms) may share one complete room; each carries the
complete room's layout in its own frame. A room's polygon, ceiling height, doors, windows,
openings and internal walls come from the first panorama of the room in the JSON (the first
primary one when some are not primary) that has ``layout_complete``; the others agree with it
(:attr:`ZindRoom.spread` says by how much; docs/measurements.md#zind-layouts). The ceiling counts
as flat only when every panorama of the room says so (one vaulted partial room would put false
ceiling edges around the whole room).

**Lines of a layout** (:func:`room_lines`, metres): one vertical per wall corner (floor to
ceiling), floor edges along every wall except where an opening spans it (no wall meets the
floor there), ceiling edges when the ceiling is flat, and each element as its frame: two
verticals and the top edge (the top of an opening that reaches the ceiling is the ceiling edge
already and is skipped), plus the bottom edge for windows (a door's bottom lies on the floor
edge). ``internal`` walls (polylines of free-standing wall pieces, e.g. a partition's outline)
give floor edges and a vertical at every polyline vertex; their height is not annotated, so
they get no top edges (a wall stub may stop below the ceiling) and their verticals run floor to
ceiling only when the ceiling is flat (then they are true wall corners of a full-height
partition, which is what ZInD annotates as internal walls: docs/measurements.md#zind-layouts).
Vertices of one internal outline closer than 0.15 m share one vertical: the outline runs
around a wall about 0.1 m thick, whose two faces would otherwise give doubled corners.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.polygon import self_intersection, signed_area

ZIND_JSON = "zind_data.json"
ELEMENT_KINDS: tuple[str, ...] = ("doors", "windows", "openings")
LINE_KINDS: tuple[str, ...] = ("corner", "floor", "ceiling", "door", "window", "opening", "internal")
_SWAP_XY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
_MIRROR_Y = np.diag([1.0, -1.0, 1.0])
_CEILING_TOL = 0.02  # metres: an opening top this close to a flat ceiling is the ceiling edge
_INTERNAL_MERGE = 0.15  # metres: internal-wall vertices closer than this share one vertical


# ------------------------------------------------------------------------------------ records


@dataclass(frozen=True)
class Placement:
    """A panorama's ``floor_plan_transformation`` with its floor's metres per coordinate."""

    translation: tuple[float, float]
    rotation_deg: float
    scale: float
    meters_per_coordinate: float
    camera_height: float = 1.0  # local units (ZInD: 1)

    @property
    def unit(self) -> float:
        """Metres per local unit (``s m``)."""
        return self.scale * self.meters_per_coordinate

    def world_from_local(self, p: np.ndarray) -> np.ndarray:
        """World points (..., 3) in metres (z up, floor at 0) of local points (..., 3)."""
        p = np.asarray(p, dtype=np.float64)
        a = math.radians(self.rotation_deg)
        c, s = math.cos(a), math.sin(a)
        gx = self.scale * (c * p[..., 0] - s * p[..., 1]) + self.translation[0]
        gy = self.scale * (s * p[..., 0] + c * p[..., 1]) + self.translation[1]
        m = self.meters_per_coordinate
        return np.stack([m * gx, -m * gy, self.unit * (p[..., 2] + self.camera_height)], axis=-1)

    def world_xy(self, xy: np.ndarray) -> np.ndarray:
        """World xy (..., 2) in metres of local xy (..., 2)."""
        xy = np.asarray(xy, dtype=np.float64)
        return self.world_from_local(np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], -1))[..., :2]

    def world_z(self, z_local: np.ndarray | float) -> np.ndarray:
        """World height (metres above the floor) of local heights."""
        return self.unit * (np.asarray(z_local, dtype=np.float64) + self.camera_height)

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` in our convention: ``p_cam = R (X - t)``, R proper, t in metres."""
        a = math.radians(self.rotation_deg)
        c, s = math.cos(a), math.sin(a)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        R = _SWAP_XY @ Rz.T @ _MIRROR_Y
        m = self.meters_per_coordinate
        t = np.array([m * self.translation[0], -m * self.translation[1], self.unit * self.camera_height])
        return R, t


@dataclass(frozen=True, eq=False)
class ZindPano:
    """One panorama of a home with its ground-truth pose (metres, our convention)."""

    image: Path
    floor: str
    complete_room: str
    partial_room: str
    pano: str
    is_inside: bool
    is_primary: bool
    label: str
    placement: Placement
    rot_cam_from_world: np.ndarray = field(repr=False)
    center: np.ndarray = field(repr=False)
    layout: dict | None = field(default=None, repr=False)  # its layout_complete (local frame), validated
    ceiling_height: float = 0.0  # local units
    is_ceiling_flat: bool = True

    @property
    def camera_height_m(self) -> float:
        return float(self.center[2])


@dataclass(frozen=True, eq=False)
class ZindRoom:
    """A complete room in world coordinates (metres, z up, floor at z = 0)."""

    floor: str
    key: str  # complete_room_YY
    polygon: np.ndarray = field(repr=False)  # (V, 2) wall polygon, xy
    ceiling_height: float  # metres above the floor
    ceiling_flat: bool
    doors: np.ndarray = field(repr=False)  # (N, 4, 3): left-bottom, right-bottom, right-top, left-top
    windows: np.ndarray = field(repr=False)
    openings: np.ndarray = field(repr=False)
    internal: tuple[np.ndarray, ...] = field(default=(), repr=False)  # (K, 2) xy polylines
    source_pano: str = ""  # partial_room/pano whose layout_complete was used
    panos: tuple[str, ...] = ()  # partial_room/pano of every panorama in the room
    spread: float = 0.0  # max distance (m) between this polygon and the others' versions of it


@dataclass(frozen=True, eq=False)
class ZindHome:
    """A parsed and validated ``zind_data.json``."""

    folder: Path
    name: str
    json_path: Path
    meters_per_coordinate: dict[str, float]
    panos: tuple[ZindPano, ...]
    rooms: dict[tuple[str, str], ZindRoom]
    warnings: tuple[str, ...] = ()  # rooms left out (a self-intersecting layout), one line each

    def floors(self) -> list[str]:
        return sorted({p.floor for p in self.panos} | {f for f, _ in self.rooms}, key=_natural_key)


# ------------------------------------------------------------------------------------ parsing


def _natural_key(text: str) -> tuple:
    """Sort key that orders embedded integers numerically (``pano_2`` before ``pano_10``)."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text))


def _num(value: Any, what: str, src: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{src}: {what} must be a number, got {value!r:.40}")
    if not math.isfinite(value):
        raise InputError(f"{src}: {what} is not finite ({value})")
    return float(value)


def _array(value: Any, shape_tail: tuple[int, ...], what: str, src: Path, min_rows: int = 0) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{src}: {what} must be numbers of shape (N, {', '.join(map(str, shape_tail))})") from None
    if arr.size == 0 and min_rows == 0:
        return np.zeros((0,) + shape_tail)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail or len(arr) < min_rows:
        raise InputError(f"{src}: {what} must have shape (N >= {min_rows}, {', '.join(map(str, shape_tail))}), "
                         f"got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{src}: {what} contains NaN or infinite values")
    return arr


def _field(d: dict, key: str, where: str, src: Path) -> Any:
    if not isinstance(d, dict) or key not in d:
        raise InputError(f"{src}: {where} lacks the field {key!r}")
    return d[key]


def _flag(d: dict, key: str, where: str, src: Path) -> bool:
    v = _field(d, key, where, src)
    if not isinstance(v, bool):
        raise InputError(f"{src}: {where}.{key} must be true or false, got {v!r:.40}")
    return v


def _check_layout(layout: Any, where: str, src: Path) -> dict:
    """Validated layout: vertices (V, 2), each element kind (N, 3, 2) as [left, right, z-range], internal polylines."""
    if not isinstance(layout, dict):
        raise InputError(f"{src}: {where} must be an object, got {type(layout).__name__}")
    out: dict = {"vertices": _array(_field(layout, "vertices", where, src), (2,), f"{where}.vertices", src, 3)}
    for kind in ELEMENT_KINDS:
        raw = layout.get(kind) or []
        arr = _array(raw, (2,), f"{where}.{kind}", src)
        if len(arr) % 3:
            raise InputError(f"{src}: {where}.{kind} must hold triples [left_xy, right_xy, [z_bottom, z_top]], "
                             f"got {len(arr)} entries")
        el = arr.reshape(-1, 3, 2)
        if np.any(el[:, 2, 1] < el[:, 2, 0]):
            raise InputError(f"{src}: {where}.{kind} has an element whose z_top is below its z_bottom")
        out[kind] = el
    internal = layout.get("internal") or []
    if not isinstance(internal, list):
        raise InputError(f"{src}: {where}.internal must be a list of polylines")
    out["internal"] = tuple(_array(poly, (2,), f"{where}.internal[{i}]", src, 2) for i, poly in enumerate(internal))
    return out


def _children(d: Any, prefix: str, where: str, src: Path) -> list[tuple[str, dict]]:
    if not isinstance(d, dict):
        raise InputError(f"{src}: {where} must be an object")
    items = [(k, v) for k, v in d.items() if k.startswith(prefix)]
    for k, v in items:
        if not isinstance(v, dict):
            raise InputError(f"{src}: {where}.{k} must be an object")
    return items


def read_zind_home(folder: str | Path) -> ZindHome:
    """Read and validate ``<folder>/zind_data.json`` (one home); :class:`InputError` on any problem."""
    folder = Path(folder)
    src = folder / ZIND_JSON
    try:
        data = json.loads(src.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"ZInD home has no {ZIND_JSON}: {folder}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {src}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"corrupt JSON in {src}: {exc.msg} at line {exc.lineno}") from None
    if not isinstance(data, dict):
        raise InputError(f"{src}: expected a JSON object at the top level")
    scales = _field(data, "scale_meters_per_coordinate", "the file", src)
    merger = _field(data, "merger", "the file", src)
    floors = _children(merger, "floor", "merger", src)
    if not floors:
        raise InputError(f"{src}: merger has no floor_XX entries")
    if not isinstance(scales, dict):
        raise InputError(f"{src}: scale_meters_per_coordinate must be an object keyed by floor")
    panos: list[ZindPano] = []
    rooms: dict[tuple[str, str], ZindRoom] = {}
    warnings: list[str] = []
    meters: dict[str, float] = {}
    for floor, fdata in floors:
        m = _num(_field(scales, floor, "scale_meters_per_coordinate", src),
                 f"scale_meters_per_coordinate.{floor}", src)
        if m <= 0:
            raise InputError(f"{src}: scale_meters_per_coordinate.{floor} must be > 0, got {m}")
        meters[floor] = m
        for room, rdata in _children(fdata, "complete_room", f"merger.{floor}", src):
            room_panos: list[ZindPano] = []
            for partial, pdata in _children(rdata, "partial_room", f"merger.{floor}.{room}", src):
                for pano, d in _children(pdata, "pano", f"merger.{floor}.{room}.{partial}", src):
                    room_panos.append(_read_pano(folder, floor, room, partial, pano, d, m, src))
            if not room_panos:
                raise InputError(f"{src}: merger.{floor}.{room} has no panoramas")
            panos.extend(room_panos)
            made = _make_room(floor, room, room_panos, src)
            problem = _layout_problem(made.polygon)
            if problem is not None:  # its map would be wrong: left out, said once per read
                warnings.append(f"{src}: merger.{floor}.{room} left out: its layout_complete polygon "
                                f"({made.source_pano}) {problem}")
                continue
            rooms[(floor, room)] = made
    if not rooms:
        raise InputError(f"{src}: no complete room with a usable layout on any floor: no map can be built"
                         + (f" ({warnings[0]})" if warnings else ""))
    panos.sort(key=lambda p: (_natural_key(p.floor), _natural_key(p.partial_room), _natural_key(p.pano)))
    return ZindHome(folder, folder.name, src, meters, tuple(panos), rooms, tuple(warnings))


def _layout_problem(poly: np.ndarray) -> str | None:
    """Why a room polygon cannot be a room (fewer than 3 corners, its boundary crossing itself, no
    area), or None. Nearly collinear or repeated corners, common in annotations, are accepted."""
    if len(poly) < 3:
        return f"has {len(poly)} vertices"
    crossing = self_intersection(poly)
    if crossing is not None:
        return f"crosses itself (edges {crossing[0]} and {crossing[1]})"
    if abs(signed_area(poly)) < 1e-6:
        return "has no area"
    return None


def _read_pano(folder: Path, floor: str, room: str, partial: str, pano: str, d: dict, m: float, src: Path) -> ZindPano:
    where = f"merger.{floor}.{room}.{partial}.{pano}"
    tr = _field(d, "floor_plan_transformation", where, src)
    T = _array([_field(tr, "translation", f"{where}.floor_plan_transformation", src)], (2,),
               f"{where}.floor_plan_transformation.translation", src, 1)[0]
    rot = _num(_field(tr, "rotation", f"{where}.floor_plan_transformation", src),
               f"{where}.floor_plan_transformation.rotation", src)
    scale = _num(_field(tr, "scale", f"{where}.floor_plan_transformation", src),
                 f"{where}.floor_plan_transformation.scale", src)
    if scale <= 0:
        raise InputError(f"{src}: {where}.floor_plan_transformation.scale must be > 0, got {scale}")
    cam = _num(_field(d, "camera_height", where, src), f"{where}.camera_height", src)
    ceil = _num(_field(d, "ceiling_height", where, src), f"{where}.ceiling_height", src)
    if cam <= 0 or ceil <= cam:
        raise InputError(f"{src}: {where}: need 0 < camera_height < ceiling_height, got {cam} and {ceil}")
    image = _field(d, "image_path", where, src)
    if not isinstance(image, str) or not image:
        raise InputError(f"{src}: {where}.image_path must be a non-empty string")
    layout = d.get("layout_complete")
    place = Placement((float(T[0]), float(T[1])), rot, scale, m, cam)
    R, t = place.pose()
    return ZindPano(
        image=folder / image, floor=floor, complete_room=room, partial_room=partial, pano=pano,
        is_inside=_flag(d, "is_inside", where, src), is_primary=bool(d.get("is_primary", True)),
        label=str(d.get("label", "")), placement=place, rot_cam_from_world=R, center=t,
        layout=None if layout is None else _check_layout(layout, f"{where}.layout_complete", src),
        ceiling_height=ceil, is_ceiling_flat=_flag(d, "is_ceiling_flat", where, src))


def _rectangles(el: np.ndarray, place: Placement) -> np.ndarray:
    """(N, 4, 3) world rectangles of local elements (N, 3, 2): left-bottom, right-bottom, right-top, left-top."""
    if len(el) == 0:
        return np.zeros((0, 4, 3))
    left, right, zs = el[:, 0], el[:, 1], el[:, 2]
    xy = place.world_xy(np.stack([left, right, right, left], 1))
    z = place.world_z(np.stack([zs[:, 0], zs[:, 0], zs[:, 1], zs[:, 1]], 1))
    return np.concatenate([xy, z[..., None]], -1)


def _make_room(floor: str, room: str, panos: list[ZindPano], src: Path) -> ZindRoom:
    with_layout = [p for p in panos if p.layout is not None]
    if not with_layout:
        raise InputError(f"{src}: merger.{floor}.{room}: no panorama has a layout_complete")
    first = next((p for p in with_layout if p.is_primary), with_layout[0])
    place, lay = first.placement, first.layout
    poly = place.world_xy(lay["vertices"])
    spread = 0.0
    for p in with_layout:
        other = p.placement.world_xy(p.layout["vertices"])
        if other.shape == poly.shape:
            spread = max(spread, float(np.linalg.norm(other - poly, axis=1).max()))
        else:
            spread = math.inf
    return ZindRoom(
        floor=floor, key=room, polygon=poly, ceiling_height=float(place.world_z(first.ceiling_height - place.camera_height)),
        ceiling_flat=all(p.is_ceiling_flat for p in panos),
        doors=_rectangles(lay["doors"], place), windows=_rectangles(lay["windows"], place),
        openings=_rectangles(lay["openings"], place),
        internal=tuple(place.world_xy(q) for q in lay["internal"]),
        source_pano=f"{first.partial_room}/{first.pano}", panos=tuple(f"{p.partial_room}/{p.pano}" for p in panos),
        spread=spread)


# ------------------------------------------------------------------------------------- lines


def _subtract_intervals(a: np.ndarray, b: np.ndarray, cuts: Iterable[tuple[np.ndarray, np.ndarray]],
                        tol: float = 0.05) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pieces of segment a-b (xy) left after removing the spans of the collinear segments ``cuts``
    (those within ``tol`` metres of the line a-b)."""
    d = b - a
    length = float(np.linalg.norm(d))
    if length < 1e-9:
        return []
    u = d / length
    n = np.array([-u[1], u[0]])
    spans = []
    for c0, c1 in cuts:
        if abs(float((c0 - a) @ n)) > tol or abs(float((c1 - a) @ n)) > tol:
            continue
        s0, s1 = sorted((float((c0 - a) @ u), float((c1 - a) @ u)))
        if s1 > 0 and s0 < length:
            spans.append((max(s0, 0.0), min(s1, length)))
    pieces, pos = [], 0.0
    for s0, s1 in sorted(spans):
        if s0 > pos + 1e-6:
            pieces.append((pos, s0))
        pos = max(pos, s1)
    if pos < length - 1e-6:
        pieces.append((pos, length))
    return [(a + u * s0, a + u * s1) for s0, s1 in pieces if s1 - s0 > 1e-3]


def room_lines(room: ZindRoom, kinds: bool = False) -> np.ndarray | tuple[np.ndarray, list[str]]:
    """3D line segments (L, 2, 3) of a room's layout (metres, z up, floor at z = 0).

    See the module docstring for what each kind of line is. ``kinds=True`` also returns the kind
    of every segment (one of :data:`LINE_KINDS`).
    """
    segs: list[tuple[np.ndarray, np.ndarray]] = []
    names: list[str] = []

    def add(p: np.ndarray, q: np.ndarray, kind: str) -> None:
        if np.linalg.norm(np.asarray(q) - np.asarray(p)) > 1e-6:
            segs.append((np.asarray(p, float), np.asarray(q, float)))
            names.append(kind)

    H = room.ceiling_height
    poly = room.polygon
    V = len(poly)

    def at(xy: np.ndarray, z: float) -> np.ndarray:
        return np.array([xy[0], xy[1], z])

    for v in poly:
        add(at(v, 0.0), at(v, H), "corner")
    opening_spans = [(o[0, :2], o[1, :2]) for o in room.openings]
    for i in range(V):
        a, b = poly[i], poly[(i + 1) % V]
        for p, q in _subtract_intervals(a, b, opening_spans):
            add(at(p, 0.0), at(q, 0.0), "floor")
        if room.ceiling_flat:
            add(at(a, H), at(b, H), "ceiling")
    for kind, rects in (("door", room.doors), ("window", room.windows), ("opening", room.openings)):
        for r in rects:  # left-bottom, right-bottom, right-top, left-top
            add(r[0], r[3], kind)
            add(r[1], r[2], kind)
            if not (kind == "opening" and room.ceiling_flat and abs(r[2, 2] - H) < _CEILING_TOL):
                add(r[3], r[2], kind)
            if kind == "window":
                add(r[0], r[1], kind)
    for poly_in in room.internal:
        for a, b in zip(poly_in[:-1], poly_in[1:]):
            add(at(a, 0.0), at(b, 0.0), "internal")
        if room.ceiling_flat:
            kept: list[np.ndarray] = []
            for v in poly_in:  # the outline of a thin wall: one vertical per corner, not per face
                if all(np.linalg.norm(v - k) >= _INTERNAL_MERGE for k in kept):
                    kept.append(v)
                    add(at(v, 0.0), at(v, H), "internal")
    lines = np.array([[p, q] for p, q in segs], dtype=np.float64).reshape(-1, 2, 3)
    return (lines, names) if kinds else lines


def room_walls(room: ZindRoom) -> np.ndarray:
    """(W, 4, 3) wall quads of a room (corner by corner), floor to ceiling along every polygon edge
    and internal wall, with its doors and openings left open: over a portal only the lintel above
    it (and the sill below it) remain. Windows count as wall (nothing behind them is mapped)."""
    H = room.ceiling_height
    quads: list[np.ndarray] = []

    def quad(p: np.ndarray, q: np.ndarray, z0: float, z1: float) -> None:
        if z1 - z0 > 1e-3 and np.linalg.norm(q - p) > 1e-3:
            quads.append(np.array([[p[0], p[1], z0], [q[0], q[1], z0], [q[0], q[1], z1], [p[0], p[1], z1]]))

    portals = [r for r in (room.doors, room.openings) if len(r)]
    rects = np.concatenate(portals) if portals else np.zeros((0, 4, 3))
    spans = [(r[0, :2], r[1, :2]) for r in rects]
    poly = room.polygon
    edges = [(poly[i], poly[(i + 1) % len(poly)]) for i in range(len(poly))]
    edges += [(a, b) for pl in room.internal for a, b in zip(pl[:-1], pl[1:])]
    for a, b in edges:
        for p, q in _subtract_intervals(a, b, spans):
            quad(p, q, 0.0, H)
        for p, q, r in ((r[0, :2], r[1, :2], r) for r in rects):
            if _subtract_intervals(p, q, [(a, b)]):  # the portal does not lie on this edge
                continue
            quad(p, q, float(max(r[2, 2], r[3, 2])), H)  # lintel
            quad(p, q, 0.0, float(min(r[0, 2], r[1, 2])))  # sill
    return np.array(quads, dtype=np.float64).reshape(-1, 4, 3)


def room_portals(room: ZindRoom) -> np.ndarray:
    """(P, 2, 2) xy segments of a room's doors and openings (where cameras may look in from)."""
    rects = [r for r in (room.doors, room.openings) if len(r)]
    if not rects:
        return np.zeros((0, 2, 2))
    R = np.concatenate(rects)
    return R[:, :2, :2].copy()


def zind_pixel(p_local: np.ndarray, width: int, height: int) -> np.ndarray:
    """ZInD's own equirectangular pixel (..., 2) of local points (..., 3) (for checks)."""
    p = np.asarray(p_local, dtype=np.float64)
    az = np.arctan2(-p[..., 0], p[..., 1])
    el = np.arcsin(p[..., 2] / np.linalg.norm(p, axis=-1))
    return np.stack([(az + np.pi) / (2 * np.pi) * width, (1 - (el + np.pi / 2) / np.pi) * height], -1)
