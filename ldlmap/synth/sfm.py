"""A synthetic COLMAP workspace of a scene mesh: pinhole photos, cameras, sparse points with tracks.

What a COLMAP SfM run of a few photos of a room would give, with known truth, for the tests and
``bench/bench_colmap_lines.py``::

    <out>/images/img_000.jpg ...          perspective photos (ray-cast like the panoramas)
    <out>/sparse/0/cameras|images|points3D .bin (or .txt)

Cameras are upright-ish (pitch and roll of a few degrees), each placed where it sees far along
its viewing direction, yaws spread around the circle. Sparse points are SIFT keypoints of the
photos lifted to the surface (rendered depth), merged within 1 cm, observed in every photo that
sees them unoccluded (each observation kept with probability ``keep_observation``, pixel noise
``obs_noise_px``), moved along their viewing ray by ``depth_noise`` x depth (triangulation
noise), and joined by ``outliers`` x N far-away points with two random observations each (what
breaks a min/max extent). Everything is in the mesh's world frame (metres, z up); COLMAP's
camera looks along +z with +x right and +y down, and pixel centres sit at ``(c + 0.5, r + 0.5)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.core.signals import import_pycolmap
from ldlmap.io.imagefile import write_image
from ldlmap.synth.poses import sample_positions
from ldlmap.synth.render import Renderer
from ldlmap.synth.types import SceneMesh

cv2 = lazy_module("cv2")
transform = lazy_module("scipy.spatial.transform")


@dataclass(frozen=True)
class SfmCapture:
    """How the synthetic photos and the sparse model are made."""

    num_images: int = 12
    width: int = 640
    height: int = 480
    fov_deg: float = 75.0  # horizontal field of view
    camera_height: tuple[float, float] = (1.2, 1.7)  # metres above the floor
    clearance: float = 0.4  # cameras keep this distance from every surface
    max_tilt_deg: float = 8.0  # pitch and roll within +- this
    keypoints: int = 1500  # SIFT keypoints per photo lifted to sparse points
    keep_observation: float = 0.85  # probability that a visible point is matched in a photo
    obs_noise_px: float = 0.5
    depth_noise: float = 0.003  # point moved along its ray by N(0, depth_noise * depth)
    outliers: float = 0.03  # far-away outlier points, as a fraction of the inliers
    supersample: int = 2
    binary: bool = True  # write .bin (else .txt)
    seed: int = 0


@dataclass
class SyntheticSfm:
    """A written workspace and its truth."""

    workspace: Path
    model_dir: Path
    images_dir: Path
    rot_cam_from_world: np.ndarray  # (M, 3, 3) COLMAP convention (x right, y down, z forward)
    centers: np.ndarray  # (M, 3)
    K: np.ndarray  # (3, 3) shared PINHOLE intrinsics
    num_points: int
    num_outliers: int


def intrinsics(cap: SfmCapture) -> np.ndarray:
    """PINHOLE calibration matrix of the capture (principal point at the image centre)."""
    f = 0.5 * cap.width / np.tan(np.radians(cap.fov_deg) / 2)
    return np.array([[f, 0, cap.width / 2], [0, f, cap.height / 2], [0, 0, 1.0]])


def look_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """COLMAP cam_from_world rotation looking along ``yaw``/``pitch`` (radians) with ``roll``."""
    f = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    c, s = np.cos(roll), np.sin(roll)
    r, d = c * r + s * d, -s * r + c * d
    return np.stack([r, d, f])


def _poses(mesh: SceneMesh, renderer: Renderer, cap: SfmCapture,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera rotations (n, 3, 3) and centres (n, 3) of the photos (module docstring)."""
    cand = sample_positions(mesh, 64 * cap.num_images, rng, *cap.camera_height, cap.clearance, renderer=renderer)
    yaws = 2 * np.pi * (np.arange(cap.num_images) + rng.uniform(0, 1, cap.num_images)) / cap.num_images
    Rs, Cs = [], []
    for yaw in yaws:  # per photo: the free position that sees farthest along its yaw
        d = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        reach = renderer.cast(cand, np.broadcast_to(d, cand.shape))["t"]
        k = int(np.argmax(np.where(np.isfinite(reach), reach, 0)))
        Cs.append(cand[k])
        cand = np.delete(cand, k, axis=0)
        tilt = np.radians(cap.max_tilt_deg)
        Rs.append(look_rotation(yaw, rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt)))
    return np.stack(Rs), np.stack(Cs)


