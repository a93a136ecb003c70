"""The LDL map file: one HDF5 file per scene, versioned. This module is the only one that opens it.

Schema (``FORMAT_VERSION`` 3; a map with 3 principal directions is written as version 1, the
layout every reader since version 1 knows; one with more, an Atlanta frame of several horizontal
directions, as version 2; one with distance fields as version 3, its fields stored as uint8 steps
``q`` (``distance_quantum * q**2`` radians, ``distance_quantum`` = pi / 255**2) instead of float16, half the size; older
readers refuse versions newer than theirs). World frame metric, z up (docs/formats.md). All groups and
datasets are readable with plain h5py::

    /                       attrs: format_version (int), name (str), created_with (str),
                            build_config (JSON str), library_versions (JSON str)
    /cloud/bounds_min       (3,) float64   robust bounding box of the input cloud (or line end points), metres:
                            the 2-98 % percentile box grown by 10 %, within the full box
    /cloud/bounds_max       (3,) float64
    /cloud/points           (P, 3) float32 subsampled colored cloud (for pictures and checks)
    /cloud/colors           (P, 3) uint8   RGB
    /lines/raw              (L0, 2, 3) float32  3D segments (start, end) before the length filter
    /lines/segments         (L, 2, 3) float32   after the length filter (used for localization)
    /lines/groups           (L,) int8   principal direction index 0..K-1 of each kept line, -1 none
                            attrs: length_threshold (m), kept_ratio (L / L0), lambda
    /principal/directions   (K, 3) float64  rows: the K principal 3D directions; K = 3 (version 1: the
                            first three right-handed) or, version 2, 4 .. MAX_PRINCIPAL (an Atlanta
                            frame: the vertical, two horizontals as rows 0-2, more horizontals after)
    /translations/centers   (N_t, 3) float32  candidate camera centres
    /lines/visibility       (N_t, L) uint8  optional: 1 where kept line l is seen from translation i
                            (maps with walls, e.g. room layouts: walls hide the other lines)
    /coverage/mapped        (N_t, G + 1, 2G) uint8  optional: 1 where the direction of node (i, j)
                            (the fields' grid) seen from translation t meets a mapped surface
                            (walls, floors, ceilings of a layout); 0 where it leaves the map
    /frame/input_to_map     (4, 4) float64  optional: similarity X_map = s R X_input from the build's input
                            frame (SfM: any up axis, any unit) to this map's (metric, z up); maps
                            without it were built in their input frame (identity)
    /free_space/footprint   (FX, FY) uint8  optional (maps built from a scan): 1 where the xy cell's column
                            holds no scan point 1.2-1.8 m above a floor (walls, the outside: 0; open doors: 1)
    /free_space/grid        (3,) float64  with it: world x, y of cell (0, 0)'s lower corner and the cell size (m)
    /translations/view_index (N_t,) int32  index of the rendered view that serves each candidate
                            (only when features are present)
    /features               attrs: backend ('sift' | 'aliked' | 'disk' | 'xfeat' | 'superpoint'), descriptor_dim,
                            width, height, extraction ('equirect' | 'cube': features of the
                            panoramas or of their cube faces, ldlmap.features.sphere; absent: equirect)
    /features/view_centers  (V, 3) float32  where views were rendered (identity rotation)
    /features/offsets       (V + 1,) int64  keypoints of view i are rows offsets[i]:offsets[i+1]
    /features/xyz           (K, 3) float32  keypoint positions in the world
    /features/keypoints     (K, 2) float32  pixel coordinates in the rendered view
    /features/scores        (K,) float16
    /features/descriptors   (K, D) uint8 (SIFT) or float16 (the learned backends)
    /fields/distances       (N_t, K, G + 1, 2G) float16  optional precomputed 3D distance fields:
                            f3D_g (radians) of each translation on an equirectangular node grid
                            (theta_i = i pi / G from +z, phi_j = -pi + j pi / G), world-aligned
                            attrs: kind ('equirect_nodes'), rows (G), num_groups, version
                            (layout and accuracy: ``ldlmap.map.fields3d``)

A lines-only map (built from a line file) has no ``/cloud/points``, no ``/features`` group
and is enough for pose search without refinement.
"""

from __future__ import annotations

