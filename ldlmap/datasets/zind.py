"""The ZInD reader (Zillow Indoor Dataset, ``--dataset zind``): real homes without scans.

**ZInD** (Zillow Indoor Dataset; ``<root>`` = e.g. ``data/zind``, or one home folder)::

    <home>/zind_data.json                                   layouts, floor-plan placements, scales
    <home>/panos/floor_XX_partial_room_ZZ_pano_N.jpg        query panoramas (upright)

Splits are the homes (``000``); there are no scans: maps are built from the room layouts
(:meth:`ZInD.layout_scene`, :mod:`ldlmap.io.zind`, which also documents the pose conversion).
``ZInD(root, map_level="room")`` has one scene per complete room (``000/floor_01/
complete_room_06``), ``map_level="floor"`` one per floor (``000/floor_01``, every room in one
map); a query's ``scene`` is the map it is localized against at that level.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.datasets.base import MAP_LEVELS, Query, as_split_list, natural_key, require_root, visible_dirs
from ldlmap.io.zind import ZIND_JSON, ZindHome, read_zind_home, room_lines, room_portals, room_walls
from ldlmap.map.translations import Walkable



class ZInD:
    """Reader for Zillow Indoor Dataset homes (``<root>/<home>/zind_data.json``); splits are homes.

    ``root`` is a folder of homes or one home folder (then its name is the only split). Scenes
    are ``<home>/<floor>/<complete_room>`` (``map_level="room"``) or ``<home>/<floor>``
    (``"floor"``). Queries are the panoramas, upright, with poses converted by
    :mod:`ldlmap.io.zind`; their ``scene_state`` is the home.
    """

    kind = "zind"

    def __init__(self, root: str | Path, map_level: str = "room") -> None:
        if map_level not in MAP_LEVELS:
            raise InputError(f"unknown ZInD map level {map_level!r}; choose one of {', '.join(MAP_LEVELS)}")
        self.root = require_root(root, "ZInD")
        self.map_level = map_level
        if (self.root / ZIND_JSON).is_file():
            self._folders = {self.root.name: self.root}
        else:
            self._folders = {p.name: p for p in visible_dirs(self.root) if (p / ZIND_JSON).is_file()}
        if not self._folders:
            raise InputError(f"not a ZInD root (no <home>/{ZIND_JSON}): {self.root}")
        self._homes: dict[str, ZindHome] = {}

    def __repr__(self) -> str:
        return f"ZInD({str(self.root)!r}, map_level={self.map_level!r})"

    def _folder(self, home: str) -> Path:
        if home not in self._folders:
            raise InputError(f"unknown ZInD home {home!r}; available: {', '.join(self.splits())}")
        return self._folders[home]

    def home(self, name: str) -> ZindHome:
        """The parsed :class:`ldlmap.io.zind.ZindHome` of a home (read once)."""
        if name not in self._homes:
            self._homes[name] = read_zind_home(self._folder(name))
        return self._homes[name]

    def json_path(self, scene_or_home: str) -> Path:
        """``zind_data.json`` of the home a scene (or home) belongs to."""
        return self._folder(scene_or_home.split("/", 1)[0]) / ZIND_JSON

    def splits(self) -> list[str]:
        """Home names (``000``, ...)."""
        return sorted(self._folders, key=natural_key)

    def _scene_of(self, home: str, floor: str, room: str) -> str:
        return f"{home}/{floor}" if self.map_level == "floor" else f"{home}/{floor}/{room}"

    def scenes(self) -> list[str]:
        """Map keys at this level: ``<home>/<floor>/<complete_room>`` or ``<home>/<floor>``."""
        out: list[str] = []
        for name in self.splits():
            keys = {self._scene_of(name, f, r) for f, r in self.home(name).rooms}
            out.extend(sorted(keys, key=natural_key))
        return out

    def queries(self, split: str | Sequence[str] | None = None, scene: str | None = None) -> list[Query]:
        """Panoramas of the given home(s) (all when None), optionally of one scene; sorted by home,
        floor, partial room and pano. Names are ``<home>/<floor>/<partial_room>/<pano>``."""
        available = self.splits()
        wanted = as_split_list(split, available, "ZInD home")
        if scene is not None:
            self._parse_scene(scene)  # one-line error for an unknown scene
        out: list[Query] = []
        for name in sorted(wanted, key=available.index):
            for p in self.home(name).panos:
                key = self._scene_of(name, p.floor, p.complete_room)
                if scene is not None and key != scene:
                    continue
                out.append(Query(image=p.image, scene=key, split=name, rot_cam_from_world=p.rot_cam_from_world,
                                 center=p.center, name=f"{name}/{p.floor}/{p.partial_room}/{p.pano}",
                                 scene_state=name, upright=True, pose_file=self.json_path(name)))
        return out

    def _parse_scene(self, scene: str) -> tuple[str, str, list[str] | None]:
        parts = scene.split("/")
        if scene not in self.scenes() or len(parts) != (2 if self.map_level == "floor" else 3):
            raise InputError(f"unknown ZInD scene {scene} at {self.map_level} level; available: {', '.join(self.scenes())}")
        return parts[0], parts[1], (parts[2:] or None)

    def layout_scene(self, scene: str):
        """``(lines (L, 2, 3), Walkable)`` of a scene: its rooms' layout lines (metres, z up, floor
        at 0), their polygons, doors and openings as portals, and the camera-height band."""

        home, floor, rooms = self._parse_scene(scene)
        return scene_layout(self.home(home), floor, rooms)

    def point_cloud(self, scene: str) -> Path:
        raise InputError(f"ZInD has no point clouds: its maps are built from the room layouts "
                         f"(ldlmap prepare --dataset zind), scene {scene}")

    def line_file(self, scene: str) -> Path | None:
        """None: ZInD distributes no 3D line files (lines come from the layouts)."""
        return None


def scene_layout(home: ZindHome, floor: str, rooms: Sequence[str] | None = None):
    """Everything a map build needs for a scene: ``(lines, Walkable)``.

    ``rooms``: complete-room keys of ``floor`` (None: every room of the floor, one floor-level
    map). The Walkable holds the rooms' polygons, their doors and openings as portals, and the
    camera-height band ``(min, max)`` over the scene's panoramas (all of the floor when no
    panorama belongs to the rooms).
    """
    keys = sorted((r for f, r in home.rooms if f == floor), key=natural_key) if rooms is None else list(rooms)
    missing = [r for r in keys if (floor, r) not in home.rooms]
    if missing or not keys:
        raise InputError(f"ZInD home {home.name} has no room(s) {', '.join(missing) or '(none given)'} on {floor}")
    sel = [home.rooms[(floor, r)] for r in keys]
    lines = np.concatenate([room_lines(r) for r in sel])
    portals = np.concatenate([room_portals(r) for r in sel])
    heights = [p.camera_height_m for p in home.panos if p.floor == floor and p.complete_room in keys]
    heights = heights or [p.camera_height_m for p in home.panos if p.floor == floor]
    walk = Walkable(polygons=tuple(r.polygon.copy() for r in sel), portals=portals,
                    z_range=(float(min(heights)), float(max(heights))),
                    walls=np.concatenate([room_walls(r) for r in sel]),
                    ceiling_heights=tuple(float(r.ceiling_height) for r in sel))
    return lines, walk
