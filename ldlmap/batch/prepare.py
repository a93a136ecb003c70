"""Build one map per scene of a dataset root: ``prepare_dataset(root, kind, maps_dir, params)``.

Maps go to ``<maps_dir>/<scene>.h5`` (default ``<root>/maps``; Stanford scene keys such as
``area_3/office_1`` become ``area_3/office_1.h5``). A map is up to date, and skipped, when it is
newer than its point cloud (and line file) and was built with the same parameters; ``overwrite``
rebuilds everything. Stanford 2D-3D-S uses the paper's grid translations (N_t = 1700) unless
parameters say otherwise.

With ``use_line_files`` (``ldlmap prepare --line-files``) maps take their 3D lines from the
dataset's line files (``pcd_line/``), beside the scan when there is one; a scene with a line file
and no scan gets a lines-only map (features ``none``, candidate translations spaced over the
lines' free space, :func:`ldlmap.map.build.build_lines_map`), and its outcome says so.

ZInD has no scans: each scene's map is a lines-only map of its room layouts
(:meth:`ldlmap.datasets.ZInD.layout_scene`: wall corners, floor and flat-ceiling edges, door,
window and opening frames) with candidate translations spaced over the rooms' polygons and
portals at the panoramas' camera height (:func:`ldlmap.map.build.build_lines_map`). ``map_level``
picks one map per complete room (``room``) or per floor (``floor``); maps go to
``<maps_dir>/<home>/<floor>/<complete_room>.h5`` or ``<maps_dir>/<home>/<floor>.h5``. Features
are always ``none`` there (``params.features.backend`` is overridden), and a map is up to date when it
is newer than the home's ``zind_data.json`` and used the same parameters.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ldlmap.core.errors import InputError, LdlError, refuse_overwriting_inputs, refuse_replacing_other_files
from ldlmap.datasets import open_dataset
from ldlmap.io.linefiles import read_lines
from ldlmap.map.build import BuildReport, build_lines_map, build_map
from ldlmap.map.mapfile import is_map_file, read_map_header
from ldlmap.map.params import BuildParams

# Paper hyperparameters per dataset (supplementary): N_t and the translation sampling (BuildParams config keys).
DATASET_DEFAULTS = {
    "omniscenes": {"num_translations": 800, "translation_method": "octree"},
    "stanford": {"num_translations": 1700, "translation_method": "grid"},
    "zind": {"features": "none"},  # layout maps: lines only, translations by spacing (``trans_spacing``)
}


LINES_ONLY_NOTE = "no scan: lines-only map of the line file (features none)"


@dataclass
class SceneOutcome:
    scene: str
    map_path: Path
    status: str  # built | up-to-date | failed
    message: str = ""
    report: BuildReport | None = None


def refuse_replacing_non_map(output: Path, overwrite: bool = False) -> None:
    """An existing ``output`` is replaced by a build only when it is a map built before
    (:func:`ldlmap.map.mapfile.is_map_file`), or with ``overwrite``; a folder never."""
    refuse_replacing_other_files(output, is_map_file, "an LDL map", overwrite)


def default_params(kind: str, base: BuildParams = BuildParams()) -> BuildParams:
    """``base`` with the paper's per-dataset translation settings."""
    return base.replaced(**DATASET_DEFAULTS.get(kind, {}))


def _comparable(config: dict) -> dict:
    keys = set(BuildParams().config()) - {"device"}
    return json.loads(json.dumps({k: config.get(k) for k in sorted(keys)}))  # tuples as lists


def is_up_to_date(map_path: Path, sources: list[Path], params: BuildParams, inputs: dict | None = None) -> bool:
    """True when ``map_path`` exists, is newer than every source and used the same parameters
    (and the same ``inputs``: build-config entries such as the line file it was built with)."""
    if not map_path.exists():
        return False
    newest = max(s.stat().st_mtime for s in sources if s is not None and s.exists())
    if map_path.stat().st_mtime < newest:
        return False
    try:
        header = read_map_header(map_path)
    except LdlError:
        return False
    config = header["build_config"]
    if any(config.get(k) != v for k, v in (inputs or {}).items()):
        return False
    return _comparable(config) == _comparable(params.config())


