"""COLMAP model ingestion through pycolmap."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import colmap_cam_from_world, pose_from_colmap
from ldlmap.io.colmap import read_colmap_model
from ldlmap.io.cloud import PointCloud
from ldlmap.io.pointcloud import write_point_cloud


def _build_reconstruction(rng: np.random.Generator):
    """A small reconstruction: 1 equirectangular camera, 4 posed images, 30 colored points."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_id(1, pycolmap.CameraModelId.EQUIRECTANGULAR, 0.0, 64, 32)
    cam.params = [64, 32]
    rec.add_camera_with_trivial_rig(cam)
    centers = {}
    for i in range(4):
        R = Rotation.random(random_state=rng).as_matrix()
        t = rng.uniform(-2, 2, 3)
        R_c, t_c = colmap_cam_from_world(R, t)
        name = f"pano_{i:03d}.jpg"
        image = pycolmap.Image(name=name, camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R_c), t_c))
        centers[name] = t
    xyz = rng.uniform(-5, 5, (30, 3))
    rgb = rng.integers(0, 256, (30, 3), dtype=np.uint8)
    for p, c in zip(xyz, rgb):
        rec.add_point3D(p, pycolmap.Track(), c)
    return rec, centers, xyz, rgb


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize("text", [False, True])
def test_read_written_model(tmp_path: Path, text: bool) -> None:
    rec, centers, xyz, rgb = _build_reconstruction(np.random.default_rng(0))
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (rec.write_text if text else rec.write_binary)(str(model))
    scene = read_colmap_model(model)
    assert scene.image_names == tuple(sorted(centers))
    expected = np.array([centers[n] for n in scene.image_names])
    assert np.allclose(scene.camera_centers, expected, atol=1e-9 if not text else 1e-6)
    got = np.concatenate([scene.points.points, scene.points.colors.astype(float)], 1)
    want = np.concatenate([xyz, rgb.astype(float)], 1)
    assert np.allclose(_sorted_rows(got), _sorted_rows(want), atol=1e-9 if not text else 1e-6)
    assert scene.dense is None and scene.cloud is scene.points
    # Each image's down axis (COLMAP +y) in the world is our camera's -z (ldlmap/core/geometry.py).
    for name, down in zip(scene.image_names, scene.camera_down):
        im = rec.find_image_with_name(name)
        R, _ = pose_from_colmap(im.cam_from_world().rotation.matrix(), im.cam_from_world().translation)
        np.testing.assert_allclose(down, -R[2], atol=1e-9 if not text else 1e-6)
    # A workspace folder resolves to sparse/0.
    assert read_colmap_model(tmp_path).image_names == scene.image_names


def test_fused_ply_used_as_dense_cloud(tmp_path: Path) -> None:
    rec, _, _, _ = _build_reconstruction(np.random.default_rng(1))
    model = tmp_path / "model"
    model.mkdir()
    rec.write(str(model))
    rng = np.random.default_rng(2)
    dense = PointCloud(rng.normal(size=(200, 3)), rng.integers(0, 256, (200, 3), dtype=np.uint8))
    write_point_cloud(tmp_path / "fused.ply", dense)  # in the model's parent
    scene = read_colmap_model(model)
    assert scene.dense_path == tmp_path / "fused.ply"
    assert np.array_equal(scene.dense.points, dense.points) and np.array_equal(scene.dense.colors, dense.colors)
    assert scene.cloud is scene.dense
    assert read_colmap_model(model, use_dense=False).dense is None
    write_point_cloud(model / "fused.ply", PointCloud(dense.points[:10], dense.colors[:10]))  # in the folder wins
    assert len(read_colmap_model(model).dense) == 10


def test_colmap_bad_inputs(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_colmap_model(tmp_path / "nope")
    with pytest.raises(InputError, match="not a COLMAP sparse model"):
        read_colmap_model(tmp_path)
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        (tmp_path / name).write_bytes(b"\x01\x02")
    with pytest.raises(InputError, match="cannot read COLMAP model") as info:
        read_colmap_model(tmp_path)
    assert "\n" not in str(info.value)


def _pinhole_model(tmp_path: Path) -> tuple[Path, np.ndarray, dict]:
    """A PINHOLE model: 3 photos looking at 40 points, each point observed where it projects
    (photo 0 also observes nothing at one keypoint); returns (model dir, points, centres)."""
    import pycolmap

    from ldlmap.synth.sfm import look_rotation

    rng = np.random.default_rng(3)
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_id(1, pycolmap.CameraModelId.PINHOLE, 300.0, 320, 240)
    cam.params = [300.0, 310.0, 160.0, 120.0]
    rec.add_camera_with_trivial_rig(cam)
    X = rng.uniform([-1, 4, -1], [1, 6, 1], (40, 3))
    centers = {}
    obs = []
    for i in range(3):
        C = np.array([i - 1.0, 0.0, 0.0])
        R = look_rotation(np.pi / 2, 0.0, 0.0)  # looking along +y
        xc = (X - C) @ R.T
        uv = xc[:, :2] / xc[:, 2:] * [300.0, 310.0] + [160.0, 120.0]
        kp = np.vstack([uv, [[5.0, 5.0]]])  # last keypoint has no 3D point
        name = f"p{i}.jpg"
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, keypoints=kp, camera_id=1, image_id=i + 1),
                                         pycolmap.Rigid3d(pycolmap.Rotation3d(R), -R @ C))
        centers[name] = C
        obs.append(uv)
    for k, x in enumerate(X):
        rec.add_point3D(x, pycolmap.Track([pycolmap.TrackElement(i + 1, k) for i in range(3)]), np.zeros(3, np.uint8))
    model = tmp_path / "ws" / "sparse" / "0"
    model.mkdir(parents=True)
    rec.write_binary(str(model))
    return model, X, centers


def test_views_with_observations(tmp_path: Path) -> None:
    from ldlmap.io.colmap import find_images_dir, read_colmap_views

    model, X, centers = _pinhole_model(tmp_path)
    cv = read_colmap_views(model)
    assert [v.name for v in cv.views] == sorted(centers)
    for v in cv.views:
        assert np.allclose(v.center, centers[v.name])
        assert len(v.obs_xy) == len(X)  # the keypoint without a 3D point is left out
        # Each observation is where its point projects (R, t: COLMAP's cam_from_world).
        xc = cv.points[v.obs_point] @ v.rot_cam_from_world.T + v.trans_cam_from_world
        assert np.allclose(v.camera.img_from_cam(xc), v.obs_xy, atol=1e-6)
    assert np.allclose(np.sort(cv.points, axis=0), np.sort(X, axis=0))
    # The photos: <workspace>/images beside sparse/0, found only when it holds one of them.
    assert find_images_dir(model, ["p0.jpg"]) is None
    (tmp_path / "ws" / "images").mkdir()
    assert find_images_dir(model, ["p0.jpg"]) is None
    (tmp_path / "ws" / "images" / "p1.jpg").write_bytes(b"x")
    assert find_images_dir(model, ["p0.jpg", "p1.jpg"]) == tmp_path / "ws" / "images"
