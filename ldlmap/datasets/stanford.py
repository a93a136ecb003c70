"""The Stanford 2D-3D-S reader (``--dataset stanford``).

**Stanford 2D-3D-S** (``<root>`` = e.g. ``data/stanford2d3ds``)::

    pano/area_N/camera_<id>_<room>_<n>_frame_equirectangular_domain_rgb.png
    pose/area_N/camera_<id>_<room>_<n>_frame_equirectangular_domain_pose.json
    pcd/area_N/<room>_<n>.txt                               the dataset's non-aligned clouds
    pcd_line/area_N/<room>_<n>lines.txt                     optional 3D line file

Splits of Stanford 2D-3D-S are its areas (``area_1`` ... ``area_6``, area 5 being distributed
as ``area_5a`` and ``area_5b``); scenes are keyed ``area_N/<room>_<n>``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

from ldlmap.datasets.base import (IMAGE_EXTENSIONS, POINT_CLOUD_EXTENSIONS, Query, STANFORD_AREAS, as_split_list,
                                  find_file, line_file_scenes, natural_key, require_root, visible_dirs)
from ldlmap.datasets.poses import read_stanford_pose
from ldlmap.core.errors import InputError


_STANFORD_RGB = re.compile(r"^camera_(?P<cam>[0-9A-Za-z]+)_(?P<room>.+_\d+)_frame_equirectangular_domain_rgb$")
# ----------------------------------------------------------------------------- Stanford 2D-3D-S


class Stanford2D3DS:
    """Reader for the Stanford 2D-3D-S panorama layout; splits are areas."""

    kind = "stanford"

    def __init__(self, root: str | Path) -> None:
        self.root = require_root(root, "Stanford 2D-3D-S")
        if not any(self._areas(sub) for sub in ("pano", "pcd", "pcd_line")):  # OmniScenes has pcd/ too
            raise InputError(f"not a Stanford 2D-3D-S root (no area_N folder in pano, pcd or pcd_line): {self.root}")

    def __repr__(self) -> str:
        return f"Stanford2D3DS({str(self.root)!r})"

    def _areas(self, sub: str) -> list[str]:
        folder = self.root / sub
        if not folder.is_dir():
            return []
        names = [p.name for p in visible_dirs(folder) if p.name.startswith("area_")]
        known = [a for a in STANFORD_AREAS if a in names]
        return known + sorted(set(names) - set(known), key=natural_key)

    def splits(self) -> list[str]:
        """Areas that have panoramas (``pano/area_*``)."""
        return self._areas("pano")

    def _panos(self, area: str) -> list[tuple[Path, str, str]]:
        """``(image, camera_id, room)`` for each panorama of an area."""
        out = []
        for img in (self.root / "pano" / area).iterdir():
            if img.suffix.lower() not in IMAGE_EXTENSIONS or img.name.startswith("."):
                continue
            m = _STANFORD_RGB.match(img.stem)
            if not m:
                raise InputError("unrecognised Stanford 2D-3D-S panorama name (expected camera_<id>_<room>_<n>_"
                                 f"frame_equirectangular_domain_rgb.png): {img}")
            out.append((img, m["cam"], m["room"]))
        return out

    def scenes(self) -> list[str]:
        """Scene keys ``area_N/<room>_<n>``: clouds in ``pcd/area_N``, line files in
        ``pcd_line/area_N`` and rooms with panoramas."""
        names: set[str] = set()
        for area in self._areas("pcd"):
            names |= {f"{area}/{p.stem}" for p in (self.root / "pcd" / area).iterdir()
                      if p.suffix.lower() in POINT_CLOUD_EXTENSIONS and not p.name.startswith(".")}
        for area in self._areas("pcd_line"):
            names |= {f"{area}/{n}" for n in line_file_scenes(self.root / "pcd_line" / area)}
        for area in self.splits():
            names |= {f"{area}/{room}" for _, _, room in self._panos(area)}
        return sorted(names, key=natural_key)

    def _scene_key(self, scene: str) -> str:
        if "/" in scene:
            return scene
        matches = [s for s in self.scenes() if s.split("/", 1)[1] == scene]
        if len(matches) != 1:
            raise InputError(f"Stanford scene {scene!r} is {'ambiguous' if matches else 'unknown'}; "
                             "use area_N/<room>_<n>" + (f" ({', '.join(matches)})" if matches else ""))
        return matches[0]

    def queries(self, split: str | Sequence[str] | None = None, scene: str | None = None) -> list[Query]:
        """Queries of the given area(s) (all when None), optionally of one scene (``area_N/room_n``
        or an unambiguous ``room_n``); sorted by area, room and camera id."""
        available = self.splits()
        wanted = as_split_list(split, available, "Stanford area")
        if scene is not None:
            scene = self._scene_key(scene)
            if scene not in self.scenes():
                raise InputError(f"unknown Stanford scene {scene}")
        out: list[Query] = []
        for area in sorted(wanted, key=available.index):
            for img, cam, room in sorted(self._panos(area), key=lambda x: (natural_key(x[2]), x[1])):
                key = f"{area}/{room}"
                if scene is not None and key != scene:
                    continue
                pose_dir = self.root / "pose" / area
                pose = pose_dir / f"camera_{cam}_{room}_frame_equirectangular_domain_pose.json"
                if not pose.is_file():
                    raise InputError(f"no pose file for query {img} (expected {pose})")
                align = pose_dir / f"{room}.txt"
                R, t = read_stanford_pose(pose, align if align.is_file() else None)
                out.append(Query(image=img, scene=key, split=area, rot_cam_from_world=R, center=t,
                                 name=f"{key}/{cam}", scene_state=area, pose_file=pose))
        return out

    def point_cloud(self, scene: str) -> Path:
        """``pcd/area_N/<room>_<n>.txt`` (or ``.ply``/``.pcd``; ``.ply`` preferred)."""
        key = self._scene_key(scene)
        area, room = key.split("/", 1)
        path = find_file(self.root / "pcd" / area, [room], POINT_CLOUD_EXTENSIONS)
        if path is None:
            raise InputError(f"no point cloud for scene {key} in {self.root / 'pcd' / area}")
        return path

    def line_file(self, scene: str) -> Path | None:
        """``pcd_line/area_N/<room>_<n>lines.txt`` (or ``<room>_<n>.txt/.obj``) when present."""
        area, room = self._scene_key(scene).split("/", 1)
        return find_file(self.root / "pcd_line" / area, [f"{room}lines", f"{room}_lines", room], (".txt", ".obj"))