def _render(renderer: Renderer, R: np.ndarray, C: np.ndarray, K: np.ndarray, cap: SfmCapture):
    """RGB (H, W, 3) uint8 and the surface point (H, W, 3) (NaN: nothing) of each pixel centre."""
    W, H = cap.width, cap.height
    uu, vv = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    Kinv = np.linalg.inv(K)

    A = Kinv.T @ R  # pixel (u, v, 1) -> world direction, as a row-vector map

    def rays(du: float, dv: float) -> np.ndarray:
        u, v = uu.ravel() + du, vv.ravel() + dv
        return u[:, None] * A[0] + v[:, None] * A[1] + A[2]

    dirs = rays(0.0, 0.0)
    hits = renderer.cast(C, dirs)
    ok = hits["tri"] >= 0
    xyz = np.full((W * H, 3), np.nan)
    xyz[ok] = C + dirs[ok] * hits["t"][ok, None]
    offs = (np.arange(cap.supersample) + 0.5) / cap.supersample - 0.5
    color = np.zeros((W * H, 3), np.float32)
    for du in offs:
        for dv in offs:
            d = rays(du, dv)
            h = renderer.cast(C, d)
            good = h["tri"] >= 0
            color[good] += renderer.surface_color(h["tri"][good], h["bary"][good], C + d[good] * h["t"][good, None])
    color /= len(offs) ** 2
    return np.clip(color, 0, 255).astype(np.uint8).reshape(H, W, 3), xyz.reshape(H, W, 3)


def _keypoints(rgb: np.ndarray, n: int) -> np.ndarray:
    """SIFT keypoint positions (k, 2), COLMAP pixel coordinates (centre of the first pixel = 0.5)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    kps = cv2.SIFT_create(nfeatures=n).detect(gray, None)
    return np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2) + 0.5


def _visible(renderer: Renderer, X: np.ndarray, R: np.ndarray, C: np.ndarray, K: np.ndarray,
             cap: SfmCapture) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of points X in one photo and whether each is seen there (in front, inside, unoccluded)."""
    Xc = (X - C) @ R.T
    z = Xc[:, 2]
    uv = (Xc[:, :2] / np.maximum(z, 1e-9)[:, None]) * K[[0, 1], [0, 1]] + K[:2, 2]
    inside = (z > 0.05) & (uv[:, 0] >= 1) & (uv[:, 0] <= cap.width - 1) & (uv[:, 1] >= 1) & (uv[:, 1] <= cap.height - 1)
    seen = inside.copy()
    if inside.any():
        d = X[inside] - C
        t = renderer.cast(C, d)["t"]
        seen[inside] = np.isfinite(t) & (t >= 1 - 0.01 / np.linalg.norm(d, axis=1))
    return uv, seen


def write_colmap_workspace(mesh: SceneMesh, out: str | Path, cap: SfmCapture = SfmCapture()) -> SyntheticSfm:
    """Render ``cap.num_images`` photos of ``mesh`` and write a COLMAP workspace into ``out``."""
    rng = np.random.default_rng(cap.seed)
    out = Path(out)
    images_dir, model_dir = out / "images", out / "sparse" / "0"
    images_dir.mkdir(parents=True, exist_ok=True)
    model_dir.mkdir(parents=True, exist_ok=True)
    renderer = Renderer(mesh)
    K = intrinsics(cap)
    Rs, Cs = _poses(mesh, renderer, cap, rng)
    names = [f"img_{i:03d}.jpg" for i in range(len(Rs))]
    photos, pts = [], []
    for R, C, name in zip(Rs, Cs, names):
        rgb, xyz = _render(renderer, R, C, K, cap)
        write_image(images_dir / name, rgb[..., ::-1], quality=95)
        photos.append(rgb)
        kp = _keypoints(rgb, cap.keypoints)
        p = xyz[kp[:, 1].astype(int), kp[:, 0].astype(int)]
        pts.append(p[np.isfinite(p).all(1)])
    X = np.concatenate(pts)
    X = X[np.unique(np.round(X / 0.01).astype(np.int64), axis=0, return_index=True)[1]]
    # Observations: every photo that sees a point, each kept with probability keep_observation.
    uv = np.zeros((len(Rs), len(X), 2))
    seen = np.zeros((len(Rs), len(X)), bool)
    for i, (R, C) in enumerate(zip(Rs, Cs)):
        uv[i], seen[i] = _visible(renderer, X, R, C, K, cap)
    seen &= rng.random(seen.shape) < cap.keep_observation
    keep = seen.sum(0) >= 2
    X, uv, seen = X[keep], uv[:, keep], seen[:, keep]
    uv += rng.normal(scale=cap.obs_noise_px, size=uv.shape)
    first = seen.argmax(0)  # move each point along the ray of its first observing photo
    ray = X - Cs[first]
    X = X + ray * rng.normal(scale=cap.depth_noise, size=(len(X), 1))
    px = np.clip(uv[first, np.arange(len(X))].astype(int), 0, [cap.width - 1, cap.height - 1])
    rgb = np.stack(photos)[first, px[:, 1], px[:, 0]]
    # Outliers: far points with two random observations.
    n_out = int(round(cap.outliers * len(X)))
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    span = hi - lo
    Xo = lo - span + rng.random((n_out, 3)) * 3 * span
    uvo = rng.random((len(Rs), n_out, 2)) * [cap.width, cap.height]
    seen_o = np.zeros((len(Rs), n_out), bool)
    pick = np.argsort(rng.random((len(Rs), n_out)), axis=0)[:2]
    seen_o[pick, np.arange(n_out)[None]] = True
    X = np.concatenate([X, Xo])
    uv = np.concatenate([uv, uvo], 1)
    seen = np.concatenate([seen, seen_o], 1)
    rgb = np.concatenate([rgb, rng.integers(0, 256, (n_out, 3))]).astype(np.uint8)
    _write_text_model(model_dir, K, cap, Rs, Cs, names, X, rgb, uv, seen)
    if cap.binary:
        pycolmap = import_pycolmap()
        pycolmap.Reconstruction(str(model_dir)).write_binary(str(model_dir))
        for f in model_dir.glob("*.txt"):
            f.unlink()
    return SyntheticSfm(out, model_dir, images_dir, Rs, Cs, K, int(len(X) - n_out), n_out)


