"""ASTM E57 scans (``.e57``, over libE57Format through ``pye57``): stations and their panoramas.

Reading (:func:`read_e57`): every scan station (``data3D``) of the file, cartesian or spherical
points (``pye57`` turns spherical range/azimuth/elevation into x, y, z), placed in the file's
frame by the station's pose (``pose``: rotation quaternion w, x, y, z and translation); invalid
points (``*InvalidState``) left out. Colour: ``colorRed/Green/Blue`` scaled by the station's
``colorLimits`` to 0-255; a station without colour but with ``intensity`` gives grey levels
scaled by its ``intensityLimits`` (or its own range); with neither, the cloud has no colour.

Images (:func:`e57_images`): the ``images2D`` of the file. A ``sphericalRepresentation`` covering
the whole sphere (``imageWidth * pixelWidth`` = 2 pi, ``imageHeight * pixelHeight`` = pi) is a
panorama; its ``pose`` takes the image's camera frame into the file's frame. The camera frame is
read as ours (:mod:`ldlmap.core.geometry`: the image centre looks along +x, the top row along
+z, azimuth growing to the left), which is E57's spherical coordinate convention (azimuth from +x
towards +y about +z, elevation above the xy plane). Pinhole and cylindrical images, and partial
spherical ones, are listed with a note and skipped.

Writing (:func:`write_e57`): the same layout, for tests and the synthetic generator.
"""

from __future__ import annotations

import os
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, atomic_file, require_file
from ldlmap.core.lazy import lazy_module

cv2 = lazy_module("cv2")
pye57 = lazy_module("pye57")
libe57 = lazy_module("pye57.libe57")
pye57_utils = lazy_module("pye57.utils")
transform = lazy_module("scipy.spatial.transform")

_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
_COLORS = ("colorRed", "colorGreen", "colorBlue")
FULL_SPHERE_TOLERANCE = 0.02  # relative: a spherical image's width x pixelWidth within 2 % of 2 pi (height: pi)


@dataclass
class E57Station:
    """One scan station of an E57 file, its points in the file's frame."""

    name: str
    points: np.ndarray  # (N, 3) float64
    colors: np.ndarray | None  # (N, 3) uint8, from colour or intensity
    color_source: str  # "color" | "intensity" | "none"
    center: np.ndarray  # (3,) the station's position (its pose's translation)
    coordinates: str  # "cartesian" | "spherical"


@dataclass
class E57Image:
    """One image of an E57 file's ``images2D``."""

    name: str
    kind: str  # "spherical" | "pinhole" | "cylindrical" | "none"
    rot_cam_from_world: np.ndarray | None  # (3, 3) world (the file's frame) to camera; None without a pose
    center: np.ndarray | None  # (3,) camera centre in the file's frame
    data: bytes = b""  # the JPEG or PNG file (spherical images only)
    suffix: str = ".jpg"
    width: int = 0
    height: int = 0
    note: str = ""  # why it is not usable as a panorama ("" when it is)


@dataclass
class E57Scan:
    """The stations read from an E57 file (a subset when asked) and notes for the user."""

    stations: list[E57Station]
    total_stations: int
    notes: list[str] = field(default_factory=list)

    @property
    def points(self) -> np.ndarray:
        return np.concatenate([s.points for s in self.stations])

    @property
    def colors(self) -> np.ndarray | None:
        if any(s.colors is None for s in self.stations):
            return None
        return np.concatenate([s.colors for s in self.stations])


def _open(path: Path):
    """The file opened by pye57, or one line naming what libE57Format found wrong."""
    try:
        return pye57.E57(str(path))
    except Exception as exc:  # libe57 raises its own E57Exception (and RuntimeError on bad XML)
        raise InputError(f"cannot read E57 file {path}: {_first_line(exc)}") from None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _child(node, name: str):
    """The typed child ``name`` of a libe57 structure node, or None when absent."""
    return pye57_utils.get_node(node, name) if node.isDefined(name) else None


