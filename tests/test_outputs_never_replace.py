"""Outputs never replace or delete a user's files: `export --format colmap --overwrite` replaces the
model files only (never the folder), pictures (`localize --vis`, `run --save-vis`) replace only
pictures of ldlloc unless --overwrite, a picture is always inside --save-vis and one per query, and
`report --html` replaces only a page that begins as its pages do."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from tests._hostile import error_line, snapshot
from tests._results_files import record, write_panorama, write_results

runner = CliRunner()


def _invoke(args: list) -> object:
    return runner.invoke(loc_app, [str(a) for a in args])


def _ok(args: list) -> str:
    res = _invoke(args)
    assert res.exit_code == 0, res.output
    return res.output


@pytest.fixture
def results(tmp_path) -> Path:
    """A results file of two localized panoramas under ``tmp_path/shots``."""
    shots = [write_panorama(tmp_path / "shots" / f"p{i}.jpg") for i in range(2)]
    return write_results(tmp_path / "r.json", [record(f"p{i}", s, t=(i, 0.0, 1.5)) for i, s in enumerate(shots)])


# (case, the user's files in the output folder before the export: relative path -> bytes)
USER_FOLDERS = [
    ("notes and images", {"NOTES.txt": b"my notes", "images/a.jpg": b"\xff\xd8 a photo"}),
    ("a COLMAP workspace", {"images/a.jpg": b"\xff\xd8 a photo", "database.db": b"SQLite format 3\x00",
                            "sparse/0/cameras.bin": b"\x01\x00", "sparse/0/images.bin": b"\x02\x00"}),
    ("a maps folder", {"room.h5": b"\x89HDF\r\n\x1a\n an LDL map", "floor/room2.h5": b"\x89HDF\r\n\x1a\n"}),
    ("an earlier binary model", {"cameras.bin": b"old", "images.bin": b"old", "points3D.bin": b"old",
                                 "NOTES.txt": b"mine"}),
    ("an earlier text model", {"cameras.txt": b"# old", "images.txt": b"# old", "points3D.txt": b"# old",
                               "NOTES.txt": b"mine"}),
]


@pytest.mark.parametrize("files", [c[1] for c in USER_FOLDERS], ids=[c[0] for c in USER_FOLDERS])
def test_colmap_overwrite_replaces_only_model_files(results, tmp_path, files):
    out = tmp_path / "out"
    for rel, data in files.items():
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).write_bytes(data)
    model = {f"{n}{s}" for n in ("cameras", "images", "points3D", "rigs", "frames") for s in (".bin", ".txt")}
    user = {rel: data for rel, data in files.items() if rel not in model}
    assert "not empty" in error_line(_invoke(["export", results, "--format", "colmap", "-o", out]))
    said = _ok(["export", results, "--format", "colmap", "-o", out, "--overwrite"])
    for rel, data in user.items():  # every file of the user's is there, unchanged
        assert (out / rel).read_bytes() == data, rel
    earlier = sorted(rel for rel in files if rel in model)
    if earlier:
        assert "replaced the earlier model files" in said and all(name in said for name in earlier), said
    assert not any((out / rel).exists() for rel in earlier if rel.endswith(".txt"))  # the old text model is gone
    rec = pycolmap.Reconstruction(str(out))
    assert sorted(im.name for im in rec.images.values()) == ["p0.jpg", "p1.jpg"]
    assert not any(p.name.startswith(".out") for p in tmp_path.iterdir())  # no temporary left


@pytest.mark.parametrize("folder_named", ["cameras.bin", "points3D.bin"])
def test_colmap_overwrite_refuses_a_folder_named_as_a_model_file(results, tmp_path, folder_named):
    """Checked before anything is moved: the model goes in whole or not at all."""
    out = tmp_path / "out"
    (out / folder_named).mkdir(parents=True)
    (out / "images.bin").write_bytes(b"old")
    before = snapshot(tmp_path)
    line = error_line(_invoke(["export", results, "--format", "colmap", "-o", out, "--overwrite"]))
    assert f"{out / folder_named} is not a file" in line
    assert snapshot(tmp_path) == before


def test_colmap_export_into_the_workspace_of_its_own_images(tmp_path):
    """A model written beside the panoramas it names (a COLMAP workspace: ``ws/images``): allowed,
    the images untouched (only the folder holds them; no model file is one of them)."""
    shots = [write_panorama(tmp_path / "ws" / "images" / f"p{i}.jpg") for i in range(2)]
    results = write_results(tmp_path / "r.json", [record(f"p{i}", s) for i, s in enumerate(shots)])
    before = {p: p.read_bytes() for p in shots}
    _ok(["export", results, "--format", "colmap", "-o", tmp_path / "ws", "--overwrite",
         "--image-root", tmp_path / "ws" / "images"])
    assert {p: p.read_bytes() for p in shots} == before
    assert len(pycolmap.Reconstruction(str(tmp_path / "ws")).images) == 2


# ----------------------------------------------------------------------------- pictures


def test_own_pictures_are_recognized(tmp_path):
    from ldlmap.core.pictures import is_own_picture, write_picture

    img = np.zeros((32, 64, 3), np.uint8)
    for ext in (".jpg", ".jpeg", ".png"):
        assert is_own_picture(write_picture(tmp_path / f"ours{ext}", img))
        user = write_panorama(tmp_path / f"user{ext}") if ext != ".png" else tmp_path / "user.png"
        if ext == ".png":
            import cv2

            user.write_bytes(cv2.imencode(".png", img)[1].tobytes())
        assert not is_own_picture(user)
    assert not is_own_picture(write_picture(tmp_path / "ours.webp", img))  # no mark in other formats
    assert not is_own_picture(tmp_path / "none.jpg")


def test_localize_vis_refuses_a_users_picture(tmp_path):
    pano = write_panorama(tmp_path / "pano.jpg")
    holiday = write_panorama(tmp_path / "holiday.jpg", width=256)
    before = snapshot(tmp_path)
    line = error_line(_invoke(["localize", tmp_path / "no_map.h5", pano, "--vis", holiday]))
    assert "holiday.jpg exists and is not a picture of ldlloc" in line and "--overwrite" in line
    assert snapshot(tmp_path) == before
    # with --overwrite the picture may be replaced: the command goes on (and stops at the missing map)
    assert "map not found" in error_line(_invoke(["localize", tmp_path / "no_map.h5", pano, "--vis", holiday,
                                                  "--overwrite"]))


def test_localize_vis_replaces_its_own_picture(tmp_path):
    from ldlmap.core.pictures import write_picture

    pano = write_panorama(tmp_path / "pano.jpg")
    ours = write_picture(tmp_path / "pose.jpg", np.zeros((32, 64, 3), np.uint8))
    assert "map not found" in error_line(_invoke(["localize", tmp_path / "no_map.h5", pano, "--vis", ours]))


def test_run_images_save_vis_refuses_a_users_picture(tmp_path):
    write_panorama(tmp_path / "shots" / "pano.jpg")
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "room.h5").write_bytes(b"\x89HDF\r\n\x1a\n")
    mine = write_panorama(tmp_path / "vis" / "pano.jpg", width=256)
    before = snapshot(tmp_path)
    line = error_line(_invoke(["run", "--images", tmp_path / "shots", "--maps", tmp_path / "maps",
                               "--save-vis", tmp_path / "vis", "-o", tmp_path / "r.json"]))
    assert f"--save-vis: {mine} exists and is not a picture of ldlloc" in line
    assert snapshot(tmp_path) == before


def test_dataset_save_vis_refuses_a_users_picture(tiny_synth, tmp_path):
    from ldlmap.datasets import open_dataset
    from ldlloc.batch.run import picture_path

    q = open_dataset(tiny_synth).queries(["robot"])[0]
    mine = write_panorama(picture_path(tmp_path / "vis", q))
    before = snapshot(tmp_path)
    line = error_line(_invoke(["run", "--root", tiny_synth, "--split", "robot", "--save-vis", tmp_path / "vis",
                               "-o", tmp_path / "r.json"]))
    assert f"{mine} exists and is not a picture of ldlloc" in line
    assert snapshot(tmp_path) == before


# (query name, where its picture goes below the --save-vis folder)
PICTURE_NAMES = [
    ("shots/../../wf/shots/p0", "shots/%2e%2e/%2e%2e/wf/shots/p0.jpg"),
    ("../p0", "%2e%2e/p0.jpg"),
    ("..", "%2e%2e.jpg"),
    ("./a/./b", "a/b.jpg"),
    ("/abs/p", "abs/p.jpg"),
    ("robot/synthroom_1_scene_1/0000", "robot/synthroom_1_scene_1/0000.jpg"),
    ("pano.v2", "pano.v2.jpg"),
]


@pytest.mark.parametrize("name, where", PICTURE_NAMES, ids=[c[0] for c in PICTURE_NAMES])
def test_picture_stays_inside_the_vis_folder(tmp_path, name, where):
    from ldlmap.core.pictures import picture_file

    vis = tmp_path / "vis"
    p = picture_file(vis, name)
    assert p == vis / where
    assert vis.resolve() in p.resolve().parents


def test_picture_of_a_glob_with_dotdot_stays_inside_the_vis_folder(tmp_path, monkeypatch):
    """`--images 'sh*/../../wf/shots/p0.jpg'` names the query with its `..`: its picture is inside vis/."""
    from ldlloc.batch.images import find_images, picture_path

    (tmp_path / "wf").mkdir()
    monkeypatch.chdir(tmp_path / "wf")
    write_panorama(tmp_path / "wf" / "shots" / "p0.jpg")
    user = write_panorama(tmp_path / "wf" / "vis" / "p0.jpg", width=256)  # where a `..` name used to land
    queries = find_images("sh*/../../wf/shots/p0.jpg")
    assert len(queries) == 1 and ".." in queries[0].name
    pic = picture_path(Path("vis"), queries[0])
    assert Path("vis").resolve() in pic.resolve().parents and pic.resolve() != user.resolve()


def test_dataset_pictures_are_one_per_query(tiny_synth, tmp_path):
    """Queries of two scene folders of one room with the same image name (``synthroom_1_scene_1/0000``,
    ``synthroom_1_scene_2/0000``) get two pictures (they used to share ``vis/robot/synthroom_1_0000.jpg``);
    so does every query of a dataset."""
    from types import SimpleNamespace

    from ldlmap.datasets import open_dataset
    from ldlloc.batch.run import picture_path

    twins = [SimpleNamespace(name=f"robot/synthroom_1_scene_{k}/0000", scene="synthroom_1", split="robot",
                             image=Path(f"data/robot_pano/synthroom_1_scene_{k}/0000.jpg")) for k in (1, 2)]
    assert picture_path(tmp_path / "vis", twins[0]) != picture_path(tmp_path / "vis", twins[1])
    queries = open_dataset(tiny_synth).queries(None)
    pictures = [picture_path(tmp_path / "vis", q) for q in queries]
    assert len(set(pictures)) == len(queries) > 1
    assert all((tmp_path / "vis").resolve() in p.resolve().parents for p in pictures)


def test_two_pictures_of_one_file_are_refused(tmp_path):
    from ldlmap.core.errors import InputError
    from ldlmap.core.pictures import refuse_replacing_pictures

    with pytest.raises(InputError, match="two pictures would be the same file"):
        refuse_replacing_pictures([tmp_path / "a.jpg", tmp_path / "x" / ".." / "a.jpg"], False, "--save-vis")


# ----------------------------------------------------------------------------- report --html


def _page_with_mark_elsewhere(head: str) -> str:
    from ldlloc.report.page import MARK

    return head.format(mark=MARK) + "<html><body>my own page</body></html>\n"


# (case, the file's text, whether report may replace it)
HTML_FILES = [
    ("the mark in a comment of line 1", "<!-- notes: {mark} -->\n<p>mine</p>\n", False),
    ("the mark on line 3", "<!DOCTYPE html>\n<!-- mine -->\n{mark}\n", False),
    ("the mark on line 2 without the doctype", "<html>\n{mark}\n", False),
    ("the mark on line 2 with text after it", "<!DOCTYPE html>\n{mark} and my notes\n", False),
    ("a page of report", "<!DOCTYPE html>\n{mark}\n", True),
]


@pytest.mark.parametrize("text, ours", [c[1:] for c in HTML_FILES], ids=[c[0] for c in HTML_FILES])
def test_report_html_replaces_only_its_own_page(results, tmp_path, text, ours):
    page = tmp_path / "page.html"
    page.write_text(_page_with_mark_elsewhere(text))
    before = page.read_bytes()
    res = _invoke(["report", results, "--html", page])
    if ours:
        assert res.exit_code == 0, res.output
        assert page.read_bytes() != before and b"Localization report" in page.read_bytes()
    else:
        assert "is not an HTML report of `ldlloc report`" in error_line(res)
        assert page.read_bytes() == before


def test_report_html_page_begins_as_its_check_expects(results, tmp_path):
    from ldlloc.report.page import PAGE_HEAD

    _ok(["report", results, "--html", tmp_path / "a.html"])
    assert (tmp_path / "a.html").read_text().startswith(PAGE_HEAD)
    _ok(["report", results, "--html", tmp_path / "a.html"])  # and a second report replaces it
    assert json.loads(results.read_text())["queries"]  # the input is untouched
