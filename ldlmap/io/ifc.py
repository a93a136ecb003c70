"""IFC (BIM) models (``.ifc``, ``ifcopenshell``): each storey's building elements as triangle
meshes, and its spaces' footprints.

Geometry comes from IfcOpenShell's geometry engine in world coordinates and in metres whatever
the file's length unit (it converts the model's ``IfcUnitAssignment``: millimetres, feet), z up
(IFC's world frame is z-up). A storey's elements are those contained in it
(``IfcRelContainedInSpatialStructure``, directly or through a contained element); its spaces are
the ``IfcSpace`` decomposing it. Kept by default: :data:`DEFAULT_CLASSES` (walls, slabs,
ceilings and other coverings, columns, doors and windows: the wall's own geometry has the
openings cut out); furniture, MEP and everything else only through ``include``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, require_file
from ldlmap.core.lazy import lazy_module

IFC_INSTALL_HINT = "pip install 'ldl-toolkit[bim]' (make install adds it)"
# ifcopenshell is the optional `bim` extra; open_ifc reports it missing before these are used.
ifc_element = lazy_module("ifcopenshell.util.element", hint=IFC_INSTALL_HINT)
ifc_geom = lazy_module("ifcopenshell.geom", hint=IFC_INSTALL_HINT)
ifc_placement = lazy_module("ifcopenshell.util.placement", hint=IFC_INSTALL_HINT)
ifc_schema = lazy_module("ifcopenshell.ifcopenshell_wrapper", hint=IFC_INSTALL_HINT)
ifc_unit = lazy_module("ifcopenshell.util.unit", hint=IFC_INSTALL_HINT)
shapely_geometry = lazy_module("shapely.geometry", hint=IFC_INSTALL_HINT)
shapely_ops = lazy_module("shapely.ops", hint=IFC_INSTALL_HINT)

DEFAULT_CLASSES: tuple[str, ...] = ("IfcWall", "IfcCurtainWall", "IfcSlab", "IfcCovering", "IfcColumn", "IfcDoor",
                                    "IfcWindow")


@dataclass
class IfcStorey:
    """One storey: its elements' triangles (world, metres) and its spaces' xy footprints."""

    name: str
    elevation: float  # metres: the storey's floor (its placement's z)
    vertices: np.ndarray  # (V, 3)
    triangles: np.ndarray  # (F, 3) int64
    tri_part: np.ndarray  # (F,) int64: the element each triangle belongs to
    classes: dict[str, int] = field(default_factory=dict)  # IFC class -> element count
    spaces: list[tuple[np.ndarray, float, float]] = field(default_factory=list)  # IfcSpace: (K, 2) footprint, z min, z max


def open_ifc(path: str | os.PathLike):
    """The model opened by ifcopenshell, or one line saying why it cannot be read."""
    try:
        import ifcopenshell  # here, where a missing `bim` extra becomes one line naming it
    except ImportError:
        raise InputError(f"IFC models need ifcopenshell: {IFC_INSTALL_HINT}") from None

    p = require_file(path, "IFC model")
    try:
        return ifcopenshell.open(str(p))
    except Exception as exc:  # ifcopenshell raises its own Error / SchemaError on damaged files
        text = str(exc).strip().splitlines()
        raise InputError(f"cannot read IFC model {p}: {text[0] if text else type(exc).__name__}") from None


def storey_names(model) -> list[str]:
    """The storeys' names in elevation order (unnamed ones as ``storey<i>``)."""
    return [name for name, _ in _storeys(model)]


def _storeys(model) -> list[tuple[str, object]]:
    """``(name, storey)`` of the model's storeys by elevation (unnamed ones as ``storey<i>``)."""
    out = []
    for i, s in enumerate(model.by_type("IfcBuildingStorey")):
        z = ifc_placement.get_local_placement(s.ObjectPlacement)[2, 3] if s.ObjectPlacement else 0.0
        out.append((float(z), s.GlobalId, s.Name or f"storey{i}", s))
    out.sort(key=lambda r: (r[0], r[1]))  # by elevation, then GlobalId: no dependence on file order
    return [(name, s) for _, _, name, s in out]


def _check_include(model, include: tuple[str, ...]) -> tuple[str, ...]:
    """The IFC classes to keep; unknown class names (not in the model's schema) refused."""
    schema = ifc_schema.schema_by_name(model.schema_identifier if hasattr(model, "schema_identifier") else model.schema)
    for name in include:
        try:
            schema.declaration_by_name(name)
        except Exception:
            raise InputError(f"--include {name}: not an IFC class of schema {model.schema} "
                             "(e.g. IfcFurnishingElement, IfcFlowTerminal, IfcBeam, IfcRailing, IfcStair)") from None
    return DEFAULT_CLASSES + tuple(include)


def _storey_of(element):
    """The storey that contains ``element`` (walking up containers and aggregates), or None."""
    seen = 0
    e = element
    while e is not None and seen < 16:
        if e.is_a("IfcBuildingStorey"):
            return e
        e = ifc_element.get_container(e) or ifc_element.get_aggregate(e)
        seen += 1
    return None