def _value(node, name: str, default=None):
    child = _child(node, name)
    return child.value() if child is not None and hasattr(child, "value") else default


def _pose(node) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of a node's ``pose`` (R takes the node's frame into the file's frame); identity without one."""
    pose = _child(node, "pose")
    R, t = np.eye(3), np.zeros(3)
    if pose is None:
        return R, t
    rot, tr = _child(pose, "rotation"), _child(pose, "translation")
    if rot is not None:
        w, x, y, z = (float(_value(rot, k, d)) for k, d in (("w", 1.0), ("x", 0.0), ("y", 0.0), ("z", 0.0)))
        q = np.array([x, y, z, w])
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
            raise InputError(f"E57 pose of {node.pathName()} has an invalid rotation quaternion {q.tolist()}")
        R = transform.Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    if tr is not None:
        t = np.array([float(_value(tr, k, 0.0)) for k in ("x", "y", "z")])
        if not np.all(np.isfinite(t)):
            raise InputError(f"E57 pose of {node.pathName()} has a non-finite translation")
    return R, t


def _limits(node, group: str, keys: tuple[str, str], fallback: np.ndarray) -> tuple[float, float]:
    """``(min, max)`` of a station's colour or intensity limits, else of the values themselves."""
    lim = _child(node, group)
    lo = _value(lim, keys[0]) if lim is not None else None
    hi = _value(lim, keys[1]) if lim is not None else None
    if lo is None or hi is None or not float(hi) > float(lo):
        lo, hi = (float(fallback.min()), float(fallback.max())) if fallback.size else (0.0, 1.0)
    return float(lo), float(hi)


