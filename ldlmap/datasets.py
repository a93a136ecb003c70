"""Readers for panoramic localization datasets in their distributed layouts.

Three layouts are supported (DESIGN.md sections 4 and 10); the synthetic generator (``ldlmap
synth``) writes the OmniScenes one, so a single reader serves real and synthetic data.

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

**Stanford 2D-3D-S** (``<root>`` = e.g. ``data/stanford2d3ds``)::

    pano/area_N/camera_<id>_<room>_<n>_frame_equirectangular_domain_rgb.png
    pose/area_N/camera_<id>_<room>_<n>_frame_equirectangular_domain_pose.json
    pcd/area_N/<room>_<n>.txt                               the dataset's non-aligned clouds
    pcd_line/area_N/<room>_<n>lines.txt                     optional 3D line file

Splits of Stanford 2D-3D-S are its areas (``area_1`` ... ``area_6``, area 5 being distributed
as ``area_5a`` and ``area_5b``); scenes are keyed ``area_N/<room>_<n>``.

**ZInD** (Zillow Indoor Dataset; ``<root>`` = e.g. ``data/zind``, or one home folder)::

    <home>/zind_data.json                                   layouts, floor-plan placements, scales
    <home>/panos/floor_XX_partial_room_ZZ_pano_N.jpg        query panoramas (upright)

Splits are the homes (``000``); there are no scans: maps are built from the room layouts
(:meth:`ZInD.layout_scene`, :mod:`ldlmap.io.zind`, which also documents the pose conversion).
``ZInD(root, map_level="room")`` has one scene per complete room (``000/floor_01/
complete_room_06``), ``map_level="floor"`` one per floor (``000/floor_01``, every room in one
map); a query's ``scene`` is the map it is localized against at that level.

Every query pose is validated on read (shape, finite values, proper rotation); a bad file raises
:class:`~ldlmap.errors.InputError` naming it.
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Protocol, Sequence, runtime_checkable

import numpy as np

from ldlmap.errors import InputError

DEFAULT_ROOTS: dict[str, Path] = {"omniscenes": Path("data/omniscenes"), "stanford": Path("data/stanford2d3ds"),
                                  "zind": Path("data/zind")}
DATASET_KINDS: tuple[str, ...] = ("omniscenes", "stanford", "zind")
# Folder under ``datasets/`` holding each kind's split manifest.
MANIFEST_DIRS: dict[str, str] = {"omniscenes": "omniscenes", "stanford": "stanford2d3ds", "zind": "zind"}
MAP_LEVELS: tuple[str, ...] = ("room", "floor")  # ZInD: one map per complete room, or per floor

# Split order used for listing and sorting (other ``<name>_pano`` splits follow alphabetically).
OMNISCENES_SPLITS: tuple[str, ...] = ("robot", "handheld", "extreme", "change_robot", "change_handheld")
STANFORD_AREAS: tuple[str, ...] = ("area_1", "area_2", "area_3", "area_4", "area_5a", "area_5b", "area_6")

IMAGE_EXTENSIONS: tuple[str, ...] = (".jpg", ".jpeg", ".png")
POINT_CLOUD_EXTENSIONS: tuple[str, ...] = (".ply", ".txt", ".pcd")  # preference order
ROTATION_TOLERANCE = 1e-3  # max |R^T R - I| entry accepted in ground-truth poses (text precision)

_STANFORD_RGB = re.compile(r"^camera_(?P<cam>[0-9A-Za-z]+)_(?P<room>.+_\d+)_frame_equirectangular_domain_rgb$")
_SCENE_FOLDER = re.compile(r"^(?:(?P<prefix>.*)_)?(?P<room>[^_]+_\d+)_(?P<state>scene_\d+)$")
# Stanford 2D-3D-S camera frame (Blender) -> ours: x forward, y left, z up (see _stanford_rotation).
_STANFORD_FLIP = np.diag([-1.0, -1.0, 1.0])


@dataclass(frozen=True, eq=False)
class Query:
    """One query panorama with its ground-truth pose (``p_cam = R (X - t)``).

    Compared by identity (it holds arrays); compare ``name`` to match queries."""

    image: Path
    scene: str  # point-cloud name: ``room_1`` (OmniScenes) or ``area_3/office_1`` (Stanford)
    split: str  # ``extreme``, ``change_robot``, ... or the Stanford area
    rot_cam_from_world: np.ndarray = field(repr=False)  # (3, 3) R, world -> camera
    center: np.ndarray = field(repr=False)  # (3,) t, camera centre in world coordinates
    name: str = ""  # stable id, e.g. ``extreme/room_1_scene_2/00012``
    scene_state: str = ""  # ``scene_2`` (OmniScenes capture session), the Stanford area or the ZInD home
    upright: bool = False  # captured upright (ZInD): localization may use an upright rotation prior
    pose_file: Path | None = None  # where the ground truth was read (never to be written over)


@runtime_checkable
class Dataset(Protocol):
    """What the batch tools need from a dataset root."""

    kind: str
    root: Path

    def splits(self) -> list[str]: ...

    def scenes(self) -> list[str]: ...

    def queries(self, split: str | Sequence[str] | None = None, scene: str | None = None) -> list[Query]: ...

    def point_cloud(self, scene: str) -> Path: ...

    def line_file(self, scene: str) -> Path | None: ...


# ------------------------------------------------------------------------------------ helpers


def _natural_key(text: str) -> tuple:
    """Sort key that orders embedded integers numerically (``img_2`` before ``img_10``)."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text))


