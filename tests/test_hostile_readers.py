"""Hostile scans and line files: malformed clouds, meshes, line files, COLMAP models and
ZInD homes give one line ``error: ...`` and exit 1 from ``ldlmap build`` (no map, no temporary file
left behind), or an :class:`InputError` from the reader; our own ``.txt`` line format is accepted.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlmap.cli import app
from ldlmap.core.errors import InputError
from tests._hostile import assert_clean_failure, snapshot

runner = CliRunner()


def _ply(count, rows: int = 5, fmt: str = "binary_little_endian", faces: str = "") -> bytes:
    head = (f"ply\nformat {fmt} 1.0\nelement vertex {count}\nproperty float x\nproperty float y\n"
            f"property float z\n{faces}end_header\n").encode()
    if fmt == "ascii":
        return head + "".join(f"{i} {i + 1} {i + 2}\n" for i in range(rows)).encode()
    return head + np.arange(rows * 3, dtype="<f4").tobytes()


_NAN_PLY = _ply(2, 0) + np.array([0, 1, 2, np.nan, 0, 0], "<f4").tobytes()
_NEG_FACES = "element face -1\nproperty list uchar int vertex_indices\n"

# (case id, file name, bytes, words the error line must hold)
CLOUDS = [
    ("ply-negative-count", "s.ply", _ply(-1), "negative count"),
    ("ply-negative-ascii", "s.ply", _ply(-2, fmt="ascii"), "negative count"),
    ("ply-negative-faces", "s.ply", _ply(3, 3, "ascii", _NEG_FACES), "negative count"),
    ("ply-huge-count", "s.ply", _ply(10 ** 15), "declares"),
    ("ply-huge-ascii", "s.ply", _ply(10 ** 12, fmt="ascii"), "declares"),
    ("ply-huge-faces", "s.ply", _ply(3, 3, "ascii", "element face 99999999\nproperty list uchar int vi\n"), "declares"),
    ("ply-truncated", "s.ply", _ply(5)[:-7], "truncated"),
    ("ply-nan", "s.ply", _NAN_PLY, "nan"),
    ("ply-inf", "s.ply", _ply(1, 0) + np.array([np.inf, 0, 0], "<f4").tobytes(), "nan/inf"),
    ("ply-empty-cloud", "s.ply", _ply(0, 0), "empty"),
    ("ply-no-xyz", "s.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n", "x, y, z"),
    ("ply-no-end-header", "s.ply", b"ply\nformat ascii 1.0\n" + b"comment x\n" * 8000, "end_header"),
    ("ply-bad-type", "s.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n1\n", "header"),
    ("ply-bad-format", "s.ply", b"ply\nformat binary_middle_endian 1.0\nend_header\n", "format"),
    ("ply-empty-file", "s.ply", b"", "not a ply"),
    ("ply-garbage", "s.ply", os.urandom(4000), "not a ply"),
    ("txt-garbage", "s.txt", os.urandom(4000), ""),
    ("txt-empty", "s.txt", b"", "empty"),
    ("txt-comments-only", "s.txt", b"# nothing\n\n", "empty"),
    ("txt-4-columns", "s.txt", b"1 2 3 4\n5 6 7 8\n", ""),  # read as a 3DLineDetection file: too few lines
    ("txt-ragged", "s.txt", b"1 2 3\n4 5 6 7 8 9\n", "columns"),
    ("txt-nan", "s.txt", b"1 2 3\nnan 1 2\n", "nan"),
    ("txt-inf", "s.txt", b"1 2 3\n1 -inf 2\n", "nan"),
    ("txt-words", "s.txt", b"1 2 3\nx y z\n", "malformed"),
    ("txt-colours-300", "s.txt", b"1 2 3 300 0 0\n", ""),
    ("txt-utf16", "s.txt", "1 2 3\n4 5 6\n".encode("utf-16"), ""),
    ("txt-count-only", "s.txt", b"5\n", "columns"),
    ("pcd-garbage", "s.pcd", os.urandom(3000), "no points"),
    ("obj-garbage", "s.obj", os.urandom(3000), "mesh"),
    ("obj-empty", "s.obj", b"", "mesh"),
    ("obj-vertices-only", "s.obj", b"v 0 0 0\nv 1 0 0\n", "no faces"),
    ("obj-face-index-out-of-range", "s.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "faces"),
    ("obj-missing-mtllib", "s.obj", b"mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "gone.mtl"),
    ("ply-mesh-zero-area", "s.ply", _ply(3, 3, "ascii", "element face 1\nproperty list uchar int vertex_indices\n")
     .replace(b"0 1 2\n1 2 3\n2 3 4\n", b"0 0 0\n0 0 0\n0 0 0\n") + b"3 0 1 2\n", "area"),
    ("xyz-unsupported-suffix", "s.rcp", b"1 2 3\n", "unsupported"),
]

_HEADER = b"# ldl lines v1\n"
LINE_FILES = [
    ("ldl-nan", "l.txt", _HEADER + b"0 0 0 1 1 nan\n", "nan"),
    ("ldl-inf", "l.txt", _HEADER + b"0 0 0 1e400 1 1\n", "infinite"),
    ("ldl-5-columns", "l.txt", _HEADER + b"0 0 0 1 1\n", "columns"),
    ("ldl-words", "l.txt", _HEADER + b"0 0 0 a b c\n", "non-numeric"),
    ("txt-garbage", "l.txt", os.urandom(2000), ""),
    ("txt-empty", "l.txt", b"", "empty"),
    ("3dld-float-ids", "l.txt", b"0 0 0 1.5\n1 1 1 1.5\n", "integers"),
    ("3dld-huge-ids", "l.txt", b"0 0 0 1e30\n1 1 1 1e30\n", "integers"),
    ("3dld-ragged", "l.txt", b"0 0 0 1\n1 1 1 1 5\n", "column"),
    ("3dld-3-columns", "l.txt", b"0 0 0\n1 1 1\n", "columns"),
    ("line3dpp-short", "l.txt", b"2 0 0 0 1 1 1 0\n", ""),
    ("obj-garbage", "l.obj", os.urandom(2000), ""),
    ("obj-empty", "l.obj", b"", "empty"),
    ("obj-nan-vertex", "l.obj", b"v 0 0 0\nv nan 1 1\nl 1 2\n", "nan"),
    ("obj-index-range", "l.obj", b"v 0 0 0\nl 1 5\n", "range"),
    ("obj-index-zero", "l.obj", b"v 0 0 0\nv 1 1 1\nl 0 1\n", "range"),
    ("obj-no-lines", "l.obj", b"v 0 0 0\nv 1 1 1\n", "no 'l'"),
    ("obj-short-vertex", "l.obj", b"v 0 0\nv 1 1 1\nl 1 2\n", "3 coordinates"),
    ("unsupported-suffix", "l.ply3", b"0 0 0 1 1 1\n", "unsupported"),
]


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """A tiny valid scan, for the `--lines` cases."""
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.pointcloud import write_point_cloud

    p = tmp_path_factory.mktemp("scan") / "scan.ply"
    return write_point_cloud(p, PointCloud(np.random.default_rng(0).uniform(0, 4, (500, 3))))


def _build_fails(tmp_path, args) -> str:
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["build", *args, "-o", str(tmp_path / "out.h5"), "--features", "none"])
    return assert_clean_failure(res, tmp_path, before).lower()


@pytest.mark.parametrize("case,name,data,words", CLOUDS, ids=[c[0] for c in CLOUDS])
def test_bad_scan_is_one_line(tmp_path, case, name, data, words):
    (tmp_path / name).write_bytes(data)
    line = _build_fails(tmp_path, [str(tmp_path / name)])
    assert words.lower() in line, line


@pytest.mark.parametrize("case,name,data,words", LINE_FILES, ids=[c[0] for c in LINE_FILES])
def test_bad_line_file_is_one_line(tmp_path, scan, case, name, data, words):
    (tmp_path / name).write_bytes(data)
    line = _build_fails(tmp_path, [str(scan), "--lines", str(tmp_path / name)])
    assert words.lower() in line, line


def test_our_line_format_is_accepted_by_build(tmp_path):
    """`ldlmap lines` writes `# ldl lines v1` .txt files: `build --lines` and `build FILE` read them."""
    from ldlmap.map.inputs import load_input
    from ldlmap.io.linefiles import write_lines_txt

    segs = np.random.default_rng(0).uniform(0, 4, (12, 2, 3))
    p = write_lines_txt(tmp_path / "mine.txt", segs)
    (tmp_path / "scan.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in np.random.default_rng(1).uniform(0, 4, (50, 3))))
    with_scan = load_input(tmp_path / "scan.txt", p, mesh_samples=1000)
    alone = load_input(p, None, mesh_samples=1000)
    for src in (with_scan, alone):
        np.testing.assert_allclose(src.lines, segs, atol=1e-6)
    assert alone.points is None


# ------------------------------------------------------------------------------- COLMAP models


@pytest.fixture(scope="module")
def colmap_model(tmp_path_factory):
    from tests.test_io_colmap import _build_reconstruction

    rec = _build_reconstruction(np.random.default_rng(0))[0]
    model = tmp_path_factory.mktemp("colmap") / "sparse"
    model.mkdir()
    rec.write_binary(str(model))
    return model


COLMAP_EDITS = [(f"{what}-{name}", name, what) for name in ("cameras.bin", "images.bin", "points3D.bin")
                for what in ("missing", "empty", "half", "garbage")]


@pytest.mark.parametrize("case,name,what", COLMAP_EDITS, ids=[c[0] for c in COLMAP_EDITS])
def test_broken_colmap_model_is_an_input_error(tmp_path, colmap_model, case, name, what):
    import shutil

    from ldlmap.io.colmap import read_colmap_model

    model = tmp_path / "sparse"
    shutil.copytree(colmap_model, model)
    f = model / name
    data = f.read_bytes()
    if what == "missing":
        f.unlink()
    else:
        f.write_bytes({"empty": b"", "half": data[: len(data) // 2], "garbage": os.urandom(len(data))}[what])
    try:
        scene = read_colmap_model(model)
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    assert len(scene.points) and np.isfinite(scene.points.points).all()  # pycolmap read something valid


# --------------------------------------------------------------------------------- ZInD homes


def _key_paths(d, prefix=()):
    """Every key path of a nested JSON object (dicts and lists)."""
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else []
    for k, v in items:
        yield prefix + (k,)
        yield from _key_paths(v, prefix + (k,))


def _zind_cases():
    from tests.test_zind import tiny_home_json

    paths = [p for p in _key_paths(tiny_home_json()) if isinstance(p[-1], str)]
    return [(p, op) for p in paths for op in ("delete", "null", "text")]


ZIND_CASES = _zind_cases()


@pytest.mark.parametrize("path,op", ZIND_CASES, ids=["/".join(map(str, p)) + ":" + op for p, op in ZIND_CASES])
def test_zind_json_with_a_key_missing_or_mistyped(tmp_path, path, op):
    """Every key of the tiny home deleted, set to null or to a string: an InputError in one line, or
    (an optional key) a home that still reads."""
    from ldlmap.io.zind import read_zind_home
    from tests.test_zind import tiny_home_json, write_tiny_home

    data = tiny_home_json()
    node = data
    for k in path[:-1]:
        node = node[k]
    if op == "delete":
        del node[path[-1]]
    else:
        node[path[-1]] = None if op == "null" else "oops"
    home = write_tiny_home(tmp_path, text=json.dumps(data))
    try:
        read_zind_home(home)
    except InputError as exc:
        assert "\n" not in str(exc)
