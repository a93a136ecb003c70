"""Equirectangular panoramas of a :class:`~ldlmap.synth.types.SceneMesh`, ray-cast with open3d.

One ray per pixel centre (``geometry.pixel_centers`` -> ``bearing_from_pixel``), rotated into
the world with ``R^T`` (``geometry.world_from_cam``), is cast against an open3d
``RaycastingScene`` that :class:`Renderer` builds once per mesh. The color of a hit is the
bilinear look-up of the texture atlas at the barycentrically interpolated texture coordinate,
times a view-independent shading (:class:`Shading`: ambient plus two-sided Lambert from a few
fixed ceiling lights). The scan (:mod:`ldlmap.synth.scan`) uses the same
:meth:`Renderer.surface_color`, so photos and scan agree on every surface.

open3d returns ``primitive_uvs = (u, v)``, the barycentric weights of the triangle's 2nd and 3rd
corner: a hit lies at ``(1 - u - v) A + u B + v C`` (checked in ``tests/test_synth_render.py``).

Photometric post-processing for the query splits: :func:`motion_blur` (a linear blur along one
image direction: the average of shifted copies, centred on the pixel so that the ground-truth
pose stays the pose of the blur's midpoint), :func:`apply_illumination` (the paper's variants:
intensity x0.75, gamma 0.2, white balance ``diag(0.7, 0.9, 0.8)``), and mild seeded sensor noise
(:func:`add_noise`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from ldlmap.core.geometry import bearing_from_pixel, normalize, pixel_centers
from ldlmap.core.lazy import lazy_module
from ldlmap.core.polygon import points_in_polygon
from ldlmap.synth.types import SceneMesh

o3d = lazy_module("open3d")

IlluminationKind = Literal["intensity", "gamma", "white_balance"]

# The paper's synthetic color variations (supplementary, "Illumination Robustness Evaluation").
INTENSITY_FACTOR = 0.75  # "lower each pixel intensity by 25 %"
GAMMA = 0.2  # "set the image gamma to 0.2": out = 255 (in / 255) ** 0.2
WHITE_BALANCE = (0.7, 0.9, 0.8)  # diag(...) applied to RGB


@dataclass(frozen=True)
class Shading:
    """View-independent shading: ``ambient + diffuse * mean_l(|n . l| / (1 + (d_l / falloff)^2))``.

    Lights hang ``light_drop`` metres below the ceiling at up to ``max_lights`` well-spread
    positions inside the footprint. Lambert is two-sided (``|n . l|``) because the mesh does not
    promise outward normals for every surface.
    """

    ambient: float = 0.45  # share of light that reaches every surface
    diffuse: float = 0.75  # weight of the ceiling lights
    light_drop: float = 0.3  # metres below the ceiling
    falloff: float = 4.0  # metres at which a light's intensity halves
    max_lights: int = 4
    light_spacing: float = 0.25  # grid step (metres) of candidate light positions


@dataclass
class Panorama:
    """A rendered equirectangular image with its per-pixel ground truth (pixel-centre rays)."""

    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 ray length in metres, inf where no surface was hit
    tri_id: np.ndarray  # (H, W) int32 triangle index, -1 where no surface was hit


def light_positions(mesh: SceneMesh, shading: Shading = Shading()) -> np.ndarray:
    """Deterministic ceiling-light positions (L, 3): farthest-point spread inside the footprint."""
    fp = np.asarray(mesh.footprint, dtype=np.float64)
    lo, hi = fp.min(axis=0), fp.max(axis=0)
    step = shading.light_spacing
    gx = np.arange(lo[0] + step / 2, hi[0], step)
    gy = np.arange(lo[1] + step / 2, hi[1], step)
    grid = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    grid = grid[points_in_polygon(grid, fp)] if len(grid) else grid
    if len(grid) == 0:
        grid = fp.mean(axis=0, keepdims=True)
    # Start near the centroid, then keep adding the grid point farthest from the chosen ones,
    # but not onto the walls: prefer points at least half the spread from the boundary.
    chosen = [int(np.argmin(np.linalg.norm(grid - grid.mean(axis=0), axis=1)))]
    dist = np.linalg.norm(grid - grid[chosen[0]], axis=1)
    edge_d = _distance_to_polygon_edges(grid, fp)
    for _ in range(shading.max_lights - 1):
        score = np.minimum(dist, 2.0 * edge_d)
        k = int(np.argmax(score))
        if score[k] < 1.0:  # room too small for another light
            break
        chosen.append(k)
        dist = np.minimum(dist, np.linalg.norm(grid - grid[k], axis=1))
    z = np.full((len(chosen), 1), float(mesh.ceiling_height) - shading.light_drop)
    return np.hstack([grid[chosen], z])


def _distance_to_polygon_edges(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    a = polygon[None, :, :]
    b = np.roll(polygon, -1, axis=0)[None, :, :]
    p = points[:, None, :]
    ab = b - a
    s = np.clip(np.sum((p - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-12), 0.0, 1.0)
    return np.min(np.linalg.norm(p - (a + s[..., None] * ab), axis=-1), axis=1)


def bilinear_lookup(image: np.ndarray, st: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, C) float32 of ``image`` (H, W, C) at OBJ texture coords ``st`` (N, 2).

    ``s`` runs right, ``t`` runs up; texel centres sit at ``((i + 0.5) / W, 1 - (j + 0.5) / H)``.
    Coordinates outside [0, 1] are clamped to the border.
    """
    h, w = image.shape[:2]
    x = np.clip(st[:, 0] * w - 0.5, 0.0, w - 1.0)
    y = np.clip((1.0 - st[:, 1]) * h - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0).astype(np.float32)[:, None], (y - y0).astype(np.float32)[:, None]
    # Corners gathered by flat index (np.take: ~5x faster than 2-D fancy indexing), then converted.
    flat = np.asarray(image).reshape(h * w, -1)

    def corner(r: np.ndarray, c: np.ndarray) -> np.ndarray:
        return np.take(flat, r * w + c, axis=0).astype(np.float32)

    top = corner(y0, x0) * (1 - fx) + corner(y0, x1) * fx
    bot = corner(y1, x0) * (1 - fx) + corner(y1, x1) * fx
    return top * (1 - fy) + bot * fy


