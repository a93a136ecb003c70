"""Z-buffered point splatting of colored point clouds into equirectangular panoramas.

The map's synthetic views (paper sec. 3.1) are rendered here. Projection follows
:mod:`ldlmap.core.geometry` exactly (``p_cam = R (X - t)``, ``u / W = 1 - (atan2(y, x) + pi) / 2 pi``,
``v / H = atan2(hypot(x, y), z) / pi``, integer grid lines are pixel corners), but runs in torch
so that the same code renders on CPU or CUDA.

Algorithm (all vectorized):

1. project every point; a point lands in pixel ``(floor(v), floor(u) mod W)``;
2. give it a square footprint sized to the angle its surface patch subtends, ``spacing / range``
   radians, widened in ``u`` by ``1 / sin(theta)`` (equirectangular stretch towards the poles),
   so that near surfaces are closed and do not let the background show through; footprints wrap
   around in ``u`` and are clipped at the poles;
3. resolve visibility with one ``scatter_reduce(amin)`` over a packed 64-bit key
   ``(float32 range bits << 32) | point index`` (non-negative float32 bit patterns sort like the
   floats), which gives both the nearest range and the winning point per pixel;
4. soft z-buffer (``depth_tolerance``): among the candidates of a pixel within a few percent of
   its nearest range (the same surface), keep the one projecting closest to the pixel centre,
   so colors stay sharp and the 3D point lies near the pixel's ray;
5. fill remaining small holes: an empty pixel takes the nearest of its 3x3 neighbours,
   repeated ``fill_iterations`` times, so that SIFT does not fire on speckle.

Outputs: an RGB image, a world-coordinate image (the 3D point seen at each pixel; NaN where
empty) and a range image (Euclidean distance from the camera centre; NaN where empty).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module

torch = lazy_module("torch")
spatial = lazy_module("scipy.spatial")

_EMPTY_KEY = (1 << 63) - 1  # int64 max: "no point" in the z-buffer


@dataclass(frozen=True)
class RenderParams:
    """Options of the point splatting renderer (the paper renders at 1024 x 512 like its queries)."""

    width: int = 1024  # panorama width W (= 2 H)
    height: int = 512  # panorama height H
    point_spacing_m: float | None = None  # surface sample spacing; None: estimated from the cloud
    local_spacing: bool = True  # size footprints by the local density (when the spacing is estimated)
    splat_scale: float = 2.0  # footprint width / projected spacing (> 1 closes random-sampling gaps)
    point_radius_px: int = 0  # minimum footprint half-width in pixels (0: one pixel)
    max_radius_px: int = 6  # cap on the footprint half-width in v (u: twice that)
    fill_iterations: int = 2  # 3x3 nearest-neighbour hole-filling passes
    depth_tolerance: float = 0.05  # soft z-buffer: relative range band treated as one surface (0: off)
    min_range_m: float = 1e-3  # points closer than this to the centre are ignored
    background: int = 0  # gray level of empty pixels in the RGB image


@dataclass(frozen=True)
class RenderedView:
    """One rendered panorama (see :func:`render_points_panorama`)."""

    rgb: np.ndarray  # (H, W, 3) uint8
    xyz: np.ndarray  # (H, W, 3) float32 world coordinates, NaN where empty
    depth: np.ndarray  # (H, W) float32 range from the centre in metres, NaN where empty
    center: np.ndarray  # (3,) float64 camera centre t
    rot_cam_from_world: np.ndarray  # (3, 3) float64 R


# ------------------------------------------------------------------------------------ inputs


def _check_cloud(points: np.ndarray, colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(points)
    colors = np.asarray(colors)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {points.shape}")
    if len(points) == 0:
        raise InputError("cannot render an empty point cloud")
    if colors.shape != points.shape:
        raise InputError(f"colors must have shape {points.shape} like the points, got {colors.shape}")
    if not np.isfinite(points).all():
        raise InputError("point cloud contains NaN or infinite coordinates")
    if colors.dtype != np.uint8:
        if np.issubdtype(colors.dtype, np.floating) and colors.size and colors.max() <= 1.0:
            colors = colors * 255.0
        colors = np.clip(np.round(colors), 0, 255).astype(np.uint8)
    return points, colors


def _check_pose(rot_cam_from_world: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R = np.asarray(rot_cam_from_world, dtype=np.float64)
    t = np.asarray(center, dtype=np.float64).reshape(-1)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise InputError(f"rotation must be a finite 3x3 matrix, got shape {R.shape}")
    if t.shape != (3,) or not np.isfinite(t).all():
        raise InputError(f"camera centre must be 3 finite numbers, got {np.asarray(center).tolist()}")
    return R, t


def estimate_point_spacing(points: np.ndarray, sample: int = 20000, seed: int = 0) -> float:
    """Mean spacing ``1 / sqrt(surface density)`` of a scan's samples, in metres.

    Computed on a random subsample of ``s`` points (nearest-neighbour median) and scaled by
    ``sqrt(s / N)``: on a 2D surface the spacing grows with ``1 / sqrt(density)``.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n < 2:
        return 0.01
    s = min(n, sample)
    sub = pts[np.random.default_rng(seed).choice(n, s, replace=False)] if s < n else pts
    d, _ = spatial.cKDTree(sub).query(sub, k=2)
    nn = d[:, 1]
    nn = nn[nn > 0]
    if len(nn) == 0:
        return 0.01
    # Median nearest-neighbour distance of uniform random samples of surface density rho is
    # sqrt(ln 2 / (pi rho)) = 0.47 / sqrt(rho): report the mean spacing 1 / sqrt(rho).
    return float(np.median(nn) * math.sqrt(s / n) / math.sqrt(math.log(2.0) / math.pi))