def _write_text_model(model_dir: Path, K: np.ndarray, cap: SfmCapture, Rs: np.ndarray, Cs: np.ndarray,
                      names: list[str], X: np.ndarray, rgb: np.ndarray, uv: np.ndarray, seen: np.ndarray) -> None:
    """COLMAP text model: one PINHOLE camera, images with their observations, points with tracks."""
    (model_dir / "cameras.txt").write_text(
        f"1 PINHOLE {cap.width} {cap.height} " + " ".join(f"{v:.17g}" for v in K[[0, 1, 0, 1], [0, 1, 2, 2]]) + "\n")
    # Observation index of point j in photo i: its rank among the points that photo sees.
    idx2d = np.cumsum(seen, axis=1) - 1
    img_lines = []
    for i, (R, C, name) in enumerate(zip(Rs, Cs, names)):
        x, y, z, w = transform.Rotation.from_matrix(R).as_quat()
        t = -R @ C
        j = np.flatnonzero(seen[i])
        obs = " ".join(f"{a:.4f} {b:.4f} {p}" for (a, b), p in zip(uv[i, j], j + 1))
        pose = " ".join(f"{v:.17g}" for v in (w, x, y, z, *t))
        img_lines += [f"{i + 1} {pose} 1 {name}", obs]
    (model_dir / "images.txt").write_text("\n".join(img_lines) + "\n")
    rows = []
    for j in range(len(X)):
        ims = np.flatnonzero(seen[:, j])
        track = " ".join(f"{i + 1} {idx2d[i, j]}" for i in ims)
        rows.append(f"{j + 1} {X[j, 0]:.17g} {X[j, 1]:.17g} {X[j, 2]:.17g} {rgb[j, 0]} {rgb[j, 1]} {rgb[j, 2]} 0.5 {track}")
    (model_dir / "points3D.txt").write_text("\n".join(rows) + "\n")


def seen_edges(mesh: SceneMesh, edges: np.ndarray, sfm: SyntheticSfm, cap: SfmCapture, min_views: int = 2,
               min_cover: float = 0.7, step: float = 0.02) -> np.ndarray:
    """Mask (E,): edges of which at least ``min_cover`` of the length is seen by ``min_views`` photos."""
    renderer = Renderer(mesh)
    E = np.asarray(edges, dtype=np.float64).reshape(-1, 2, 3)
    n = np.maximum(2, np.ceil(np.linalg.norm(E[:, 1] - E[:, 0], axis=1) / step).astype(int))
    seg = np.repeat(np.arange(len(E)), n)
    s = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
    P = E[seg, 0] + s[:, None] * (E[seg, 1] - E[seg, 0])
    count = np.zeros(len(P), int)
    for R, C in zip(sfm.rot_cam_from_world, sfm.centers):
        # Sample points sit on an edge: pull them 1 cm toward the camera so their own surface does not occlude them.
        d = C - P
        Q = P + 0.01 * d / np.linalg.norm(d, axis=1, keepdims=True)
        count += _visible(renderer, Q, R, C, sfm.K, cap)[1]
    return np.bincount(seg, count >= min_views, len(E)) / n >= min_cover