def _check_pose(R: np.ndarray, t: np.ndarray, source: Path) -> None:
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise InputError(f"pose has non-finite values: {source}")
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
        raise InputError(f"pose rotation is not a proper rotation (|R^T R - I| = {err:.2g}, "
                         f"det = {np.linalg.det(R):.3g}): {source}")


MAX_POSE_BYTES = 1 << 20  # a pose file is a few hundred bytes; a larger one is not a pose file


def _read_pose_text(p: Path) -> str:
    """The text of pose file ``p``; one-line errors for a missing, unreadable, binary or huge file."""
    try:
        if p.is_dir():
            raise InputError(f"pose file is a folder: {p}")
        if p.stat().st_size > MAX_POSE_BYTES:
            raise InputError(f"not a pose file ({p.stat().st_size} bytes; a pose file is a few hundred): {p}")
        return p.read_text()
    except FileNotFoundError:
        raise InputError(f"pose file not found: {p}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read pose file {p}: {getattr(exc, 'strerror', None) or exc}") from None


def read_pose_txt(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an OmniScenes pose file: a 3x4 ``[R | t]`` (a 4x4 with last row 0 0 0 1 is accepted).

    Returns ``(R, t)`` exactly as stored (R world->camera, t camera centre).
    """
    p = Path(path)
    text = _read_pose_text(p)
    rows = [line.replace(",", " ").split() for line in text.splitlines()]
    rows = [r for r in rows if r and not r[0].startswith("#")]
    try:
        M = np.array([[float(x) for x in r] for r in rows], dtype=np.float64)
    except ValueError:
        raise InputError(f"malformed pose file (expected a 3x4 matrix of numbers): {p}") from None
    if M.shape == (4, 4) and np.allclose(M[3], [0, 0, 0, 1]):
        M = M[:3]
    if M.shape != (3, 4):
        got = "x".join(map(str, M.shape)) if M.ndim == 2 else "empty" if M.size == 0 else "ragged"
        raise InputError(f"malformed pose file (expected a 3x4 [R | t] matrix, got {got}): {p}")
    R, t = M[:, :3].copy(), M[:, 3].copy()
    _check_pose(R, t, p)
    return R, t


def write_pose_txt(path: str | Path, rot_cam_from_world: np.ndarray, center: np.ndarray) -> None:
    """Write a pose in the OmniScenes 3x4 ``[R | t]`` text format (full float precision)."""
    M = np.concatenate([np.asarray(rot_cam_from_world, float), np.asarray(center, float).reshape(3, 1)], 1)
    Path(path).write_text("\n".join(" ".join(repr(float(x)) for x in row) for row in M) + "\n")


def stanford_rotation(final_camera_rotation: Sequence[float]) -> np.ndarray:
    """World->camera rotation from a Stanford 2D-3D-S ``final_camera_rotation`` (Euler 'xyz').

    ``M = Rotation.from_euler('xyz', angles)`` is the Blender camera-to-world rotation (camera
    looks along its -Z, +Y up, +X right). Columns reordered to ``[M[:,2], M[:,0], M[:,1]]``,
    inverted, then left-multiplied by ``diag(-1, -1, 1)`` give our frame: +x forward (image
    centre), +y left, +z up.
    """
    from scipy.spatial.transform import Rotation

    M = Rotation.from_euler("xyz", np.asarray(final_camera_rotation, dtype=np.float64)).as_matrix()
    return _STANFORD_FLIP @ M[:, [2, 0, 1]].T  # inverse of a rotation = transpose


def read_stanford_pose(path: str | Path, alignment: str | Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read a Stanford 2D-3D-S ``*_pose.json`` as ``(R, t)`` in our convention.

    ``alignment``: optional 3x4 ``[A | b]`` text file mapping the pose's world frame to the point
    cloud's (``X_cloud = A (X - b)``), as used by some re-distributions of area 5; then
    ``R' = R A^T`` and ``t' = A (t - b)``.
    """
    p = Path(path)
    try:
        data = json.loads(_read_pose_text(p))
    except (json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"cannot read pose JSON {p}: {exc if isinstance(exc, ValueError) else 'nested too deeply'}") from None
    if not isinstance(data, dict):
        raise InputError(f"pose JSON must be an object with camera_location and final_camera_rotation: {p}")
    try:
        t = np.asarray(data["camera_location"], dtype=np.float64)
        angles = np.asarray(data["final_camera_rotation"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"pose JSON lacks a numeric camera_location / final_camera_rotation ({exc}): {p}") from None
    if t.shape != (3,) or angles.shape != (3,):
        raise InputError(f"pose JSON camera_location and final_camera_rotation must have 3 values each: {p}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(angles))):
        raise InputError(f"pose has non-finite values: {p}")
    R = stanford_rotation(angles)
    if alignment is not None:
        A_b = read_pose_txt(alignment)  # same 3x4 layout and validation
        A, b = A_b
        R, t = R @ A.T, A @ (t - b)
    _check_pose(R, t, p)
    return R, t


def read_pose_file(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A query's known pose ``(R, t)`` from the file format its dataset stores it in: an
    OmniScenes 3x4 ``[R | t]`` ``.txt`` (:func:`read_pose_txt`) or a Stanford 2D-3D-S
    ``*_pose.json`` (:func:`read_stanford_pose`)."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        return read_stanford_pose(p)
    if p.suffix.lower() == ".txt":
        return read_pose_txt(p)
    raise InputError(f"unsupported pose file {p}: use a 3x4 [R | t] .txt (OmniScenes) or a *_pose.json "
                     "(Stanford 2D-3D-S)")


def _as_split_list(split: str | Sequence[str] | None, available: list[str], what: str) -> list[str]:
    if split is None:
        return list(available)
    wanted = [split] if isinstance(split, str) else list(split)
    unknown = [s for s in wanted if s not in available]
    if unknown:
        raise InputError(f"unknown {what} {', '.join(unknown)}; available: {', '.join(available) or 'none'}")
    return wanted


def _find_file(folder: Path, stems: Iterable[str], extensions: Iterable[str]) -> Path | None:
    for stem in stems:
        for ext in extensions:
            candidate = folder / f"{stem}{ext}"
            if candidate.is_file():
                return candidate
    return None


def _line_file_scenes(folder: Path) -> set[str]:
    """Scene names of the 3D line files in ``folder``: ``<scene>lines.txt``, ``<scene>_lines.txt``
    or ``<scene>.txt`` / ``.obj`` (what ``line_file`` looks for)."""
    if not folder.is_dir():
        return set()
    out = set()
    for p in folder.iterdir():
        if p.is_file() and p.suffix.lower() in (".txt", ".obj") and not p.name.startswith("."):
            stem = p.stem
            for suffix in ("_lines", "lines"):
                if stem.endswith(suffix) and len(stem) > len(suffix):
                    stem = stem[: -len(suffix)]
                    break
            out.add(stem)
    return out


def _visible_dirs(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))


def _require_root(root: str | Path, kind: str) -> Path:
    r = Path(root).expanduser()
    what = f"{kind} dataset root" if kind else "dataset root"
    if not r.exists():
        raise InputError(f"{what} not found: {r} (pass --root, see datasets/README.md)")
    if not r.is_dir():
        raise InputError(f"{what} is not a folder: {r}")
    return r


# ----------------------------------------------------------------------------------- OmniScenes


class OmniScenes:
    """Reader for the OmniScenes layout (also written by ``ldlmap synth``)."""

    kind = "omniscenes"

    def __init__(self, root: str | Path) -> None:
        self.root = _require_root(root, "OmniScenes")
        has_pano = any(p.name.endswith("_pano") for p in _visible_dirs(self.root))
        if not has_pano and not (self.root / "pcd").is_dir() and not (self.root / "pcd_line").is_dir():
            raise InputError(f"not an OmniScenes root (no <split>_pano, pcd or pcd_line folder): {self.root}")

    def __repr__(self) -> str:
        return f"OmniScenes({str(self.root)!r})"

    def splits(self) -> list[str]:
        """Split names present (folders ``<split>_pano``): the paper's splits first, then others."""
        names = [p.name[: -len("_pano")] for p in _visible_dirs(self.root) if p.name.endswith("_pano")]
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
            raise InputError(f"unrecognised OmniScenes scene folder (expected <split>_<room>_<n>_scene_<k>): {folder}")
        return m["room"], m["state"]

    def _scene_folders(self, split: str) -> list[tuple[Path, str, str]]:
        pano_dir = self.root / f"{split}_pano"
        return [(d, *self._parse_scene_folder(split, d)) for d in _visible_dirs(pano_dir)]

    def scenes(self) -> list[str]:
        """Scene (point cloud) names: clouds in ``pcd/``, line files in ``pcd_line/`` and rooms
        that have queries."""
        names: set[str] = set()
        pcd = self.root / "pcd"
        if pcd.is_dir():
            names |= {p.stem for p in pcd.iterdir() if p.suffix.lower() in POINT_CLOUD_EXTENSIONS and not p.name.startswith(".")}
        names |= _line_file_scenes(self.root / "pcd_line")
        for split in self.splits():
            names |= {room for _, room, _ in self._scene_folders(split)}
        return sorted(names, key=_natural_key)

    def queries(self, split: str | Sequence[str] | None = None, scene: str | None = None) -> list[Query]:
        """Queries of the given split(s) (all when None), optionally of one scene; sorted by
        split (paper order), scene, capture session and image name."""
        available = self.splits()
        wanted = _as_split_list(split, available, "OmniScenes split")
        if scene is not None and scene not in self.scenes():
            raise InputError(f"unknown OmniScenes scene {scene}; available: {', '.join(self.scenes()) or 'none'}")
        out: list[Query] = []
        for s in sorted(wanted, key=available.index):
            for folder, room, state in sorted(self._scene_folders(s), key=lambda f: (_natural_key(f[1]), _natural_key(f[2]))):
                if scene is not None and room != scene:
                    continue
                images = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS
                                 and not p.name.startswith(".")), key=lambda p: _natural_key(p.stem))
                for img in images:
                    pose_path = self.root / f"{s}_pose" / folder.name / f"{img.stem}.txt"
                    if not pose_path.is_file():
                        raise InputError(f"no pose file for query {img} (expected {pose_path})")
                    R, t = read_pose_txt(pose_path)
                    out.append(Query(image=img, scene=room, split=s, rot_cam_from_world=R, center=t,
                                     name=f"{s}/{room}_{state}/{img.stem}", scene_state=state, pose_file=pose_path))
        return out

    def point_cloud(self, scene: str) -> Path:
        """``pcd/<scene>.ply`` if present, else ``.txt`` (or ``.pcd``)."""
        path = _find_file(self.root / "pcd", [scene], POINT_CLOUD_EXTENSIONS)
        if path is None:
            raise InputError(f"no point cloud for scene {scene} in {self.root / 'pcd'} "
                             f"(looked for {scene}{{{','.join(POINT_CLOUD_EXTENSIONS)}}})")
        return path

    def line_file(self, scene: str) -> Path | None:
        """The distributed 3D line file ``pcd_line/<scene>lines.txt`` (or ``<scene>.txt/.obj``)."""
        return _find_file(self.root / "pcd_line", [f"{scene}lines", f"{scene}_lines", scene], (".txt", ".obj"))

    def mesh_file(self, scene: str) -> Path | None:
        """Textured mesh ``mesh/<scene>.obj`` (or ``.ply``) of a synthetic scene, when present."""
        return _find_file(self.root / "mesh", [scene], (".obj", ".ply"))

    def gt_line_file(self, scene: str) -> Path | None:
        """Ground-truth 3D edges ``gt_lines/<scene>.obj`` (or ``.txt``) of a synthetic scene, when present."""
        return _find_file(self.root / "gt_lines", [scene], (".obj", ".txt"))


# ----------------------------------------------------------------------------- Stanford 2D-3D-S


class Stanford2D3DS:
    """Reader for the Stanford 2D-3D-S panorama layout; splits are areas."""

    kind = "stanford"

    def __init__(self, root: str | Path) -> None:
        self.root = _require_root(root, "Stanford 2D-3D-S")
        if not any((self.root / sub).is_dir() for sub in ("pano", "pcd", "pcd_line")):
            raise InputError(f"not a Stanford 2D-3D-S root (no pano, pcd or pcd_line folder): {self.root}")

    def __repr__(self) -> str:
        return f"Stanford2D3DS({str(self.root)!r})"

    def _areas(self, sub: str) -> list[str]:
        folder = self.root / sub
        if not folder.is_dir():
            return []
        names = [p.name for p in _visible_dirs(folder) if p.name.startswith("area_")]
        known = [a for a in STANFORD_AREAS if a in names]
        return known + sorted(set(names) - set(known), key=_natural_key)

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
            names |= {f"{area}/{n}" for n in _line_file_scenes(self.root / "pcd_line" / area)}
        for area in self.splits():
            names |= {f"{area}/{room}" for _, _, room in self._panos(area)}
        return sorted(names, key=_natural_key)

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
        wanted = _as_split_list(split, available, "Stanford area")
        if scene is not None:
            scene = self._scene_key(scene)
            if scene not in self.scenes():
                raise InputError(f"unknown Stanford scene {scene}")
        out: list[Query] = []
        for area in sorted(wanted, key=available.index):
            for img, cam, room in sorted(self._panos(area), key=lambda x: (_natural_key(x[2]), x[1])):
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
        path = _find_file(self.root / "pcd" / area, [room], POINT_CLOUD_EXTENSIONS)
        if path is None:
            raise InputError(f"no point cloud for scene {key} in {self.root / 'pcd' / area}")
        return path

    def line_file(self, scene: str) -> Path | None:
        """``pcd_line/area_N/<room>_<n>lines.txt`` (or ``<room>_<n>.txt/.obj``) when present."""
        area, room = self._scene_key(scene).split("/", 1)
        return _find_file(self.root / "pcd_line" / area, [f"{room}lines", f"{room}_lines", room], (".txt", ".obj"))


# ------------------------------------------------------------------------------------- ZInD


class ZInD:
    """Reader for Zillow Indoor Dataset homes (``<root>/<home>/zind_data.json``); splits are homes.

    ``root`` is a folder of homes or one home folder (then its name is the only split). Scenes
    are ``<home>/<floor>/<complete_room>`` (``map_level="room"``) or ``<home>/<floor>``
    (``"floor"``). Queries are the panoramas, upright, with poses converted by
    :mod:`ldlmap.io.zind`; their ``scene_state`` is the home.
    """

    kind = "zind"

    def __init__(self, root: str | Path, map_level: str = "room") -> None:
        from ldlmap.io.zind import ZIND_JSON

        if map_level not in MAP_LEVELS:
            raise InputError(f"unknown ZInD map level {map_level!r}; choose one of {', '.join(MAP_LEVELS)}")
        self.root = _require_root(root, "ZInD")
        self.map_level = map_level
        if (self.root / ZIND_JSON).is_file():
            self._folders = {self.root.name: self.root}
        else:
            self._folders = {p.name: p for p in _visible_dirs(self.root) if (p / ZIND_JSON).is_file()}
        if not self._folders:
            raise InputError(f"not a ZInD root (no <home>/{ZIND_JSON}): {self.root}")
        self._homes: dict[str, object] = {}

    def __repr__(self) -> str:
        return f"ZInD({str(self.root)!r}, map_level={self.map_level!r})"

    def _folder(self, home: str) -> Path:
        if home not in self._folders:
            raise InputError(f"unknown ZInD home {home!r}; available: {', '.join(self.splits())}")
        return self._folders[home]

    def home(self, name: str):
        """The parsed :class:`ldlmap.io.zind.ZindHome` of a home (read once)."""
        from ldlmap.io.zind import read_zind_home

        if name not in self._homes:
            self._homes[name] = read_zind_home(self._folder(name))
        return self._homes[name]

    def json_path(self, scene_or_home: str) -> Path:
        """``zind_data.json`` of the home a scene (or home) belongs to."""
        from ldlmap.io.zind import ZIND_JSON

        return self._folder(scene_or_home.split("/", 1)[0]) / ZIND_JSON

    def splits(self) -> list[str]:
        """Home names (``000``, ...)."""
        return sorted(self._folders, key=_natural_key)

    def _scene_of(self, home: str, floor: str, room: str) -> str:
        return f"{home}/{floor}" if self.map_level == "floor" else f"{home}/{floor}/{room}"

    def scenes(self) -> list[str]:
        """Map keys at this level: ``<home>/<floor>/<complete_room>`` or ``<home>/<floor>``."""
        out: list[str] = []
        for name in self.splits():
            keys = {self._scene_of(name, f, r) for f, r in self.home(name).rooms}
            out.extend(sorted(keys, key=_natural_key))
        return out

    def queries(self, split: str | Sequence[str] | None = None, scene: str | None = None) -> list[Query]:
        """Panoramas of the given home(s) (all when None), optionally of one scene; sorted by home,
        floor, partial room and pano. Names are ``<home>/<floor>/<partial_room>/<pano>``."""
        available = self.splits()
        wanted = _as_split_list(split, available, "ZInD home")
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
        from ldlmap.io.zind import scene_layout

        home, floor, rooms = self._parse_scene(scene)
        return scene_layout(self.home(home), floor, rooms)

    def point_cloud(self, scene: str) -> Path:
        raise InputError(f"ZInD has no point clouds: its maps are built from the room layouts "
                         f"(ldlmap prepare --dataset zind), scene {scene}")

    def line_file(self, scene: str) -> Path | None:
        """None: ZInD distributes no 3D line files (lines come from the layouts)."""
        return None


# ------------------------------------------------------------------------------ entry points


def detect_kind(root: str | Path) -> str:
    """Guess the layout of ``root``: ``"zind"`` (``<home>/zind_data.json``, or a home folder),
    ``"stanford"`` (``area_*`` folders in ``pano``, ``pcd`` or ``pcd_line``) or ``"omniscenes"``."""
    from ldlmap.io.zind import ZIND_JSON

    r = _require_root(root, "")
    if (r / ZIND_JSON).is_file() or any((p / ZIND_JSON).is_file() for p in _visible_dirs(r)):
        return "zind"
    for sub in ("pano", "pcd", "pcd_line"):
        if (r / sub).is_dir() and any(p.name.startswith("area_") for p in _visible_dirs(r / sub)):
            return "stanford"
    if any(p.name.endswith("_pano") for p in _visible_dirs(r)) or (r / "pcd").is_dir() or (r / "pcd_line").is_dir():
        return "omniscenes"
    raise InputError(f"no recognisable dataset layout in {r} (expected OmniScenes <split>_pano/, "
                     "Stanford 2D-3D-S pano/area_N/ or ZInD <home>/zind_data.json; see datasets/README.md)")


def open_dataset(root: str | Path | None = None, kind: str | None = "omniscenes", map_level: str = "room") -> Dataset:
    """Open a dataset root of the given kind (``None``: detect it). ``root=None`` uses
    :data:`DEFAULT_ROOTS` for the kind. ``map_level`` (``room`` | ``floor``) picks ZInD's scenes
    (one map per complete room or per floor); other kinds ignore it."""
    if kind is not None and kind not in DATASET_KINDS:
        raise InputError(f"unknown dataset kind {kind!r}; choose one of {', '.join(DATASET_KINDS)}")
    if map_level not in MAP_LEVELS:
        raise InputError(f"unknown map level {map_level!r}; choose one of {', '.join(MAP_LEVELS)}")
    if root is None:
        if kind is None:
            raise InputError("give a dataset root or a dataset kind")
        root = DEFAULT_ROOTS[kind]
    if kind is None:
        kind = detect_kind(root)
    if kind == "zind":
        return ZInD(root, map_level)
    return OmniScenes(root) if kind == "omniscenes" else Stanford2D3DS(root)


# --------------------------------------------------------------------------------- manifests


def manifest_path(kind: str) -> Path:
    """Location of ``datasets/<dir>/splits.toml`` for a dataset kind.

    The manifests live in the repository's top-level ``datasets/`` folder (data, not code). They
    are found beside the package (source checkout / editable install), or under
    ``<sys.prefix>/share/ldl-toolkit/datasets`` where a wheel install puts them.
    """
    if kind not in MANIFEST_DIRS:
        raise InputError(f"unknown dataset kind {kind!r}; choose one of {', '.join(MANIFEST_DIRS)}")
    rel = Path(MANIFEST_DIRS[kind]) / "splits.toml"
    bases = [Path(__file__).resolve().parent.parent / "datasets", Path(sys.prefix) / "share" / "ldl-toolkit" / "datasets"]
    for base in bases:
        if (base / rel).is_file():
            return base / rel
    raise InputError(f"split manifest datasets/{rel.as_posix()} not found (looked in {', '.join(map(str, bases))})")


def load_manifest(kind: str) -> dict:
    """Parsed split manifest of ``"omniscenes"``, ``"stanford"`` or ``"zind"`` (see ``datasets/README.md``)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]

    path = manifest_path(kind)
    try:
        return tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"cannot read split manifest {path}: {exc}") from None
