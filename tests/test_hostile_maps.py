"""Hostile maps: every dataset and attribute of a map corrupted in turn, flipped bits and
truncated files give one line ``error: ...`` and exit 1 from ``ldlmap info`` (and ``ldlloc
localize``), never a traceback or a silently wrong summary; maps written before checksums still read.
"""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlmap.cli import app
from ldlmap.map.mapfile import read_map, read_map_header, write_map
from tests._hostile import assert_clean_failure, snapshot
from tests.test_mapfile import make_map

runner = CliRunner()


def full_map():
    """The test map with every optional part: features, fields, visibility, coverage, a frame."""
    m = make_map()
    rng = np.random.default_rng(1)
    nt, g = len(m.translations), 4
    m.fields = {"distances": rng.uniform(0, np.pi, size=(nt, 3, g + 1, 2 * g)).astype(np.float16)}
    m.fields_attrs = {"kind": "equirect_nodes", "rows": g, "num_groups": 3, "version": 1}
    m.visibility = rng.random((nt, len(m.lines))) > 0.3
    m.coverage = rng.random((nt, g + 1, 2 * g)) > 0.2
    m.input_to_map = np.diag([2.0, 2.0, 2.0, 1.0])
    m.config["orthonormal_directions"] = True
    return m


@pytest.fixture(scope="module")
def good_map(tmp_path_factory):
    return write_map(tmp_path_factory.mktemp("good") / "room.h5", full_map())


def _set(path: str, value):
    """Replace dataset ``path`` by ``value`` (any shape or dtype)."""
    def edit(h5):
        del h5[path]
        h5[path] = value
    return edit


def _set_attr(obj: str, key: str, value):
    def edit(h5):
        h5[obj].attrs[key] = value
    return edit


def _del_attr(obj: str, key: str):
    def edit(h5):
        del h5[obj].attrs[key]
    return edit


def _del(path: str):
    def edit(h5):
        del h5[path]
    return edit


def _values(path: str, change):
    """Dataset ``path`` replaced by ``change(its array)`` (same dtype unless ``change`` says otherwise)."""
    def edit(h5):
        a = h5[path][()]
        del h5[path]
        h5[path] = change(a.copy())
    return edit


def _nan_at(a):
    a = a.astype(np.float64)
    a.flat[min(3, a.size - 1)] = np.nan
    return a


def _as_group(path: str):
    def edit(h5):
        del h5[path]
        h5.create_group(path)
    return edit


_REQUIRED = ["cloud/bounds_min", "cloud/bounds_max", "lines/raw", "lines/segments", "lines/groups",
             "principal/directions", "translations/centers", "features/view_centers", "features/offsets",
             "features/xyz", "features/keypoints", "features/scores", "features/descriptors",
             "translations/view_index"]
_FLOAT_SETS = ["cloud/bounds_min", "cloud/points", "lines/raw", "lines/segments", "principal/directions",
               "translations/centers", "frame/input_to_map", "features/view_centers", "features/xyz",
               "features/keypoints", "features/scores", "fields/distances"]

