"""The LDL map file: one HDF5 file per scene, versioned. This module is the only one that opens it.

Schema (``FORMAT_VERSION`` 1). World frame metric, z up (DESIGN.md section 2). All groups and
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
    /lines/groups           (L,) int8   principal direction index 0..2 of each kept line, -1 none
                            attrs: length_threshold (m), kept_ratio (L / L0), lambda
    /principal/directions   (3, 3) float64  rows: the 3 principal 3D directions (right-handed)
    /translations/centers   (N_t, 3) float32  candidate camera centres
    /lines/visibility       (N_t, L) uint8  optional: 1 where kept line l is seen from translation i
                            (maps with walls, e.g. room layouts: walls hide the other lines)
    /coverage/mapped        (N_t, G + 1, 2G) uint8  optional: 1 where the direction of node (i, j)
                            (the fields' grid) seen from translation t meets a mapped surface
                            (walls, floors, ceilings of a layout); 0 where it leaves the map
    /frame/input_to_map     (4, 4) float64  optional: similarity X_map = s R X_input from the build's input
                            frame (SfM: any up axis, any unit) to this map's (metric, z up); maps
                            without it were built in their input frame (identity)
    /translations/view_index (N_t,) int32  index of the rendered view that serves each candidate
                            (only when features are present)
    /features               attrs: backend ('sift' | 'superpoint'), descriptor_dim, width, height
    /features/view_centers  (V, 3) float32  where views were rendered (identity rotation)
    /features/offsets       (V + 1,) int64  keypoints of view i are rows offsets[i]:offsets[i+1]
    /features/xyz           (K, 3) float32  keypoint positions in the world
    /features/keypoints     (K, 2) float32  pixel coordinates in the rendered view
    /features/scores        (K,) float16
    /features/descriptors   (K, D) uint8 (SIFT) or float16 (SuperPoint)
    /fields/distances       (N_t, 3, G + 1, 2G) float16  optional precomputed 3D distance fields:
                            f3D_g (radians) of each translation on an equirectangular node grid
                            (theta_i = i pi / G from +z, phi_j = -pi + j pi / G), world-aligned
                            attrs: kind ('equirect_nodes'), rows (G), num_groups, version
                            (layout and accuracy: ``ldlmap.fields3d``)

A lines-only map (built from a line file) has no ``/cloud/points``, no ``/features`` group
and is enough for pose search without refinement.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ldlmap.errors import FormatVersionError, InputError, atomic_file, require_file

FORMAT_VERSION = 1
_COMPRESS = dict(compression="gzip", compression_opts=4, shuffle=True)


@dataclass
class MapFeatures:
    """Local features of the rendered views, stored as one ragged (CSR) table."""

    backend: str
    view_centers: np.ndarray  # (V, 3)
    offsets: np.ndarray  # (V + 1,)
    xyz: np.ndarray  # (K, 3)
    keypoints: np.ndarray  # (K, 2)
    scores: np.ndarray  # (K,)
    descriptors: np.ndarray  # (K, D)
    translation_view: np.ndarray  # (N_t,) view serving each candidate translation
    width: int = 1024
    height: int = 512

    @property
    def num_views(self) -> int:
        return int(len(self.view_centers))

    def view_slice(self, view: int) -> slice:
        """Rows of view ``view`` in ``xyz``, ``keypoints``, ``scores``, ``descriptors``."""
        return slice(int(self.offsets[view]), int(self.offsets[view + 1]))


@dataclass
class LdlMap:
    """Everything localization needs for one scene (see the module docstring for units)."""

    name: str
    bounds_min: np.ndarray
    bounds_max: np.ndarray
    lines_raw: np.ndarray
    lines: np.ndarray
    line_groups: np.ndarray
    length_threshold: float
    kept_ratio: float
    principal_directions: np.ndarray
    translations: np.ndarray
    cloud_points: np.ndarray | None = None
    cloud_colors: np.ndarray | None = None
    features: MapFeatures | None = None
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    fields_attrs: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    line_lambda: float = 0.1
    visibility: np.ndarray | None = None  # (N_t, L) bool: kept lines seen from each translation (None: all)
    coverage: np.ndarray | None = None  # (N_t, G + 1, 2G) bool: directions meeting a mapped surface
    input_to_map: np.ndarray | None = None  # (4, 4) similarity from the build's input frame (None: identity)

    @property
    def lines_only(self) -> bool:
        return self.features is None


def _check_array(name: str, a: np.ndarray | None, shape: tuple, dtype_kind: str = "f") -> None:
    if a is None:
        return
    a = np.asarray(a)
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
        raise InputError(f"map field {name} has shape {a.shape}, expected {shape}")
    if dtype_kind == "f" and not np.all(np.isfinite(a)):
        raise InputError(f"map field {name} contains NaN or infinite values")


def validate_map(m: LdlMap) -> None:
    """Check shapes and finiteness of every field; raise InputError on the first problem."""
    _check_array("bounds_min", m.bounds_min, (3,))
    _check_array("bounds_max", m.bounds_max, (3,))
    _check_array("lines_raw", m.lines_raw, (None, 2, 3))
    _check_array("lines", m.lines, (None, 2, 3))
    _check_array("line_groups", m.line_groups, (len(m.lines),), "i")
    _check_array("principal_directions", m.principal_directions, (3, 3))
    _check_array("translations", m.translations, (None, 3))
    if len(m.translations) == 0:
        raise InputError("map has no candidate translations")
    if len(m.lines) == 0:
        raise InputError("map has no 3D lines")
    if m.visibility is not None:
        _check_array("visibility", m.visibility, (len(m.translations), len(m.lines)), "b")
    if m.coverage is not None:
        _check_array("coverage", m.coverage, (len(m.translations), None, None), "b")
        if m.coverage.shape[2] != 2 * (m.coverage.shape[1] - 1) or m.coverage.shape[1] < 3:
            raise InputError(f"map field coverage has shape {m.coverage.shape}, expected (N_t, G + 1, 2G)")
    if m.input_to_map is not None:
        from ldlmap.frame import decompose

        _check_array("input_to_map", m.input_to_map, (4, 4))
        decompose(m.input_to_map)
    if m.cloud_points is not None:
        _check_array("cloud_points", m.cloud_points, (None, 3))
        if m.cloud_colors is not None:
            _check_array("cloud_colors", m.cloud_colors, (len(m.cloud_points), 3), "u")
    f = m.features
    if f is not None:
        k = len(f.xyz)
        _check_array("features.view_centers", f.view_centers, (None, 3))
        _check_array("features.offsets", f.offsets, (f.num_views + 1,), "i")
        _check_array("features.xyz", f.xyz, (k, 3))
        _check_array("features.keypoints", f.keypoints, (k, 2))
        _check_array("features.scores", f.scores, (k,))
        _check_array("features.descriptors", f.descriptors, (k, None), "u")
        _check_array("features.translation_view", f.translation_view, (len(m.translations),), "i")
        if f.offsets[0] != 0 or f.offsets[-1] != k or np.any(np.diff(f.offsets) < 0):
            raise InputError("map features: offsets do not index the keypoint table")
        if len(f.translation_view) and (f.translation_view.min() < 0 or f.translation_view.max() >= f.num_views):
            raise InputError("map features: translation_view out of range")


def _library_versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {}
    for pkg in ("ldl-toolkit", "numpy", "torch", "open3d", "opencv-python-headless", "h5py", "pycolmap"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


def write_map(path: str | Path, m: LdlMap) -> Path:
    """Validate ``m`` and write it to ``path`` atomically (temporary file, then rename)."""
    import h5py

    validate_map(m)
    path = Path(path)
    with atomic_file(path) as tmp:
        with h5py.File(tmp, "w") as h5:
            h5.attrs["format_version"] = FORMAT_VERSION
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
                for k, v in m.fields.items():
                    fl.create_dataset(k, data=v, **_COMPRESS)
    return path


def read_map_header(path: str | Path) -> dict[str, Any]:
    """Format version, name, build config and sizes of a map, its principal directions (3, 3) and
    kept lines per principal group (``line_group_counts``: group -> count, -1 = none), without
    loading the large arrays."""

    path = require_file(path, "map")
    with _open(path) as h5:
        _check_version(h5, path)
        try:
            info = {
                "format_version": int(h5.attrs["format_version"]),
                "name": str(h5.attrs.get("name", path.stem)),
                "build_config": json.loads(h5.attrs.get("build_config", "{}")),
                "library_versions": json.loads(h5.attrs.get("library_versions", "{}")),
                "num_lines_raw": int(h5["lines/raw"].shape[0]),
                "num_lines": int(h5["lines/segments"].shape[0]),
                "kept_ratio": float(h5["lines"].attrs["kept_ratio"]),
                "length_threshold": float(h5["lines"].attrs["length_threshold"]),
                "num_translations": int(h5["translations/centers"].shape[0]),
                "num_cloud_points": int(h5["cloud/points"].shape[0]) if "cloud/points" in h5 else 0,
                "feature_backend": str(h5["features"].attrs["backend"]) if "features" in h5 else None,
                "num_views": int(h5["features/view_centers"].shape[0]) if "features" in h5 else 0,
                "num_keypoints": int(h5["features/xyz"].shape[0]) if "features" in h5 else 0,
                "fields": sorted(h5["fields"].keys()) if "fields" in h5 else [],
                "line_visibility": "lines/visibility" in h5,
                "input_to_map": h5["frame/input_to_map"][()].tolist() if "frame/input_to_map" in h5 else None,
                "principal_directions": np.asarray(h5["principal/directions"][()], dtype=np.float64),
                "line_group_counts": _group_counts(h5["lines/groups"][()]) if "lines/groups" in h5 else {},
                "file_size_bytes": path.stat().st_size,
            }
        except (KeyError, OSError, ValueError) as exc:
            raise InputError(f"corrupt LDL map {path}: {exc}") from None
    return info


def _group_counts(groups: np.ndarray) -> dict[int, int]:
    """Lines per principal group: ``{0: n0, 1: n1, 2: n2, -1: unassigned}`` (zeros kept)."""
    g = np.asarray(groups, dtype=np.int64)
    return {k: int(np.sum(g == k)) for k in (0, 1, 2, -1)}


def _open(path: Path):
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError:
        raise InputError(f"not a readable HDF5 map (corrupt or another format): {path}") from None


def _check_version(h5, path: Path) -> None:
    if "format_version" not in h5.attrs:
        raise InputError(f"not an LDL map (no format_version attribute): {path}")
    v = int(h5.attrs["format_version"])
    if v != FORMAT_VERSION:
        newer = "a newer" if v > FORMAT_VERSION else "an older"
        raise FormatVersionError(
            f"map {path} has format version {v}, this ldl-toolkit reads version {FORMAT_VERSION} "
            f"({newer} version wrote it): rebuild it with `ldlmap build`")


def read_map(path: str | Path, load_cloud: bool = True) -> LdlMap:
    """Load and validate a map; raise InputError / FormatVersionError with one-line messages."""
    path = require_file(path, "map")
    with _open(path) as h5:
        _check_version(h5, path)
        try:
            lines_grp = h5["lines"]
            feats = None
            if "features" in h5:
                fg = h5["features"]
                feats = MapFeatures(
                    backend=str(fg.attrs["backend"]),
                    view_centers=fg["view_centers"][()].astype(np.float64),
                    offsets=fg["offsets"][()],
                    xyz=fg["xyz"][()],
                    keypoints=fg["keypoints"][()],
                    scores=fg["scores"][()],
                    descriptors=fg["descriptors"][()],
                    translation_view=h5["translations/view_index"][()],
                    width=int(fg.attrs.get("width", 1024)),
                    height=int(fg.attrs.get("height", 512)),
                )
            fields, fields_attrs = {}, {}
            if "fields" in h5:
                fields = {k: h5["fields"][k][()] for k in h5["fields"].keys()}
                fields_attrs = dict(h5["fields"].attrs)
            m = LdlMap(
                name=str(h5.attrs.get("name", path.stem)),
                bounds_min=h5["cloud/bounds_min"][()],
                bounds_max=h5["cloud/bounds_max"][()],
                lines_raw=lines_grp["raw"][()].astype(np.float64),
                lines=lines_grp["segments"][()].astype(np.float64),
                line_groups=lines_grp["groups"][()].astype(np.int64),
                length_threshold=float(lines_grp.attrs["length_threshold"]),
                kept_ratio=float(lines_grp.attrs["kept_ratio"]),
                line_lambda=float(lines_grp.attrs.get("lambda", 0.1)),
                principal_directions=h5["principal/directions"][()],
                translations=h5["translations/centers"][()].astype(np.float64),
                cloud_points=h5["cloud/points"][()] if load_cloud and "cloud/points" in h5 else None,
                cloud_colors=h5["cloud/colors"][()] if load_cloud and "cloud/colors" in h5 else None,
                features=feats,
                fields=fields,
                fields_attrs=fields_attrs,
                config=json.loads(h5.attrs.get("build_config", "{}")),
                visibility=lines_grp["visibility"][()].astype(bool) if "visibility" in lines_grp else None,
                coverage=h5["coverage/mapped"][()].astype(bool) if "coverage/mapped" in h5 else None,
                input_to_map=h5["frame/input_to_map"][()].astype(np.float64) if "frame/input_to_map" in h5 else None,
            )
        except (KeyError, OSError, ValueError) as exc:
            raise InputError(f"corrupt LDL map {path}: {exc}") from None
    validate_map(m)
    return m
