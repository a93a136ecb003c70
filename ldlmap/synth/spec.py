"""Synthetic scene specification: dataclasses, TOML I/O, validation (random specs: :mod:`.presets`).

A scene is one room: a footprint polygon extruded to ``ceiling_height`` (floor at z = 0), with
furniture (``objects``), doors and windows (``openings``) and ``posters`` on the walls, plus the
capture (``capture``: panorama splits) and scanner (``scan``) parameters. ``datasets/synthetic/
SPEC.md`` documents every field; ``datasets/synthetic/l_room.toml`` is a complete example.

Walls are numbered by footprint edge: wall ``i`` runs from vertex ``i`` to vertex ``i + 1``
(counter-clockwise; a clockwise footprint is reversed on load and its wall indices and offsets
remapped). Positions along a wall (``offset``) are measured from the wall's start vertex to the
near side of the opening or poster.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tomllib
import typing
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ldlmap.core.errors import InputError, require_file
from ldlmap.core import polygon as pg
from ldlmap.synth.ceiling import CEILING_KINDS, ceiling_profile


OBJECT_KINDS = ("box", "table", "shelf", "cabinet", "sofa")
OPENING_KINDS = ("door", "window")
MATERIALS = ("plaster", "wallpaper", "brick", "concrete", "ceiling", "parquet", "tiles", "carpet",
             "wood", "dark_wood", "painted", "fabric", "marble", "metal")
DEFAULT_OBJECT_MATERIAL = {"box": "painted", "table": "wood", "shelf": "dark_wood",
                           "cabinet": "painted", "sofa": "fabric"}
DEFAULT_SILL = {"door": 0.0, "window": 0.9}

FRAME_WIDTH = 0.07  # m, width of door/window frames around the opening (in the wall plane)
FRAME_DEPTH = 0.04  # m, how far frames stand out of the wall
PANEL_OFFSET = 0.01  # m, door/window panel in front of the wall
POSTER_OFFSET = 0.005  # m, posters in front of the wall


# Bounds on spec fields (checked before any work): beyond them a room takes unbounded memory or time.
MAX_ROOM_EXTENT = 100.0  # m, footprint width or depth
MAX_CEILING = 20.0  # m
MAX_VERTICES = 256  # footprint corners
MAX_ITEMS = 200  # objects, openings and posters, each
MIN_WIDTH = 16  # px, smallest panorama width
MAX_WIDTH = 4096  # px, panorama width: a render holds about 450 bytes per pixel (about 4 GB at this width)
MAX_COUNT = 1000  # panoramas per split
MAX_BLUR_PX = 200.0  # px at W = 1024: motion blur averages one shifted copy per pixel of length
MAX_SCAN_POINTS = 5_000_000  # scan points: about 600 bytes each while sampling (3 GB at this bound)
MAX_DENSITY = 1e6  # scan points per m^2
MAX_HOLES = 10_000
MAX_STATIONS = 256
MAX_CHANGES = 100  # objects moved, removed or added
MAX_GAIN = 100.0  # illumination intensity, gamma and white-balance gains
MAX_METRES = 100.0  # any other length (clearances, jitters, shifts, noise, hole radii, camera heights)
SEED_LIMIT = 2**32  # seeds feed numpy streams as 32-bit words: 1 and 2**32 + 1 would give identical data


# --------------------------------------------------------------------------------- dataclasses


@dataclass(frozen=True)
class ObjectSpec:
    """A piece of furniture standing on the floor."""

    kind: str  # one of OBJECT_KINDS
    center: tuple[float, float]  # m, centre of the footprint on the floor
    size: tuple[float, float, float]  # m, (sx, sy, sz): width, depth, height before yaw
    yaw_deg: float = 0.0  # rotation about +z, counter-clockwise; the front faces local -y
    material: str = ""  # one of MATERIALS; "" = the kind's default


@dataclass(frozen=True)
class OpeningSpec:
    """A door or window: a frame standing out of the wall around a textured panel."""

    kind: str  # "door" or "window"
    wall: int  # footprint edge index
    offset: float  # m, from the wall's start vertex to the opening's near side
    width: float  # m
    height: float  # m
    sill: float = -1.0  # m above the floor; < 0 = default (door 0, window 0.9)


@dataclass(frozen=True)
class PosterSpec:
    """A flat textured rectangle just in front of a wall."""

    wall: int  # footprint edge index
    offset: float  # m, from the wall's start vertex to the poster's near side
    bottom: float  # m, height of the lower edge above the floor
    width: float  # m
    height: float  # m


@dataclass(frozen=True)
class ViewSpec:
    """Pose sampling of one split."""

    count: int = 3  # panoramas in the split
    camera_height: float = 1.0  # m, mean camera height
    height_jitter: float = 0.05  # m, uniform +- around camera_height
    max_tilt_deg: float = 2.0  # deg, tilt of the up axis (180 = any rotation)
    blur_px: float = 0.0  # px, motion blur length (0 = none)


@dataclass(frozen=True)
class ChangeSpec:
    """Scene changes between the scan and the change_* splits."""

    count: int = 3  # panoramas per change split (change_robot, change_handheld)
    moved: int = 1  # objects moved
    removed: int = 1  # objects removed
    added: int = 1  # objects added
    max_shift: float = 0.8  # m, largest move of a moved object
    max_turn_deg: float = 45.0  # deg, largest turn of a moved object


@dataclass(frozen=True)
class IlluminationSpec:
    """The paper's color variations (supplementary): extra splits when enabled."""

    enabled: bool = True
    intensity: float = 0.75  # multiply every pixel by this (-25 %)
    gamma: float = 0.2  # image gamma
    white_balance: tuple[float, float, float] = (0.7, 0.9, 0.8)  # diagonal RGB gains