def _shape(settings, element) -> tuple[np.ndarray, np.ndarray] | None:
    """The element's triangles ``(V, F)`` from IfcOpenShell's geometry engine, None when it has none."""
    try:
        sh = ifc_geom.create_shape(settings, element)
    except Exception:  # an element whose geometry IfcOpenShell cannot build: left out, counted by the caller
        return None
    V = np.asarray(sh.geometry.verts, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(sh.geometry.faces, dtype=np.int64).reshape(-1, 3)
    return (V, F) if len(F) and np.all(np.isfinite(V)) else None


def _footprint(V: np.ndarray, F: np.ndarray) -> np.ndarray | None:
    """The xy outline of a space's floor: the union of its downward-facing triangles."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    down = F[n[:, 2] < -1e-9 * np.maximum(np.linalg.norm(n, axis=1), 1e-300)]
    tris = [shapely_geometry.Polygon(V[t, :2]) for t in down]
    shape = shapely_ops.unary_union([t for t in tris if t.area > 1e-12]).buffer(0)
    if shape.is_empty:
        return None
    biggest = max(getattr(shape, "geoms", [shape]), key=lambda g: g.area)
    ring = np.asarray(biggest.exterior.coords)[:-1]
    return ring if len(ring) >= 3 else None


def read_ifc(path: str | os.PathLike, storey: str | None = None, include: tuple[str, ...] = ()) -> tuple[list[IfcStorey], str]:
    """The storeys of an IFC model (one when ``storey`` names it) with their elements of the kept
    classes; and a note (unit, storeys, classes). One-line :class:`InputError` for an unreadable
    model, one without storeys, an unknown storey or class, or a storey with no kept element."""
    p = Path(path)
    model = open_ifc(p)
    storeys = _storeys(model)
    if not storeys:
        raise InputError(f"IFC model has no storeys (IfcBuildingStorey): {p}; maps are built per storey")
    names = [n for n, _ in storeys]
    if storey is not None:
        if storey not in names:
            raise InputError(f"--storey {storey!r}: no such storey in {p} (storeys: {', '.join(names)})")
        storeys = [s for s in storeys if s[0] == storey]
    classes = _check_include(model, tuple(include))
    settings = ifc_geom.settings()
    settings.set("use-world-coords", True)
    scale = ifc_unit.calculate_unit_scale(model)
    wanted = {s.id(): i for i, (_, s) in enumerate(storeys)}
    parts: dict[int, list] = {i: [] for i in range(len(storeys))}
    counts: dict[int, dict[str, int]] = {i: {} for i in range(len(storeys))}
    spaces: dict[int, list] = {i: [] for i in range(len(storeys))}
    elements = sorted({e.id(): e for c in classes for e in model.by_type(c)}.values(), key=lambda e: e.GlobalId)
    failed = 0
    for e in elements + sorted(model.by_type("IfcSpace"), key=lambda e: e.GlobalId):
        s = _storey_of(e)
        if s is None or s.id() not in wanted or e.Representation is None:
            continue
        shape = _shape(settings, e)
        if shape is None:
            failed += 1
            continue
        k = wanted[s.id()]
        if e.is_a("IfcSpace"):
            fp = _footprint(*shape)
            if fp is not None:
                spaces[k].append((fp, float(shape[0][:, 2].min()), float(shape[0][:, 2].max())))
        else:
            parts[k].append(shape)
            counts[k][e.is_a()] = counts[k].get(e.is_a(), 0) + 1
    out = []
    for i, (name, s) in enumerate(storeys):
        if not parts[i]:
            raise InputError(f"IFC storey {name!r} holds no element of the kept classes ({', '.join(classes)}): {p}")
        sizes = np.array([len(V) for V, _ in parts[i]])
        base = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        V = np.concatenate([V for V, _ in parts[i]])
        F = np.concatenate([F + b for (_, F), b in zip(parts[i], base)])
        part = np.repeat(np.arange(len(parts[i])), [len(F) for _, F in parts[i]])
        z = ifc_placement.get_local_placement(s.ObjectPlacement)[2, 3] * scale if s.ObjectPlacement else 0.0
        out.append(IfcStorey(name, float(z), V, F, part, counts[i], spaces[i]))
    unit = {1.0: "metres", 0.001: "millimetres", 0.3048: "feet"}.get(round(scale, 6), f"{scale:g} m per unit")
    note = (f"IFC {model.schema}: length unit {unit} (converted to metres), {len(names)} storey(s) "
            f"({', '.join(names[:8])}{', ...' if len(names) > 8 else ''}); kept {', '.join(classes)}"
            + (f"; {failed} element(s) without buildable geometry left out" if failed else ""))
    return out, note


def storey_file_name(name: str) -> str:
    """A file name for a storey's map (letters, digits, ``-``, ``_`` and ``.``; others become ``_``)."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")
    return safe or "storey"