# (case id, edit of the file, words the error line must hold)
CASES = [
    *[(f"missing-{p}", _del(p), "missing") for p in _REQUIRED],
    *[(f"nan-{p}", _values(p, _nan_at), "nan") for p in _FLOAT_SETS],
    *[(f"text-{p}", _set(p, np.array([b"x"] * 3)), "dtype") for p in ("lines/segments", "translations/centers",
                                                                       "lines/groups", "features/descriptors")],
    *[(f"shape-{p}", _values(p, lambda a: a.reshape(-1)), "shape") for p in
      ("lines/segments", "cloud/points", "features/xyz", "principal/directions", "fields/distances",
       "coverage/mapped", "lines/visibility")],
    ("short-groups", _values("lines/groups", lambda a: a[:-2]), "shape"),
    ("short-colors", _values("cloud/colors", lambda a: a[:-1]), "shape"),
    ("short-view-index", _values("translations/view_index", lambda a: a[:-1]), "shape"),
    ("group-label-7", _values("lines/groups", lambda a: np.full_like(a, 7)), "-1..2"),
    ("principal-not-unit", _values("principal/directions", lambda a: a * 1.5), "unit"),
    ("principal-repeated", _values("principal/directions", lambda a: a[[0, 0, 1]]), "distinct"),
    ("principal-left-handed", _values("principal/directions", lambda a: a[[1, 0, 2]]), "right-handed"),
    ("no-translations", _set("translations/centers", np.zeros((0, 3), np.float32)), "shape"),
    ("bounds-swapped", _values("cloud/bounds_min", lambda a: a + 100), "bounds"),
    ("offsets-decreasing", _values("features/offsets", lambda a: a[::-1].copy()), "offsets"),
    ("view-index-range", _values("translations/view_index", lambda a: a + 50), "translation_view"),
    ("keypoints-outside", _values("features/keypoints", lambda a: a + 5000), "outside"),
    ("frame-not-similarity", _set("frame/input_to_map", np.arange(16.0).reshape(4, 4)), "similarity"),
    ("fields-negative", _values("fields/distances", lambda a: -a.astype(np.float16) - 1), "[0, pi]"),
    ("fields-quantum-negative", _set_attr("fields", "distance_quantum", -0.1), "distance_quantum"),
    ("fields-quantum-missing", _del_attr("fields", "distance_quantum"), "distance_quantum"),
    ("segments-a-group", _as_group("lines/segments"), "not a dataset"),
    ("no-format-version", _del_attr("/", "format_version"), "format_version"),
    ("format-version-text", _set_attr("/", "format_version", "1"), "integer"),
    ("format-version-float", _set_attr("/", "format_version", 1.5), "integer"),
    ("format-version-array", _set_attr("/", "format_version", np.array([1, 1])), "integer"),
    ("format-version-newer", _set_attr("/", "format_version", 99), "newer"),
    ("format-version-older", _set_attr("/", "format_version", 0), "older"),
    ("name-numbers", _set_attr("/", "name", np.arange(3)), "text"),
    ("config-not-json", _set_attr("/", "build_config", "{oops"), "json"),
    ("config-a-list", _set_attr("/", "build_config", "[1, 2]"), "json"),
    ("kept-ratio-missing", _del_attr("lines", "kept_ratio"), "kept_ratio"),
    ("kept-ratio-text", _set_attr("lines", "kept_ratio", "most"), "kept_ratio"),
    ("kept-ratio-2", _set_attr("lines", "kept_ratio", 2.0), "kept_ratio"),
    ("threshold-nan", _set_attr("lines", "length_threshold", np.nan), "length_threshold"),
    ("threshold-negative", _set_attr("lines", "length_threshold", -1.0), "length_threshold"),
    ("lambda-inf", _set_attr("lines", "lambda", np.inf), "lambda"),
    ("backend-missing", _del_attr("features", "backend"), "backend"),
    ("width-negative", _set_attr("features", "width", -5), "width"),
    ("height-text", _set_attr("features", "height", "tall"), "height"),
    ("descriptor-dim", _set_attr("features", "descriptor_dim", 7), "descriptor_dim"),
    ("fields-rows", _set_attr("fields", "rows", 9), "rows"),
]


def _corrupt(src, dst, edit, keep_checksums: bool):
    shutil.copy(src, dst)
    with h5py.File(dst, "a") as h5:
        edit(h5)
        if not keep_checksums and "checksums" in h5.attrs:
            del h5.attrs["checksums"]
    return dst


def _info_fails(tmp_path, path) -> str:
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["info", str(path)])
    return assert_clean_failure(res, tmp_path, before).lower()