def local_point_spacing(points: np.ndarray, global_spacing: float, voxel_factor: float = 6.0,
                        clip: tuple[float, float] = (0.5, 4.0)) -> np.ndarray:
    """Per-point mean sample spacing from the point count of its voxel, in metres (N,) float32.

    Voxels of edge ``v = voxel_factor * global_spacing`` hold about ``v^2`` of surface, so a
    voxel with ``n`` points has spacing ``v / sqrt(n)``. Clipped to ``clip`` times the global
    spacing so that voxels clipped by a surface corner do not produce huge footprints.
    """
    pts = np.asarray(points, dtype=np.float64)
    v = max(voxel_factor * global_spacing, 1e-6)
    cell = np.floor((pts - pts.min(axis=0)) / v).astype(np.int64)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    spacing = v / np.sqrt(counts[inverse].astype(np.float64))
    return np.clip(spacing, clip[0] * global_spacing, clip[1] * global_spacing).astype(np.float32)


# ------------------------------------------------------------------------------------ renderer


class PointRenderer:
    """A colored cloud moved once to a torch device, rendered from many poses.

    Coordinates are stored relative to the cloud's centroid in float32 (keeps millimetre
    precision for large scans); outputs are in world coordinates.
    """

    def __init__(self, points: np.ndarray, colors: np.ndarray, params: RenderParams = RenderParams(),
                 device: str = "cpu") -> None:
        points, colors = _check_cloud(points, colors)
        if params.width != 2 * params.height or params.height < 2:
            raise InputError(f"panorama size must be W = 2 H, got {params.width} x {params.height}")
        try:
            self.device = torch.device(device)
            torch.empty(0, device=self.device)
        except (RuntimeError, AssertionError) as exc:
            raise InputError(f"torch device {device!r} is not available: {exc}") from None
        self.params = params
        self.origin = points.mean(axis=0).astype(np.float64)
        self.points = torch.from_numpy((points - self.origin).astype(np.float32)).to(self.device)
        self.colors = torch.from_numpy(np.ascontiguousarray(colors)).to(self.device)
        spacing = params.point_spacing_m
        self.spacing = float(spacing) if spacing is not None else estimate_point_spacing(points)
        use_local = params.local_spacing and spacing is None  # an explicit spacing is used as given
        local = local_point_spacing(points, self.spacing) if use_local else None
        self.point_spacing = None if local is None else torch.from_numpy(local).to(self.device)

    def render(self, rot_cam_from_world: np.ndarray, center: np.ndarray) -> RenderedView:
        """Render the panorama seen from pose ``(R, t)`` (``R`` world -> camera, ``t`` centre)."""
        R, t = _check_pose(rot_cam_from_world, center)
        p = self.params
        W, H = p.width, p.height
        dev = self.device
        with torch.no_grad():
            idx, rng, u, v, theta, row, col = self._project(R, t)
            # Packed z-buffer keys: range bits (monotone for non-negative float32) | position in
            # ``idx``. Pass 1: every point into its own pixel.
            n = len(idx)
            key = (rng.view(torch.int32).long() << 32) | torch.arange(n, device=dev)
            zbuf = torch.full((H * W,), _EMPTY_KEY, dtype=torch.int64, device=dev)
            zbuf.scatter_reduce_(0, row * W + col, key, reduce="amin", include_self=True)
            extra = self._splat_winners(zbuf, key, idx, rng, u, v, theta)
            if p.depth_tolerance > 0:
                zbuf = self._select_surface_points(zbuf, rng, u, v, (row, col), extra)
            zbuf = zbuf.view(H, W)
            for _ in range(p.fill_iterations):
                zbuf = _fill_holes_once(zbuf)

            valid = zbuf != _EMPTY_KEY
            pidx = idx.index_select(0, torch.where(valid, zbuf & 0xFFFFFFFF, torch.zeros_like(zbuf)).view(-1))
            depth = (zbuf >> 32).int().view(torch.float32)
            rgb = self.colors.index_select(0, pidx).view(H, W, -1)
            rgb[~valid] = p.background
            xyz = self.points.index_select(0, pidx).view(H, W, 3)
            nan = torch.tensor(float("nan"), device=dev)
            depth = torch.where(valid, depth, nan)
        xyz_np = xyz.cpu().numpy().astype(np.float64) + self.origin
        xyz_np[~valid.cpu().numpy()] = np.nan
        return RenderedView(rgb=rgb.cpu().numpy(), xyz=xyz_np.astype(np.float32), depth=depth.cpu().numpy(),
                            center=t, rot_cam_from_world=R)

    def _project(self, R: np.ndarray, t: np.ndarray) -> tuple:
        """The points beyond ``min_range_m`` seen from pose ``(R, t)``: their indices, ranges,
        panorama coordinates ``u, v``, polar angles and own pixels ``(row, col)``."""
        p = self.params
        W, H = p.width, p.height
        dev = self.device
        Rt = torch.from_numpy(R.astype(np.float32)).to(dev)
        tc = torch.from_numpy((t - self.origin).astype(np.float32)).to(dev)
        cam = (self.points - tc) @ Rt.T
        rng = torch.linalg.vector_norm(cam, dim=1)
        keep = rng > p.min_range_m
        if bool(keep.all()):
            idx = torch.arange(len(rng), device=dev)
        else:
            idx = torch.nonzero(keep).squeeze(1)
            cam, rng = cam[idx], rng[idx]
        x, y, z = cam.unbind(1)
        # Same maths as geometry.pixel_from_bearing.
        u = W * (1.0 - (torch.atan2(y, x) + math.pi) / (2.0 * math.pi))
        rho = torch.hypot(x, y)
        theta = torch.atan2(rho, z)
        v = H * theta / math.pi
        col = torch.floor(u).long().remainder(W)
        row = torch.floor(v).long().clamp_(0, H - 1)
        return idx, rng, u, v, theta, row, col

    def _splat_winners(self, zbuf: "torch.Tensor", key: "torch.Tensor", idx: "torch.Tensor", rng: "torch.Tensor",
                       u: "torch.Tensor", v: "torch.Tensor", theta: "torch.Tensor") -> tuple | None:
        """Pass 2 of the z-buffer (in place): the winner of each pixel is splatted to its footprint:
        the pixels touched by a square of the angular size of splat_scale sample spacings, centred
        on the projection, u widened by 1 / sin(theta). Points that lost their own pixel lie behind
        a winner there; where the cloud is denser than the image (the costly case) the winners'
        footprints already cover theirs, so only winners are expanded. Returns the footprint
        pixels (row, col, point), or None when every footprint is one pixel."""
        p = self.params
        W, H = p.width, p.height
        win = zbuf[zbuf != _EMPTY_KEY] & 0xFFFFFFFF
        px_per_rad = H / math.pi
        w_min = 2.0 * p.point_radius_px + 1.0 if p.point_radius_px > 0 else 0.0
        spacing = (self.spacing if self.point_spacing is None
                   else self.point_spacing.index_select(0, idx.index_select(0, win)))
        w_max = 2.0 * p.max_radius_px + 1.0
        w_v = (p.splat_scale * spacing * px_per_rad / rng.index_select(0, win)).clamp(w_min, w_max)
        # Near the poles every pixel of a row has its own winner: cap the u stretch at 2x.
        w_u = (w_v / torch.sin(theta.index_select(0, win)).clamp_min(1e-6)).clamp_max(2.0 * w_max)
        # Sub-pixel footprints stay in the point's own pixel (no straddling of pixel borders).
        w_v = torch.where(w_v < 1.0, torch.zeros_like(w_v), w_v)
        w_u = torch.where(w_u < 1.0, torch.zeros_like(w_u), w_u)
        uw, vw = u.index_select(0, win), v.index_select(0, win)
        v0 = torch.floor(vw - 0.5 * w_v).long()
        u0 = torch.floor(uw - 0.5 * w_u).long()
        nv = torch.floor(vw + 0.5 * w_v).long() - v0 + 1
        nu = torch.floor(uw + 0.5 * w_u).long() - u0 + 1
        big = torch.nonzero(nu * nv > 1).squeeze(1)
        if not len(big):
            return None
        # Expanded in two steps, footprint rows then their pixels, with no integer
        # division: one entry per footprint pixel, (row, col, key of its owner).
        nv_b, nu_b = nv.index_select(0, big), nu.index_select(0, big)
        rows_b = torch.cumsum(nv_b, 0) - nv_b
        n_rows = int(nv_b.sum())
        in_fp = torch.arange(n_rows, device=self.device) - torch.repeat_interleave(rows_b, nv_b)
        # Rows beyond a pole are clamped onto the pole row (they are near it).
        rr_r = (torch.repeat_interleave(v0.index_select(0, big), nv_b) + in_fp).clamp_(0, H - 1)
        nu_r = torch.repeat_interleave(nu_b, nv_b)
        key_r = torch.repeat_interleave(key.index_select(0, win.index_select(0, big)), nv_b)
        # Column of pixel j of the expansion: u0 + (j - first pixel of its row).
        first_r = torch.cumsum(nu_r, 0) - nu_r
        base_r = torch.repeat_interleave(u0.index_select(0, big), nv_b) - first_r
        cc = torch.repeat_interleave(base_r, nu_r) + torch.arange(int(nu_r.sum()), device=self.device)
        if W > 2.0 * w_max + 2.0:  # footprints overhang u by less than W: one wrap each way
            cc = torch.where(cc < 0, cc + W, cc)
            cc = torch.where(cc >= W, cc - W, cc)
        else:
            cc = cc.remainder(W)
        rr = torch.repeat_interleave(rr_r, nu_r)
        key2 = torch.repeat_interleave(key_r, nu_r)
        zbuf.scatter_reduce_(0, rr * W + cc, key2, reduce="amin", include_self=True)
        return rr, cc, key2 & 0xFFFFFFFF

    def _select_surface_points(self, zbuf: "torch.Tensor", rng: "torch.Tensor", u: "torch.Tensor",
                               v: "torch.Tensor", own: tuple, extra: tuple | None) -> "torch.Tensor":
        """Soft z-buffer: per pixel, of the candidates within ``depth_tolerance`` of the nearest
        range, keep the one projecting closest to the pixel centre (sharper images and 3D points
        on the pixel's ray instead of the nearest footprint's centre). ``own``: (row, col) of every
        point's own pixel; ``extra``: (row, col, point) of the footprint pixels, or None. Returns
        range-keyed keys."""
        W = self.params.width
        has = zbuf != _EMPTY_KEY
        min_rng = torch.where(has, zbuf >> 32, torch.zeros_like(zbuf)).int().view(torch.float32)
        sel = torch.full_like(zbuf, _EMPTY_KEY)
        parts = [(*own, None)] + ([extra] if extra is not None else [])
        for r, c, pos in parts:
            flat = r * W + c
            if pos is None:  # every point in its own pixel
                pos, rng_p, u_p, v_p = torch.arange(len(rng), device=zbuf.device), rng, u, v
            else:
                rng_p, u_p, v_p = (x.index_select(0, pos) for x in (rng, u, v))
            ok = rng_p <= min_rng.index_select(0, flat) * (1.0 + self.params.depth_tolerance)
            du = torch.remainder(c + 0.5 - u_p + 0.5 * W, W) - 0.5 * W
            dv = r + 0.5 - v_p
            d2 = (du * du + dv * dv).float()
            cand = torch.where(ok, (d2.view(torch.int32).long() << 32) | pos, _EMPTY_KEY)
            sel.scatter_reduce_(0, flat, cand, reduce="amin", include_self=True)
        chosen = sel & 0xFFFFFFFF
        out = (rng[torch.where(has, chosen, torch.zeros_like(chosen))].view(torch.int32).long() << 32) | chosen
        return torch.where(has, out, zbuf)