import importlib.metadata as md
import json
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ldlmap.core.errors import FormatVersionError, HDF5_SIGNATURE, InputError, atomic_file, require_file, starts_with
from ldlmap.core.lazy import lazy_module
from ldlmap.map.contents import Footprint, LdlMap, MapFeatures
from ldlmap.map.validate import KINDS, KIND_NAMES, check_line_header, is_int, manhattan_map, validate_map

h5py = lazy_module("h5py")


FORMAT_VERSION = 3  # the newest version this code reads and writes (it reads every version from 1)
_VERSION_3_DIRECTIONS = 1  # what maps of 3 principal directions are written as (unchanged since version 1)
_VERSION_MANY_DIRECTIONS = 2  # maps of more principal directions, float16 fields
_VERSION_QUANTIZED = 3  # maps with distance fields, stored as uint8 codes q of DISTANCE_QUANTUM * q**2 radians
DISTANCE_QUANTUM = float(np.pi / 255 ** 2)  # square-root coding: steps of 0.0014 rad at 0.01 rad, 0.0044 at the search's
# inlier threshold (0.1 rad), 0.025 at pi (no line): fine where lines are near (docs/measurements.md#fields-uint8)
_COMPRESS = dict(compression="gzip", compression_opts=4, shuffle=True)

def _library_versions() -> dict[str, str]:
    out = {}
    for pkg in ("ldl-toolkit", "numpy", "torch", "open3d", "opencv-python-headless", "h5py", "pycolmap"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


def map_format_version(m: LdlMap) -> int:
    """The format version ``m`` is written as: 3 with distance fields (stored quantized), else 1 with 3
    principal directions (readable by every version), 2 with more."""
    if m.fields.get("distances") is not None:
        return _VERSION_QUANTIZED
    return _VERSION_3_DIRECTIONS if len(m.principal_directions) == 3 else _VERSION_MANY_DIRECTIONS


def quantized_distances(d: np.ndarray) -> np.ndarray:
    """Distance fields (radians in [0, pi]) as uint8 codes q, ``d ~ DISTANCE_QUANTUM * q**2`` (nearest code)."""
    d = np.maximum(np.asarray(d, np.float32), 0.0)
    return np.clip(np.rint(np.sqrt(d / np.float32(DISTANCE_QUANTUM))), 0, 255).astype(np.uint8)


def dequantized_distances(q: np.ndarray, quantum: float) -> np.ndarray:
    """Stored uint8 codes back to float16 radians, ``quantum * q**2`` (float16 fields, as version 1 and 2 maps
    store, pass through)."""
    if q.dtype != np.uint8:
        return q
    return (np.square(q.astype(np.float32)) * np.float32(quantum)).astype(np.float16)


def stored_distances(h5, stored: np.ndarray, path: Path) -> np.ndarray:
    """A map's distance fields as float16 radians: uint8 steps (version 3) scaled by the ``/fields``
    attr ``distance_quantum``, float16 (versions 1-2) as stored."""
    if stored.dtype != np.uint8:
        return stored
    quantum = _attr_value(h5["fields"], "distance_quantum", "float", path)
    if not 0 < quantum * 255 ** 2 <= 4:  # a missing attribute is refused by _attr_value
        raise InputError(f"corrupt LDL map {path}: uint8 distance fields need a /fields distance_quantum in (0, 4 / 255**2], "
                         f"got {quantum!r}")
    return dequantized_distances(stored, quantum)


def write_map(path: str | Path, m: LdlMap) -> Path:
    """Validate ``m`` and write it to ``path`` atomically (temporary file, then rename)."""
    validate_map(m)
    path = Path(path)
    with atomic_file(path) as tmp:
        # Built in memory, then written as one file image: a disk that fills up (or a file size
        # limit) is then an OSError of a plain write, not an HDF5 driver failure that leaves the
        # library in a state that crashes the interpreter at exit (exit 139).
        with h5py.File(tmp, "w", driver="core", backing_store=False) as h5:
            h5.attrs["format_version"] = map_format_version(m)
            h5.attrs["name"] = m.name
            h5.attrs["created_with"] = "ldl-toolkit"
            h5.attrs["build_config"] = json.dumps(m.config, sort_keys=True, default=str)
            h5.attrs["library_versions"] = json.dumps(_library_versions(), sort_keys=True)
            c = h5.create_group("cloud")
            c["bounds_min"] = np.asarray(m.bounds_min, np.float64)
            c["bounds_max"] = np.asarray(m.bounds_max, np.float64)
            if m.cloud_points is not None:
                c.create_dataset("points", data=np.asarray(m.cloud_points, np.float32), **_COMPRESS)
                if m.cloud_colors is not None:
                    c.create_dataset("colors", data=np.asarray(m.cloud_colors, np.uint8), **_COMPRESS)
            g = h5.create_group("lines")
            g.create_dataset("raw", data=np.asarray(m.lines_raw, np.float32).reshape(-1, 2, 3), **_COMPRESS)
            g.create_dataset("segments", data=np.asarray(m.lines, np.float32).reshape(-1, 2, 3), **_COMPRESS)
            g["groups"] = np.asarray(m.line_groups, np.int8)
            g.attrs["length_threshold"] = float(m.length_threshold)
            g.attrs["kept_ratio"] = float(m.kept_ratio)
            g.attrs["lambda"] = float(m.line_lambda)
            if m.visibility is not None:
                g.create_dataset("visibility", data=np.asarray(m.visibility, np.uint8), **_COMPRESS)
            if m.coverage is not None:
                h5.create_group("coverage").create_dataset("mapped", data=np.asarray(m.coverage, np.uint8), **_COMPRESS)
            h5.create_group("principal")["directions"] = np.asarray(m.principal_directions, np.float64)
            if m.input_to_map is not None:
                h5.create_group("frame")["input_to_map"] = np.asarray(m.input_to_map, np.float64)
            if m.footprint is not None:
                fs = h5.create_group("free_space")
                fs.create_dataset("footprint", data=np.asarray(m.footprint.mask, np.uint8), **_COMPRESS)
                fs["grid"] = np.array([*np.asarray(m.footprint.origin, np.float64), m.footprint.cell])
            t = h5.create_group("translations")
            t["centers"] = np.asarray(m.translations, np.float32)
            f = m.features
            if f is not None:
                t["view_index"] = np.asarray(f.translation_view, np.int32)
                fg = h5.create_group("features")
                fg.attrs["backend"] = f.backend
                fg.attrs["descriptor_dim"] = int(f.descriptors.shape[1])
                fg.attrs["width"] = int(f.width)
                fg.attrs["height"] = int(f.height)
                fg.attrs["extraction"] = str(f.extraction)
                fg["view_centers"] = np.asarray(f.view_centers, np.float32)
                fg["offsets"] = np.asarray(f.offsets, np.int64)
                fg.create_dataset("xyz", data=np.asarray(f.xyz, np.float32), **_COMPRESS)
                fg.create_dataset("keypoints", data=np.asarray(f.keypoints, np.float32), **_COMPRESS)
                fg.create_dataset("scores", data=np.asarray(f.scores, np.float16), **_COMPRESS)
                desc = f.descriptors
                desc = desc if desc.dtype == np.uint8 else np.asarray(desc, np.float16)
                fg.create_dataset("descriptors", data=desc, chunks=(min(len(desc), 4096) or 1, desc.shape[1]), **_COMPRESS)
            if m.fields:
                fl = h5.create_group("fields")
                for k, v in m.fields_attrs.items():
                    fl.attrs[k] = v
                fl.attrs["distance_quantum"] = DISTANCE_QUANTUM
                for k, v in m.fields.items():
                    fl.create_dataset(k, data=quantized_distances(v) if k == "distances" else v, **_COMPRESS)
            h5.flush()
            h5.attrs[_CHECKSUMS] = json.dumps(_checksums(*_read_datasets(h5, path)), sort_keys=True)
            h5.flush()
            image = h5.id.get_file_image()
        try:
            with open(tmp, "wb") as fh:
                fh.write(image)
        except OSError as exc:  # ENOSPC, EFBIG, EDQUOT: said of the map, not of its temporary file
            raise InputError(f"cannot write map {path}: {exc.strerror or exc}") from None
    return path


_CHECKSUMS = "checksums"  # root attribute (absent in older maps: docs/measurements.md#map-checksums): JSON
# {"datasets": {path: crc32}, "attrs": crc32}
_H5_ERRORS = (KeyError, OSError, ValueError, TypeError, RuntimeError)  # what h5py raises on a damaged file

# Stored datasets: path -> (kind, shape). Kinds as in ``KINDS``; a named size (L: kept lines,
# N: candidate translations, K: keypoints, ...) must be the same in every dataset that names it.
_SCHEMA: dict[str, tuple[str, tuple]] = {
    "cloud/bounds_min": ("f", (3,)),
    "cloud/bounds_max": ("f", (3,)),
    "cloud/points": ("f", ("P", 3)),
    "cloud/colors": ("u", ("P", 3)),
    "lines/raw": ("f", ("L0", 2, 3)),
    "lines/segments": ("f", ("L", 2, 3)),
    "lines/groups": ("i", ("L",)),
    "lines/visibility": ("b", ("N", "L")),
    "coverage/mapped": ("b", ("N", "C1", "C2")),
    "principal/directions": ("f", ("NP", 3)),
    "frame/input_to_map": ("f", (4, 4)),
    "free_space/footprint": ("b", ("FX", "FY")),
    "free_space/grid": ("f", (3,)),
    "translations/centers": ("f", ("N", 3)),
    "translations/view_index": ("i", ("N",)),
    "features/view_centers": ("f", ("V", 3)),
    "features/offsets": ("i", ("V1",)),
    "features/xyz": ("f", ("K", 3)),
    "features/keypoints": ("f", ("K", 2)),
    "features/scores": ("f", ("K",)),
    "features/descriptors": ("d", ("K", "D")),
    "fields/distances": ("d", ("N", "F", "G1", "G2")),  # float16 (versions 1-2) or uint8 steps (3)
}
_REQUIRED = ("cloud/bounds_min", "cloud/bounds_max", "lines/raw", "lines/segments", "lines/groups",
             "principal/directions", "translations/centers")
_FEATURE_DATASETS = ("features/view_centers", "features/offsets", "features/xyz", "features/keypoints",
                     "features/scores", "features/descriptors", "translations/view_index")
_MAX_EXPANSION = 1000  # a dataset may hold at most this many times its file's size (gzip of zeros: ~1000x)


def _dataset_items(h5) -> list[tuple[str, Any]]:
    """Every dataset of the file as ``(path, dataset)``, sorted by path."""
    out: list[tuple[str, Any]] = []
    h5.visititems(lambda name, obj: out.append((name, obj)) if isinstance(obj, h5py.Dataset) else None)
    return sorted(out, key=lambda item: item[0])


def _read_datasets(h5, path: Path, max_bytes: int | None = None) -> tuple[dict[str, np.ndarray], list]:
    """Every dataset's array by path (after a size check against ``max_bytes``) and every object
    holding attributes (root, groups, datasets), for the checksums."""
    items = _dataset_items(h5)
    if max_bytes is not None:
        for name, ds in items:
            if ds.size * ds.dtype.itemsize > max_bytes:
                raise InputError(f"corrupt LDL map {path}: dataset /{name} claims shape {ds.shape}, more than "
                                 f"its file can hold")
    data = {name: ds[()] for name, ds in items}
    objects: list = [h5]
    h5.visititems(lambda name, obj: objects.append(obj))
    return data, objects


def _bytes_of(value: Any) -> bytes:
    """A canonical byte string of an array or attribute value (dtype, shape and contents)."""
    if isinstance(value, str):
        return b"s" + value.encode("utf-8", "surrogatepass")
    if isinstance(value, bytes):
        return b"b" + value
    a = np.asarray(value)
    head = f"{a.dtype.str}{a.shape}".encode()
    if a.dtype.kind == "O":
        return head + repr(a.tolist()).encode("utf-8", "surrogatepass")
    return head + np.ascontiguousarray(a).tobytes()


def _crc_of_array(a: np.ndarray) -> int:
    """CRC-32 of an array's dtype, shape and bytes (read in place: no copy of large arrays)."""
    if a.dtype.kind == "O" or a.ndim == 0:
        return zlib.crc32(_bytes_of(a))
    crc = zlib.crc32(f"{a.dtype.str}{a.shape}".encode())
    return zlib.crc32(np.ascontiguousarray(a).reshape(-1).view(np.uint8), crc)


def _checksums(data: dict[str, np.ndarray], objects: list) -> dict[str, Any]:
    """CRC-32 of every dataset (dtype, shape, bytes) and one over every attribute of every object."""
    attrs = 0
    for obj in objects:
        for key in sorted(obj.attrs.keys()):
            if obj.name == "/" and key == _CHECKSUMS:
                continue
            attrs = zlib.crc32(f"{obj.name}@{key}=".encode() + _bytes_of(obj.attrs[key]), attrs)
    return {"datasets": {name: _crc_of_array(np.asarray(a)) for name, a in data.items()}, "attrs": attrs}


def _verify_checksums(h5, data: dict[str, np.ndarray], objects: list, path: Path) -> bool:
    """Compare with the stored checksums; False for maps written before checksums (not verifiable)."""
    if _CHECKSUMS not in h5.attrs:
        return False
    try:
        stored = json.loads(_attr_value(h5, _CHECKSUMS, "str", path))
        stored_sets, stored_attrs = dict(stored["datasets"]), stored["attrs"]
    except (ValueError, KeyError, TypeError):
        raise InputError(f"corrupt LDL map {path}: its checksums attribute is unreadable") from None
    now = _checksums(data, objects)
    bad = sorted(k for k in set(now["datasets"]) | set(stored_sets) if now["datasets"].get(k) != stored_sets.get(k))
    if bad:
        raise InputError(f"corrupt LDL map {path}: dataset /{bad[0]} fails its checksum (flipped bits, or changed "
                         f"after it was written): rebuild the map")
    if now["attrs"] != stored_attrs:
        raise InputError(f"corrupt LDL map {path}: its attributes fail their checksum (flipped bits, or changed "
                         f"after it was written): rebuild the map")
    return True


def _attr_value(obj, key: str, kind: str, path: Path, default: Any = None) -> Any:
    """Attribute ``key`` of ``obj`` checked as ``kind`` (int, float, str, json: a JSON object);
    ``default`` when absent (None: required)."""
    where = f"attribute {key} of {obj.name}"
    if key not in obj.attrs:
        if default is None:
            raise InputError(f"corrupt LDL map {path}: {where} is missing")
        return default
    v = obj.attrs[key]
    if kind == "int":
        if not is_int(v):
            raise InputError(f"corrupt LDL map {path}: {where} must be an integer, got {str(v)[:40]!r}")
        return int(v)
    if kind == "float":
        if np.ndim(v) != 0 or not isinstance(v, (int, float, np.integer, np.floating)) or isinstance(v, (bool, np.bool_)):
            raise InputError(f"corrupt LDL map {path}: {where} must be a number, got {str(v)[:40]!r}")
        return float(v)
    if isinstance(v, bytes):
        try:
            v = v.decode("utf-8")
        except UnicodeDecodeError:
            v = None
    if not isinstance(v, str):
        raise InputError(f"corrupt LDL map {path}: {where} must be text, got {str(v)[:40]!r}")
    if kind == "json":
        try:
            v = json.loads(v)
        except ValueError:
            v = None
        if not isinstance(v, dict):
            raise InputError(f"corrupt LDL map {path}: {where} is not a JSON object")
    return v


def is_map_file(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file written as an LDL map (``format_version`` and ``lines``), of
    any version: the files a build may replace without ``--overwrite`` (never a user's other HDF5)."""
    if not starts_with(path, HDF5_SIGNATURE):
        return False
    try:
        with h5py.File(path, "r") as h5:
            return "format_version" in h5.attrs and isinstance(h5.get("lines"), h5py.Group)
    except _H5_ERRORS:
        return False


def _open(path: Path):
    try:
        return h5py.File(path, "r")
    except _H5_ERRORS:
        raise InputError(f"not a readable HDF5 map (corrupt or another format): {path}") from None


def _check_version(h5, path: Path) -> int:
    """The map's format version; FormatVersionError for one this code cannot read."""
    if "format_version" not in h5.attrs:
        raise InputError(f"not an LDL map (no format_version attribute): {path}")
    v = h5.attrs["format_version"]
    if not is_int(v):
        raise InputError(f"corrupt LDL map {path}: format_version must be an integer, got {str(v)[:40]!r}")
    v = int(v)
    if not 1 <= v <= FORMAT_VERSION:
        newer = "a newer" if v > FORMAT_VERSION else "an older"
        raise FormatVersionError(
            f"map {path} has format version {v}, this ldl-toolkit reads versions 1 to {FORMAT_VERSION} "
            f"({newer} version wrote it): rebuild it with `ldlmap build`")
    ds = h5.get("principal/directions")
    shape = ds.shape if isinstance(ds, h5py.Dataset) else None
    k = shape[0] if shape is not None and len(shape) == 2 and shape[1] == 3 else 3  # other shapes: _check_schema
    if v < _VERSION_QUANTIZED and (k == 3) != (v == _VERSION_3_DIRECTIONS):
        raise InputError(f"corrupt LDL map {path}: format version {v} with {k} principal directions "
                         f"(version 1 has 3, version 2 more)")
    return v


def _check_schema(h5, path: Path) -> None:
    """Every required dataset present, each known one with its kind and a shape consistent with the others."""
    required = list(_REQUIRED) + (list(_FEATURE_DATASETS) if "features" in h5 else [])
    required += ["cloud/points"] if "cloud/colors" in h5 else []
    required += ["free_space/footprint", "free_space/grid"] if "free_space" in h5 else []
    for name in required:
        if name not in h5:
            raise InputError(f"corrupt LDL map {path}: dataset /{name} is missing")
    sizes: dict[str, int] = {}
    for name, (kind, shape) in _SCHEMA.items():
        if name not in h5:
            continue
        ds = h5[name]
        if not isinstance(ds, h5py.Dataset):
            raise InputError(f"corrupt LDL map {path}: /{name} is not a dataset")
        if ds.dtype.kind not in KINDS[kind]:
            raise InputError(f"corrupt LDL map {path}: dataset /{name} has dtype {ds.dtype}, expected {KIND_NAMES[kind]}")
        ok = len(ds.shape) == len(shape)
        for want, got in zip(shape, ds.shape):
            ok = ok and (sizes.setdefault(want, got) == got if isinstance(want, str) else want == got)
        if not ok:
            expected = "(" + ", ".join(f"{w}={sizes[w]}" if isinstance(w, str) and w in sizes else str(w) for w in shape) + ")"
            raise InputError(f"corrupt LDL map {path}: dataset /{name} has shape {ds.shape}, expected {expected}")


def _group_counts(groups: np.ndarray, num_groups: int = 3) -> dict[int, int]:
    """Lines per principal group: ``{0: n0, .., K-1: n_K-1, -1: unassigned}`` (zeros kept)."""
    g = np.asarray(groups, dtype=np.int64)
    return {k: int(np.sum(g == k)) for k in (*range(num_groups), -1)}


def read_map_header(path: str | Path) -> dict[str, Any]:
    """Format version, name, build config and sizes of a map, its principal directions (K, 3) and
    kept lines per principal group (``line_group_counts``: group -> count, -1 = none), without
    loading the large arrays. The layout (datasets, dtypes, shapes, attributes), the principal
    directions and group labels are validated; the values of the large arrays and the checksums
    only by :func:`read_map`."""
    path = require_file(path, "map")
    with _open(path) as h5:
        try:
            version = _check_version(h5, path)
            _check_schema(h5, path)
            config = _attr_value(h5, "build_config", "json", path, "{}")
            principal = np.asarray(h5["principal/directions"][()], dtype=np.float64)
            groups = h5["lines/groups"][()]
            info = {
                "format_version": version,
                "name": _attr_value(h5, "name", "str", path, path.stem),
                "build_config": config,
                "library_versions": _attr_value(h5, "library_versions", "json", path, "{}"),
                "num_lines_raw": int(h5["lines/raw"].shape[0]),
                "num_lines": int(h5["lines/segments"].shape[0]),
                "kept_ratio": _attr_value(h5["lines"], "kept_ratio", "float", path),
                "length_threshold": _attr_value(h5["lines"], "length_threshold", "float", path),
                "num_translations": int(h5["translations/centers"].shape[0]),
                "num_cloud_points": int(h5["cloud/points"].shape[0]) if "cloud/points" in h5 else 0,
                "feature_backend": _attr_value(h5["features"], "backend", "str", path) if "features" in h5 else None,
                "feature_extraction": (_attr_value(h5["features"], "extraction", "str", path, "equirect")
                                       if "features" in h5 else None),
                "num_views": int(h5["features/view_centers"].shape[0]) if "features" in h5 else 0,
                "num_keypoints": int(h5["features/xyz"].shape[0]) if "features" in h5 else 0,
                "fields": sorted(h5["fields"].keys()) if "fields" in h5 else [],
                "line_visibility": "lines/visibility" in h5,
                "input_to_map": h5["frame/input_to_map"][()].tolist() if "frame/input_to_map" in h5 else None,
                "principal_directions": principal,
                "line_group_counts": _group_counts(groups, len(principal)),
                "checksummed": _CHECKSUMS in h5.attrs,
                "file_size_bytes": path.stat().st_size,
            }
            check_line_header(groups, info["length_threshold"], info["kept_ratio"], principal, manhattan_map(config))
        except _H5_ERRORS as exc:
            raise InputError(f"corrupt LDL map {path}: {_short(exc)}") from None
        except InputError as exc:
            raise _located(exc, path) from None
    return info


def _short(exc: BaseException) -> str:
    """The first line of an exception's message, for a one-line error."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:200] if text else ''}"


def _located(exc: InputError, path: Path) -> InputError:
    """``exc`` with the map's path in its message (messages from :func:`validate_map` lack it)."""
    msg = str(exc)
    return exc if str(path) in msg else InputError(f"invalid LDL map {path}: {msg}")


def read_map(path: str | Path, load_cloud: bool = True) -> LdlMap:
    """Load and validate a map (layout, values, checksums); raise InputError / FormatVersionError
    with one-line messages."""
    path = require_file(path, "map")
    max_bytes = _MAX_EXPANSION * path.stat().st_size + (1 << 26)
    with _open(path) as h5:
        try:
            _check_version(h5, path)
            _check_schema(h5, path)
            data, objects = _read_datasets(h5, path, max_bytes)
            _verify_checksums(h5, data, objects, path)
            m = _map_from(h5, data, path, load_cloud)
        except _H5_ERRORS as exc:
            raise InputError(f"corrupt LDL map {path}: {_short(exc)}") from None
        except InputError as exc:
            raise _located(exc, path) from None
    try:
        validate_map(m)
    except InputError as exc:
        raise _located(exc, path) from None
    return m


def _map_from(h5, data: dict[str, np.ndarray], path: Path, load_cloud: bool) -> LdlMap:
    """The :class:`LdlMap` of a file whose layout passed :func:`_check_schema`."""
    def get(name: str, dtype=None):
        a = data.get(name)
        return None if a is None or dtype is None else a.astype(dtype)

    feats = None
    if "features" in h5:
        fg = h5["features"]
        feats = MapFeatures(
            backend=_attr_value(fg, "backend", "str", path),
            view_centers=get("features/view_centers", np.float64),
            offsets=get("features/offsets", np.int64),
            xyz=data["features/xyz"],
            keypoints=data["features/keypoints"],
            scores=data["features/scores"],
            descriptors=data["features/descriptors"],
            translation_view=get("translations/view_index", np.int64),
            width=_attr_value(fg, "width", "int", path, 1024),
            height=_attr_value(fg, "height", "int", path, 512),
            extraction=_attr_value(fg, "extraction", "str", path, "equirect"),
        )
        dim = _attr_value(fg, "descriptor_dim", "int", path, feats.descriptors.shape[1])
        if dim != feats.descriptors.shape[1]:
            raise InputError(f"map features: descriptor_dim {dim} but descriptors have {feats.descriptors.shape[1]}")
    has_fields = "fields/distances" in data
    lines_grp = h5["lines"]
    return LdlMap(
        name=_attr_value(h5, "name", "str", path, path.stem),
        bounds_min=get("cloud/bounds_min", np.float64),
        bounds_max=get("cloud/bounds_max", np.float64),
        lines_raw=get("lines/raw", np.float64),
        lines=get("lines/segments", np.float64),
        line_groups=get("lines/groups", np.int64),
        length_threshold=_attr_value(lines_grp, "length_threshold", "float", path),
        kept_ratio=_attr_value(lines_grp, "kept_ratio", "float", path),
        line_lambda=_attr_value(lines_grp, "lambda", "float", path, 0.1),
        principal_directions=get("principal/directions", np.float64),
        translations=get("translations/centers", np.float64),
        cloud_points=data.get("cloud/points") if load_cloud else None,
        cloud_colors=data.get("cloud/colors") if load_cloud else None,
        features=feats,
        fields={"distances": stored_distances(h5, data["fields/distances"], path)} if has_fields else {},
        fields_attrs=dict(h5["fields"].attrs) if has_fields else {},
        config=_attr_value(h5, "build_config", "json", path, "{}"),
        visibility=get("lines/visibility", bool),
        coverage=get("coverage/mapped", bool),
        input_to_map=get("frame/input_to_map", np.float64),
        footprint=_footprint(data),
    )


def _footprint(data: dict[str, np.ndarray]) -> Footprint | None:
    """The stored :class:`Footprint` (None in maps without one: built before it, or without a scan)."""
    mask, grid = data.get("free_space/footprint"), data.get("free_space/grid")
    if mask is None or grid is None:
        return None
    return Footprint(mask.astype(bool), grid[:2].astype(np.float64), float(grid[2]))