@pytest.mark.parametrize("case,edit,words", CASES, ids=[c[0] for c in CASES])
def test_corrupt_map_is_one_line(tmp_path, good_map, case, edit, words):
    """The validation layer names the problem (checksums removed, as in a map of an older writer);
    with the checksums kept, the same edit is caught too (by them or by the layer)."""
    line = _info_fails(tmp_path, _corrupt(good_map, tmp_path / "bare.h5", edit, keep_checksums=False))
    assert words.lower() in line, line
    line = _info_fails(tmp_path, _corrupt(good_map, tmp_path / "sealed.h5", edit, keep_checksums=True))
    assert "bare.h5" not in line


def test_good_map_reads_and_info_says_verified(tmp_path, good_map):
    res = runner.invoke(app, ["info", str(good_map)])
    assert res.exit_code == 0, res.output
    assert "verified" in res.output
    m = read_map(good_map)
    assert m.fields["distances"].shape[1:] == (3, 5, 8) and read_map_header(good_map)["checksummed"]


def test_map_without_checksums_still_reads(tmp_path, good_map):
    """Maps written by format version 1 before checksums existed stay readable (unverified)."""
    p = _corrupt(good_map, tmp_path / "old.h5", lambda h5: None, keep_checksums=False)
    res = runner.invoke(app, ["info", str(p)])
    assert res.exit_code == 0 and "written before checksums" in res.output, res.output
    np.testing.assert_array_equal(read_map(p).lines, read_map(good_map).lines)


SILENT_EDITS = [  # values that pass every range check: only the checksums can tell
    ("segment-moved", _values("lines/segments", lambda a: a + np.float32(0.001)), "lines/segments"),
    ("translation-moved", _values("translations/centers", lambda a: a[::-1].copy()), "translations/centers"),
    ("descriptor-changed", _values("features/descriptors", lambda a: a ^ np.uint8(1)), "features/descriptors"),
    ("name-changed", _set_attr("/", "name", "other"), "attributes"),
    ("dataset-added", lambda h5: h5.create_dataset("extra", data=np.arange(3)), "extra"),
    ("checksums-garbled", _set_attr("/", "checksums", "{not json"), "checksums"),
]


@pytest.mark.parametrize("case,edit,words", SILENT_EDITS, ids=[c[0] for c in SILENT_EDITS])
def test_checksums_catch_plausible_edits(tmp_path, good_map, case, edit, words):
    line = _info_fails(tmp_path, _corrupt(good_map, tmp_path / "m.h5", edit, keep_checksums=True))
    assert words in line and ("checksum" in line), line


def _flip_positions(size: int, count: int, seed: int = 0) -> list[int]:
    return sorted(np.random.default_rng(seed).choice(size * 8, size=count, replace=False).tolist())


FLIPS = 60


