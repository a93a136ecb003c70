"""HDF5 map schema: round trip, validation, versions, corrupt files, atomic writes."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from ldlmap.core.errors import FormatVersionError, InputError
from ldlmap.map.mapfile import FORMAT_VERSION, read_map, read_map_header, write_map
from ldlmap.map.contents import LdlMap, MapFeatures


def make_map(with_features: bool = True, seed: int = 0) -> LdlMap:
    rng = np.random.default_rng(seed)
    lines = rng.uniform(0, 4, size=(30, 2, 3))
    feats = None
    nt = 12
    if with_features:
        counts = np.array([5, 0, 7])
        k = counts.sum()
        feats = MapFeatures(
            backend="sift",
            view_centers=rng.uniform(0, 4, size=(3, 3)),
            offsets=np.concatenate([[0], np.cumsum(counts)]),
            xyz=rng.uniform(0, 4, size=(k, 3)).astype(np.float32),
            keypoints=rng.uniform(0, 512, size=(k, 2)).astype(np.float32),
            scores=rng.uniform(size=k).astype(np.float16),
            descriptors=rng.integers(0, 255, size=(k, 128), dtype=np.uint8),
            translation_view=rng.integers(0, 3, size=nt).astype(np.int32),
        )
    return LdlMap(
        name="room_1",
        bounds_min=np.zeros(3),
        bounds_max=np.array([4.0, 4.0, 2.5]),
        lines_raw=np.concatenate([lines, lines[:5] * 0.1]),
        lines=lines,
        line_groups=rng.integers(-1, 3, size=30),
        length_threshold=0.35,
        kept_ratio=30 / 35,
        principal_directions=np.eye(3),
        translations=rng.uniform(0, 4, size=(nt, 3)),
        cloud_points=rng.uniform(0, 4, size=(100, 3)),
        cloud_colors=rng.integers(0, 255, size=(100, 3), dtype=np.uint8),
        features=feats,
        config={"lambda": 0.1, "features": "sift"},
    )


def test_round_trip(tmp_path):
    m = make_map()
    p = write_map(tmp_path / "room_1.h5", m)
    r = read_map(p)
    np.testing.assert_allclose(r.lines, m.lines, atol=1e-5)
    np.testing.assert_array_equal(r.line_groups, m.line_groups)
    np.testing.assert_allclose(r.translations, m.translations, atol=1e-5)
    assert r.features.backend == "sift"
    assert r.features.descriptors.dtype == np.uint8
    np.testing.assert_array_equal(r.features.descriptors, m.features.descriptors)
    s = r.features.view_slice(2)
    np.testing.assert_allclose(r.features.xyz[s], m.features.xyz[5:12])
    assert r.features.view_slice(1) == slice(5, 5)
    assert r.kept_ratio == pytest.approx(30 / 35)
    assert r.config["features"] == "sift"
    info = read_map_header(p)
    assert info["num_lines"] == 30 and info["num_lines_raw"] == 35 and info["feature_backend"] == "sift"
    # Only the target file remains: no temporary leftovers.
    assert [x.name for x in tmp_path.iterdir()] == ["room_1.h5"]


def test_lines_only_map(tmp_path):
    m = make_map(with_features=False)
    m.cloud_points = m.cloud_colors = None
    r = read_map(write_map(tmp_path / "l.h5", m))
    assert r.lines_only and r.cloud_points is None


def test_superpoint_descriptors_stored_as_float16(tmp_path):
    m = make_map()
    m.features.backend = "superpoint"
    m.features.descriptors = np.random.default_rng(0).normal(size=(12, 256)).astype(np.float32)
    r = read_map(write_map(tmp_path / "sp.h5", m))
    assert r.features.descriptors.dtype == np.float16


def test_invalid_map_is_not_written(tmp_path):
    m = make_map()
    m.lines[3, 0, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        write_map(tmp_path / "bad.h5", m)
    assert not any(tmp_path.iterdir())
    m = make_map()
    m.translations = m.translations[:, :2]
    with pytest.raises(InputError, match="translations"):
        write_map(tmp_path / "bad.h5", m)
    assert not any(tmp_path.iterdir())


def test_other_format_version_is_rejected(tmp_path):
    p = write_map(tmp_path / "m.h5", make_map())
    with h5py.File(p, "a") as h5:
        h5.attrs["format_version"] = FORMAT_VERSION + 1
    with pytest.raises(FormatVersionError, match="newer"):
        read_map(p)


def test_corrupt_and_missing_files(tmp_path):
    bad = tmp_path / "corrupt.h5"
    bad.write_bytes(b"this is not hdf5" * 10)
    with pytest.raises(InputError, match="not a readable HDF5"):
        read_map(bad)
    with pytest.raises(InputError, match="not found"):
        read_map(tmp_path / "missing.h5")
    p = write_map(tmp_path / "m.h5", make_map())
    with h5py.File(p, "a") as h5:
        del h5["lines/segments"]
    with pytest.raises(InputError, match="corrupt"):
        read_map(p)


def test_optional_input_frame_transform(tmp_path):
    """``/frame/input_to_map`` (SfM maps) is optional: maps without it read as the identity (None)."""
    from ldlmap.core.frame import similarity
    from ldlmap.core.geometry import rotation_from_axis_angle

    m = make_map(with_features=False)
    assert read_map(write_map(tmp_path / "plain.h5", m)).input_to_map is None
    assert read_map_header(tmp_path / "plain.h5")["input_to_map"] is None
    A = similarity(0.37, rotation_from_axis_angle(np.array([1.0, 2.0, 3.0]), 1.2), [1.0, -2.0, 0.5])
    m.input_to_map = A
    r = read_map(write_map(tmp_path / "sfm.h5", m))
    np.testing.assert_allclose(r.input_to_map, A)
    np.testing.assert_allclose(read_map_header(tmp_path / "sfm.h5")["input_to_map"], A)
    with h5py.File(tmp_path / "sfm.h5", "r") as h5:
        assert h5.attrs["format_version"] == 1  # still version 1 (3 principal directions)
    for bad in (np.eye(3), np.diag([1.0, 1.0, 2.0, 1.0]), np.diag([-1.0, 1.0, 1.0, 1.0])):
        m.input_to_map = bad
        with pytest.raises(InputError):
            write_map(tmp_path / "bad.h5", m)
    assert not (tmp_path / "bad.h5").exists()


def test_camera_height_band_round_trips(tmp_path):
    """The build records the camera-height band of lines-only maps; the geometric refinement reads
    it back (LdlMap.camera_height_band); maps without one, or with a malformed one, give None."""
    m = make_map(with_features=False)
    assert m.camera_height_band is None
    m.config = {"translations": {"method": "spacing", "camera_height": [1.2, 1.6]}}
    assert read_map(write_map(tmp_path / "band.h5", m)).camera_height_band == (1.2, 1.6)
    for bad in (None, [1.6, 1.2], [1.2], ["a", "b"], [float("nan"), 1.0], 3.0):
        m.config = {"translations": {"camera_height": bad}}
        assert m.camera_height_band is None


@pytest.mark.parametrize("config, valid", [
    ({"principal_frame": "atlanta", "orthonormal_directions": True}, True),
    ({"principal_frame": "manhattan", "orthonormal_directions": True}, False),
    ({"orthonormal_directions": True}, False),  # maps from before principal_frame: Manhattan
    ({}, True),  # maps from before the Manhattan frame: directions as voted
])
def test_only_manhattan_frames_must_be_orthonormal(tmp_path, config, valid):
    """An Atlanta frame (vertical and two horizontals 45 deg apart) is a valid map's
    frame; a map that says Manhattan (or an older map that says orthonormal) must be orthonormal."""
    from dataclasses import replace

    s = np.sqrt(0.5)
    m = replace(make_map(with_features=False), principal_directions=np.array([[0, 0, 1.0], [1.0, 0, 0], [s, s, 0]]),
                config={"lambda": 0.1, "features": "none", **config})
    if valid:
        p = write_map(tmp_path / "a.h5", m)
        np.testing.assert_allclose(read_map(p).principal_directions, m.principal_directions, atol=1e-9)
        assert read_map_header(p)["principal_directions"].shape == (3, 3)
    else:
        with pytest.raises(InputError, match="orthonormal"):
            write_map(tmp_path / "a.h5", m)
        assert not (tmp_path / "a.h5").exists()


def test_build_params_config_keeps_the_stored_keys_and_order():
    """The map's config stores the build parameters flat, with the keys (and order) maps were written with
    before the parameters were grouped per stage, so that `prepare` still finds those maps up to date."""
    from ldlmap.map.params import BuildParams

    keys = ["lam", "min_line_length", "num_translations", "translation_method", "clearance", "features", "weights",
            "num_views", "width", "height", "max_keypoints", "feature_extraction", "stored_cloud_points",
            "mesh_samples", "device", "seed", "distance_fields", "trans_spacing", "camera_height", "up", "scale",
            "min_kept_lines", "min_kept_length_share", "max_kept_lines", "orthonormal_directions", "atlanta_frame",
            "max_horizontals", "max_inclined", "stations"]
    params = BuildParams().replaced(features="none", trans_spacing=0.7, camera_height=(1.0, 2.0), atlanta_frame=False)
    assert list(params.config()) == keys
    assert params.features.backend == "none" and params.translations.spacing == 0.7 and not params.principal.atlanta
    assert BuildParams().replaced(**params.config()) == params
    with pytest.raises(TypeError, match="config key"):
        BuildParams().replaced(spacing=1.0)


def test_optional_footprint_round_trips_and_must_be_whole(tmp_path):
    """``/free_space`` (a scan's footprint: where a walk may step) is optional: maps without it read None;
    one of its two datasets without the other, or a cell of no size, fails in one line."""
    from ldlmap.map.contents import Footprint

    m = make_map(with_features=False)
    assert read_map(write_map(tmp_path / "plain.h5", m)).footprint is None
    mask = np.zeros((7, 5), bool)
    mask[1:6, 1:4] = True
    m.footprint = Footprint(mask, np.array([-0.5, 0.25]), 0.3)
    r = read_map(write_map(tmp_path / "walls.h5", m))
    np.testing.assert_array_equal(r.footprint.mask, mask)
    np.testing.assert_allclose(r.footprint.origin, [-0.5, 0.25])
    assert r.footprint.cell == pytest.approx(0.3)
    assert r.footprint.free_at(np.array([[-0.5 + 0.45, 0.25 + 0.45], [-0.4, 0.3], [9.0, 9.0]])).tolist() == [True, False, False]
    with h5py.File(tmp_path / "walls.h5", "r") as h5:
        assert h5.attrs["format_version"] == 1  # readers that predate it still read the map
    with h5py.File(tmp_path / "walls.h5", "a") as h5:
        del h5["free_space/grid"]
    with pytest.raises(InputError, match="free_space/grid is missing"):
        read_map(tmp_path / "walls.h5")
    m.footprint = Footprint(mask, np.array([0.0, 0.0]), 0.0)
    with pytest.raises(InputError, match="footprint.cell"):
        write_map(tmp_path / "bad.h5", m)
    assert not (tmp_path / "bad.h5").exists()