def _to_uint8(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    scaled = (np.asarray(values, dtype=np.float64) - lo) * (255.0 / max(hi - lo, 1e-12))
    return np.rint(np.clip(scaled, 0.0, 255.0)).astype(np.uint8)


def station_names(path: str | os.PathLike) -> list[str]:
    """The names of the scan stations of an E57 file, in file order."""
    e = _open(require_file(path, "E57 scan"))
    try:
        return [str(_value(e.data3d[i], "name", f"scan{i}")) for i in range(e.scan_count)]
    finally:
        e.close()


def select_stations(names: list[str], wanted: list[str] | None, path: Path) -> list[int]:
    """Indices of ``wanted`` stations, given by name or by 0-based index (all when None)."""
    if not wanted:
        return list(range(len(names)))
    out: list[int] = []
    for w in wanted:
        w = w.strip()
        if w in names:
            out.append(names.index(w))
        elif w.isdigit() and int(w) < len(names):
            out.append(int(w))
        else:
            raise InputError(f"--stations {w!r}: no such station in {path} (stations: "
                             f"{', '.join(f'{i}:{n}' for i, n in enumerate(names[:10]))}{', ...' if len(names) > 10 else ''})")
    return sorted(set(out))


def _read_station(e, i: int) -> E57Station:
    """Station ``i``: its points placed by its pose, colour from colour or intensity."""
    node = e.data3d[i]
    name = str(_value(node, "name", f"scan{i}"))
    header = e.get_header(i)
    fields = set(header.point_fields)
    if set(_CARTESIAN) <= fields:
        coords = "cartesian"
    elif set(_SPHERICAL) <= fields:
        coords = "spherical"
    else:
        raise InputError(f"E57 station {name} has neither cartesian nor spherical coordinates "
                         f"(fields: {', '.join(sorted(fields))})")
    has_color, has_int = set(_COLORS) <= fields, "intensity" in fields
    data = e.read_scan(i, colors=has_color, intensity=has_int, ignore_missing_fields=True, transform=False)
    if coords == "spherical":
        local = pye57_utils.convert_spherical_to_cartesian(np.stack([data[k] for k in _SPHERICAL], axis=1).astype(np.float64))
    else:
        local = np.stack([data[k] for k in _CARTESIAN], axis=1).astype(np.float64)
    R, t = _pose(node)
    points = local @ R.T + t
    colors, source = None, "none"
    if has_color:
        colors = np.stack([_to_uint8(data[k], *_limits(node, "colorLimits", (f"{k}Minimum", f"{k}Maximum"), data[k]))
                           for k in _COLORS], axis=1)
        source = "color"
    elif has_int:
        grey = _to_uint8(data["intensity"], *_limits(node, "intensityLimits", ("intensityMinimum", "intensityMaximum"),
                                                       data["intensity"]))
        colors, source = np.repeat(grey[:, None], 3, axis=1), "intensity"
    return E57Station(name, points, colors, source, t, coords)


def read_e57(path: str | os.PathLike, stations: list[str] | None = None) -> E57Scan:
    """The stations of an E57 file (``stations``: names or 0-based indices; all when None), each in
    the file's frame by its pose. One-line :class:`InputError` for an unreadable or truncated file,
    a file without scans or points, or an unknown station."""
    p = require_file(path, "E57 scan")
    e = _open(p)
    try:
        names = [str(_value(e.data3d[i], "name", f"scan{i}")) for i in range(e.scan_count)]
        if not names:
            raise InputError(f"E57 file has no scan stations (data3D is empty): {p}")
        try:
            read = [_read_station(e, i) for i in select_stations(names, stations, p)]
        except InputError:
            raise
        except Exception as exc:  # a truncated or damaged binary section
            raise InputError(f"cannot read the points of E57 file {p}: {_first_line(exc)}") from None
    finally:
        e.close()
    read = [s for s in read if len(s.points)]
    if not read:
        raise InputError(f"E57 file has no valid points in the chosen stations: {p}")
    for s in read:
        if not np.all(np.isfinite(s.points)):
            raise InputError(f"E57 station {s.name} has non-finite coordinates: {p}")
    scan = E57Scan(read, len(names))
    sources = sorted({s.color_source for s in read})
    scan.notes.append(f"E57: {len(read)} of {len(names)} station(s) ({', '.join(s.name for s in read[:6])}"
                      f"{', ...' if len(read) > 6 else ''}), {sum(len(s.points) for s in read)} points, "
                      f"each placed by its pose; colour from {' and '.join(sources)}")
    if "none" in sources and len(sources) > 1:
        scan.notes.append("E57: a station has neither colour nor intensity: the map's cloud has no colour")
    return scan


def e57_images(path: str | os.PathLike) -> list[E57Image]:
    """The ``images2D`` of an E57 file: full spherical images with their data, others with a note."""
    p = require_file(path, "E57 scan")
    e = _open(p)
    try:
        images = e.root["images2D"] if e.root.isDefined("images2D") else None
        n = images.childCount() if images is not None else 0
        return [_read_image(images.get(i), i, p) for i in range(n)]
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"cannot read the images of E57 file {p}: {_first_line(exc)}") from None
    finally:
        e.close()


