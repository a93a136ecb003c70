"""Learned backends with packaged weights (ALIKED, DISK, XFeat + LightGlue): conventions, batched
matching, the panorama rotated into the map's frame, and localization with no network at all."""

from __future__ import annotations

import socket
from dataclasses import replace

import numpy as np
import pytest

from ldlmap.features import get_backend
from ldlmap.features.sphere import extract_in_map_frame, rotate_panorama
from ldlmap.core.geometry import bearing_from_pixel, rotation_from_axis_angle
from tests._localize import assert_refined_by_features

pytest.importorskip("kornia")
LEARNED = ("aliked", "disk", "xfeat")
# Map views of the localization test, few for the slow backends (DISK: ~7 s per 1024 x 512 view on
# one core): the fewest with which each of the three queries still ends well inside 0.1 m.
MAP_VIEWS = {"aliked": 4, "disk": 2, "xfeat": 8}


@pytest.fixture()
def offline(monkeypatch, tmp_path):
    """No network: sockets refuse to connect, hubs are told to stay offline, caches start empty."""
    from ldlmap.features.learned import load_detector
    from ldlmap.features.lightglue import load_lightglue

    def refuse(*args, **kwargs):
        raise OSError("network disabled in this test")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    for var in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE"):
        monkeypatch.setenv(var, "1")
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setenv("LDL_CACHE_DIR", str(tmp_path / "ldl"))
    load_detector.cache_clear()
    load_lightglue.cache_clear()
    yield
    assert not (tmp_path / "torch").exists() and not (tmp_path / "ldl").exists()  # nothing fetched


def _texture(h: int = 256, w: int = 512) -> np.ndarray:
    from tests.test_features import _texture as tex

    return tex(h, w)


@pytest.mark.parametrize("name", LEARNED)
def test_keypoints_descriptors_and_lightglue_on_a_yaw_roll(name, offline):
    b = get_backend(name)
    img = _texture()
    f = b.extract(img)
    assert b.name == name and len(f) > 100 and f.descriptors.dtype == np.float16
    assert f.descriptors.shape == (len(f), b.descriptor_dim) and np.all(np.diff(f.scores) <= 0)
    assert f.keypoints.min() >= 0 and np.all(f.keypoints < [512, 256])
    mask = np.zeros(img.shape[:2], bool)
    mask[:, :256] = True
    assert b.extract(img, mask=mask).keypoints[:, 0].max() < 256
    shift = 37  # a horizontal roll of a panorama is a yaw rotation
    g = b.extract(np.roll(img, shift, axis=1))
    m = b.match_views(f, (512, 256), [g], (512, 256))[0]
    du = np.mod(f.keypoints[m[:, 0], 0] + shift - g.keypoints[m[:, 1], 0] + 256, 512) - 256
    dv = f.keypoints[m[:, 0], 1] - g.keypoints[m[:, 1], 1]
    # (XFeat's keypoints repeat within a few pixels on this blocky texture; the others within one)
    assert len(m) > 0.5 * min(len(f), len(g)) and np.mean(np.hypot(du, dv) < 4.0) > 0.85
    assert np.median(np.hypot(du, dv)) <= 1.0


def test_batched_lightglue_equals_one_view_at_a_time():
    b = get_backend("xfeat", max_keypoints=300)
    img = _texture()
    f = b.extract(img)
    views = [b.extract(np.roll(img, s, axis=1), max_keypoints=n) for s, n in ((11, 300), (60, 120), (5, 0))]
    views.insert(1, b.extract(img[:, :0 or 16].repeat(32, axis=1)))  # a flat view: few or no keypoints
    together = b.matcher.match_batched(f, (512, 256), views, (512, 256), batch=8)
    alone = [b.matcher.match_batched(f, (512, 256), [v], (512, 256))[0] for v in views]
    assert all(np.array_equal(x, y) for x, y in zip(together, alone))
    assert len(together[0]) > 100


def test_rotated_panorama_keypoints_map_back_to_the_panorama():
    img = _texture(256, 512)
    R = rotation_from_axis_angle(np.array([1.0, 0.3, 0.2]), np.radians(35.0))
    # Rotating by R then by R^T gives the image back (away from the poles, bilinear blur aside).
    back = rotate_panorama(rotate_panorama(img, R), R.T)
    band = slice(60, 196)
    assert np.mean(np.abs(back[band].astype(int) - img[band].astype(int))) < 12
    b = get_backend("sift")
    f = extract_in_map_frame(b, img, R)
    # Each lifted keypoint's bearing, rotated into the map frame, lands on a keypoint of the rotated image.
    g = b.extract(rotate_panorama(img, R))
    d = bearing_from_pixel(f.keypoints, 512, 256) @ R
    e = bearing_from_pixel(g.keypoints, 512, 256)
    assert np.median(np.max(d @ e.T, axis=1)) > np.cos(np.radians(0.05))


@pytest.mark.parametrize("name", LEARNED)
def test_localization_with_packaged_weights_offline(name, demo_dataset, offline):
    """Map features of one demo room from each learned backend (2 to 8 views), then the whole
    pipeline on a robot and two extreme queries: each within 0.1 m / 5 deg, refined by features."""
    from ldlmap.map.build import BuildParams, compute_features
    from ldlmap.datasets import open_dataset
    from ldlmap.core.frame import is_identity
    from ldlmap.io.pointcloud import read_point_cloud
    from ldlmap.map.mapfile import read_map
    from ldlloc.pipeline import LocalizeParams, Localizer

    ds = open_dataset(demo_dataset, "omniscenes")
    scene = "synthroom_1"
    m = read_map(demo_dataset / "maps" / f"{scene}.h5", load_cloud=False)
    assert is_identity(m.input_to_map)
    cloud = read_point_cloud(ds.point_cloud(scene))
    feats = compute_features(cloud.points, cloud.colors, m.translations,
                             BuildParams().replaced(features=name, num_views=MAP_VIEWS[name]))
    assert feats.backend == name and feats.extraction == ("cube" if name == "aliked" else "equirect")  # measured defaults
    loc = Localizer(replace(m, features=feats), LocalizeParams(query_frame="map"))
    assert loc.feature_backend == name
    assert_refined_by_features(loc, ds, scene)


def test_build_lists_every_backend_for_an_unknown_name(tmp_path):
    from typer.testing import CliRunner

    from ldlmap.cli import app

    cloud = tmp_path / "c.txt"
    cloud.write_text("0 0 0 1 2 3\n")
    res = CliRunner().invoke(app, ["build", str(cloud), "--features", "orb"])
    assert res.exit_code == 1
    assert "valid: aliked, disk, sift, superpoint, xfeat, none" in res.output