def prepare_dataset(root: str | Path, kind: str | None, maps_dir: str | Path | None = None,
                    params: BuildParams | None = None, overwrite: bool = False, use_line_files: bool = False,
                    scenes: list[str] | None = None,
                    progress: Callable[[str, str, int, int], None] | None = None,
                    map_level: str = "room") -> list[SceneOutcome]:
    """Build (or skip when up to date) the map of every scene; failures are reported, not raised.

    ``progress(scene, stage, done, total)`` is called as work advances. ``map_level``: ZInD's
    scenes (``room`` or ``floor``), ignored for other datasets.
    """
    ds = open_dataset(root, kind, map_level=map_level)
    kind = ds.kind
    params = params or default_params(kind)
    if kind == "zind":
        params = params.replaced(features="none")
    maps_dir = Path(maps_dir) if maps_dir is not None else Path(ds.root) / "maps"
    todo = ds.scenes() if not scenes else scenes
    unknown = sorted(set(todo) - set(ds.scenes()))
    if unknown:
        raise InputError(f"unknown scene(s) {', '.join(unknown)}; available: {', '.join(ds.scenes())}")
    out: list[SceneOutcome] = []
    for scene in todo:
        target = maps_dir / f"{scene}.h5"
        try:
            sources, scene_params, build, note = _scene_build(ds, scene, use_line_files, params)
            refuse_overwriting_inputs(sources, [target])
            refuse_replacing_non_map(target, overwrite)
            inputs = None if ds.kind == "zind" else _inputs(sources, note)
            if not overwrite and is_up_to_date(target, sources, scene_params, inputs):
                out.append(SceneOutcome(scene, target, "up-to-date", note))
                if progress:
                    progress(scene, "up-to-date", 1, 1)
                continue
            cb = (lambda stage, d, t, s=scene: progress(s, stage, d, t)) if progress else None
            rep = build(target, scene_params, scene.replace("/", "_"), cb)
            out.append(SceneOutcome(scene, target, "built", note, report=rep))
        except LdlError as exc:
            out.append(SceneOutcome(scene, target, "failed", str(exc)))
            if progress:
                progress(scene, "failed", 1, 1)
    return out


def _inputs(sources: list[Path | None], note: str) -> dict:
    """The build-config entries a map of these sources records (``build_map`` / ``build_lines_map``)."""
    if note == LINES_ONLY_NOTE:
        return {"input": f"lines:{sources[0]}", "lines_file": None}
    return {"input": str(sources[0]), "lines_file": str(sources[1]) if len(sources) > 1 and sources[1] else None}


def _scene_build(ds, scene: str, use_line_files: bool,
                 params: BuildParams) -> tuple[list[Path | None], BuildParams, Callable[..., BuildReport], str]:
    """What a scene's map is built from: the source files (for the up-to-date check), the
    parameters, a function ``build(target, params, name, progress)`` and a note for the user.

    From the scan (with the dataset's 3D line file when ``use_line_files``); with
    ``use_line_files`` and no scan, a lines-only map of the line file (features ``none``); for
    ZInD, a lines-only map of the room layouts (``build_lines_map``)."""
    if ds.kind == "zind":
        def build_layout(target: Path, params: BuildParams, name: str, progress) -> BuildReport:
            lines, walkable = ds.layout_scene(scene)
            return build_lines_map(lines, target, params, name=name, walkable=walkable, source=f"zind:{scene}",
                                   progress=progress)

        return [ds.json_path(scene)], params, build_layout, ""
    lines = ds.line_file(scene)
    try:
        cloud = ds.point_cloud(scene)
    except InputError as exc:
        if lines is None or not use_line_files:
            hint = f" (its 3D line file {lines} maps with --line-files)" if lines is not None else ""
            raise InputError(f"{exc}{hint}") from None
        cloud = None
    if not use_line_files:
        return [cloud], params, lambda target, p, name, progress: build_map(cloud, target, None, p, name=name,
                                                                           progress=progress), ""
    if lines is None:
        raise InputError(f"no 3D line file for scene {scene} (looked for <scene>lines.txt, <scene>_lines.txt, "
                         f"<scene>.txt or .obj in pcd_line/)")
    if cloud is not None:
        return [cloud, lines], params, lambda target, p, name, progress: build_map(cloud, target, lines, p, name=name,
                                                                                  progress=progress), ""

    def build_lines_only(target: Path, p: BuildParams, name: str, progress) -> BuildReport:
        return build_lines_map(read_lines(lines), target, p, name=name, source=f"lines:{lines}", progress=progress)

    return [lines], params.replaced(features="none"), build_lines_only, LINES_ONLY_NOTE
