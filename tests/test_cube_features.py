"""Features of panoramas from their cube faces (ldlmap.features.sphere.CubeFaces): keypoints lifted
back to the panorama's pixels, masks and budgets, the map's record of the extraction, and
localization with a cube-face map."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.features import backend_for, get_backend
from ldlmap.features.sphere import CubeFaces, for_panoramas
from tests._localize import assert_refined_by_features
from tests.test_features import _texture


def test_cube_keypoints_land_where_the_panoramas_own_are():
    """SIFT on the cube faces and on the whole panorama find the same corners: descriptor matches
    between the two sets sit within a pixel (faces of 128 px here)."""
    img = _texture(256, 512)
    b = get_backend("sift")
    cube, whole = CubeFaces(b).extract(img), b.extract(img)
    assert len(cube) > 300 and cube.descriptors.dtype == whole.descriptors.dtype
    assert cube.keypoints[:, 0].min() >= 0 and cube.keypoints[:, 0].max() < 512
    assert cube.keypoints[:, 1].min() >= 0 and cube.keypoints[:, 1].max() <= 256
    m = b.match(cube.descriptors, whole.descriptors, ratio=0.8)
    assert len(m) > 150
    d = np.linalg.norm(cube.keypoints[m[:, 0]] - whole.keypoints[m[:, 1]], axis=1)
    assert np.median(d) < 0.5 and np.mean(d < 1.5) > 0.8, np.median(d)


def test_cube_faces_respect_the_mask_and_the_budget():
    img = _texture(256, 512, seed=3)
    cb = CubeFaces(get_backend("sift"))
    mask = np.zeros(img.shape[:2], bool)
    mask[:, :256] = True
    f = cb.extract(img, mask=mask)
    assert len(f) > 50 and f.keypoints[:, 0].max() < 256 + 2.0
    all_f = cb.extract(img)
    top = cb.extract(img, max_keypoints=50)
    assert len(top) == 50 and np.all(np.diff(top.scores) <= 0)
    assert top.scores.min() >= np.sort(all_f.scores)[-50] - 1e-6
    # without a budget, the backend's for one image holds for the whole panorama, not for each face
    assert len(CubeFaces(get_backend("sift", max_keypoints=100)).extract(img)) == 100
    blank = cb.extract(np.full((256, 512, 3), 128, np.uint8))
    assert len(blank) == 0 and blank.descriptors.shape[1] == 128


def test_unknown_extraction_is_refused(tmp_path):
    from typer.testing import CliRunner

    from ldlmap.cli import app

    with pytest.raises(InputError, match="valid: equirect, cube"):
        for_panoramas(get_backend("sift"), "sphere")
    cloud = tmp_path / "c.txt"
    cloud.write_text("0 0 0 1 2 3\n")
    res = CliRunner().invoke(app, ["build", str(cloud), "--feature-extraction", "sphere"])
    assert res.exit_code == 1 and "valid: equirect, cube" in res.output


def test_cube_face_map_records_its_extraction_and_localizes(demo_dataset, tmp_path):
    """Map features of one demo room from cube faces (4 views): the map records the extraction,
    the localizer extracts the queries' features the same way, and a robot and two extreme queries
    end within 0.1 m / 5 deg, refined by features."""
    from ldlmap.map.build import BuildParams, compute_features
    from ldlmap.datasets import open_dataset
    from ldlmap.io.pointcloud import read_point_cloud
    from ldlmap.map.mapfile import read_map, read_map_header, write_map
    from ldlloc.pipeline import LocalizeParams, Localizer

    ds = open_dataset(demo_dataset, "omniscenes")
    scene = "synthroom_1"
    m = read_map(demo_dataset / "maps" / f"{scene}.h5", load_cloud=False)
    cloud = read_point_cloud(ds.point_cloud(scene))
    feats = compute_features(cloud.points, cloud.colors, m.translations,
                             BuildParams().replaced(features="sift", num_views=4, feature_extraction="cube"))
    assert feats.extraction == "cube"
    path = write_map(tmp_path / "cube.h5", replace(m, features=feats))
    assert read_map_header(path)["feature_extraction"] == "cube"
    cube_map = read_map(path, load_cloud=False)
    assert cube_map.features.extraction == "cube"
    loc = Localizer(cube_map, LocalizeParams())
    assert isinstance(loc.backend, CubeFaces) and loc.feature_backend == "sift"
    assert not isinstance(backend_for("sift"), CubeFaces)
    assert_refined_by_features(loc, ds, scene)
    with pytest.raises(InputError, match="extraction 'sphere'"):  # an extraction this version does not know
        write_map(tmp_path / "bad.h5", replace(m, features=replace(feats, extraction="sphere")))
    assert not (tmp_path / "bad.h5").exists()


def test_query_frames_split_candidates_by_their_up_axis():
    """Candidates that differ by a yaw share the best one's frame (a yaw only rolls the panorama);
    a flipped or tipped Manhattan twin gets its own, up to the bound, and each candidate joins the
    frame nearest its up axis."""
    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlloc.pipeline import query_frame_groups

    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    tilt = rotation_from_axis_angle(np.array([1.0, 2.0, 0.5]), np.radians(30.0))
    yaw = [tilt @ rotation_from_axis_angle(z, np.radians(a)) for a in (0.0, 90.0, 180.0)]
    flip = [tilt @ rotation_from_axis_angle(x, np.pi) @ rotation_from_axis_angle(z, np.radians(a)) for a in (0.0, 90.0)]
    tip = tilt @ rotation_from_axis_angle(x, np.pi / 2)
    R = np.stack([yaw[0], yaw[1], flip[0], yaw[2], tip, flip[1]])
    groups = query_frame_groups(R, max_frames=3, split_deg=45.0)
    assert [g[1].tolist() for g in groups] == [[0, 1, 3], [2, 5], [4]]
    np.testing.assert_array_equal(groups[1][0], R[2])
    two = query_frame_groups(R, max_frames=2)
    assert [g[1].tolist() for g in two] == [[0, 1, 3, 4], [2, 5]] or [g[1].tolist() for g in two] == [[0, 1, 3], [2, 4, 5]]
    one = query_frame_groups(R, max_frames=1)
    assert len(one) == 1 and one[0][1].tolist() == list(range(6))
