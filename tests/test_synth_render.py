"""Ray-cast panoramas, pose sampling and the simulated scan, on a small textured box room."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import bearing_from_pixel, pixel_centers, project_to_pixels
from ldlmap.synth.poses import random_rotation, sample_poses
from ldlmap.core.polygon import points_in_polygon
from ldlmap.synth.render import Renderer, apply_illumination, bilinear_lookup, motion_blur
from ldlmap.synth.scan import sample_scan, write_ply, write_txt
from ldlmap.synth.types import SceneMesh

ROOM = (4.0, 3.0, 2.5)
BOX_LO, BOX_HI = (2.5, 1.8, 0.0), (3.3, 2.6, 0.8)


def _box(lo, hi):
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    V = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)
    F = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                  [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return V, F


def make_room(atlas: np.ndarray | None = None) -> SceneMesh:
    """A 4 x 3 x 2.5 m box room with a 0.8 m cube-ish box; uv = in-plane coordinates / 4."""
    V1, F1 = _box((0, 0, 0), ROOM)
    V2, F2 = _box(BOX_LO, BOX_HI)
    V = np.vstack([V1, V2])
    F = np.vstack([F1[:, ::-1], F2 + 8])
    tri = V[F]
    axis = np.argmax(np.abs(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])), axis=1)
    uvs = np.zeros((len(F), 3, 2), np.float32)
    for i, a in enumerate(axis):
        uvs[i] = tri[i][:, [k for k in range(3) if k != a]] / 4.0
    if atlas is None:
        atlas = np.random.default_rng(0).integers(0, 256, (64, 64, 3)).astype(np.uint8)
    return SceneMesh(vertices=V, triangles=F, tri_uvs=uvs, atlas=atlas,
                     tri_object=np.r_[np.full(12, -1), np.zeros(12)].astype(np.int32),
                     footprint=np.array([[0, 0], [4, 0], [4, 3], [0, 3]], float), ceiling_height=ROOM[2],
                     name="box", object_boxes=[V2])


@pytest.fixture(scope="module")
def room() -> SceneMesh:
    return make_room()


@pytest.fixture(scope="module")
def renderer(room) -> Renderer:
    return Renderer(room)


def test_open3d_barycentrics_weight_second_and_third_corner(renderer, room):
    rng = np.random.default_rng(1)
    tri_idx = 2  # a ceiling triangle, in plain view from the origin below
    A, B, C = room.vertices[room.triangles[tri_idx]]
    w = rng.dirichlet([2, 2, 2], size=20)
    target = w @ np.stack([A, B, C])
    origin = np.array([1.0, 1.0, 1.2])
    d = target - origin
    hits = renderer.cast(origin, d)  # t in units of |d|: the target is at t = 1
    assert np.all(hits["tri"] == tri_idx)
    np.testing.assert_allclose(hits["t"], 1.0, atol=1e-5)
    u, v = hits["bary"][:, 0], hits["bary"][:, 1]
    np.testing.assert_allclose(u, w[:, 1], atol=1e-4)
    np.testing.assert_allclose(v, w[:, 2], atol=1e-4)


def test_bilinear_lookup_texel_centres_and_midpoints():
    img = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    h, w = img.shape[:2]
    # Texel (row 1, col 2) centre in OBJ coords: s = 2.5 / 6, t = 1 - 1.5 / 4.
    st = np.array([[2.5 / w, 1 - 1.5 / h], [3.0 / w, 1 - 1.5 / h]])
    out = bilinear_lookup(img, st)
    np.testing.assert_allclose(out[0], img[1, 2])
    np.testing.assert_allclose(out[1], (img[1, 2].astype(float) + img[1, 3]) / 2)


def test_depth_matches_closed_form_box_room(renderer):
    """Depth of every pixel-centre ray = distance to the first box-room plane (closed form)."""
    W, H = 64, 32
    center = np.array([1.0, 0.8, 1.1])
    R = random_rotation(np.random.default_rng(3))
    _, depth, tri = renderer.render_float(R, center, W, H, supersample=1)
    d = bearing_from_pixel(pixel_centers(W, H), W, H) @ R  # world directions
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo = (0.0 - center) / d
        t_hi = (np.array(ROOM) - center) / d
    t_exit = np.min(np.where(d > 0, t_hi, t_lo), axis=-1)
    hit = center + d * depth[..., None].astype(np.float64)
    on_box = (tri >= 12)
    # Pixels that see the room shell: depth is the closed-form exit distance.
    np.testing.assert_allclose(depth[~on_box], t_exit[~on_box], rtol=1e-5, atol=1e-4)
    # Pixels that see the box: the hit lies on the box surface.
    lo, hi = np.array(BOX_LO), np.array(BOX_HI)
    pts = hit[on_box]
    assert on_box.sum() > 10
    assert np.all((pts >= lo - 1e-4) & (pts <= hi + 1e-4))
    assert np.all(np.min(np.minimum(np.abs(pts - lo), np.abs(pts - hi)), axis=1) < 1e-4)


def test_flat_texture_colour_is_albedo_times_shading_and_supersampling_averages():
    atlas = np.full((8, 8, 3), (200, 100, 50), np.uint8)
    rend = Renderer(make_room(atlas))
    W, H = 32, 16
    center = np.array([1.5, 1.2, 1.0])
    img, depth, tri = rend.render_float(np.eye(3), center, W, H, supersample=1)
    d = bearing_from_pixel(pixel_centers(W, H), W, H).reshape(-1, 3)
    pts = center + d * depth.reshape(-1, 1)
    factor = rend.shade(pts, rend.face_normals[tri.reshape(-1)])
    np.testing.assert_allclose(img.reshape(-1, 3), np.clip(np.outer(factor, [200, 100, 50]), 0, 255), rtol=1e-4)
    # Supersampling: depth/tri stay the pixel-centre truth, color = mean of the 2x2 sub-rays.
    img2, depth2, tri2 = rend.render_float(np.eye(3), center, W, H, supersample=2)
    np.testing.assert_array_equal(depth2, depth)
    np.testing.assert_array_equal(tri2, tri)
    sub = []
    for du in (-0.25, 0.25):
        for dv in (-0.25, 0.25):
            dd = bearing_from_pixel(pixel_centers(W, H).reshape(-1, 2) + [du, dv], W, H)
            h = rend.cast(center, dd)
            p = center + dd * h["t"][:, None]
            sub.append(rend.surface_color(h["tri"], h["bary"], p))
    np.testing.assert_allclose(img2.reshape(-1, 3), np.mean(sub, axis=0), rtol=1e-4, atol=1e-3)


def test_visible_vertices_reproject_onto_the_pixel_that_sees_them(renderer, room):
    W, H = 512, 256
    rng = np.random.default_rng(5)
    for split in ("robot", "extreme"):
        for R, t in sample_poses(room, split, 2, rng, renderer=renderer):
            pano = renderer.render(R, t, W, H, supersample=1)
            off = vertex_pixel_offsets(room.vertices, R, t, pano.depth, pano.tri_id, renderer)
            assert len(off) >= 4 and np.max(off) <= 1.0
            # Projecting with a pose off by one degree (about 1.4 px) fails the same check.
            bad = vertex_pixel_offsets(room.vertices, R, t, pano.depth, pano.tri_id, renderer,
                                       R_proj=R @ small_rotation(np.radians(1.0)))
            assert np.max(bad) > 1.0


def small_rotation(angle: float) -> np.ndarray:
    from ldlmap.core.geometry import rotation_from_axis_angle

    return rotation_from_axis_angle(np.array([0.3, -0.5, 0.8]), angle)


def vertex_pixel_offsets(vertices, R, t, depth, tri_id, renderer, R_proj=None, depth_tol: float = 0.05,
                         window: int = 3, return_index: bool = False):
    """Reprojection offsets (pixels) of the clearly visible vertices of a panorama rendered at
    pose ``(R, t)`` (its ``depth`` and ``tri_id``), projected with ``R_proj`` (default ``R``).

    The pixel that sees a vertex is the one, within ``window`` px of the projection, whose
    pixel-centre ray (pose ``R``) at the rendered ``depth`` (the renderer's own ground truth)
    hits the vertex's part of the mesh closest to the vertex; the offset is the Chebyshev
    distance from the projection to that pixel's centre in units of the pixel's angular size
    (u offsets times ``sin(theta)``; about 0.5 at most for a perfect pose). A
    vertex is visible when a ray cast from ``t`` towards it first hits at the vertex distance
    (within 3 mm), and clearly visible when also the 3 x 3 pixels around the projection see its
    own part within ``depth_tol`` (relative) of that distance: silhouette corners and surfaces
    seen edge-on are ambiguous at one pixel and are left out. ``vertices`` are the mesh's.
    """
    mesh = renderer.mesh
    part = mesh.tri_part if mesh.tri_part is not None else mesh.tri_object
    vertex_part = np.full(len(mesh.vertices), -10)
    vertex_part[np.asarray(mesh.triangles).ravel()] = np.repeat(np.asarray(part), 3)
    H, W = depth.shape
    vec = vertices - t
    dist = np.linalg.norm(vec, axis=1)
    hits = renderer.cast(t, vec / dist[:, None])
    visible = np.abs(hits["t"] - dist) < 3e-3
    V, dV, vpart = vertices[visible], dist[visible], vertex_part[visible]
    uv = project_to_pixels(V, R if R_proj is None else R_proj, t, W, H)
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    best = np.full(len(V), np.inf)
    best_centre = np.zeros_like(uv)
    clear = np.ones(len(V), dtype=bool)
    for dr in range(-window, window + 1):
        for dc in range(-window, window + 1):
            r, c = np.clip(row + dr, 0, H - 1), col + dc
            centre = np.stack([c + 0.5, r + 0.5], -1)
            b = bearing_from_pixel(centre, W, H) @ R
            d, tri = depth[r, np.mod(c, W)], tri_id[r, np.mod(c, W)]
            same = (tri >= 0) & (np.asarray(part)[np.maximum(tri, 0)] == vpart)
            if max(abs(dr), abs(dc)) <= 1:
                clear &= same & (np.abs(d - dV) <= depth_tol * dV)
            miss = np.where(same, np.linalg.norm(t + b * d[:, None] - V, axis=1), np.inf)
            closer = miss < best
            best[closer] = miss[closer]
            best_centre[closer] = centre[closer]
    # Pixels narrow towards the poles: measure u offsets by their angular size (sin theta).
    du = (best_centre[:, 0] - uv[:, 0]) * np.sin(np.pi * uv[:, 1] / H)
    off = np.maximum(np.abs(du), np.abs(best_centre[:, 1] - uv[:, 1]))[clear]
    return (off, np.flatnonzero(visible)[clear]) if return_index else off


def test_illumination_variants_follow_the_paper():
    img = np.array([[[0, 128, 255], [10, 20, 30]]], np.uint8)
    np.testing.assert_array_equal(apply_illumination(img, "intensity"), np.rint(img * 0.75).astype(np.uint8))
    np.testing.assert_array_equal(apply_illumination(img, "gamma"),
                                  np.rint(255 * (img / 255.0) ** 0.2).astype(np.uint8))
    np.testing.assert_array_equal(apply_illumination(img, "white_balance"),
                                  np.rint(img * np.array([0.7, 0.9, 0.8])).astype(np.uint8))
    with pytest.raises(ValueError):
        apply_illumination(img, "sepia")


def test_motion_blur_is_centred_and_preserves_flat_images():
    img = np.zeros((20, 40, 3), np.float32)
    img[10, 20] = 90.0
    out = motion_blur(img, 8.0, 0.0)  # horizontal
    assert out[..., 0].sum() == pytest.approx(90.0)
    cols = np.arange(40)
    centroid = np.sum(out[10, :, 0] * cols) / out[10, :, 0].sum()
    assert centroid == pytest.approx(20.0)
    assert np.count_nonzero(out[10, :, 0]) >= 8 and np.count_nonzero(out[:, 20, 0]) == 1
    flat = np.full((10, 20, 3), 77.0, np.float32)
    np.testing.assert_allclose(motion_blur(flat, 5.0, 1.0), 77.0, rtol=1e-6)


def test_poses_per_split(room, renderer):
    rng = np.random.default_rng(7)
    for split, (zlo, zhi), max_tilt in (("robot", (0.95, 1.05), 2.0), ("handheld", (1.35, 1.65), 10.0),
                                        ("change_robot", (0.95, 1.05), 2.0)):
        poses = sample_poses(room, split, 20, rng, renderer=renderer)
        for R, t in poses:
            assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) > 0
            # Camera +z (image top) in the world is R^T e_z; its tilt from world +z:
            tilt = np.degrees(np.arccos(np.clip(R[2, 2], -1, 1)))
            assert tilt <= max_tilt + 1e-9
            assert zlo <= t[2] <= zhi
        centers = np.array([t for _, t in poses])
        assert np.all(points_in_polygon(centers[:, :2], room.footprint))
        assert np.all(renderer.distance(centers) >= 0.3 - 1e-6)
        in_box = np.all((centers[:, :2] >= np.array(BOX_LO[:2])) & (centers[:, :2] <= np.array(BOX_HI[:2])), axis=1)
        assert not np.any(in_box)
        tilts = np.degrees(np.arccos(np.clip([R[2, 2] for R, _ in poses], -1, 1)))
        assert np.max(tilts) > 0.5 * max_tilt  # the tilt range is used
        yaws = np.array([np.arctan2(R[0, 1], R[0, 0]) for R, _ in poses])
        assert np.ptp(yaws) > np.pi  # any yaw
    extreme = sample_poses(room, "extreme", 300, rng, renderer=renderer)
    mean_R = np.mean([R for R, _ in extreme], axis=0)  # E[R] = 0 for Haar-uniform rotations
    assert np.abs(mean_R).max() < 0.12
    with pytest.raises(InputError):
        sample_poses(room, "sideways", 1, rng, renderer=renderer)


def test_scan_is_visible_surface_only_noisy_and_colored_like_the_renders(room, renderer, tmp_path):
    from ldlmap.synth.scan import ScanParams

    params = ScanParams(density=1000.0, max_points=60_000, stations=3, noise_std=0.0, holes=0)
    pts, cols = sample_scan(room, params, np.random.default_rng(2), renderer=renderer)
    assert 55_000 < len(pts) <= 60_000 and cols.dtype == np.uint8
    assert np.max(renderer.distance(pts)) < 1e-4
    # Nothing under the box (the floor there is hidden from every station).
    under = np.all((pts[:, :2] > np.array(BOX_LO[:2]) + 0.01) & (pts[:, :2] < np.array(BOX_HI[:2]) - 0.01), axis=1)
    assert not np.any(under & (pts[:, 2] < 0.79))
    # Colors = the renderer's surface color at the same point.
    eye = np.array([1.0, 1.0, 1.3])
    sub = pts[:3000]
    vec = sub - eye
    dist = np.linalg.norm(vec, axis=1)
    h = renderer.cast(eye, vec / dist[:, None])
    seen = np.abs(h["t"] - dist) < 1e-4
    assert seen.sum() > 500
    ref = renderer.surface_color(h["tri"][seen], h["bary"][seen], sub[seen])
    assert np.abs(ref - cols[:3000][seen]).max() <= 1.0
    noisy, _ = sample_scan(room, ScanParams(density=1000.0, max_points=60_000, stations=3, holes=4),
                           np.random.default_rng(2), renderer=renderer)
    d = renderer.distance(noisy)
    assert 0.002 < np.median(d) < 0.006 and len(noisy) < len(pts)
    write_ply(tmp_path / "s.ply", pts, cols)
    write_txt(tmp_path / "s.txt", pts, cols)
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(tmp_path / "s.ply"))
    np.testing.assert_array_equal(np.asarray(pc.points), pts)
    np.testing.assert_array_equal(np.rint(np.asarray(pc.colors) * 255), cols)
    txt = np.loadtxt(tmp_path / "s.txt")
    np.testing.assert_allclose(txt[:, :3], pts, atol=1e-6)
    np.testing.assert_array_equal(txt[:, 3:], cols)
    with pytest.raises(InputError):
        write_ply(tmp_path / "bad.ply", np.full((2, 3), np.nan), np.zeros((2, 3)))
    assert not (tmp_path / "bad.ply").exists()
