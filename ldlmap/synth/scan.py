"""A scanner-like colored point cloud of a :class:`~ldlmap.synth.types.SceneMesh`.

Like a terrestrial scanner, a few stations inside the room each shoot rays in uniformly random
directions; every first hit becomes a point. This gives what real scans look like:

* only surfaces visible from some station are scanned (nothing under furniture, behind boxes);
* density falls with distance (``1 / d^2``) and incidence (``cos``), grazing returns are
  dropped with probability rising as the incidence angle nears 90 degrees, and a smooth random
  field (``uneven``) modulates it further; the count is ``density x mesh area`` (capped);
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

from ldlmap.core.errors import InputError, atomic_file
from ldlmap.synth.poses import sample_positions
from ldlmap.synth.render import Renderer
from ldlmap.synth.types import SceneMesh


@dataclass(frozen=True)
class ScanParams:
    """Scanner simulation parameters; the first fields mirror :class:`~ldlmap.synth.spec.ScanSpec`."""

    noise_std: float = 0.005  # metres, Gaussian position noise per axis (0 = exact)
    density: float = 2000.0  # mean points per m^2 of mesh surface
    max_points: int = 1_000_000  # cap on the point count
    uneven: float = 0.5  # 0..1, amplitude of smooth density variations on top of the 1/d^2 falloff
    holes: int = 6  # small circular holes (missing data)
    hole_radius: float = 0.15  # metres, largest hole radius (radii uniform in [r/2, r])
    stations: int = 2  # scanner positions inside the room
    station_height: float = 1.3  # metres (tripod), +-0.15 m
    station_clearance: float = 0.4  # metres from any surface
    grazing_cos: float = 0.25  # below this |cos(incidence)| returns are dropped proportionally


def scan_params(scan_spec: Any = None) -> ScanParams:
    """:class:`ScanParams` with every field that ``scan_spec`` also has taken from it."""
    if scan_spec is None:
        return ScanParams()
    if isinstance(scan_spec, ScanParams):
        return scan_spec
    fields = {k: getattr(scan_spec, k) for k in ScanParams.__dataclass_fields__ if hasattr(scan_spec, k)}
    return ScanParams(**fields)


def mesh_area(mesh: SceneMesh) -> float:
    """Total triangle area of ``mesh`` in m^2."""
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.triangles, dtype=np.int64)]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


def _smooth_field(points: np.ndarray, rng: np.random.Generator, wavelength: float = 1.5) -> np.ndarray:
    """A smooth random field in [0, 1]: the mean of three random plane waves."""
    k = rng.normal(size=(3, 3))
    k *= (2.0 * np.pi / wavelength) / np.linalg.norm(k, axis=1, keepdims=True)
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    return 0.5 + 0.5 * np.mean(np.cos(points @ k.T + phase), axis=1)


def _sphere_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sample_scan(mesh: SceneMesh, scan_spec: Any = None, rng: np.random.Generator | None = None,
                renderer: Renderer | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Simulated scan: ``points`` (N, 3) float64 and ``colors`` (N, 3) uint8."""
    p = scan_params(scan_spec)
    if p.density <= 0 or p.max_points <= 0 or p.stations <= 0:
        raise InputError("scan needs density > 0, max_points > 0 and stations > 0")
    if p.noise_std < 0 or not 0 <= p.uneven <= 1 or p.holes < 0 or p.hole_radius < 0:
        raise InputError("scan needs noise_std >= 0, 0 <= uneven <= 1, holes >= 0 and hole_radius >= 0")
    rng = rng if rng is not None else np.random.default_rng(0)
    renderer = renderer or Renderer(mesh)
    target = int(min(p.max_points, round(p.density * mesh_area(mesh))))
    stations = sample_positions(mesh, p.stations, rng, p.station_height - 0.15, p.station_height + 0.15,
                                p.station_clearance, renderer=renderer)
    # The dropouts keep about (1 - uneven / 2) * 0.9 of the returns: shoot enough rays.
    per_station = int(np.ceil(target / p.stations / (0.9 * (1.0 - 0.5 * p.uneven))))
    origins = np.repeat(stations, per_station, axis=0)
    dirs = _sphere_directions(len(origins), rng)
    hits = renderer.cast(origins, dirs)
    ok = hits["tri"] >= 0
    origins, dirs, t, tri, bary = origins[ok], dirs[ok], hits["t"][ok], hits["tri"][ok], hits["bary"][ok]
    points = origins + dirs * t[:, None]
    cos = np.abs(np.einsum("nc,nc->n", dirs, renderer.face_normals[tri]))
    keep_prob = np.clip(cos / p.grazing_cos, 0.0, 1.0) * (1.0 - p.uneven * _smooth_field(points, rng))
    keep = rng.random(len(cos)) < keep_prob
    if np.count_nonzero(keep) > target:
        idx = np.flatnonzero(keep)
        keep[:] = False
        keep[np.sort(rng.choice(idx, target, replace=False))] = True
    points = points[keep]
    colors = renderer.surface_color(tri[keep], bary[keep], points)
    if p.holes > 0 and len(points):
        holes = min(p.holes, len(points))  # a tiny scan cannot have more holes than points
        centres = points[rng.choice(len(points), holes, replace=False)]
        radii = rng.uniform(0.5 * p.hole_radius, p.hole_radius, holes)
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
