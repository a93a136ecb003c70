"""A scanner-like colored point cloud of a :class:`~ldlmap.synth.types.SceneMesh`.

Like a terrestrial scanner, a few stations inside the room each shoot rays in uniformly random
directions; every first hit becomes a point. This gives what real scans look like:

* only surfaces visible from some station are scanned (nothing under furniture, behind boxes);
* density falls with distance (``1 / d^2``) and incidence (``cos``), and grazing returns are
  dropped with probability rising as the incidence angle nears 90 degrees;
* Gaussian position noise (``noise_std``, default 5 mm, 0 allowed) and a few small holes.

Colors come from :meth:`Renderer.surface_color` at the exact hit (before noise), i.e. the same
texture look-up and shading as the panoramas. Writers: binary ``.ply`` and OmniScenes ``.txt``
(``x y z r g b`` per row), both atomic.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from ldlmap.errors import InputError, atomic_file
from ldlmap.synth.render import Renderer
from ldlmap.synth.types import SceneMesh


@dataclass(frozen=True)
class ScanParams:
    """Scanner simulation parameters (a :class:`ScanSpec` with the same field names overrides)."""

    num_points: int = 1_500_000  # target number of points (before holes)
    num_stations: int = 4  # scanner positions inside the room
    station_height: float = 1.3  # metres (tripod), +-0.15 m
    station_clearance: float = 0.4  # metres from any surface
    noise_std: float = 0.005  # metres, Gaussian per coordinate
    grazing_cos: float = 0.25  # below this |cos(incidence)| returns are dropped proportionally
    num_holes: int = 6  # small holes (missing returns)
    hole_radius_min: float = 0.04  # metres
    hole_radius_max: float = 0.12


def scan_params(scan_spec: Any = None) -> ScanParams:
    """:class:`ScanParams` with every field that ``scan_spec`` also has taken from it."""
    if scan_spec is None:
        return ScanParams()
    if isinstance(scan_spec, ScanParams):
        return scan_spec
    fields = {k: getattr(scan_spec, k) for k in ScanParams.__dataclass_fields__ if hasattr(scan_spec, k)}
    aliases = {"points": "num_points", "stations": "num_stations", "noise": "noise_std",
               "holes": "num_holes"}
    for alias, name in aliases.items():
        if name not in fields and hasattr(scan_spec, alias):
            fields[name] = getattr(scan_spec, alias)
    return ScanParams(**fields)


def _sphere_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sample_scan(mesh: SceneMesh, scan_spec: Any = None, rng: np.random.Generator | None = None,
                renderer: Renderer | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Simulated scan: ``points`` (N, 3) float64 and ``colors`` (N, 3) uint8."""
    from ldlmap.synth.poses import sample_positions

    p = scan_params(scan_spec)
    if p.num_points <= 0 or p.num_stations <= 0:
        raise InputError("scan needs num_points > 0 and num_stations > 0")
    if p.noise_std < 0:
        raise InputError(f"scan noise_std must be >= 0, got {p.noise_std}")
    rng = rng if rng is not None else np.random.default_rng(0)
    renderer = renderer or Renderer(mesh)
    stations = sample_positions(mesh, p.num_stations, rng, p.station_height - 0.15, p.station_height + 0.15,
                                p.station_clearance, renderer=renderer)
    # Expected keep rate of the grazing dropout is ~0.9; shoot a few more rays than points.
    per_station = int(np.ceil(p.num_points / p.num_stations / 0.9))
    origins = np.repeat(stations, per_station, axis=0)
    dirs = _sphere_directions(len(origins), rng)
    hits = renderer.cast(origins, dirs)
    ok = hits["tri"] >= 0
    origins, dirs, t, tri, bary = origins[ok], dirs[ok], hits["t"][ok], hits["tri"][ok], hits["bary"][ok]
    cos = np.abs(np.einsum("nc,nc->n", dirs, renderer.face_normals[tri]))
    keep = rng.random(len(cos)) < np.clip(cos / p.grazing_cos, 0.0, 1.0)
    if np.count_nonzero(keep) > p.num_points:
        idx = np.flatnonzero(keep)
        keep[:] = False
        keep[rng.choice(idx, p.num_points, replace=False)] = True
    points = origins[keep] + dirs[keep] * t[keep, None]
    colors = renderer.surface_color(tri[keep], bary[keep], points)
    if p.num_holes > 0 and len(points):
        centres = points[rng.choice(len(points), p.num_holes, replace=False)]
        radii = rng.uniform(p.hole_radius_min, p.hole_radius_max, p.num_holes)
        alive = np.ones(len(points), dtype=bool)
        for c, r in zip(centres, radii):
            alive &= np.einsum("nc,nc->n", points - c, points - c) > r * r
        points, colors = points[alive], colors[alive]
    if p.noise_std > 0:
        points = points + rng.normal(0.0, p.noise_std, size=points.shape)
    return points, np.clip(np.rint(colors), 0, 255).astype(np.uint8)


def _check_cloud(points: np.ndarray, colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(points, dtype=np.float64)
    colors = np.asarray(colors)
    if points.ndim != 2 or points.shape[1] != 3 or colors.shape != points.shape:
        raise InputError(f"point cloud needs points (N, 3) and colors (N, 3), got {points.shape} and {colors.shape}")
    if not np.all(np.isfinite(points)):
        raise InputError("point cloud contains NaN or infinite coordinates")
    return points, np.clip(colors, 0, 255).astype(np.uint8)


def write_ply(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray) -> None:
    """Binary little-endian PLY with ``double x, y, z`` and ``uchar red, green, blue`` (atomic)."""
    points, colors = _check_cloud(points, colors)
    rec = np.empty(len(points), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                       ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    rec["red"], rec["green"], rec["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(points)}\n"
              "property double x\nproperty double y\nproperty double z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    with atomic_file(path) as tmp, open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(rec.tobytes())


def write_txt(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray) -> None:
    """OmniScenes point cloud text: one ``x y z r g b`` row per point (mm-precise, 0-255 ints)."""
    points, colors = _check_cloud(points, colors)
    table = np.hstack([points, colors.astype(np.float64)])
    with atomic_file(path) as tmp:
        np.savetxt(tmp, table, fmt="%.6f %.6f %.6f %d %d %d")