class Renderer:
    """Ray caster for one mesh: build the open3d scene once, render many panoramas."""

    def __init__(self, mesh: SceneMesh, shading: Shading = Shading()) -> None:
        self.mesh = mesh
        self.shading = shading
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        tris = np.asarray(mesh.triangles, dtype=np.int64)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)),
                                  o3d.core.Tensor(tris.astype(np.uint32)))
        a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
        self.face_normals = normalize(np.cross(b - a, c - a))
        self.lights = light_positions(mesh, shading)

    # ------------------------------------------------------------------------------ ray casts

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
        """First hits of rays (N, 3) + (N, 3): ``t`` (N,) in units of ``|d|``, ``tri`` (N,) int32
        (-1 for none) and ``bary`` (N, 2) open3d barycentrics of the 2nd and 3rd corner."""
        o = np.broadcast_to(np.asarray(origins, dtype=np.float32), directions.shape)
        rays = np.ascontiguousarray(np.concatenate([o, np.asarray(directions, np.float32)], axis=-1))
        ans = self._scene.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6)))
        t = ans["t_hit"].numpy().astype(np.float64)
        tri = ans["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        tri = np.where(hit, tri, -1).astype(np.int32)
        return {"t": t, "tri": tri, "bary": ans["primitive_uvs"].numpy().astype(np.float64)}

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (N,) from each point (N, 3) to the nearest mesh surface."""
        q = o3d.core.Tensor(np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3)))
        return self._scene.compute_distance(q).numpy().astype(np.float64)

    # -------------------------------------------------------------------------------- colors

    def shade(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Shading factor (N,) of surface points with unit normals (see :class:`Shading`)."""
        s = self.shading
        pts = np.asarray(points, dtype=np.float32)
        nrm = np.asarray(normals, dtype=np.float32)
        lambert = np.zeros(len(pts), dtype=np.float32)
        for light in self.lights.astype(np.float32):
            to_light = light - pts
            d2 = np.einsum("nc,nc->n", to_light, to_light)
            cos = np.abs(np.einsum("nc,nc->n", to_light, nrm)) / np.sqrt(np.maximum(d2, 1e-12))
            lambert += cos / (1.0 + d2 / np.float32(s.falloff ** 2))
        return s.ambient + s.diffuse * lambert / np.float32(len(self.lights))

    def surface_color(self, tri: np.ndarray, bary: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Shaded color (N, 3) float32 in [0, 255] of points on triangles ``tri`` (all valid)."""
        tri = np.asarray(tri, dtype=np.int64)
        uvs = np.asarray(self.mesh.tri_uvs, dtype=np.float64)[tri]  # (N, 3, 2)
        w = np.stack([1.0 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], axis=1)
        st = np.einsum("nk,nkc->nc", w, uvs)
        albedo = bilinear_lookup(self.mesh.atlas, st)
        factor = self.shade(points, self.face_normals[tri]).astype(np.float32)
        return np.clip(albedo * factor[:, None], 0.0, 255.0)

    def _colors_of_rays(self, center: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, dict]:
        hits = self.cast(center, dirs)
        ok = hits["tri"] >= 0
        if ok.all():  # a closed room: every ray hits, no masked copies
            pts = center + dirs * hits["t"][:, None]
            return self.surface_color(hits["tri"], hits["bary"], pts), hits
        colors = np.zeros((len(dirs), 3), dtype=np.float32)
        if np.any(ok):
            pts = center + dirs[ok] * hits["t"][ok, None]
            colors[ok] = self.surface_color(hits["tri"][ok], hits["bary"][ok], pts)
        return colors, hits

    # ----------------------------------------------------------------------------- panoramas

    def render_float(self, rot_cam_from_world: np.ndarray, center: np.ndarray, width: int, height: int,
                     supersample: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Linear float RGB (H, W, 3) in [0, 255], depth (H, W) and triangle ids (H, W).

        Depth and triangle ids belong to the pixel-centre ray; with ``supersample = s > 1`` the
        color is the mean of ``s x s`` sub-rays on a regular grid centred on the pixel centre.
        """
        return render_float_through([(self, np.zeros(3))], rot_cam_from_world, center, width, height, supersample)

    def render(self, rot_cam_from_world: np.ndarray, center: np.ndarray, width: int = 1024,
               height: int | None = None, supersample: int = 2, blur_px: float = 0.0,
               blur_angle: float = 0.0, noise_sigma: float = 0.0,
               rng: np.random.Generator | None = None) -> Panorama:
        """Render a panorama at pose ``(R, t)``: optional motion blur and seeded sensor noise."""
        return render_through([(self, np.zeros(3))], rot_cam_from_world, center, width, height, supersample, blur_px,
                              blur_angle, noise_sigma, rng)


@lru_cache(maxsize=8)
def _pixel_bearings(width: int, height: int, du: float, dv: float) -> np.ndarray:
    """Camera-frame bearings (H W, 3) of the pixel centres shifted by ``(du, dv)`` pixels: the
    same for every panorama of a size, so made once (read only)."""
    uv = pixel_centers(width, height).reshape(-1, 2)
    if du or dv:
        uv = uv + np.array([du, dv])
    out = bearing_from_pixel(uv, width, height)
    out.flags.writeable = False
    return out


# -------------------------------------------------------------------------- post-processing


def to_uint8(img: np.ndarray) -> np.ndarray:
    """Round and clip a float image to uint8."""
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def motion_blur(img: np.ndarray, length_px: float, angle_rad: float) -> np.ndarray:
    """Linear motion blur: the mean of copies shifted along ``(cos a, sin a)`` over
    ``[-length/2, length/2]`` pixels (centred, so the sharp pose is the blur's midpoint).

    Shifts wrap around horizontally (the panorama is periodic in ``u``) and clamp at the poles.
    """
    img = np.asarray(img, dtype=np.float32)
    h, w = img.shape[:2]
    taps = max(2, int(np.ceil(length_px)) + 1)
    steps = np.linspace(-length_px / 2.0, length_px / 2.0, taps)
    cols, rows = np.arange(w), np.arange(h)
    out = np.zeros_like(img)
    for s in steps:
        du, dv = s * np.cos(angle_rad), s * np.sin(angle_rad)
        # Bilinear in u (wrapping), nearest in v (clamped): cheap and artefact-free for blur.
        u0 = int(np.floor(du))
        fu = du - u0
        src_r = np.clip(rows + int(np.rint(dv)), 0, h - 1)
        a = img[src_r][:, np.mod(cols + u0, w)]
        b = img[src_r][:, np.mod(cols + u0 + 1, w)]
        out += (1.0 - fu) * a + fu * b
    return out / float(len(steps))


def add_noise(img: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Add Gaussian sensor noise of standard deviation ``sigma`` (intensity levels)."""
    return np.asarray(img, dtype=np.float32) + rng.normal(0.0, sigma, size=img.shape).astype(np.float32)


def apply_illumination(img: np.ndarray, kind: IlluminationKind, intensity: float = INTENSITY_FACTOR,
                       gamma: float = GAMMA, white_balance: tuple[float, float, float] = WHITE_BALANCE) -> np.ndarray:
    """The paper's color variations of a uint8 RGB image: ``intensity`` (``in * 0.75``),
    ``gamma`` (``255 (in / 255) ** 0.2``, literally) or ``white_balance`` (``diag(0.7, 0.9, 0.8)``)."""
    x = np.asarray(img, dtype=np.float64)
    if kind == "intensity":
        out = x * intensity
    elif kind == "gamma":
        out = 255.0 * (x / 255.0) ** gamma
    elif kind == "white_balance":
        out = x * np.asarray(white_balance, dtype=np.float64)
    else:
        raise ValueError(f"unknown illumination variant {kind!r}; valid: intensity, gamma, white_balance")
    return to_uint8(out)


def _cast_through(parts: list[tuple[Renderer, np.ndarray]], center: np.ndarray, dirs: np.ndarray,
                  colors: bool = True) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """Rays from world point ``center`` through several rooms (``parts``: each renderer with the world
    position of its mesh's origin): the first room's hits, and where a ray leaves it (an open door)
    the nearest hit in the others. Returns colours (None unless ``colors``), depth and the first
    room's triangle ids (-1 where the ray left it)."""
    first, off = parts[0]
    c = center - off
    if colors:
        col, hits = first._colors_of_rays(c, dirs)
    else:
        col, hits = None, first.cast(c, dirs)
    t, tri = hits["t"].copy(), hits["tri"].copy()
    out = np.flatnonzero(~np.isfinite(t))
    for rend, off in parts[1:]:
        if not len(out):
            break
        c = center - off
        h = rend.cast(c, dirs[out])
        k = np.flatnonzero(h["t"] < t[out])
        if len(k) and colors:
            col[out[k]] = rend.surface_color(h["tri"][k], h["bary"][k], c + dirs[out[k]] * h["t"][k, None])
        t[out[k]] = h["t"][k]
    return col, t, tri


def render_float_through(parts: list[tuple[Renderer, np.ndarray]], rot_cam_from_world: np.ndarray,
                         center: np.ndarray, width: int, height: int,
                         supersample: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`Renderer.render_float` from world point ``center`` in the first of ``parts`` (renderers
    with the world positions of their meshes' origins), seeing the others through its open doors
    (:func:`_cast_through`)."""
    R = np.asarray(rot_cam_from_world, dtype=np.float64)
    c = np.asarray(center, dtype=np.float64).reshape(3)
    parts = [(r, np.asarray(off, dtype=np.float64).reshape(3)) for r, off in parts]
    dirs = _pixel_bearings(width, height, 0.0, 0.0) @ R  # world_from_cam without the offset
    colors, t, tri = _cast_through(parts, c, dirs, colors=supersample <= 1)
    if supersample > 1:
        offs = (np.arange(supersample) + 0.5) / supersample - 0.5
        colors = np.zeros((len(dirs), 3), dtype=np.float32)
        for du in offs:
            for dv in offs:
                colors += _cast_through(parts, c, _pixel_bearings(width, height, float(du), float(dv)) @ R)[0]
        colors /= float(supersample * supersample)
    return colors.reshape(height, width, 3), t.astype(np.float32).reshape(height, width), tri.reshape(height, width)


def render_through(parts: list[tuple[Renderer, np.ndarray]], rot_cam_from_world: np.ndarray, center: np.ndarray,
                   width: int = 1024, height: int | None = None, supersample: int = 2, blur_px: float = 0.0,
                   blur_angle: float = 0.0, noise_sigma: float = 0.0,
                   rng: np.random.Generator | None = None) -> Panorama:
    """:meth:`Renderer.render` from world point ``center`` in the first of ``parts`` (renderers with
    the world positions of their meshes' origins), seeing the others through its open doors."""
    height = int(height) if height else int(width) // 2
    img, depth, tri = render_float_through(parts, rot_cam_from_world, center, int(width), height, supersample)
    if blur_px > 0:
        img = motion_blur(img, blur_px, blur_angle)
    if noise_sigma > 0:
        img = add_noise(img, noise_sigma, rng if rng is not None else np.random.default_rng(0))
    return Panorama(to_uint8(img), depth, tri)
