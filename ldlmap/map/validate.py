"""Checks of an in-memory map before it is written and after it is read: shapes, dtypes, finite
values, ranges and cross-references, each failure one :class:`InputError` line.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.frame import MAX_MAP_COORDINATE, decompose
from ldlmap.features.sphere import PANORAMA_EXTRACTIONS
from ldlmap.map.contents import LdlMap, MapFeatures


def _check_array(name: str, a: np.ndarray | None, shape: tuple, dtype_kind: str = "f", finite: bool = True) -> None:
    if a is None:
        return
    a = np.asarray(a)
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
        raise InputError(f"map field {name} has shape {a.shape}, expected {shape}")
    if a.dtype.kind not in KINDS[dtype_kind]:
        raise InputError(f"map field {name} has dtype {a.dtype}, expected {KIND_NAMES[dtype_kind]}")
    if finite and a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
        raise InputError(f"map field {name} contains NaN or infinite values")


# Accepted numpy dtype kinds per expected kind: f float, i integer, u unsigned 8-bit data, b mask.
KINDS = {"f": "f", "i": "iu", "u": "u", "b": "ub", "d": "uf"}
KIND_NAMES = {"f": "floats", "i": "integers", "u": "unsigned integers", "b": "a 0/1 mask",
               "d": "uint8 or float descriptors"}
_MAX_IMAGE_SIDE = 1 << 15  # rendered views: at most this many pixels on a side


def _check_coordinates(name: str, a: np.ndarray | None) -> None:
    """Coordinates of the map frame within :data:`ldlmap.core.frame.MAX_MAP_COORDINATE` metres."""
    if a is not None and np.asarray(a).size and np.abs(a).max() > MAX_MAP_COORDINATE:
        raise InputError(f"map field {name} has coordinates of {np.abs(a).max():.3g} m, beyond the "
                         f"{MAX_MAP_COORDINATE:.0e} m of any map (damaged or not in metres)")


def check_range(name: str, value: float, lo: float, hi: float) -> None:
    if not (np.isfinite(value) and lo <= value <= hi):
        raise InputError(f"map field {name} is {value}, expected a value in [{lo:g}, {hi:g}]")


def manhattan_map(config: dict) -> bool:
    """Whether a map's config says its principal directions are a Manhattan (orthonormal) frame:
    ``principal_frame`` "manhattan"; maps built before that key, ``orthonormal_directions``
    true. Atlanta frames (``principal_frame`` "atlanta") and voted directions are not."""
    if "principal_frame" in config:
        return config["principal_frame"] == "manhattan"
    return config.get("orthonormal_directions") is True


MAX_PRINCIPAL = 7  # at most this many principal directions (an Atlanta frame: the vertical and 6 horizontals)
MAX_PRINCIPAL_COS = 0.98  # distinct directions: |cos| at most this (11.5 deg; a 15-deg ceiling slope's
# direction beside its horizontal, ldlmap.lines3d.principal.FrameParams.inclined_apart_deg)


def check_principal(P: np.ndarray, orthonormal: bool) -> None:
    """3 to :data:`MAX_PRINCIPAL` distinct unit directions; an orthonormal right-handed frame of 3
    when the map says it used the Manhattan frame (maps built before that option record nothing
    and may be a little off)."""
    _check_array("principal_directions", P, (None, 3))
    if not 3 <= len(P) <= MAX_PRINCIPAL:
        raise InputError(f"map has {len(P)} principal directions, expected 3 to {MAX_PRINCIPAL}")
    if not np.allclose(np.linalg.norm(P, axis=1), 1.0, atol=1e-4):
        raise InputError("map principal directions are not unit vectors")
    cos = np.abs(P @ P.T)[np.triu_indices(len(P), 1)]
    if np.any(cos > MAX_PRINCIPAL_COS):
        raise InputError("map principal directions are not distinct directions")
    if orthonormal and not (len(P) == 3 and np.allclose(P @ P.T, np.eye(3), atol=1e-4) and np.linalg.det(P) > 0):
        raise InputError("map principal directions are not an orthonormal right-handed frame")


def validate_map(m: LdlMap) -> None:
    """Check shapes, dtypes, finite values and ranges of every field; raise InputError on the first problem."""
    _check_array("bounds_min", m.bounds_min, (3,))
    _check_array("bounds_max", m.bounds_max, (3,))
    if np.any(np.asarray(m.bounds_min) > np.asarray(m.bounds_max)):
        raise InputError("map field bounds_min exceeds bounds_max")
    _check_array("lines_raw", m.lines_raw, (None, 2, 3))
    _check_array("lines", m.lines, (None, 2, 3))
    _check_array("line_groups", m.line_groups, (len(m.lines),), "i")
    check_line_header(m.line_groups, float(m.length_threshold), float(m.kept_ratio),
                       np.asarray(m.principal_directions), manhattan_map(m.config))
    check_range("lambda", float(m.line_lambda), 0.0, np.inf)
    _check_array("translations", m.translations, (None, 3))
    for name, a in (("bounds_min", m.bounds_min), ("bounds_max", m.bounds_max), ("lines_raw", m.lines_raw),
                    ("lines", m.lines), ("translations", m.translations), ("cloud_points", m.cloud_points)):
        _check_coordinates(name, a)
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
        _check_array("input_to_map", m.input_to_map, (4, 4))
        decompose(m.input_to_map)
    if m.footprint is not None:
        _validate_footprint(m.footprint)
    if m.cloud_points is not None:
        _check_array("cloud_points", m.cloud_points, (None, 3))
        if m.cloud_colors is not None:
            _check_array("cloud_colors", m.cloud_colors, (len(m.cloud_points), 3), "u")
    _validate_fields(m)
    if m.features is not None:
        _validate_features(m.features, len(m.translations))


def _validate_footprint(fp) -> None:
    """A scan's footprint (:class:`ldlmap.map.contents.Footprint`): a 2D mask, an origin within the map's
    coordinates and a cell of positive size."""
    _check_array("footprint.mask", fp.mask, (None, None), "b")
    _check_array("footprint.origin", fp.origin, (2,))
    _check_coordinates("footprint.origin", fp.origin)
    check_range("footprint.cell", float(fp.cell), 1e-6, MAX_MAP_COORDINATE)


def _validate_fields(m: LdlMap) -> None:
    """Precomputed distance fields: (N_t, groups, G + 1, 2G) radians in [0, pi]."""
    d = m.fields.get("distances")
    if d is None:
        return
    _check_array("fields.distances", d, (len(m.translations), None, None, None), finite=False)
    if d.shape[1] != len(m.principal_directions) or d.shape[2] < 2 or d.shape[3] != 2 * (d.shape[2] - 1):
        raise InputError(f"map field fields.distances has shape {d.shape}, expected (N_t, K, G + 1, 2G) for K principal directions")
    if not _angles_in_range(d, np.pi + 0.01):
        raise InputError("map field fields.distances holds NaN or angles outside [0, pi]")
    rows = m.fields_attrs.get("rows")
    if rows is not None and not (is_int(rows) and int(rows) == d.shape[2] - 1):
        raise InputError(f"map fields: attribute rows = {rows!r} does not match the array ({d.shape[2] - 1})")


def _angles_in_range(a: np.ndarray, hi: float) -> bool:
    """Every value finite and in [0, hi]. float16 (the fields' dtype, 40 MB for N_t = 800) is checked
    on its bits: non-negative finite halves order like their uint16 patterns, NaN/inf/negatives above
    (-0 excepted), much faster than float16 comparisons (docs/measurements.md#float16-checks)."""
    if a.size == 0:
        return True
    if a.dtype != np.float16:
        return bool(np.all(np.isfinite(a)) and a.min() >= 0 and a.max() <= hi)
    bits = np.ascontiguousarray(a).view(np.uint16)
    limit = np.array(hi, np.float16).view(np.uint16)
    top = bits.max()
    return bool(top <= limit or (top == 0x8000 and (bits & 0x7FFF).max() <= limit))


def _validate_features(f: MapFeatures, num_translations: int) -> None:
    """The ragged keypoint table: sizes, finite values, offsets and view indices in range."""
    k = len(f.xyz)
    _check_array("features.view_centers", f.view_centers, (None, 3))
    _check_array("features.offsets", f.offsets, (f.num_views + 1,), "i")
    _check_array("features.xyz", f.xyz, (k, 3))
    _check_coordinates("features.xyz", f.xyz)
    _check_array("features.keypoints", f.keypoints, (k, 2))
    _check_array("features.scores", f.scores, (k,))
    _check_array("features.descriptors", f.descriptors, (k, None), "d")
    _check_array("features.translation_view", f.translation_view, (num_translations,), "i")
    if f.num_views == 0 or f.descriptors.shape[1] == 0:
        raise InputError("map features: no rendered view or zero-length descriptors")
    if f.offsets[0] != 0 or f.offsets[-1] != k or np.any(np.diff(f.offsets) < 0):
        raise InputError("map features: offsets do not index the keypoint table")
    if len(f.translation_view) and (f.translation_view.min() < 0 or f.translation_view.max() >= f.num_views):
        raise InputError("map features: translation_view out of range")
    for side, size in (("width", f.width), ("height", f.height)):
        if not (is_int(size) and 0 < int(size) <= _MAX_IMAGE_SIDE):
            raise InputError(f"map features: {side} {size!r} is not a pixel count in 1..{_MAX_IMAGE_SIDE}")
    if f.extraction not in PANORAMA_EXTRACTIONS:
        raise InputError(f"map features: extraction {f.extraction!r} is not one of {', '.join(PANORAMA_EXTRACTIONS)}")
    kp = np.asarray(f.keypoints, dtype=np.float64)
    if k and (kp.min() < -1.0 or kp[:, 0].max() > f.width + 1.0 or kp[:, 1].max() > f.height + 1.0):
        raise InputError(f"map features: keypoints lie outside the {f.width} x {f.height} views")


def is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def check_line_header(groups: np.ndarray, length_threshold: float, kept_ratio: float, principal: np.ndarray,
                       orthonormal: bool) -> None:
    """What both a full read and a header read check of the lines: group labels, length filter and
    principal directions."""
    if len(groups) and (np.min(groups) < -1 or np.max(groups) > len(principal) - 1):
        raise InputError(f"map field line_groups holds labels outside -1..{len(principal) - 1}")
    check_range("length_threshold", length_threshold, 0.0, np.inf)
    check_range("kept_ratio", kept_ratio, 0.0, 1.0)
    check_principal(principal, orthonormal)
