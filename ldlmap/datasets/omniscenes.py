"""The OmniScenes reader (``ldlloc run --dataset omniscenes``; also the synthetic datasets' layout).

**OmniScenes** (``<root>`` = e.g. ``data/omniscenes``)::

    <split>_pano/<prefix>_<room>_<n>_scene_<k>/<id>.jpg     query panoramas (.jpg or .png)
    <split>_pose/<prefix>_<room>_<n>_scene_<k>/<id>.txt     3x4 [R | t], R world->camera, t centre
    pcd/<room>_<n>.txt                                      colored scan (x y z r g b), or .ply
    pcd_line/<room>_<n>lines.txt                            optional 3D line file

``<prefix>`` is the split name for the plain splits (``extreme_room_1_scene_2``) and the
capture type in the released change splits (``change_handheld_pano/handheld_pyebaekRoom_1_
scene_2``); both are accepted. When a scene has both ``pcd/<scene>.ply`` and ``.txt`` the
``.ply`` is used: it holds the same points (the generator writes both) and binary PLY reads
several times faster than text.

Synthetic scenes of several rooms (``--preset multiroom``, ``building``) name each query's room,
and a building's its floor, in the ground truth: ``Query.room``, ``Query.floor``
(:func:`query_rooms`).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Sequence

from ldlmap.datasets.base import (IMAGE_EXTENSIONS, OMNISCENES_SPLITS, POINT_CLOUD_EXTENSIONS, Query, as_split_list,
                                  find_file, line_file_scenes, natural_key, require_root, visible_dirs)
from ldlmap.datasets.poses import read_pose_txt
from ldlmap.core.errors import InputError


SYNTH_GENERATOR = "ldlmap.synth"  # the ``generator`` of a dataset.json written by ``ldlmap synth``


def written_by_synth(root: str | Path) -> bool:
    """Whether ``root`` holds a dataset written by ``ldlmap synth`` (its ``dataset.json`` says so)."""
    try:
        return json.loads((Path(root) / "dataset.json").read_text()).get("generator") == SYNTH_GENERATOR
    except (OSError, ValueError, AttributeError):
        return False


def query_rooms(root: str | Path) -> dict[tuple[str, str, str], tuple[int | None, str]]:
    """``(split, scene, image stem) -> (floor, room id)`` of the queries of a synthetic dataset
    whose scenes hold several rooms (``ldlmap synth --preset multiroom | building``: the rooms and
    their query stems in ``dataset.json``; a walk split's frames, ``ldlmap synth --walk``, in its
    ``walks``); empty for any other dataset. Multi-room rooms have no floor and are named ``room<i>``."""
    try:
        meta = json.loads((Path(root) / "dataset.json").read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(meta, dict) or meta.get("generator") != SYNTH_GENERATOR:
        return {}
    out: dict[tuple[str, str, str], tuple[int | None, str]] = {}
    for scene in meta.get("scenes", []):
        for room in scene.get("rooms", []) or []:
            rid = room.get("id") or f"room{room.get('index')}"
            floor = room.get("floor")
            for split, stems in (room.get("queries") or {}).items():
                for stem in stems:
                    out[(split, scene.get("name"), stem)] = (None if floor is None else int(floor), rid)
    for split, walk in (meta.get("walks") or {}).items():  # a walk's frames name their room themselves
        for f in walk.get("frames", []) if isinstance(walk, dict) else []:
            if f.get("room"):
                out[(split, f.get("scene"), f.get("stem"))] = (None if f.get("floor") is None else int(f["floor"]), f["room"])
    return out


_SCENE_FOLDER = re.compile(r"^(?:(?P<prefix>.*)_)?(?P<room>[^_]+_\d+)_(?P<state>scene_\d+)$")
# ----------------------------------------------------------------------------------- OmniScenes


class OmniScenes:
    """Reader for the OmniScenes layout (also written by ``ldlmap synth``: its ``label`` is then
    ``synthetic``, the name users see in tables, file names and errors)."""

    kind = "omniscenes"

    def __init__(self, root: str | Path) -> None:
        self.root = require_root(root, "OmniScenes")
        self.label = "synthetic" if written_by_synth(self.root) else "omniscenes"
        self.title = "synthetic" if self.label == "synthetic" else "OmniScenes"  # in messages
        has_pano = any(p.name.endswith("_pano") for p in visible_dirs(self.root))
        if not has_pano and not (self.root / "pcd").is_dir() and not (self.root / "pcd_line").is_dir():
            raise InputError(f"not an {self.title} root (no <split>_pano, pcd or pcd_line folder): {self.root}")

    def __repr__(self) -> str:
        return f"OmniScenes({str(self.root)!r})"

    def splits(self) -> list[str]:
        """Split names present (folders ``<split>_pano``): the paper's splits first, then others."""
        names = [p.name[: -len("_pano")] for p in visible_dirs(self.root) if p.name.endswith("_pano")]
        names = [n for n in names if n]
        known = [s for s in OMNISCENES_SPLITS if s in names]
        return known + sorted(set(names) - set(known))

    def _parse_scene_folder(self, split: str, folder: Path) -> tuple[str, str]:
        """``(room, scene_state)`` of a ``<prefix>_<room>_<n>_scene_<k>`` folder."""
        name = folder.name
        # Known prefixes first, so room names containing underscores survive.
        prefixes = [split, split.removeprefix("change_"), split.split("_")[0]]
        for prefix in dict.fromkeys(prefixes):
            if name.startswith(prefix + "_"):
                m = re.match(r"^(?P<room>.+)_(?P<state>scene_\d+)$", name[len(prefix) + 1:])
                if m:
                    return m["room"], m["state"]
        m = _SCENE_FOLDER.match(name)
        if not m:
            raise InputError(f"unrecognised {self.title} scene folder (expected <split>_<room>_<n>_scene_<k>): {folder}")
        return m["room"], m["state"]

    def _scene_folders(self, split: str) -> list[tuple[Path, str, str]]:
        pano_dir = self.root / f"{split}_pano"
        return [(d, *self._parse_scene_folder(split, d)) for d in visible_dirs(pano_dir)]

    def scenes(self) -> list[str]:
        """Scene (point cloud) names: clouds in ``pcd/``, line files in ``pcd_line/`` and rooms
        that have queries."""
        names: set[str] = set()
        pcd = self.root / "pcd"
        if pcd.is_dir():
            names |= {p.stem for p in pcd.iterdir() if p.suffix.lower() in POINT_CLOUD_EXTENSIONS and not p.name.startswith(".")}
        names |= line_file_scenes(self.root / "pcd_line")
        for split in self.splits():
            names |= {room for _, room, _ in self._scene_folders(split)}
        return sorted(names, key=natural_key)

    def queries(self, split: str | Sequence[str] | None = None, scene: str | None = None) -> list[Query]:
        """Queries of the given split(s) (all when None), optionally of one scene; sorted by
        split (paper order), scene, capture session and image name."""
        available = self.splits()
        wanted = as_split_list(split, available, f"{self.title} split")
        if scene is not None and scene not in self.scenes():
            raise InputError(f"unknown {self.title} scene {scene}; available: {', '.join(self.scenes()) or 'none'}")
        out: list[Query] = []
        rooms = query_rooms(self.root) if self.label == "synthetic" else {}
        for s in sorted(wanted, key=available.index):
            for folder, room, state in sorted(self._scene_folders(s), key=lambda f: (natural_key(f[1]), natural_key(f[2]))):
                if scene is not None and room != scene:
                    continue
                images = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS
                                 and not p.name.startswith(".")), key=lambda p: natural_key(p.stem))
                for img in images:
                    pose_path = self.root / f"{s}_pose" / folder.name / f"{img.stem}.txt"
                    if not pose_path.is_file():
                        raise InputError(f"no pose file for query {img} (expected {pose_path})")
                    R, t = read_pose_txt(pose_path)
                    floor, room_id = rooms.get((s, room, img.stem), (None, None))
                    out.append(Query(image=img, scene=room, split=s, rot_cam_from_world=R, center=t,
                                     name=f"{s}/{room}_{state}/{img.stem}", scene_state=state, pose_file=pose_path,
                                     floor=floor, room=room_id))
        return out

    def point_cloud(self, scene: str) -> Path:
        """``pcd/<scene>.ply`` if present, else ``.txt`` (or ``.pcd``)."""
        path = find_file(self.root / "pcd", [scene], POINT_CLOUD_EXTENSIONS)
        if path is None:
            raise InputError(f"no point cloud for scene {scene} in {self.root / 'pcd'} "
                             f"(looked for {scene}{{{','.join(POINT_CLOUD_EXTENSIONS)}}})")
        return path

    def line_file(self, scene: str) -> Path | None:
        """The distributed 3D line file ``pcd_line/<scene>lines.txt`` (or ``<scene>.txt/.obj``)."""
        return find_file(self.root / "pcd_line", [f"{scene}lines", f"{scene}_lines", scene], (".txt", ".obj"))

    def mesh_file(self, scene: str) -> Path | None:
        """Textured mesh ``mesh/<scene>.obj`` (or ``.ply``) of a synthetic scene, when present."""
        return find_file(self.root / "mesh", [scene], (".obj", ".ply"))

    def gt_line_file(self, scene: str) -> Path | None:
        """Ground-truth 3D edges ``gt_lines/<scene>.obj`` (or ``.txt``) of a synthetic scene, when present."""
        return find_file(self.root / "gt_lines", [scene], (".obj", ".txt"))