@dataclass(frozen=True)
class CaptureSpec:
    """Panorama rendering and the splits (mirroring OmniScenes)."""

    width: int = 1024  # px, equirectangular width (= 2 x height)
    height: int = 512  # px
    min_clearance: float = 0.3  # m, minimum distance of the camera from any surface
    robot: ViewSpec = ViewSpec(3, 1.0, 0.05, 2.0, 0.0)
    handheld: ViewSpec = ViewSpec(3, 1.5, 0.15, 10.0, 0.0)
    extreme: ViewSpec = ViewSpec(3, 1.3, 0.3, 180.0, 8.0)
    change: ChangeSpec = ChangeSpec()
    illumination: IlluminationSpec = IlluminationSpec()


@dataclass(frozen=True)
class ScanSpec:
    """The simulated laser scan (colored point cloud of the unchanged scene)."""

    noise_std: float = 0.005  # m, Gaussian position noise per axis (0 = exact)
    density: float = 4000.0  # points per m^2 of surface (mean; a Matterport-like room scan: ~0.5-1.5 M points)
    max_points: int = 1_500_000  # cap on the point count
    uneven: float = 0.5  # 0..1, relative amplitude of smooth density variations
    holes: int = 6  # number of circular holes (missing data)
    hole_radius: float = 0.15  # m
    stations: int = 6  # scanner stations (surfaces seen from none of them are not sampled; real room scans
    # take a sweep every ~2 m; too few leave edges unseen: docs/measurements.md#scan-stations)


@dataclass(frozen=True)
class CeilingSpec:
    """The ceiling's shape (:mod:`ldlmap.synth.ceiling`); ``ceiling_height`` is its lowest point."""

    kind: str = "flat"  # flat | shed (one slope) | gable (two slopes, a ridge) | stepped | vault (barrel)
    direction_deg: float = 0.0  # deg, azimuth of the axis along which the height varies
    slope_deg: float = 30.0  # deg, shed and gable pitch
    step: float = 0.5  # m, stepped: how much higher the first part (smaller positions along the axis) is
    step_at: float = 0.5  # stepped: where the step stands, as a fraction of the room's extent along the axis
    rise: float = 0.8  # m, vault: height of the arch's crown above its springing (the walls' top)
    segments: int = 12  # vault: flat facets of the arch


@dataclass(frozen=True)
class SceneSpec:
    """One synthetic room."""

    name: str
    footprint: tuple[tuple[float, float], ...]  # m, polygon vertices (x, y), counter-clockwise
    ceiling_height: float  # m
    objects: tuple[ObjectSpec, ...] = ()
    openings: tuple[OpeningSpec, ...] = ()
    posters: tuple[PosterSpec, ...] = ()
    seed: int = 0  # texture seed (also seeds poses and the scan in the generator)
    wall_material: str = "plaster"
    floor_material: str = "parquet"
    ceiling_material: str = "ceiling"
    ceiling: CeilingSpec = CeilingSpec()
    capture: CaptureSpec = CaptureSpec()
    scan: ScanSpec = ScanSpec()

    def wall_lengths(self) -> np.ndarray:
        p = np.asarray(self.footprint, dtype=np.float64)
        return np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)


