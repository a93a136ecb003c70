"""Synthetic rooms and buildings written as IFC (BIM) models with ``ifcopenshell.api``.

Each room (a :class:`~ldlmap.synth.spec.SceneSpec`, moved by its storey's offset) becomes: one
``IfcWall`` per footprint edge (its inner face on the edge, ``WALL_THICKNESS`` outward), with an
``IfcOpeningElement`` voiding it per opening, filled by an ``IfcDoor`` / ``IfcWindow`` shaped as the
generator's frame (``FRAME_WIDTH`` around the opening, ``FRAME_DEPTH`` out of the wall); an
``IfcSlab`` (FLOOR) under the footprint, an ``IfcCovering`` (CEILING) at the ceiling height;
an ``IfcSpace`` (footprint extruded to the ceiling) aggregated to the storey; and an
``IfcFurnishingElement`` box per object (left out of maps by default). Storeys stand at their
elevations. Lengths are given to ``ifcopenshell.api`` in metres and stored in the file's unit:
metres, or feet (``units="foot"``, a conversion-based unit) to test unit handling. Flat ceilings
only (the IFC has no sloped ceilings).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, atomic_file
from ldlmap.core.lazy import lazy_module
from ldlmap.io.ifc import IFC_INSTALL_HINT
from ldlmap.synth.multiroom import translate_spec
from ldlmap.synth.spec import FRAME_DEPTH, FRAME_WIDTH, SceneSpec

ifc_api = lazy_module("ifcopenshell.api", hint=IFC_INSTALL_HINT)

WALL_THICKNESS = 0.2  # m
SLAB_DEPTH = 0.2  # m, floor slab under z = 0 of the storey
CEILING_DEPTH = 0.05  # m, ceiling covering above the ceiling height


@dataclass
class StoreyToWrite:
    """One storey: its name, floor elevation (m) and rooms with their (dx, dy) offsets (m)."""

    name: str
    elevation: float
    rooms: list = field(default_factory=list)  # SceneSpec
    offsets: list = field(default_factory=list)  # (dx, dy) per room; zeros when empty


def _matrix(origin, x_axis) -> np.ndarray:
    """4x4 placement with local x along ``x_axis`` (horizontal), z up, at ``origin``."""
    x = np.array([x_axis[0], x_axis[1], 0.0])
    x /= np.linalg.norm(x)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = x, np.cross([0.0, 0.0, 1.0], x), [0.0, 0.0, 1.0], origin
    return M


class _Writer:
    """The file being written, its body context and its helpers (one call of :func:`write_ifc`)."""

    def __init__(self, units: str):
        self.api = ifc_api
        self.f = ifc_api.run("project.create_file", version="IFC4")
        self.project = self.run("root.create_entity", ifc_class="IfcProject", name="ldlmap synthetic")
        if units == "foot":
            foot = self.run("unit.add_conversion_based_unit", name="foot")
            self.run("unit.assign_unit", units=[foot])
        elif units == "metre":
            self.run("unit.assign_unit", length={"is_metric": True, "raw": "METERS"})
        else:
            raise InputError(f"IFC units must be metre or foot, got {units!r}")
        model = self.run("context.add_context", context_type="Model")
        self.body = self.run("context.add_context", context_type="Model", context_identifier="Body",
                             target_view="MODEL_VIEW", parent=model)
        self.site = self.entity("IfcSite", "site", self.project)
        self.building = self.entity("IfcBuilding", "building", self.site)

    def run(self, usecase: str, **kw):
        return self.api.run(usecase, self.f, **kw)

    def entity(self, cls: str, name: str, parent=None, container=None, predefined: str | None = None):
        e = self.run("root.create_entity", ifc_class=cls, name=name, predefined_type=predefined)
        if parent is not None:
            self.run("aggregate.assign_object", products=[e], relating_object=parent)
        if container is not None:
            self.run("spatial.assign_container", products=[e], relating_structure=container)
        return e

    def place(self, e, matrix: np.ndarray, rep=None) -> None:
        self.run("geometry.edit_object_placement", product=e, matrix=matrix, is_si=True)
        if rep is not None:
            self.run("geometry.assign_representation", product=e, representation=rep)

    def box(self, length: float, depth: float, height: float):
        """A box representation: x in [0, length], y in [0, depth] (local), z in [0, height]."""
        return self.run("geometry.add_wall_representation", context=self.body, length=float(length),
                        thickness=float(depth), height=float(height))

    def prism(self, polygon: np.ndarray, depth: float):
        """The xy ``polygon`` (local) extruded ``depth`` up."""
        return self.run("geometry.add_slab_representation", context=self.body, depth=float(depth),
                        polyline=[(float(x), float(y)) for x, y in polygon])


def _frame_rep(w: _Writer, kind: str, width: float, height: float):
    """The frame the generator draws around an opening (:mod:`ldlmap.synth.scene`), in the opening's
    plane (x along the wall from the opening's start, y up from its bottom): a door's U open at the
    floor; a window's ring as two C halves (an extrusion has no holes; their shared faces are flush)."""
    fw, wd, h = FRAME_WIDTH, float(width), float(height)
    if kind == "door":
        return w.prism(np.array([(-fw, 0), (0, 0), (0, h), (wd, h), (wd, 0), (wd + fw, 0), (wd + fw, h + fw),
                                 (-fw, h + fw)]), FRAME_DEPTH)
    m = wd / 2
    left = w.prism(np.array([(-fw, -fw), (m, -fw), (m, 0), (0, 0), (0, h), (m, h), (m, h + fw), (-fw, h + fw)]),
                   FRAME_DEPTH)
    right = w.prism(np.array([(m, -fw), (wd + fw, -fw), (wd + fw, h + fw), (m, h + fw), (m, h), (wd, h), (wd, 0),
                              (m, 0)]), FRAME_DEPTH)
    left.Items = tuple(left.Items) + tuple(right.Items)
    return left


def _room(w: _Writer, spec: SceneSpec, storey, z0: float, tag: str) -> None:
    """Room ``spec`` on ``storey`` (floor at ``z0``): walls voided by openings and filled by their frames,
    floor slab, ceiling covering, space and furniture boxes."""
    fp = np.asarray(spec.footprint, dtype=np.float64)
    h = float(spec.ceiling_height)
    if spec.ceiling.kind != "flat":
        raise InputError(f"room {spec.name}: only flat ceilings can be written as IFC (got {spec.ceiling.kind})")
    walls = []
    for i in range(len(fp)):
        a, b = fp[i], fp[(i + 1) % len(fp)]
        d = b - a
        length = float(np.linalg.norm(d))
        wall = w.entity("IfcWall", f"{tag} wall {i}", container=storey)
        M = _matrix([a[0], a[1], z0], d)  # local +y points into the room (footprint counter-clockwise)
        M[:3, 3] -= M[:3, 1] * WALL_THICKNESS  # the box spans y in [-thickness, 0]: outside the room
        w.place(wall, M, w.box(length, WALL_THICKNESS, h))
        walls.append((wall, a, d / length))
    for k, op in enumerate(spec.openings):
        wall, a, u = walls[op.wall]
        sill = op.sill if op.sill >= 0 else (0.0 if op.kind == "door" else 0.9)
        origin = np.array([a[0], a[1], z0]) + np.append(u, 0.0) * op.offset
        M = _matrix(origin, u)
        hole = w.entity("IfcOpeningElement", f"{tag} opening {k}")
        Mo = M.copy()
        Mo[:3, 3] += Mo[:3, 1] * -(WALL_THICKNESS + 0.05) + [0.0, 0.0, sill]
        w.place(hole, Mo, w.box(op.width, WALL_THICKNESS + 0.1, op.height))
        w.run("feature.add_feature", feature=hole, element=wall)
        fill = w.entity("IfcDoor" if op.kind == "door" else "IfcWindow", f"{tag} {op.kind} {k}", container=storey)
        Mf = np.eye(4)  # local x along the wall, y up, z into the wall: profiles extruded FRAME_DEPTH back to it
        Mf[:3, 0], Mf[:3, 1], Mf[:3, 2] = M[:3, 0], [0.0, 0.0, 1.0], -M[:3, 1]
        Mf[:3, 3] = M[:3, 3] + M[:3, 1] * FRAME_DEPTH + [0.0, 0.0, sill]
        w.place(fill, Mf, _frame_rep(w, op.kind, op.width, op.height))
        w.run("feature.add_filling", opening=hole, element=fill)
    floor = w.entity("IfcSlab", f"{tag} floor", container=storey, predefined="FLOOR")
    w.place(floor, _matrix([0.0, 0.0, z0 - SLAB_DEPTH], [1.0, 0.0]), w.prism(fp, SLAB_DEPTH))
    ceiling = w.entity("IfcCovering", f"{tag} ceiling", container=storey, predefined="CEILING")
    w.place(ceiling, _matrix([0.0, 0.0, z0 + h], [1.0, 0.0]), w.prism(fp, CEILING_DEPTH))
    space = w.entity("IfcSpace", f"{tag} space", parent=storey)
    w.place(space, _matrix([0.0, 0.0, z0], [1.0, 0.0]), w.prism(fp, h))
    for k, obj in enumerate(spec.objects):
        sx, sy, sz = obj.size
        yaw = np.radians(obj.yaw_deg)
        u = np.array([np.cos(yaw), np.sin(yaw)])
        v = np.array([-u[1], u[0]])
        corner = np.asarray(obj.center) - u * sx / 2 - v * sy / 2
        item = w.entity("IfcFurnishingElement", f"{tag} {obj.kind} {k}", container=storey)
        w.place(item, _matrix([corner[0], corner[1], z0], u), w.box(sx, sy, sz))


def write_ifc(path: str | os.PathLike, storeys: list[StoreyToWrite], units: str = "metre") -> Path:
    """Write the storeys' rooms as an IFC4 model (module docstring), atomically. An empty
    ``storeys`` list writes a model with a building and no storey (for tests of that error)."""
    w = _Writer(units)
    for s in storeys:
        storey = w.entity("IfcBuildingStorey", s.name, w.building)
        w.place(storey, _matrix([0.0, 0.0, float(s.elevation)], [1.0, 0.0]))
        storey.Elevation = float(s.elevation) / (0.3048 if units == "foot" else 1.0)
        offsets = s.offsets or [(0.0, 0.0)] * len(s.rooms)
        for j, (spec, off) in enumerate(zip(s.rooms, offsets)):
            _room(w, translate_spec(spec, off), storey, float(s.elevation), f"{s.name} {spec.name}")
    target = Path(path)
    with atomic_file(target, suffix=".ifc") as tmp:
        w.f.write(str(tmp))
    return target
