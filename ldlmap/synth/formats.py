"""One synthetic room written in the formats scanners, phones and architects hand over: ``.ply``,
``.e57`` (stations with poses, their panoramas embedded), ``.las`` / ``.laz`` (UTM-sized
coordinates), ``.glb`` (y-up textured mesh) and ``.ifc`` (BIM), for tests and ``bench/bench_inputs.py``.

:func:`room_capture` simulates the scan of a scene spec once; :func:`write_room` writes it in one
format. Every format holds the same surfaces: the scan's points (ply, e57, las, laz), the mesh
(glb) or the spec's walls, slabs and openings (ifc).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import rotation_from_axis_angle
from ldlmap.io.cloud import PointCloud
from ldlmap.io.e57 import ImageToWrite, StationToWrite, write_e57
from ldlmap.io.gltf import write_glb
from ldlmap.io.imagefile import encode_image
from ldlmap.io.las import write_las
from ldlmap.io.pointcloud import write_point_cloud
from ldlmap.synth.ifc import StoreyToWrite, write_ifc
from ldlmap.synth.poses import sample_positions
from ldlmap.synth.render import Renderer
from ldlmap.synth.scan import sample_scan
from ldlmap.synth.scene import build_scene

ROOM_FORMATS: tuple[str, ...] = ("ply", "e57", "las", "laz", "glb", "ifc")
UTM_OFFSET = np.array([500_000.0, 4_300_000.0, 120.0])  # metres: LAS files carry the scan at UTM-sized coordinates


@dataclass
class RoomCapture:
    """A room's spec, mesh, simulated scan and the scanner stations' panoramas."""

    spec: object  # SceneSpec
    mesh: object  # SceneMesh
    points: np.ndarray  # (N, 3) world
    colors: np.ndarray  # (N, 3) uint8
    station_centers: np.ndarray  # (S, 3)
    station_rots: np.ndarray  # (S, 3, 3) world -> camera of each station's panorama
    panoramas: list  # (H, W, 3) uint8 per station


def room_capture(spec, density: float = 3000.0, stations: int = 2, pano_width: int = 512, seed: int = 0) -> RoomCapture:
    """The scan of ``spec`` (``density`` points per m^2, noise 5 mm) and ``stations`` panoramas
    rendered at scanner positions with random headings."""

    mesh = build_scene(spec)
    render = Renderer(mesh)
    rng = np.random.default_rng(seed)
    scan = replace(spec.scan, density=float(density), holes=0, stations=max(2, stations))
    points, colors = sample_scan(mesh, scan, rng, renderer=render)
    centers = sample_positions(mesh, stations, rng, 1.2, 1.5, 0.5, renderer=render)
    rots = np.array([rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), a)
                     for a in rng.uniform(0, 2 * np.pi, stations)])
    panos = [render.render(R, c, pano_width).rgb for R, c in zip(rots, centers)]
    return RoomCapture(spec, mesh, points, colors, centers, rots, panos)


def _jpeg(rgb: np.ndarray) -> bytes:
    """An RGB panorama as JPEG file bytes (quality 95)."""
    try:
        return encode_image(rgb[..., ::-1], ".jpg", quality=95)
    except ValueError:
        raise InputError("cannot encode a panorama as JPEG") from None


def write_e57_room(path: str | os.PathLike, cap: RoomCapture, spherical_second: bool = True,
                   intensity_second: bool = False, pinhole: bool = True) -> Path:
    """The scan split among the stations (each point to its nearest station), stored in each
    station's own frame with its pose (the second station spherical when ``spherical_second``, its
    colour given as intensity when ``intensity_second``), the panoramas as spherical images, and a
    pinhole image (``pinhole``) that readers must skip."""

    owner = np.argmin(np.linalg.norm(cap.points[:, None] - cap.station_centers[None], axis=2), axis=1)
    stations = []
    for s, (c, R) in enumerate(zip(cap.station_centers, cap.station_rots)):
        sel = owner == s
        local = (cap.points[sel] - c) @ R.T  # the station frame is the panorama's camera frame
        second = s == 1
        grey = cap.colors[sel].mean(axis=1)
        stations.append(StationToWrite(local, R.T, c, colors=None if second and intensity_second else cap.colors[sel],
                                       intensity=grey / 255.0 if second and intensity_second else None,
                                       spherical=second and spherical_second, name=f"station{s}"))
    images = [ImageToWrite(f"station{s}", R, c, _jpeg(p), p.shape[1], p.shape[0])
              for s, (R, c, p) in enumerate(zip(cap.station_rots, cap.station_centers, cap.panoramas))]
    if pinhole:
        images.append(ImageToWrite("photo0", cap.station_rots[0], cap.station_centers[0],
                                   _jpeg(cap.panoramas[0][:, : cap.panoramas[0].shape[1] // 2]),
                                   cap.panoramas[0].shape[1] // 2, cap.panoramas[0].shape[0], kind="pinhole"))
    return write_e57(path, stations, images)


def write_room(fmt: str, path: str | os.PathLike, cap: RoomCapture, units: str = "metre") -> Path:
    """Write ``cap`` as ``fmt`` (one of :data:`ROOM_FORMATS`) at ``path``."""

    if fmt == "ply":

        return write_point_cloud(path, PointCloud(cap.points, cap.colors))
    if fmt == "e57":
        return write_e57_room(path, cap)
    if fmt in ("las", "laz"):

        return write_las(path, PointCloud(cap.points + UTM_OFFSET, cap.colors))
    if fmt == "glb":

        m = cap.mesh
        return write_glb(path, m.vertices, m.triangles, m.tri_uvs, m.atlas)
    if fmt == "ifc":

        return write_ifc(path, [StoreyToWrite("ground floor", 0.0, [cap.spec])], units=units)
    raise InputError(f"unknown room format {fmt!r}; choose one of {', '.join(ROOM_FORMATS)}")