# ------------------------------------------------------------------------------ dict -> spec


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_name(args[0])}"
        return f"list of {len(args)} {_type_name(args[0])}s"
    if dataclasses.is_dataclass(tp):
        return "table"
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, path: str) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise InputError(f"spec field '{path}' must be a table, got {type(value).__name__}")
        return dataclass_from_dict(tp, value, path)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise InputError(f"spec field '{path}' must be a {_type_name(tp)}, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise InputError(f"spec field '{path}' must have {len(args)} values, got {len(value)}")
        return tuple(_convert(v, a, f"{path}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if tp is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise InputError(f"spec field '{path}' must be true or false, got {value!r}")
        return bool(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise InputError(f"spec field '{path}' must be an integer, got {value!r}")
        return int(value)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise InputError(f"spec field '{path}' must be a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise InputError(f"spec field '{path}' must be finite, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise InputError(f"spec field '{path}' must be a string, got {value!r}")
        return value
    raise TypeError(f"unsupported spec type {tp!r}")  # programming error


def dataclass_from_dict(cls: type, d: dict, path: str, base: Any = None) -> Any:
    """Build ``cls`` from ``d``; fields missing from ``d`` come from ``base`` (or the defaults).

    A nested table that sets only some fields keeps the other fields of the enclosing default
    (e.g. ``[capture.extreme] count = 5`` keeps the extreme split's tilt and blur).
    """
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    prefix = f"{path}." if path else ""
    unknown = [k for k in d if k not in names]
    if unknown:
        raise InputError(f"unknown spec field '{prefix}{unknown[0]}' (valid: {', '.join(names)})")
    kwargs = {}
    for f in dataclasses.fields(cls):
        inherited = getattr(base, f.name) if base is not None else (
            f.default if f.default is not dataclasses.MISSING else None)
        if f.name in d:
            tp = hints[f.name]
            if dataclasses.is_dataclass(tp) and isinstance(d[f.name], dict) and dataclasses.is_dataclass(inherited):
                kwargs[f.name] = dataclass_from_dict(tp, d[f.name], prefix + f.name, base=inherited)
            else:
                kwargs[f.name] = _convert(d[f.name], tp, prefix + f.name)
        elif base is not None:
            kwargs[f.name] = inherited
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise InputError(f"missing required spec field '{prefix}{f.name}'")
    return cls(**kwargs)


def spec_from_dict(d: dict) -> SceneSpec:
    """Parse and validate a scene spec from plain data (as loaded from TOML)."""
    if not isinstance(d, dict):
        raise InputError(f"a scene spec must be a table, got {type(d).__name__}")
    spec = dataclass_from_dict(SceneSpec, d, "")
    spec = _resolve_defaults(_make_ccw(spec))
    validate_spec(spec)
    return spec


def load_spec(path: str | os.PathLike) -> SceneSpec:
    """Read and validate a TOML scene spec."""
    p = require_file(path, "scene spec")
    try:
        with open(p, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"invalid TOML in {p}: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read scene spec {p}: {exc}") from None
    try:
        return spec_from_dict(data)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None


def _make_ccw(spec: SceneSpec) -> SceneSpec:
    """Reverse a clockwise footprint, remapping wall indices and offsets."""
    fp = np.asarray(spec.footprint, dtype=np.float64)
    if not 3 <= len(fp) <= MAX_VERTICES or pg.simple_polygon_problem(fp) is not None or pg.signed_area(fp) > 0:
        return spec  # validation reports problems; counter-clockwise needs nothing
    k = len(fp)
    lengths = spec.wall_lengths()

    def remap(wall: int, offset: float, width: float) -> tuple[int, float]:
        if not 0 <= wall < k:
            return wall, offset
        return (k - 2 - wall) % k, float(lengths[wall] - offset - width)

    openings = tuple(replace(o, wall=remap(o.wall, o.offset, o.width)[0],
                             offset=remap(o.wall, o.offset, o.width)[1]) for o in spec.openings)
    posters = tuple(replace(o, wall=remap(o.wall, o.offset, o.width)[0],
                            offset=remap(o.wall, o.offset, o.width)[1]) for o in spec.posters)
    return replace(spec, footprint=tuple(spec.footprint[::-1]), openings=openings, posters=posters)


def _resolve_defaults(spec: SceneSpec) -> SceneSpec:
    objects = tuple(replace(o, material=o.material or DEFAULT_OBJECT_MATERIAL.get(o.kind, "painted"))
                    for o in spec.objects)
    openings = tuple(replace(o, sill=DEFAULT_SILL.get(o.kind, 0.0) if o.sill < 0 else o.sill)
                     for o in spec.openings)
    return replace(spec, objects=objects, openings=openings)


# ---------------------------------------------------------------------------------- validation


def object_footprint(obj: ObjectSpec) -> np.ndarray:
    """Rotated footprint rectangle (4, 2), counter-clockwise, of an object."""
    hx, hy = obj.size[0] / 2.0, obj.size[1] / 2.0
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    a = math.radians(obj.yaw_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return local @ rot.T + np.asarray(obj.center, dtype=np.float64)


def _positive(value: float, path: str) -> None:
    if not value > 0:
        raise InputError(f"spec field '{path}' must be positive, got {value}")


def _non_negative(value: float, path: str) -> None:
    if not value >= 0:
        raise InputError(f"spec field '{path}' must be >= 0, got {value}")


def _at_most(value: float, limit: float, path: str, why: str = "") -> None:
    if not value <= limit:
        raise InputError(f"spec field '{path}' must be at most {limit:g}, got {value:g}" + (f" ({why})" if why else ""))


def _validate_size(spec: SceneSpec, fp: np.ndarray) -> None:
    """Bounds that keep a room's memory and time finite: extent, corners, item counts, seed."""
    extent = fp.max(axis=0) - fp.min(axis=0) if len(fp) else np.zeros(2)
    _at_most(float(extent.max()), MAX_ROOM_EXTENT, "footprint", "room width or depth in metres")
    _at_most(spec.ceiling_height, MAX_CEILING, "ceiling_height")
    for key in ("objects", "openings", "posters"):
        _at_most(len(getattr(spec, key)), MAX_ITEMS, key, "number of entries")
    if not 0 <= spec.seed < SEED_LIMIT:
        raise InputError(f"spec field 'seed' must be in [0, 2**32), got {spec.seed}")


def validate_spec(spec: SceneSpec) -> None:
    """Raise :class:`InputError` naming the field when ``spec`` is not a valid scene."""
    if not spec.name or any(c in spec.name for c in "/\\ \t\n") or spec.name in (".", ".."):
        raise InputError(f"spec field 'name' must be a non-empty name without spaces or slashes, got {spec.name!r}")
    fp = np.asarray(spec.footprint, dtype=np.float64).reshape(-1, 2)
    if len(fp) > MAX_VERTICES:  # before the simplicity check, quadratic in the corners
        raise InputError(f"spec field 'footprint' has {len(fp)} corners, at most {MAX_VERTICES} are supported")
    problem = pg.simple_polygon_problem(fp)
    if problem is not None:
        raise InputError(f"spec field 'footprint' {problem}")
    _positive(spec.ceiling_height, "ceiling_height")
    _validate_size(spec, fp)
    for key in ("wall_material", "floor_material", "ceiling_material"):
        if getattr(spec, key) not in MATERIALS:
            raise InputError(f"spec field '{key}' must be one of {', '.join(MATERIALS)}, got {getattr(spec, key)!r}")
    h = spec.ceiling_height
    rects = []
    for i, obj in enumerate(spec.objects):
        path = f"objects[{i}]"
        if obj.kind not in OBJECT_KINDS:
            raise InputError(f"spec field '{path}.kind' must be one of {', '.join(OBJECT_KINDS)}, got {obj.kind!r}")
        if obj.material not in MATERIALS:
            raise InputError(f"spec field '{path}.material' must be one of {', '.join(MATERIALS)}, got {obj.material!r}")
        for j, s in enumerate(obj.size):
            _positive(s, f"{path}.size[{j}]")
        if min(obj.size) < 0.1:
            raise InputError(f"spec field '{path}.size' must be at least 0.1 m on every side, got {list(obj.size)}")
        if obj.size[2] > h:
            raise InputError(f"spec field '{path}.size' is taller ({obj.size[2]} m) than the ceiling ({h} m)")
        rect = object_footprint(obj)
        if not pg.convex_inside_polygon(rect, fp, eps=1e-6):
            raise InputError(f"spec field '{path}' ({obj.kind} at {list(obj.center)}) is not inside the room footprint")
        for j, other in enumerate(rects):
            if pg.convex_overlap(rect, other, eps=1e-6):
                raise InputError(f"spec field '{path}' overlaps objects[{j}]")
        rects.append(rect)
    lengths = spec.wall_lengths()
    spans: dict[int, list[tuple[float, float, float, float, str]]] = {}
    for i, op in enumerate(spec.openings):
        path = f"openings[{i}]"
        if op.kind not in OPENING_KINDS:
            raise InputError(f"spec field '{path}.kind' must be door or window, got {op.kind!r}")
        _check_on_wall(path, op.wall, op.offset, op.width, op.height, op.sill, lengths, h, FRAME_WIDTH,
                       bottom_frame=op.kind == "window")
        lo = op.sill - (FRAME_WIDTH if op.kind == "window" else 0.0)
        box = (op.offset - FRAME_WIDTH, op.offset + op.width + FRAME_WIDTH, lo, op.sill + op.height + FRAME_WIDTH, path)
        _check_no_overlap_on_wall(spans.setdefault(op.wall, []), box)
    for i, po in enumerate(spec.posters):
        path = f"posters[{i}]"
        _check_on_wall(path, po.wall, po.offset, po.width, po.height, po.bottom, lengths, h, 0.0, bottom_frame=False)
        box = (po.offset, po.offset + po.width, po.bottom, po.bottom + po.height, path)
        _check_no_overlap_on_wall(spans.setdefault(po.wall, []), box)
    _validate_ceiling(spec, fp)
    _validate_capture(spec.capture)
    _validate_scan(spec.scan)


def _validate_ceiling(spec: SceneSpec, fp: np.ndarray) -> None:
    c = spec.ceiling
    if c.kind not in CEILING_KINDS:
        raise InputError(f"spec field 'ceiling.kind' must be one of {', '.join(CEILING_KINDS)}, got {c.kind!r}")
    if c.kind == "flat":
        return
    if not pg.is_convex(fp):
        raise InputError(f"spec field 'ceiling.kind' = {c.kind!r} needs a convex footprint (only flat ceilings "
                         "cover other rooms)")
    _in_range(c.direction_deg, -360, 360, "ceiling.direction_deg")
    _in_range(c.slope_deg, 0, 60, "ceiling.slope_deg", positive=True)
    _in_range(c.step, 0, MAX_CEILING, "ceiling.step", positive=True)
    _in_range(c.step_at, 0.05, 0.95, "ceiling.step_at")
    _in_range(c.rise, 0, MAX_CEILING, "ceiling.rise", positive=True)
    _in_range(c.segments, 2, 64, "ceiling.segments")
    top = ceiling_profile(c, fp, spec.ceiling_height).top
    _at_most(top, MAX_CEILING, "ceiling", "the ceiling's highest point in metres")


def _check_on_wall(path: str, wall: int, offset: float, width: float, height: float, bottom: float,
                   lengths: np.ndarray, ceiling: float, frame: float, bottom_frame: bool) -> None:
    if not 0 <= wall < len(lengths):
        raise InputError(f"spec field '{path}.wall' must be a wall index in 0..{len(lengths) - 1}, got {wall}")
    _positive(width, f"{path}.width")
    _positive(height, f"{path}.height")
    _non_negative(bottom, f"{path}.{'sill' if frame else 'bottom'}")
    _non_negative(offset - frame, f"{path}.offset (minus the {frame} m frame)" if frame else f"{path}.offset")
    if offset + width + frame > lengths[wall] + 1e-9:
        raise InputError(f"spec field '{path}' does not fit on wall {wall}: offset {offset} + width {width}"
                         f"{f' + frame {frame}' if frame else ''} > wall length {lengths[wall]:.3f} m")
    low = bottom - (frame if bottom_frame else 0.0)
    if low < -1e-9:
        raise InputError(f"spec field '{path}.sill' leaves no room for the {frame} m frame below the window")
    if bottom + height + frame > ceiling + 1e-9:
        raise InputError(f"spec field '{path}' does not fit on wall {wall}: top at {bottom + height + frame:.3f} m"
                         f" is above the ceiling ({ceiling} m)")


def _check_no_overlap_on_wall(spans: list, box: tuple[float, float, float, float, str]) -> None:
    for other in spans:
        if box[0] < other[1] - 1e-9 and other[0] < box[1] - 1e-9 and box[2] < other[3] - 1e-9 and other[2] < box[3] - 1e-9:
            raise InputError(f"spec field '{box[4]}' overlaps {other[4]} on the same wall")
    spans.append(box)


def _in_range(value: float, lo: float, hi: float, path: str, positive: bool = False, why: str = "") -> None:
    """``value`` in ``[lo, hi]`` (``(lo, hi]`` when ``positive``), else a one-line error naming the field."""
    if not (value > lo if positive else value >= lo):
        raise InputError(f"spec field '{path}' must be {'>' if positive else '>='} {lo:g}, got {value}")
    _at_most(value, hi, path, why)


def _validate_capture(c: CaptureSpec) -> None:
    _in_range(c.width, MIN_WIDTH, MAX_WIDTH, "capture.width", why="rendering holds about 450 bytes per pixel")
    _positive(c.height, "capture.height")
    if c.width != 2 * c.height:
        raise InputError(f"spec field 'capture.width' must be twice capture.height, got {c.width}x{c.height}")
    _in_range(c.min_clearance, 0, MAX_METRES, "capture.min_clearance")
    for name in ("robot", "handheld", "extreme"):
        v: ViewSpec = getattr(c, name)
        _in_range(v.count, 0, MAX_COUNT, f"capture.{name}.count")
        _in_range(v.camera_height, 0, MAX_METRES, f"capture.{name}.camera_height", positive=True)
        _in_range(v.height_jitter, 0, MAX_METRES, f"capture.{name}.height_jitter")
        _in_range(v.blur_px, 0, MAX_BLUR_PX, f"capture.{name}.blur_px")
        if not 0 <= v.max_tilt_deg <= 180:
            raise InputError(f"spec field 'capture.{name}.max_tilt_deg' must be in [0, 180], got {v.max_tilt_deg}")
    ch = c.change
    _in_range(ch.count, 0, MAX_COUNT, "capture.change.count")
    for key in ("moved", "removed", "added"):
        _in_range(getattr(ch, key), 0, MAX_CHANGES, f"capture.change.{key}")
    _in_range(ch.max_shift, 0, MAX_METRES, "capture.change.max_shift")
    _in_range(ch.max_turn_deg, 0, 180, "capture.change.max_turn_deg")
    il = c.illumination
    _in_range(il.intensity, 0, MAX_GAIN, "capture.illumination.intensity", positive=True)
    _in_range(il.gamma, 0, MAX_GAIN, "capture.illumination.gamma", positive=True)
    for j, g in enumerate(il.white_balance):
        _in_range(g, 0, MAX_GAIN, f"capture.illumination.white_balance[{j}]", positive=True)


def _validate_scan(s: ScanSpec) -> None:
    _in_range(s.noise_std, 0, MAX_METRES, "scan.noise_std")
    _in_range(s.density, 0, MAX_DENSITY, "scan.density", positive=True)
    _in_range(s.max_points, 0, MAX_SCAN_POINTS, "scan.max_points", positive=True,
              why="sampling holds about 600 bytes per point")
    if not 0 <= s.uneven <= 1:
        raise InputError(f"spec field 'scan.uneven' must be in [0, 1], got {s.uneven}")
    _in_range(s.holes, 0, MAX_HOLES, "scan.holes")
    _in_range(s.hole_radius, 0, MAX_METRES, "scan.hole_radius")
    _in_range(s.stations, 0, MAX_STATIONS, "scan.stations", positive=True)


# ------------------------------------------------------------------------------ spec -> TOML


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def spec_to_dict(spec: SceneSpec) -> dict:
    """Plain nested dict/list data of ``spec`` (inverse of :func:`spec_from_dict`)."""
    return _plain(spec)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot write non-finite number {v} to TOML")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # JSON string escapes are valid TOML basic strings
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _toml_table(d: dict, prefix: str, out: list[str]) -> None:
    def is_table_array(v: Any) -> bool:
        return isinstance(v, list) and len(v) > 0 and all(isinstance(x, dict) for x in v)

    for k, v in d.items():
        if not isinstance(v, dict) and not is_table_array(v):
            out.append(f"{k} = {_toml_value(v)}")
    for k, v in d.items():
        if isinstance(v, dict):
            out.append("")
            out.append(f"[{prefix}{k}]")
            _toml_table(v, f"{prefix}{k}.", out)
    for k, v in d.items():
        if is_table_array(v):
            for item in v:
                out.append("")
                out.append(f"[[{prefix}{k}]]")
                _toml_table(item, f"{prefix}{k}.", out)


def dump_spec_toml(spec: SceneSpec) -> str:
    """The spec as TOML text that :func:`load_spec` reads back to an equal spec."""
    out = ["# ldl synthetic scene spec (see datasets/synthetic/SPEC.md)"]
    _toml_table(spec_to_dict(spec), "", out)
    return "\n".join(out) + "\n"
