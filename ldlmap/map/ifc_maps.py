"""Lines-only maps of an IFC (BIM) model, one per storey: ``build_ifc_maps(model, out, params)``.

Each storey's kept elements (:mod:`ldlmap.io.ifc`) give its 3D lines: the creases of each
element's solid (``ldlmap.synth.edges.mesh_edges``, per element: a wall's corners and the edges of
its openings, a slab's rim, a column's edges), merged where collinear, less the segments wholly
below the storey's floor (a slab's underside: no camera on the storey sees it) and, when the storey
has spaces, those whose middle lies outside every space by more than :data:`SPACE_MARGIN` in xy
(the walls' outer faces) or half that below its floor or above its top (the top of a ceiling). Candidate
translations stand on a lattice of ``params.translations.spacing`` inside the storey's spaces (IfcSpace
footprints), or in the free space of its lines when it has none, within a camera-height band above
the storey's floor (``params.translations.camera_height``, default :data:`DEFAULT_BAND`). No features (a
model has no photos): queries are refined geometrically.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.io.ifc import read_ifc, storey_file_name
from ldlmap.map.build import BuildReport, build_lines_map
from ldlmap.map.params import BuildParams
from ldlmap.map.translations import Walkable
from ldlmap.synth.edges import mesh_edges

shapely_geometry = lazy_module("shapely.geometry")
shapely = lazy_module("shapely")

DEFAULT_BAND = (0.8, 1.8)  # metres above the storey's floor: tripods, robots and hand-held 360 cameras
SPACE_MARGIN = 0.05  # metres: with spaces, segments whose middle lies farther outside all of them are left out
BELOW_FLOOR = 0.01  # metres: segments wholly lower than this under the storey's floor are left out


def storey_lines(storey) -> np.ndarray:
    """The 3D lines (N, 2, 3) of one :class:`ldlmap.io.ifc.IfcStorey` (module docstring)."""

    mesh = SimpleNamespace(vertices=storey.vertices, triangles=storey.triangles, tri_part=storey.tri_part)
    lines = mesh_edges(mesh)
    keep = lines[:, :, 2].max(axis=1) >= storey.elevation - BELOW_FLOOR
    lines = _clip_z(lines, storey.elevation, True)  # a corner line merged with the slab's edge stops at the floor
    if storey.spaces:  # the outer faces of walls and what lies beyond them face no space: no camera sees them
        mid = lines.mean(axis=1)
        near = np.zeros(len(lines), dtype=bool)
        for fp, zlo, zhi in storey.spaces:
            inside = shapely.contains_xy(shapely_geometry.Polygon(fp).buffer(SPACE_MARGIN), mid[:, 0], mid[:, 1])
            near |= inside & (mid[:, 2] >= zlo - SPACE_MARGIN / 2) & (mid[:, 2] <= zhi + SPACE_MARGIN / 2)
        keep &= near
        top = max(zhi for _, _, zhi in storey.spaces)  # ... and with the ceiling's edge, at the spaces' top
        lines = _clip_z(lines, top, False)
    return lines[keep]


def _clip_z(lines: np.ndarray, plane: float, keep_above: bool) -> np.ndarray:
    """Segments (N, 2, 3) cut at the plane z = ``plane``, the part below (``keep_above``) or above it
    removed; segments wholly on the removed side are returned unchanged (the caller masks them)."""
    a, b = lines[:, 0].copy(), lines[:, 1].copy()
    za, zb = a[:, 2], b[:, 2]
    cross = (np.minimum(za, zb) < plane) & (np.maximum(za, zb) > plane)
    t = (plane - za[cross]) / (zb[cross] - za[cross])
    cut = a[cross] + t[:, None] * (b[cross] - a[cross])
    a_out = (za[cross] < plane) if keep_above else (za[cross] > plane)  # which end lies on the removed side
    a_new, b_new = a[cross], b[cross]
    a_new[a_out], b_new[~a_out] = cut[a_out], cut[~a_out]
    a[cross], b[cross] = a_new, b_new
    return np.stack([a, b], axis=1)


def storey_outputs(model: Path, names: list[str], output: Path | None) -> dict[str, Path]:
    """Where each storey's map goes: one storey -> ``output`` (default MODEL.h5); several -> a
    folder ``output`` (default MODEL_storeys/) holding ``<storey>.h5`` each."""

    if len(names) == 1:
        out = output if output is not None else model.with_suffix(".h5")
        if out.is_dir():
            out = out / f"{storey_file_name(names[0])}.h5"
        return {names[0]: out}
    folder = output if output is not None else model.with_name(model.stem + "_storeys")
    if folder.suffix.lower() == ".h5":
        raise InputError(f"the model has {len(names)} storeys ({', '.join(names[:6])}): give -o a folder for one map "
                         f"per storey, or pick one with --storey NAME")
    files = [folder / f"{storey_file_name(n)}.h5" for n in names]
    if len(set(files)) < len(files):
        raise InputError(f"two storeys of {model} get the same map file name in {folder}: pick one with --storey NAME")
    return dict(zip(names, files))


def build_ifc_maps(model: str | Path, outputs: dict[str, Path], params: BuildParams = BuildParams(),
                   include: tuple[str, ...] = (), progress: Callable[[str, str, int, int], None] | None = None
                   ) -> tuple[list[BuildReport], str]:
    """Build the lines-only map of each storey named in ``outputs`` (storey -> map path); returns
    the reports (in the storeys' order) and the model's note."""

    model = Path(model)
    if params.input.scale != 1.0 or (params.input.up or "auto").lower() not in ("auto", "z", "+z"):
        raise InputError("IFC models are metric and z-up (their unit is read from the file): --scale and --up do not apply")
    names = list(outputs)
    storeys, note = read_ifc(model, names[0] if len(names) == 1 else None, include)
    storeys = [s for s in storeys if s.name in outputs]
    band = params.translations.camera_height or DEFAULT_BAND
    lines_only = params.replaced(features="none", camera_height=None)  # the band goes into the walkable z range
    all_lines = [storey_lines(s) for s in storeys]  # every storey checked before any map is written
    for s, lines in zip(storeys, all_lines):
        if len(lines) == 0:
            raise InputError(f"IFC storey {s.name!r} gives no 3D lines")
        height = float(lines[..., 2].max()) - s.elevation  # its ceiling, above its floor
        if band[0] >= height:
            raise InputError(f"--camera-height {band[0]:g}:{band[1]:g} lies above the ceiling of storey {s.name!r} "
                             f"({height:.2f} m above its floor): no camera can stand there")
    reports = []
    for s, lines in zip(storeys, all_lines):
        walkable = Walkable(polygons=tuple(fp for fp, _, _ in s.spaces), z_range=(s.elevation + band[0], s.elevation + band[1]))
        cb = (lambda stage, done, total, n=s.name: progress(n, stage, done, total)) if progress else None
        outputs[s.name].parent.mkdir(parents=True, exist_ok=True)
        report = build_lines_map(lines, outputs[s.name], lines_only, name=s.name, walkable=walkable,
                                 source=f"ifc:{model}#{s.name}", progress=cb)
        where = f"{len(s.spaces)} space(s)" if s.spaces else "the free space of its lines (no IfcSpace)"
        report.notes.insert(0, f"storey {s.name}: floor at z = {s.elevation:.2f} m, "
                               f"{sum(s.classes.values())} elements ({', '.join(f'{k} {v}' for k, v in sorted(s.classes.items()))}), "
                               f"{len(lines)} lines; candidates in {where}, {band[0]:g}-{band[1]:g} m above the floor")
        reports.append(report)
    return reports, note
