"""Feature registry, SIFT backend, batched matching, keypoint back-projection."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core import geometry as geo
from ldlmap.core.errors import InputError
from ldlmap.features import available_backends, get_backend, mutual_nn_match
from ldlmap.map.keypoints3d import backproject_keypoints, view_features
from ldlmap.map.render import PointRenderer, RenderParams


def _texture(h: int = 256, w: int = 512, seed: int = 0) -> np.ndarray:
    """A blobby random RGB texture with plenty of SIFT corners."""
    import cv2

    rng = np.random.default_rng(seed)
    img = np.full((h, w, 3), 128, np.uint8)
    for _ in range(400):
        c = tuple(int(x) for x in rng.integers(0, 256, 3))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        if rng.random() < 0.5:
            cv2.circle(img, (x, y), int(rng.integers(3, 15)), c, -1)
        else:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(4, 25)), y + int(rng.integers(4, 25))), c, -1)
    return cv2.GaussianBlur(img, (3, 3), 0.8)


def _room(n: int, size=(5.0, 4.0, 2.6), seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the faces of a box room, colored by random 15 cm cells plus fine noise."""
    rng = np.random.default_rng(seed)
    s = np.asarray(size)
    areas = np.array([s[0] * s[1]] * 2 + [s[0] * s[2]] * 2 + [s[1] * s[2]] * 2)
    face = rng.choice(6, n, p=areas / areas.sum())
    P = rng.random((n, 3)) * s
    axis = face // 2
    P[np.arange(n), axis] = np.where(face % 2 == 0, 0.0, s[axis])
    cell = np.floor(P / 0.15).astype(np.int64)
    h = (cell[:, 0] * 73856093 ^ cell[:, 1] * 19349663 ^ cell[:, 2] * 83492791) % 4099
    lut = np.random.default_rng(seed + 1).integers(0, 256, (4099, 3), dtype=np.uint8)
    return P, lut[h]


def test_registry_names_and_unknown_backend():
    assert available_backends() == ["aliked", "disk", "sift", "superpoint", "xfeat"]
    b = get_backend("SIFT", max_keypoints=100)
    assert b.name == "sift" and b.descriptor_dtype == np.uint8 and b.config.max_keypoints == 100
    with pytest.raises(InputError, match="valid: aliked, disk, sift, superpoint, xfeat"):
        get_backend("orb")
    with pytest.raises(InputError, match="invalid SIFT option"):
        get_backend("sift", bogus=1)


def test_sift_keypoints_follow_our_pixel_convention():
    import cv2

    img = _texture()
    f = get_backend("sift", max_keypoints=0, normalize_contrast=False).extract(img)
    kps = cv2.SIFT_create().detect(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None)
    ref = np.array(sorted((k.pt[0] + 0.5, k.pt[1] + 0.5) for k in kps))
    assert len(f) == len(ref) > 200
    np.testing.assert_allclose(np.array(sorted(map(tuple, f.keypoints))), ref, atol=1e-4)
    assert f.descriptors.dtype == np.uint8 and f.descriptors.shape == (len(f), 128)
    assert f.keypoints.dtype == np.float32 and np.all(np.diff(f.scores) <= 0)
    top = get_backend("sift").extract(img, max_keypoints=50)
    assert len(top) == 50 and top.scores.min() >= np.sort(f.scores)[-50] - 1e-9
    mask = np.zeros(img.shape[:2], bool)
    mask[:, :256] = True
    fm = get_backend("sift").extract(img, mask=mask)
    assert len(fm) > 50 and fm.keypoints[:, 0].max() < 257
    with pytest.raises(InputError, match="uint8"):
        get_backend("sift").extract(img.astype(np.float32))
    with pytest.raises(InputError, match="mask"):
        get_backend("sift").extract(img, mask=mask[:10])