def _read_image(raw, i: int, path: Path) -> E57Image:
    """Image ``i`` of ``images2D``: a full spherical image with its data, or one with a note why it is skipped."""
    node = libe57.StructureNode(raw)
    name = str(_value(node, "name", f"image{i}"))
    R, t = _pose(node) if node.isDefined("pose") else (None, None)
    rot = None if R is None else R.T  # the pose takes camera to file frame; ours is world to camera
    for kind in ("pinhole", "cylindrical"):
        if node.isDefined(f"{kind}Representation"):
            return E57Image(name, kind, rot, t, note=f"{kind} image: not a panorama, skipped")
    rep = _child(node, "sphericalRepresentation")
    if rep is None:
        return E57Image(name, "none", rot, t, note="no image representation, skipped")
    w, h = int(_value(rep, "imageWidth", 0)), int(_value(rep, "imageHeight", 0))
    pw, ph = float(_value(rep, "pixelWidth", 0.0)), float(_value(rep, "pixelHeight", 0.0))
    img = E57Image(name, "spherical", rot, t, width=w, height=h)
    if R is None:
        img.note = "spherical image without a pose, skipped"
    elif not (w > 0 and h > 0 and abs(w * pw - 2 * np.pi) <= FULL_SPHERE_TOLERANCE * 2 * np.pi
              and abs(h * ph - np.pi) <= FULL_SPHERE_TOLERANCE * np.pi):
        img.note = (f"spherical image covering {np.degrees(w * pw):.0f} x {np.degrees(h * ph):.0f} deg, "
                    "not the whole sphere: skipped")
    else:
        for key, suffix in (("jpegImage", ".jpg"), ("pngImage", ".png")):
            blob = _child(rep, key)
            if blob is not None:
                buf = np.empty(int(blob.byteCount()), dtype=np.uint8)
                blob.read(buf, 0, len(buf))
                img.data, img.suffix = buf.tobytes(), suffix
                break
        else:
            img.note = "spherical image without JPEG or PNG data, skipped"
        if img.data and not _decodes(img.data):
            img.note, img.data = f"spherical image whose {img.suffix[1:].upper()} data cannot be decoded, skipped", b""
    return img


def _decodes(data: bytes) -> bool:
    """Whether an image file's bytes decode (OpenCV)."""
    return cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_REDUCED_COLOR_8) is not None


# ------------------------------------------------------------------------------------------- writing


@dataclass
class StationToWrite:
    """A station for :func:`write_e57`: points in the station's own frame and its pose."""

    points: np.ndarray  # (N, 3) in the station frame
    rot_station_to_file: np.ndarray = field(default_factory=lambda: np.eye(3))
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    colors: np.ndarray | None = None  # (N, 3) uint8
    intensity: np.ndarray | None = None  # (N,) float
    spherical: bool = False  # store range, azimuth, elevation instead of x, y, z
    name: str = ""