def test_flipped_bits_never_pass_silently(tmp_path, good_map):
    """Single bit flips spread over the file: each one fails with one line, or (a flip in unused
    bytes) reads back exactly the original map. None gives a traceback or a changed map."""
    original = good_map.read_bytes()
    ref = read_map(good_map)
    caught = 0
    for bit in _flip_positions(len(original), FLIPS):
        data = bytearray(original)
        data[bit // 8] ^= 1 << (bit % 8)
        p = tmp_path / "flip.h5"
        p.write_bytes(bytes(data))
        res = runner.invoke(app, ["info", str(p)])
        assert res.exit_code in (0, 1) and "Traceback" not in res.output, (bit, res.output)
        if res.exit_code == 1:
            caught += 1
            assert len(res.output.strip().splitlines()) == 1, (bit, res.output)
            continue
        m = read_map(p)
        for a, b in ((m.lines, ref.lines), (m.translations, ref.translations), (m.features.xyz, ref.features.xyz),
                     (m.fields["distances"], ref.fields["distances"])):
            np.testing.assert_array_equal(a, b)
        assert m.name == ref.name and m.config == ref.config
    assert caught > 0


def _storage_ranges(path) -> list[tuple[str, int, int]]:
    """(dataset, first byte, byte count) of every dataset's stored data (contiguous or first chunk)."""
    out = []
    with h5py.File(path, "r") as h5:
        def visit(name, obj):
            if not isinstance(obj, h5py.Dataset):
                return
            if obj.chunks is None:
                out.append((name, obj.id.get_offset(), obj.id.get_storage_size()))
            else:
                info = obj.id.get_chunk_info(0)
                out.append((name, info.byte_offset, info.size))
        h5.visititems(visit)
    return out


def test_a_flipped_bit_in_any_dataset_is_caught(tmp_path, good_map):
    """One bit flipped in the middle of each dataset's stored bytes (compressed or not): exit 1."""
    original = good_map.read_bytes()
    ranges = _storage_ranges(good_map)
    assert len(ranges) >= 20
    for name, start, size in ranges:
        data = bytearray(original)
        data[start + size // 2] ^= 0x10
        p = tmp_path / "flip.h5"
        p.write_bytes(bytes(data))
        res = runner.invoke(app, ["info", str(p)])
        assert res.exit_code == 1 and len(res.output.strip().splitlines()) == 1, (name, res.output)


@pytest.mark.parametrize("fraction", [0.0, 0.01, 0.1, 0.5, 0.9, 0.999])
def test_truncated_map_is_one_line(tmp_path, good_map, fraction):
    data = good_map.read_bytes()
    p = tmp_path / "cut.h5"
    p.write_bytes(data[: int(len(data) * fraction)])
    _info_fails(tmp_path, p)


def test_localize_refuses_a_corrupt_map_in_one_line(tmp_path, good_map):
    """``ldlloc localize`` reads maps through the same layer."""
    import cv2

    from ldlloc.cli import app as loc_app

    pano = tmp_path / "q.png"
    cv2.imwrite(str(pano), np.full((64, 128, 3), 128, np.uint8))
    p = _corrupt(good_map, tmp_path / "m.h5", _values("lines/segments", _nan_at), keep_checksums=False)
    before = snapshot(tmp_path)
    res = runner.invoke(loc_app, ["localize", str(p), str(pano)])
    line = assert_clean_failure(res, tmp_path, before)
    assert "nan" in line.lower(), line


def test_huge_dataset_claim_is_refused_before_reading(tmp_path, good_map):
    """A dataset whose declared size could not come from its file (a corrupted dimension) is
    refused with an estimate, not allocated."""
    p = tmp_path / "big.h5"
    shutil.copy(good_map, p)
    with h5py.File(p, "a") as h5:
        h5.create_dataset("cloud/huge", shape=(1 << 40,), dtype=np.float64, chunks=(1 << 16,),
                          compression="gzip", fillvalue=0.0)
    line = _info_fails(tmp_path, p)
    assert "claims" in line, line


def test_checksums_are_json_of_every_dataset(good_map):
    with h5py.File(good_map, "r") as h5:
        sums = json.loads(h5.attrs["checksums"])
        names = []
        h5.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
    assert sorted(sums["datasets"]) == sorted(names) and isinstance(sums["attrs"], int)


# ----------------------------------------------------------------- coordinate origin and unit


@pytest.fixture(scope="module")
def room_cloud():
    """A small box room centred on the origin with colours from its normals (edges show in renders)."""
    import open3d as o3d

    from tests._room_cloud import box_room

    P, _ = box_room(seed=0, density=800, size=(5.0, 4.0, 2.6))
    P = P - np.round(np.median(P, axis=0))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
    return P, (60 + 180 * np.abs(np.asarray(pc.normals))).astype(np.uint8)


UTM = np.array([512345.0, 4123456.0, 12.0])  # easting, northing, height: float32 spacing 0.25-0.5 m there


@pytest.mark.xdist_group("hostile_maps")  # one worker makes ``room_cloud``
def test_utm_scan_localizes_like_the_same_scan_at_the_origin(tmp_path, room_cloud):
    """The map of a scan in UTM coordinates is recentred (float32 storage would snap it to
    0.25-0.5 m); its poses, given in the input frame, match the un-offset map's within 1 cm."""
    from ldlloc.pipeline import Localizer, LocalizeParams
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.core.frame import apply, invert
    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.pointcloud import write_point_cloud
    from ldlmap.map.render import PointRenderer, RenderParams

    P, colors = room_cloud
    params = BuildParams().replaced(features="none", num_translations=100, distance_fields=False)
    maps = {}
    for name, X in (("plain", P), ("utm", P + UTM)):
        write_point_cloud(tmp_path / f"{name}.ply", PointCloud(X, colors))
        report = build_map(tmp_path / f"{name}.ply", tmp_path / f"{name}.h5", params=params)
        maps[name] = read_map(report.path)
    assert "centred on (512345, 4123456, 12)" in report.notes[0]
    plain, utm = maps["plain"], maps["utm"]
    assert np.abs(utm.lines).max() < 10  # stored near the origin
    back = invert(utm.input_to_map)
    # Line extraction sees the same points up to float64 rounding (1e-9 m): a borderline piece or
    # two may differ, the candidate translations do not.
    assert abs(len(utm.lines) - len(plain.lines)) <= 0.05 * len(plain.lines)
    np.testing.assert_allclose(apply(back, utm.translations) - UTM, plain.translations, atol=1e-3)
    true_center = np.array([0.3, -0.4, -0.1])
    img = PointRenderer(P, colors, RenderParams(width=512, height=256)).render(
        rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.4), true_center).rgb
    a = Localizer(plain, LocalizeParams()).localize(img)
    b = Localizer(utm, LocalizeParams()).localize(img)
    rot_b, center_b = b.input_frame_pose()
    assert np.linalg.norm(center_b - UTM - a.center) < 0.01
    assert np.degrees(np.arccos(np.clip((np.trace(rot_b.T @ a.rot_cam_from_world) - 1) / 2, -1, 1))) < 0.1
    assert np.linalg.norm(a.center - true_center) < 0.1  # and it localizes at all


@pytest.mark.xdist_group("hostile_maps")  # one worker makes ``room_cloud``
@pytest.mark.parametrize("factor,words", [(1000.0, "--scale 0.001"), (2e6, "--scale s")])
def test_scan_in_another_unit_is_refused_in_one_line(tmp_path, room_cloud, factor, words):
    """Millimetres (or a x2e6 scene that used to exhaust 24 GB): one line naming --scale, before
    any grid is allocated, and no map left behind."""
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.pointcloud import write_point_cloud

    P, colors = room_cloud
    write_point_cloud(tmp_path / "mm.ply", PointCloud(P[::10] * factor, colors[::10]))
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["build", str(tmp_path / "mm.ply"), "-o", str(tmp_path / "mm.h5"), "--features", "none"])
    line = assert_clean_failure(res, tmp_path, before).lower()
    assert words in line and "millimetres" in line, line


def test_lattice_that_would_exhaust_memory_is_refused_with_an_estimate(tmp_path):
    """A lines-only map with a tiny --trans-spacing: the lattice size is estimated first."""
    from ldlmap.io.linefiles import write_lines_txt

    rng = np.random.default_rng(0)
    a = rng.uniform(0, 400, size=(40, 3))  # 400 m: large, yet metres (not refused as millimetres)
    segs = np.stack([a, a + np.eye(3)[np.arange(40) % 3] * 150], axis=1)
    write_lines_txt(tmp_path / "l.txt", segs)
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["build", str(tmp_path / "l.txt"), "-o", str(tmp_path / "l.h5"),
                              "--trans-spacing", "0.001"])
    line = assert_clean_failure(res, tmp_path, before)
    assert "GiB" in line and "--trans-spacing" in line, line