def _fill_holes_once(zbuf: "torch.Tensor") -> "torch.Tensor":
    """Empty pixels take the smallest key (nearest point) of their 3x3 neighbourhood."""
    H, W = zbuf.shape
    padded = torch.cat([zbuf[:, -1:], zbuf, zbuf[:, :1]], dim=1)  # wrap in u
    edge = torch.full((1, W + 2), _EMPTY_KEY, dtype=zbuf.dtype, device=zbuf.device)
    padded = torch.cat([edge, padded, edge], dim=0)  # nothing beyond the poles
    nearest = zbuf.clone()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                torch.minimum(nearest, padded[1 + dr:1 + dr + H, 1 + dc:1 + dc + W], out=nearest)
    return torch.where(zbuf == _EMPTY_KEY, nearest, zbuf)


# ------------------------------------------------------------------------------------ functions


def render_points_panorama(points: np.ndarray, colors: np.ndarray, rot_cam_from_world: np.ndarray,
                           center: np.ndarray, width: int = 1024, height: int = 512, *,
                           device: str = "cpu", point_radius_px: int = 0,
                           point_spacing_m: float | None = None, splat_scale: float = 2.0,
                           max_radius_px: int = 6, fill_iterations: int = 2,
                           depth_tolerance: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a colored point cloud as an equirectangular panorama at pose ``(R, t)``.

    Args:
        points: (N, 3) world coordinates. colors: (N, 3) uint8 RGB (floats in [0, 1] accepted).
        rot_cam_from_world: R, rotates world into camera. center: t, the camera centre.
        width, height: panorama size (W = 2 H).
        device: torch device ("cpu", "cuda").
        point_radius_px: minimum footprint half-width (0 = one pixel).
        point_spacing_m: surface sample spacing that sizes the footprints (None: estimated).
        splat_scale, max_radius_px, fill_iterations, depth_tolerance: see :class:`RenderParams`.

    Returns:
        ``rgb`` (H, W, 3) uint8, ``xyz`` (H, W, 3) float32 world coordinates of the visible point
        (NaN where empty), ``depth`` (H, W) float32 range in metres (NaN where empty).
    """
    params = RenderParams(width=int(width), height=int(height), point_spacing_m=point_spacing_m,
                          splat_scale=splat_scale, point_radius_px=point_radius_px,
                          max_radius_px=max_radius_px, fill_iterations=fill_iterations,
                          depth_tolerance=depth_tolerance)
    view = PointRenderer(points, colors, params, device=device).render(rot_cam_from_world, center)
    return view.rgb, view.xyz, view.depth


def render_views(points: np.ndarray, colors: np.ndarray, centers: np.ndarray,
                 params: RenderParams = RenderParams(), *, device: str = "cpu",
                 rot_cam_from_world: np.ndarray | None = None) -> Iterator[RenderedView]:
    """Render one panorama per translation in ``centers`` (N_t, 3), lazily.

    The map's views are axis-aligned: the rotation defaults to the identity. The cloud is moved
    to ``device`` once and its point spacing estimated once.
    """
    centers = np.asarray(centers, dtype=np.float64)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise InputError(f"centers must have shape (N_t, 3), got {centers.shape}")
    R = np.eye(3) if rot_cam_from_world is None else rot_cam_from_world
    renderer = PointRenderer(points, colors, params, device=device)
    for t in centers:
        yield renderer.render(R, t)