@dataclass
class ImageToWrite:
    """A panorama for :func:`write_e57` (``jpeg``: the file's bytes) or a pinhole image (``kind``)."""

    name: str
    rot_cam_from_world: np.ndarray
    center: np.ndarray
    jpeg: bytes
    width: int
    height: int
    kind: str = "spherical"  # or "pinhole" (written with a pinholeRepresentation, for tests)


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of rotation matrix ``R``."""
    x, y, z, w = transform.Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    return np.array([w, x, y, z])


def _pose_node(imf, R: np.ndarray, t: np.ndarray):
    """An E57 ``pose`` node: rotation ``R`` (as a quaternion) and translation ``t``."""
    pose, rot, tr = libe57.StructureNode(imf), libe57.StructureNode(imf), libe57.StructureNode(imf)
    for k, v in zip("wxyz", _quat_wxyz(R)):
        rot.set(k, libe57.FloatNode(imf, float(v)))
    for k, v in zip("xyz", np.asarray(t, dtype=np.float64)):
        tr.set(k, libe57.FloatNode(imf, float(v)))
    pose.set("rotation", rot)
    pose.set("translation", tr)
    return pose


def _write_station(imf, data3d, st: StationToWrite, index: int) -> None:
    """Append station ``st`` to ``data3D``: its pose, point prototype, limits and points."""
    P = np.asarray(st.points, dtype=np.float64)
    node = libe57.StructureNode(imf)
    node.set("guid", libe57.StringNode(imf, "{%s}" % uuid.uuid4()))
    node.set("name", libe57.StringNode(imf, st.name or f"station{index}"))
    node.set("pose", _pose_node(imf, st.rot_station_to_file, st.center))
    proto = libe57.StructureNode(imf)
    if st.spherical:
        r = np.linalg.norm(P, axis=1)
        cols = {"sphericalRange": r, "sphericalAzimuth": np.arctan2(P[:, 1], P[:, 0]),
                "sphericalElevation": np.arcsin(np.clip(P[:, 2] / np.maximum(r, 1e-12), -1, 1))}
    else:
        cols = dict(zip(_CARTESIAN, P.T))
    for k, v in cols.items():
        proto.set(k, libe57.FloatNode(imf, float(v.min()), libe57.E57_DOUBLE, float(v.min()), float(v.max())))
    if st.colors is not None:
        limits = libe57.StructureNode(imf)
        for k, v in zip(_COLORS, np.asarray(st.colors).T):
            proto.set(k, libe57.IntegerNode(imf, 0, 0, 255))
            limits.set(f"{k}Minimum", libe57.IntegerNode(imf, 0))
            limits.set(f"{k}Maximum", libe57.IntegerNode(imf, 255))
            cols[k] = v
        node.set("colorLimits", limits)
    if st.intensity is not None:
        inten = np.asarray(st.intensity, dtype=np.float64)
        proto.set("intensity", libe57.FloatNode(imf, float(inten.min()), libe57.E57_DOUBLE, float(inten.min()), float(inten.max())))
        limits = libe57.StructureNode(imf)
        limits.set("intensityMinimum", libe57.FloatNode(imf, float(inten.min())))
        limits.set("intensityMaximum", libe57.FloatNode(imf, float(inten.max())))
        node.set("intensityLimits", limits)
        cols["intensity"] = inten
    points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
    node.set("points", points)
    data3d.append(node)
    arrays = {k: np.ascontiguousarray(v, dtype=np.uint8 if k in _COLORS else np.float64) for k, v in cols.items()}
    buffers = libe57.VectorSourceDestBuffer()
    for k, a in arrays.items():
        buffers.append(libe57.SourceDestBuffer(imf, k, a, len(a), True, True))
    writer = points.writer(buffers)
    writer.write(len(P))
    writer.close()


def _write_image(imf, images2d, im: ImageToWrite) -> None:
    """Append image ``im`` to ``images2D``: its pose, a spherical or pinhole representation and its JPEG."""
    node = libe57.StructureNode(imf)
    node.set("guid", libe57.StringNode(imf, "{%s}" % uuid.uuid4()))
    node.set("name", libe57.StringNode(imf, im.name))
    node.set("pose", _pose_node(imf, np.asarray(im.rot_cam_from_world).T, im.center))
    rep = libe57.StructureNode(imf)
    blob = libe57.BlobNode(imf, len(im.jpeg))
    rep.set("jpegImage", blob)
    rep.set("imageWidth", libe57.IntegerNode(imf, int(im.width)))
    rep.set("imageHeight", libe57.IntegerNode(imf, int(im.height)))
    if im.kind == "spherical":
        rep.set("pixelWidth", libe57.FloatNode(imf, 2 * np.pi / im.width))
        rep.set("pixelHeight", libe57.FloatNode(imf, np.pi / im.height))
        node.set("sphericalRepresentation", rep)
    else:
        rep.set("focalLength", libe57.FloatNode(imf, 0.01))
        rep.set("pixelWidth", libe57.FloatNode(imf, 1e-5))
        rep.set("pixelHeight", libe57.FloatNode(imf, 1e-5))
        rep.set("principalPointX", libe57.FloatNode(imf, im.width / 2))
        rep.set("principalPointY", libe57.FloatNode(imf, im.height / 2))
        node.set("pinholeRepresentation", rep)
    images2d.append(node)
    buf = np.frombuffer(im.jpeg, dtype=np.uint8).copy()
    blob.write(buf, 0, len(buf))


def write_e57(path: str | os.PathLike, stations: list[StationToWrite], images: list[ImageToWrite] = ()) -> Path:
    """Write stations (and images) as an E57 file, atomically."""
    target = Path(path)
    with atomic_file(target) as tmp:
        e = pye57.E57(str(tmp), mode="w")
        try:
            imf = e.image_file
            for i, st in enumerate(stations):
                _write_station(imf, e.data3d, st, i)
            for im in images:
                _write_image(imf, e.root["images2D"], im)
        finally:
            e.close()
    return target