def test_mutual_nn_match_against_brute_force():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(300, 16)).astype(np.float32)
    b = np.concatenate([a[:150] + 0.05 * rng.normal(size=(150, 16)), rng.normal(size=(200, 16))]).astype(np.float32)
    for metric in ("l2", "cosine"):
        got = mutual_nn_match(a, b, metric=metric, ratio=0.8, chunk=64)
        A, B = (a, b) if metric == "l2" else (geo.normalize(a), geo.normalize(b))
        d = np.linalg.norm(A[:, None] - B[None], axis=2)
        nn = np.argsort(d, axis=1)
        d1, d2 = d[np.arange(len(a)), nn[:, 0]], d[np.arange(len(a)), nn[:, 1]]
        ok = (d1 < 0.8 * d2) & (np.argmin(d, axis=0)[nn[:, 0]] == np.arange(len(a)))
        want = np.stack([np.nonzero(ok)[0], nn[ok, 0]], 1)
        assert np.array_equal(got, want)
        true = got[got[:, 0] < 150]
        assert len(true) >= 140 and np.all(true[:, 0] == true[:, 1])
    assert mutual_nn_match(a[:0], b).shape == (0, 2)
    with pytest.raises(InputError):
        mutual_nn_match(a, b[:, :8])


def test_sift_matches_shifted_and_rotated_images():
    import cv2

    img = _texture()
    sift = get_backend("sift")
    fa = sift.extract(img)
    # A horizontal roll of an equirectangular image is a yaw rotation of the panorama.
    shift = 37
    fb = sift.extract(np.roll(img, shift, axis=1))
    m = sift.match(fa.descriptors, fb.descriptors)
    du = np.mod(fa.keypoints[m[:, 0], 0] + shift - fb.keypoints[m[:, 1], 0] + 256, 512) - 256
    dv = fa.keypoints[m[:, 0], 1] - fb.keypoints[m[:, 1], 1]
    assert len(m) > 150 and np.mean(np.hypot(du, dv) < 1.5) > 0.9
    # An in-plane rotation by 25 degrees (OpenCV's pixel-centre convention is ours - 0.5).
    A = cv2.getRotationMatrix2D((255.5, 127.5), 25.0, 1.0)
    fr = sift.extract(cv2.warpAffine(img, A, (512, 256), borderValue=(128, 128, 128)))
    m = sift.match(fa.descriptors, fr.descriptors)
    pa = fa.keypoints[m[:, 0]] - 0.5
    pred = pa @ A[:, :2].T + A[:, 2] + 0.5
    err = np.linalg.norm(pred - fr.keypoints[m[:, 1]], axis=1)
    assert len(m) > 100 and np.mean(err < 3.0) > 0.9


def test_backproject_nearest_pixel_window_and_wrap():
    H, W = 4, 8
    img = np.full((H, W, 3), np.nan, np.float32)
    img[1, 2] = [1, 2, 3]
    img[2, 7] = [7, 7, 7]
    kp = np.array([[2.5, 1.5],  # exactly on the valid pixel
                   [3.9, 1.2],  # empty pixel (1, 3): nearest valid is (1, 2)
                   [0.2, 2.5],  # empty pixel (2, 0): wraps to (2, 7)
                   [5.5, 0.5]])  # nothing within one pixel
    xyz, valid = backproject_keypoints(kp, img)
    assert valid.tolist() == [True, True, True, False]
    np.testing.assert_array_equal(xyz[:3], [[1, 2, 3], [1, 2, 3], [7, 7, 7]])
    assert np.isnan(xyz[3]).all()
    xyz0, valid0 = backproject_keypoints(kp, img, search_radius=0)
    assert valid0.tolist() == [True, False, False, False]
    with pytest.raises(InputError):
        backproject_keypoints(kp[:, :1], img)


