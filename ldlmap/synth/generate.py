"""Write a synthetic dataset in the OmniScenes layout (docs/synthetic.md, docs/datasets.md).

For each scene ``<room>_<n>`` (``synthroom_1``, ``synthroom_2``, ...)::

    pcd/<room>_<n>.txt, .ply                    the simulated scan of the unchanged scene
    mesh/<room>_<n>.obj (+ .mtl, .png)          the textured mesh
    gt_lines/<room>_<n>.obj, .txt               ground-truth 3D edges of the mesh
    layout/<room>_<n>.obj                       the room's layout, its shell's creases (``furnished`` preset)
    specs/<room>_<n>.toml                       the spec used (scene_2: the changed scene)
    <split>_pano/<split>_<room>_<n>_scene_<k>/<id>.jpg   query panoramas (JPEG quality 95)
    <split>_pose/<split>_<room>_<n>_scene_<k>/<id>.txt   3x4 [R | t] (R world->camera, t centre)
    dataset.json                                what was generated (no timestamps)

``scene_1`` holds the splits captured in the unchanged scene (robot, handheld, extreme and the
illumination variants ``extreme_intensity``, ``extreme_gamma``, ``extreme_white_balance``, same
poses as ``extreme``); ``scene_2`` the change splits, rendered in ``changed_spec(spec)`` while the
scan stays the unchanged scene.

Everything derives from ``seed`` through independent random streams per scene and per stage
(``np.random.default_rng([seed, spec.seed, scene, stage])``), so the same seed gives byte-identical files
and turning the illumination splits off changes nothing else. The whole folder is built in a
temporary sibling and renamed at the end (:func:`~ldlmap.core.errors.atomic_dir`); ``dataset.json``
lists the files written (``files``), and ``--overwrite`` replaces only those, keeping a user's
other files (:func:`ldlmap.synth.capture.dataset_output`).
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Callable, Sequence

from ldlmap.datasets.omniscenes import SYNTH_GENERATOR
from ldlmap.io.linefiles import write_lines
from ldlmap.synth import scan  # through the module: tests replace scan.sample_scan to fail midway
from ldlmap.synth.building import generate_building, is_building_preset
from ldlmap.synth.capture import (BASE_SPLITS, GENERATOR_VERSION, ILLUMINATION_SPLITS, CaptureSettings, DatasetSummary,
                                  ProgressTicks, check_dataset_seed, capture_settings, dataset_output, list_generated,
                                  stream_rng, write_split_panoramas)
from ldlmap.synth.edges import mesh_edges
from ldlmap.synth.furnished import furnished_spec, layout_spec, room_function, room_shape
from ldlmap.synth.meshio import write_textured_obj
from ldlmap.synth.multiroom import generate_multiroom, is_multiroom_preset
from ldlmap.synth.presets import changed_spec, get_preset, random_spec
from ldlmap.synth.render import Renderer
from ldlmap.synth.scene import build_scene
from ldlmap.synth.shapes import classify_room
from ldlmap.synth.spec import SceneSpec, dump_spec_toml, load_spec
from ldlmap.synth.walk import check_doors, check_walk_doors, write_walks
from ldlmap.synth.walkplan import WalkRoom


def _room_name(spec: SceneSpec) -> str:
    name = re.sub(r"[^A-Za-z0-9]", "", str(getattr(spec, "name", "") or ""))
    return name or "synthroom"


def load_specs(preset: str | None, spec_paths: Sequence[Path], seed: int,
               scenes: int | None = None) -> list[tuple[str, SceneSpec]]:
    """``(room name, spec)`` pairs: the spec files when given (room = the spec's name), else
    ``random_spec(preset, seed, i)`` (``furnished_spec(seed, i)`` for ``furnished``) for the
    preset's scenes (room ``synthroom``); ``scenes`` overrides the preset's count."""
    if spec_paths:
        return [(_room_name(s), s) for s in (load_spec(Path(p)) for p in spec_paths)]
    preset = preset or "demo"
    count = int(scenes if scenes is not None else get_preset(preset).get("scenes", 2))
    make = (lambda i: furnished_spec(seed, i)) if preset == "furnished" else (lambda i: random_spec(preset, seed, i))
    return [("synthroom", make(i)) for i in range(1, count + 1)]


def _scene_extra(preset: str | None, spec_paths: Sequence[Path], index: int) -> dict:
    """What a preset adds to a scene's ``dataset.json`` entry: the furnished rooms' function and shape."""
    if spec_paths or preset != "furnished":
        return {}
    return {"function": room_function(index), "shape": room_shape(index)}


def generate_dataset(out: Path, preset: str | None = "demo", spec_paths: Sequence[Path] = (), seed: int = 0,
                     overwrite: bool = False, progress: bool = True, illumination: bool = True,
                     width: int | None = None, per_split: int | None = None,
                     scenes: int | None = None, walk: tuple[str, ...] = (),
                     walk_step: float | None = None, doors: str = "closed",
                     walk_doors: str | None = None) -> DatasetSummary:
    """Generate the dataset into ``out`` (atomically) and return a :class:`DatasetSummary`.

    ``width`` and ``per_split`` override the specs' panorama width and panoramas per split.
    A multi-room preset (``multiroom``: several rooms in one scan, one scene) is generated by
    :func:`ldlmap.synth.multiroom.generate_multiroom`, a building preset (``building``,
    ``building_small``: floors of rooms, one scene per floor) by
    :func:`ldlmap.synth.building.generate_building`. ``scenes``: how many rooms of a single-room
    preset (default: the preset's count).
    """
    check_dataset_seed(seed)
    if not spec_paths and is_building_preset(preset):
        return generate_building(out, preset, seed, overwrite=overwrite, progress=progress, illumination=illumination,
                                 width=width, per_split=per_split, walk=walk, walk_step=walk_step,
                                 doors=doors, walk_doors=walk_doors)
    check_doors(doors, building=False)  # no other preset has doors between rooms
    if walk_doors not in (None, "closed"):
        check_walk_doors(walk_doors, walk, building=False)
    if not spec_paths and is_multiroom_preset(preset):
        return generate_multiroom(out, preset, seed, overwrite=overwrite, progress=progress, illumination=illumination,
                                  width=width, per_split=per_split, walk=walk, walk_step=walk_step)
    start = time.perf_counter()
    out = Path(out)
    named = load_specs(preset, list(spec_paths), seed, scenes)  # bad specs fail before anything is written
    specs = [s for _, s in named]
    names = [f"{room}_{i}" for i, (room, _) in enumerate(named, start=1)]
    settings = [capture_settings(s.capture, width, per_split, illumination) for s in specs]
    splits = list(BASE_SPLITS) + [v for v in ILLUMINATION_SPLITS if any(v in c.illumination for c in settings)]
    split_counts = {s: 0 for s in splits}
    total = sum(4 + sum(c.counts.values()) for c in settings)

    with dataset_output(out, overwrite) as tmp, ProgressTicks(progress, total) as tick:
        scene_info = [_write_scene(tmp, name, spec, idx, cap, seed, split_counts, tick,
                                   _scene_extra(preset, spec_paths, idx))
                      for idx, (spec, cap, name) in enumerate(zip(specs, settings, names), start=1)]
        spaces = [[WalkRoom(id="", scene=name, spec=spec)] for name, spec in zip(names, specs)]
        walks = write_walks(tmp, spaces, walk, seed, settings[0], split_counts, tick, walk_step) if walk else {}
        meta = {"generator": SYNTH_GENERATOR, "version": GENERATOR_VERSION, "seed": int(seed),
                "preset": None if spec_paths else (preset or "demo"),
                "illumination": sorted({v for c in settings for v in c.illumination}),
                "layout": "omniscenes", "scenes": scene_info,
                "splits": {s: {"images": split_counts[s]} for s in split_counts}, **({"walks": walks} if walks else {})}
        (tmp / "dataset.json").write_text(json.dumps(list_generated(tmp, meta), indent=2) + "\n")

    return DatasetSummary(out=out, seed=int(seed), scenes=names, splits=split_counts,
                          points={s["name"]: s["points"] for s in scene_info},
                          width=settings[0].width if settings else 0,
                          height=settings[0].height if settings else 0,
                          seconds=time.perf_counter() - start)


def _write_scene(tmp: Path, name: str, spec: SceneSpec, idx: int, cap: CaptureSettings, seed: int,
                 split_counts: dict[str, int], tick: Callable[[str], None], extra: dict | None = None) -> dict:
    """Write scene ``name`` of one room: spec, mesh, true lines, scan, changed spec and the panoramas
    of every split (``split_counts`` grows in place); returns its ``dataset.json`` entry, with
    ``extra`` (a furnished room's function and shape; then also its layout line file)."""
    mesh = build_scene(spec)
    renderer = Renderer(mesh)
    (tmp / "specs").mkdir(parents=True, exist_ok=True)
    (tmp / "specs" / f"{name}.toml").write_text(dump_spec_toml(spec))
    tick(f"{name}: mesh")
    (tmp / "mesh").mkdir(exist_ok=True)
    write_textured_obj(mesh, tmp / "mesh" / f"{name}.obj")
    segs = mesh_edges(mesh)
    (tmp / "gt_lines").mkdir(exist_ok=True)
    write_lines(tmp / "gt_lines" / f"{name}.obj", segs)
    write_lines(tmp / "gt_lines" / f"{name}.txt", segs)
    if extra:
        layout = mesh_edges(build_scene(layout_spec(spec)))
        (tmp / "layout").mkdir(exist_ok=True)
        write_lines(tmp / "layout" / f"{name}.obj", layout)
        extra = {**extra, "layout": f"layout/{name}.obj", "layout_lines": int(len(layout))}
    tick(f"{name}: scan")
    pts, cols = scan.sample_scan(mesh, spec.scan, stream_rng(seed, spec, idx, "scan"), renderer=renderer)
    (tmp / "pcd").mkdir(exist_ok=True)
    scan.write_ply(tmp / "pcd" / f"{name}.ply", pts, cols)
    scan.write_txt(tmp / "pcd" / f"{name}.txt", pts, cols)
    tick(f"{name}: changed scene")
    changed = changed_spec(spec, stream_rng(seed, spec, idx, "change"))
    (tmp / "specs" / f"{name}_scene_2.toml").write_text(dump_spec_toml(changed))
    changed_renderer = Renderer(build_scene(changed))
    tick(f"{name}: panoramas")
    write_split_panoramas(tmp, name, spec, idx, cap, seed, renderer, changed_renderer, split_counts, tick)
    return {"name": name, "spec": f"specs/{name}.toml", "changed_spec": f"specs/{name}_scene_2.toml",
            "points": int(len(pts)), "triangles": int(mesh.num_triangles),
            "gt_lines": int(len(segs)), "width": cap.width, "height": cap.height, "kind": classify_room(spec),
            **(extra or {})}
