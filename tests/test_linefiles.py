"""3D line file readers and writers (docs/formats.md, "3D line files")."""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.io.linefiles import (detect_txt_format, read_3dlinedetection_txt, read_line3dpp_obj,
                                 read_line3dpp_txt, read_lines, write_lines, write_lines_obj,
                                 write_lines_txt)


@pytest.fixture
def segs() -> np.ndarray:
    rng = np.random.default_rng(3)
    return rng.uniform(-5, 5, (7, 2, 3))


@pytest.mark.parametrize("ext", [".obj", ".txt"])
def test_round_trip(tmp_path, segs, ext):
    path = tmp_path / f"lines{ext}"
    write_lines(path, segs)
    back = read_lines(path)
    np.testing.assert_allclose(back, segs, atol=1e-6)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp leftovers


def test_empty_ours_round_trip(tmp_path):
    write_lines_txt(tmp_path / "e.txt", np.zeros((0, 2, 3)))
    assert read_lines(tmp_path / "e.txt").shape == (0, 2, 3)


def test_3dlinedetection_unsorted_ids_extra_columns(tmp_path):
    # Points along two lines, ids 7 and 2, interleaved, with an extra (color) column.
    rows = [
        "0 0 0 0.5 7",
        "1 0 0 0.5 2",
        "0 0 1 0.5 7",
        "1 1 0 0.5 2",
        "0 0 3 0.5 7",
        "1 4 0 0.5 2",
    ]
    path = tmp_path / "pcd_line.txt"
    path.write_text("\n".join(rows) + "\n")
    assert detect_txt_format(path) == "3dlinedetection"
    segs = read_lines(path)
    np.testing.assert_allclose(segs, [[[0, 0, 0], [0, 0, 3]], [[1, 0, 0], [1, 4, 0]]])
    np.testing.assert_allclose(read_3dlinedetection_txt(path), segs)


def test_line3dpp_txt(tmp_path):
    # Row 1: two segments, one observation; row 2: one segment, two observations.
    r1 = [2, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 1, 1, 1, 3, 5, 10.0, 20.0, 30.0, 40.0]
    r2 = [1, 2, 2, 2, 3, 3, 3, 2, 0, 1, 1, 2, 3, 4, 4, 0, 5, 6, 7, 8]
    path = tmp_path / "Line3D++.txt"
    path.write_text("\n".join(" ".join(str(v) for v in r) for r in (r1, r2)) + "\n")
    assert detect_txt_format(path) == "line3dpp"
    segs = read_lines(path)
    np.testing.assert_allclose(segs, [[[0, 0, 0], [1, 0, 0]], [[0, 1, 0], [0, 1, 1]], [[2, 2, 2], [3, 3, 3]]])
    np.testing.assert_allclose(read_line3dpp_txt(path), segs)


def test_line3dpp_obj_polyline_and_comments(tmp_path):
    path = tmp_path / "lines.obj"
    path.write_text("# Line3D++\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 1\nl 1 2 3\nl -1 -3\n")
    segs = read_line3dpp_obj(path)
    np.testing.assert_allclose(segs, [[[0, 0, 0], [1, 0, 0]], [[1, 0, 0], [1, 1, 0]], [[1, 1, 0], [0, 0, 0]]])


def test_writers_obj_format(tmp_path, segs):
    path = write_lines_obj(tmp_path / "x.obj", segs)
    text = path.read_text().splitlines()
    assert sum(t.startswith("v ") for t in text) == 2 * len(segs)
    assert [t for t in text if t.startswith("l ")][0] == "l 1 2"


@pytest.mark.parametrize("content, match", [
    ("", "empty"),
    ("# only a comment\n", "empty"),
    ("1 2 x 4\n", "non-numeric"),
    ("1 2 3 4\n1 2 3\n", "column counts"),
    ("1 2 nan 4\n", "NaN"),
    ("# ldl lines v1\n1 2 3 4 5\n", "columns"),
    ("1 2 3\n", "at least 4 columns"),
])
def test_bad_txt(tmp_path, content, match):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(InputError, match=match):
        read_lines(path)


def test_bad_inputs(tmp_path, segs):
    with pytest.raises(InputError, match="not found"):
        read_lines(tmp_path / "missing.txt")
    (tmp_path / "a.obj").write_text("v 0 0 0\nl 1 2\n")
    with pytest.raises(InputError, match="out of range"):
        read_lines(tmp_path / "a.obj")
    (tmp_path / "b.obj").write_text("v 0 0 0\n")
    with pytest.raises(InputError, match="no 'l' records"):
        read_lines(tmp_path / "b.obj")
    with pytest.raises(InputError, match="extension"):
        write_lines(tmp_path / "x.ply", segs)
    bad = segs.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        write_lines(tmp_path / "n.txt", bad)
    assert not (tmp_path / "n.txt").exists()
    with pytest.raises(InputError, match="shape"):
        write_lines(tmp_path / "s.txt", np.zeros((3, 3)))
