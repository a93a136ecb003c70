"""Export the poses of a results file to the tools people use next (``ldlloc export``).

``export_results(results, fmt, out)`` with ``fmt``:

- ``colmap`` (:mod:`.colmap`): a model folder that ``pycolmap.Reconstruction(out)`` reads;
- ``nerfstudio`` (:mod:`.nerfstudio`): a ``transforms.json``;
- ``ply`` (:mod:`.ply`): cameras and map lines for a viewer;
- ``tum`` (:mod:`.tum`): a walk's trajectory as TUM text (``timestamp tx ty tz qx qy qz qw``).

Which queries, which frame, image names and maps: :mod:`.poses`. Outputs are written through a
temporary beside ``out`` and renamed at the end; an existing ``out`` is replaced only with
``overwrite``, and a COLMAP output folder never as a whole: only its model files are (the other
files of the folder stay).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ldlloc.batch.results import run_kind, unfinished_note
from ldlloc.export.colmap import (MODEL_FILES, MODEL_SUFFIXES, check_image_names, line_points, model_files,
                                  write_colmap_model)
from ldlloc.export import nerfstudio, ply, tum  # the writers of a format, called through their module
from ldlloc.export.poses import (check_frame, export_poses, image_names, image_size, input_to_map_of, map_lines,
                                 map_path_for, read_records, select_queries)
from ldlmap.core.errors import InputError, atomic_dir, atomic_file, refuse_overwriting_inputs
from ldlmap.core.frame import decompose

FORMATS = ("colmap", "nerfstudio", "ply", "tum")


@dataclass
class ExportOutcome:
    """What :func:`export_results` wrote, and what it has to say about it (one line each)."""

    out: Path
    count: int
    notes: list[str] = field(default_factory=list)


def _check_options(fmt: str, out: Path, text: bool, image_root: Path | None, overwrite: bool) -> None:
    """One-line errors for options that do not fit ``fmt`` and for an ``out`` that may not be replaced."""
    if fmt not in FORMATS:
        raise InputError(f"unknown --format {fmt!r}; valid: {', '.join(FORMATS)}")
    if fmt != "colmap" and (text or image_root is not None):
        raise InputError(f"{'--text' if text else '--image-root'} is for --format colmap (a COLMAP model), "
                         f"not {fmt}")
    suffix = {"nerfstudio": ".json", "ply": ".ply", "tum": ".txt"}.get(fmt)
    if suffix is not None:
        if out.suffix.lower() != suffix:
            raise InputError(f"--format {fmt} writes a {suffix} file: name -o OUT{suffix}, got {out}")
        if out.is_dir():
            raise InputError(f"output {out} is a folder; name a {suffix} file")
        if out.exists() and not overwrite:
            raise InputError(f"output {out} exists; use --overwrite to replace it, or another name")
    else:
        if out.exists() and not out.is_dir():
            raise InputError(f"output {out} exists and is not a folder (a COLMAP model is a folder)")
        if out.is_dir() and any(out.iterdir()) and not overwrite:
            raise InputError(f"output folder {out} is not empty; use --overwrite to replace the model files in it "
                             "(its other files stay), or another name")
        odd = [f for f in (model_files(out) if out.is_dir() else []) if f.is_dir() or not f.is_file()]
        if odd:  # checked here, so that the new model's files are moved in all or none
            raise InputError(f"{odd[0]} is not a file: a COLMAP model file cannot replace it (move it away)")
    if image_root is not None and not Path(image_root).is_dir():
        raise InputError(f"--image-root is not a folder: {image_root}")


def _frame_units(poses: list, frame: str, meta: dict[str, Any], map_path: Path | None) -> np.ndarray:
    """Frame units per metre of each pose: 1 in the map frame; 1 / s in the input frame of a map
    built with ``--scale s`` (1 where the map is not found)."""
    units = np.ones(len(poses))
    if frame != "input":
        return units
    scale: dict[Path, float] = {}
    for i, p in enumerate(poses):
        found, _ = map_path_for(p.record, meta, map_path)
        if found is not None:
            if found not in scale:
                A = input_to_map_of(found)
                scale[found] = 1.0 if A is None else decompose(A)[0]
            units[i] = 1.0 / scale[found]
    return units


def _write_colmap(out: Path, poses: list, lines, text: bool, image_root: Path | None, overwrite: bool) -> list[str]:
    """Write the COLMAP model into ``out``: built and checked in a temporary folder beside it, then
    its files moved in. Only model files are replaced (an earlier model's, binary or text); every
    other file of ``out`` stays. Returns what to say about it."""
    root, names = image_names([p.image for p in poses], image_root)
    check_image_names(names, text)  # before reading every image's size
    sizes = [image_size(p.image) for p in poses]
    points, colors = line_points(lines.lines, lines.groups)
    earlier = model_files(out) if out.is_dir() else []

    def commit(tmp: Path, target: Path) -> None:  # move the new model in; remove the earlier model's other files
        if not target.exists():
            os.replace(tmp, target)
            return
        written = {f.name for f in tmp.iterdir()}
        for f in earlier:
            if f.name not in written:
                f.unlink()
        for name in sorted(written):
            os.replace(tmp / name, target / name)

    with atomic_dir(out, overwrite=overwrite, commit=commit) as tmp:
        write_colmap_model(tmp, poses, names, sizes, points, colors, text, shown_as=out)
    said = [f"image names relative to {root} (COLMAP's image path); points3D: the {len(lines.lines)} map lines' "
            "end points"]
    if earlier:
        others = sorted({f.name for f in out.iterdir()} - {f.name for f in model_files(out)})
        said.append(f"replaced the earlier model files in {out}: {', '.join(f.name for f in earlier)}"
                    + (f"; kept its other {len(others)} file(s) and folder(s)" if others else ""))
    return said


def _write_nerfstudio(out: Path, poses: list, frame: str, results: Path) -> None:
    """Write the ``transforms.json`` (atomically)."""
    sizes = [image_size(p.image) for p in poses]
    world = "the map's (metres, z up)" if frame == "map" else "the map's input frame"
    extra = {"ldl_export": {"results": str(results), "frame": frame,
                            "convention": f"camera to world, OpenGL camera (x right, y up, z back); world: {world}"}}
    with atomic_file(out) as tmp:
        nerfstudio.write_transforms(tmp, nerfstudio.transforms(poses, out, sizes, extra))


def export_results(results: str | Path, fmt: str, out: str | Path, include_all: bool = False, frame: str = "map",
                   text: bool = False, image_root: str | Path | None = None, map_path: str | Path | None = None,
                   scene: str | None = None, overwrite: bool = False) -> ExportOutcome:
    """Write the poses of ``results`` (a results JSON of ``ldlloc run``) as ``fmt`` to ``out``.

    ``include_all``: also the queries whose verdict is not ``confident`` (failed ones never);
    ``frame``: ``map`` or ``input`` (:func:`ldlloc.export.poses.pose_in_frame`); ``text``: a COLMAP
    model in text files (default binary); ``image_root``: the folder COLMAP image names are relative
    to (default: the deepest folder holding every image); ``map_path``: the map for records that do
    not name one that exists (``--map``); ``scene``: only this scene's queries."""
    results, out = Path(results), Path(out)
    map_path = Path(map_path) if map_path is not None else None
    image_root = Path(image_root) if image_root is not None else None
    check_frame(frame)
    _check_options(fmt, out, text, image_root, overwrite)
    records, meta = read_records(results)
    if fmt in ("colmap", "nerfstudio") and run_kind(meta) == "video":
        raise InputError(f"{results} holds the frames of a video, not image files: --format {fmt} needs the images "
                         "(a video's poses export as --format tum or ply)")
    sel = select_queries(records, include_all, scene)
    if not sel.chosen:
        scenes = sorted({q["scene"] for q in records})
        why = ("it holds no queries" if not records else
               f"no query of scene {scene} (scenes: {', '.join(scenes[:8])})" if sel.other_scenes == len(records)
               else sel.describe(len(records)))
        raise InputError(f"nothing to export from {results}: {why}")
    told = f"exporting {sel.describe(len(records))}"
    notes = [told if sel.have_verdicts else f"{results} holds no verdicts (written before confidence existed): "
             f"{told}, every localized one"]
    if meta.get("finished") is False:  # killed or interrupted: say so, as `report` does
        notes.append(f"{results}: {unfinished_note(records, meta)}")
    poses = export_poses(sel.chosen, frame, meta, map_path)
    if fmt == "tum" and not any(p.record.get("walk") for p in poses):
        notes.append(f"{results} is not of a walk (--walk, --video): the timestamps are the poses' ranks in name order")
    maps = {map_path_for(p.record, meta, map_path)[0] for p in poses}  # the maps whose lines the export reads
    # a COLMAP export replaces its model files only, never the folder (which may hold the images)
    written = [out / f"{n}{x}" for n in MODEL_FILES for x in MODEL_SUFFIXES] if fmt == "colmap" else [out]
    refuse_overwriting_inputs([results, map_path, *maps, *(p.image for p in poses)], written)
    scenes = sorted({p.scene for p in poses})
    if len(scenes) > 1:
        notes.append(f"poses of {len(scenes)} scenes/maps in one file: they share a frame only when their maps do "
                     f"(ZInD room maps of one floor do); --scene NAME exports one")
    if fmt == "nerfstudio":
        _write_nerfstudio(out, poses, frame, results)
        return ExportOutcome(out=out, count=len(poses), notes=notes)
    if fmt == "tum":
        tum.check_one_walk(poses, results)
        with atomic_file(out) as tmp:
            Path(tmp).write_text(tum.tum_text(poses, frame))
        return ExportOutcome(out=out, count=len(poses), notes=notes)
    lines = map_lines(poses, frame, meta, map_path)
    if lines.missing:
        notes.append(f"no map lines of scene(s) {', '.join(lines.missing[:5])}: map not found (give it with --map)")
    if fmt == "colmap":
        notes += _write_colmap(out, poses, lines, text, image_root, overwrite)
    else:
        units = _frame_units(poses, frame, meta, map_path)
        with atomic_file(out) as tmp:
            ply.write_cameras_ply(tmp, poses, lines.lines, lines.groups, units, comment=f"frame: {frame}")
    return ExportOutcome(out=out, count=len(poses), notes=notes)


__all__ = ["FORMATS", "ExportOutcome", "export_results"]