def test_sift_view_features_lie_on_scanned_surfaces():
    from scipy.spatial import cKDTree

    size = np.array([5.0, 4.0, 2.6])
    P, C = _room(250_000, tuple(size))
    renderer = PointRenderer(P, C, RenderParams(width=1024, height=512))
    center = np.array([2.2, 1.7, 1.4])
    vf = view_features(None, None, center, get_backend("sift"), renderer=renderer)
    assert len(vf.xyz) > 300 and vf.backend == "sift" and np.isfinite(vf.xyz).all()
    assert len(vf.xyz) == len(vf.descriptors) == len(vf.scores) == len(vf.keypoints)
    d_cloud, _ = cKDTree(P).query(vf.xyz)
    d_surface = np.minimum(np.abs(vf.xyz), np.abs(vf.xyz - size)).min(axis=1)
    assert np.median(d_cloud) < 0.02 and np.median(d_surface) < 0.02
    # The 3D point is the one seen along the keypoint's ray (soft z-buffer), within the splat footprint (about
    # 2 * 1.7 cm / 2 m = 3 px wide here).
    uv = geo.project_to_pixels(vf.xyz, np.eye(3), center, 1024, 512)
    du = np.mod(uv[:, 0] - vf.keypoints[:, 0] + 512, 1024) - 512
    err = np.hypot(du, uv[:, 1] - vf.keypoints[:, 1])
    assert np.median(err) < 1.2 and np.mean(err < 3.0) > 0.9
    # Map views seen from a nearby translation match back to the right 3D points.
    vf2 = view_features(None, None, center + [0.3, -0.2, 0.0], get_backend("sift"), renderer=renderer)
    m = get_backend("sift").match(vf.descriptors, vf2.descriptors)
    dist3 = np.linalg.norm(vf.xyz[m[:, 0]] - vf2.xyz[m[:, 1]], axis=1)
    # (the blocky random texture repeats a little, so a few matches land on look-alike cells)
    assert len(m) > 100 and np.mean(dist3 < 0.05) > 0.85 and np.median(dist3) < 0.02


class _SameIndexMatcher:
    """Matches query feature i with view feature i (the views hold the query's points in order)."""

    def match_views(self, query, query_size, views, view_size, ratio=0.8):
        return [np.stack([np.arange(len(v)), np.arange(len(v))], 1) for v in views]


def _copies_map(points: np.ndarray, second: np.ndarray):
    """Feature table of two views: view 0 holds ``points``, view 1 ``second`` (same descriptors)."""
    from ldlmap.map.contents import MapFeatures

    n = len(points)
    return MapFeatures(backend="sift", view_centers=np.zeros((2, 3)), offsets=np.array([0, n, 2 * n]),
                       xyz=np.concatenate([points, second]).astype(np.float32),
                       keypoints=np.zeros((2 * n, 2), np.float32), scores=np.ones(2 * n, np.float32),
                       descriptors=np.zeros((2 * n, 8), np.uint8), translation_view=np.array([0, 1]))


@pytest.mark.parametrize("pnp_views", [5, 1])
def test_identical_copy_is_the_pnp_rival(pnp_views):
    """Two identical rooms 6 m apart: PnP on either copy's view explains all the query's features, so
    the kept pose has a rival with as many inliers (also when only one view is tried by default: one
    more view of a distinct candidate is tried); a second view of unrelated points gives no rival."""
    from ldlmap.features import Features
    from ldlloc.refine.features import RefineParams, refine_candidates

    P, _ = _room(300, seed=3)
    R0 = geo.rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.7)
    c0 = np.array([2.0, 1.5, 1.4])
    W, H = 1024, 512
    query = Features(geo.project_to_pixels(P, R0, c0, W, H).astype(np.float32), np.ones(len(P), np.float32),
                     np.zeros((len(P), 8), np.uint8))
    shift = np.array([6.0, 0.0, 0.0])
    rotations = np.stack([R0, R0])
    centers = np.stack([c0 + [0.1, 0.0, 0.0], c0 + shift])
    params = RefineParams(pnp_views=pnp_views)
    ref = refine_candidates(query, (W, H), rotations, centers, np.array([0, 1]), _copies_map(P, P + shift),
                            _SameIndexMatcher(), params)
    assert ref.refined and ref.num_inliers >= 290
    assert ref.rival_inliers >= 0.95 * ref.num_inliers
    # the kept pose is one copy's, the rival the other's
    pair = sorted([ref.center[0], ref.rival_center[0]])
    assert np.allclose(pair, [c0[0], c0[0] + 6.0], atol=0.01)

    rng = np.random.default_rng(5)
    ref = refine_candidates(query, (W, H), rotations, centers, np.array([0, 1]),
                            _copies_map(P, rng.random(P.shape) * [5, 4, 2.6]), _SameIndexMatcher(), params)
    assert ref.refined and np.allclose(ref.center, c0, atol=0.01)
    assert ref.rival_inliers < 0.2 * ref.num_inliers
