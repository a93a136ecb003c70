"""`ldlloc run --images`: which files become queries and under which names, and which outputs a
run may write. Links are followed once (never in a loop), each file is one query, names are unique
(``a.jpg``, ``a.png``, ``a.jpg.png``: three), the --save-vis folder's exclusion is said, empty
paths are refused, a resumed run refuses another folder or kind, the default output never replaces
another folder's results, a user's CSV is never replaced by a resumed run that starts anew."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.batch.accuracy import QueryResult, summarize
from ldlloc.batch.images import find_images, query_names
from ldlloc.batch.results import ResultsWriter
from ldlloc.cli import app
from ldlmap.core.errors import InputError
from tests._hostile import assert_clean_failure, error_line, snapshot

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]


def small_pano(path: Path) -> Path:
    """A readable 2:1 image too small to localize (its query fails fast with a reason)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(path.suffix, np.full((32, 64, 3), 128, np.uint8))
    path.write_bytes(buf.tobytes())
    return path


def fake_maps(tmp_path: Path) -> Path:
    """A folder with one .h5 name (refusals come before any map is read)."""
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "room.h5").write_bytes(b"\x89HDF\r\n\x1a\n")
    return maps


# ----------------------------------------------------------------------------- names


@pytest.mark.parametrize("files, names", [
    (["a.jpg", "a.png", "a.jpg.png"], ["a.jpg", "a.jpg.png", "a.png"]),
    (["a.jpg", "b.png"], ["a", "b"]),
    (["x/p.jpg", "y/p.jpg"], ["x/p", "y/p"]),
    (["p.jpg", "p.JPG"], ["p.JPG", "p.jpg"]),
    (["a.jpg", "a.jpg.png"], ["a", "a.jpg.png"]),  # the stem "a.jpg" is the other's whole name
])
def test_query_names_are_unique(tmp_path, files, names):
    for f in files:
        small_pano(tmp_path / "shots" / f) if f.lower().endswith((".jpg", ".png")) else None
    got = find_images(tmp_path / "shots")
    assert sorted(q.name for q in got) == sorted(names)
    assert len({q.name for q in got}) == len(files)


def test_query_names_rule_alone():
    rel = [Path("a.jpg"), Path("a.png"), Path("a.jpg.png"), Path("s/b.jpg")]
    assert query_names(rel) == ["a.jpg", "a.png", "a.jpg.png", "s/b"]


def test_three_photos_of_one_stem_give_three_records(demo_dataset, tmp_path):
    shots = tmp_path / "shots"
    for f in ("a.jpg", "a.png", "a.jpg.png"):
        small_pano(shots / f)
    out = tmp_path / "r.json"
    res = runner.invoke(app, ["run", "--images", str(shots), "--maps", str(demo_dataset / "maps" / "synthroom_1.h5"),
                              "-o", str(out)])
    data = json.loads(out.read_text()) if out.exists() else {"queries": []}
    assert sorted(q["name"] for q in data["queries"]) == ["a.jpg", "a.jpg.png", "a.png"], res.output


# ----------------------------------------------------------------------------- links


def test_folder_mode_follows_links_once_and_says_what_it_left_out(tmp_path):
    shots = tmp_path / "shots"
    small_pano(shots / "a.jpg")
    small_pano(tmp_path / "elsewhere" / "b.jpg")
    (shots / "linked").symlink_to(tmp_path / "elsewhere")  # a linked folder: searched (was skipped)
    (shots / "loop").symlink_to(shots)  # a loop: not searched again
    (shots / "twin.jpg").symlink_to(shots / "a.jpg")  # the same file twice: one query
    said = []
    got = find_images(shots, warn=said.append)
    assert [q.name for q in got] == ["a", "linked/b"]
    assert any("not searched again" in s and "loop" in s for s in said), said
    assert any("the same file as another" in s and "twin.jpg" in s for s in said), said


FIND = "import sys; from ldlloc.batch.images import find_images; print(len(find_images(sys.argv[1])))"


def test_a_double_star_glob_never_loops(tmp_path):
    """Two links to the folder itself: one photo is one query, found at once (it hung, or gave 41)."""
    shots = tmp_path / "shots"
    small_pano(shots / "p.jpg")
    (shots / "l1").symlink_to(shots)
    (shots / "l2").symlink_to(shots)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", FIND, f"{shots}/**/*.jpg"], env=env, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "1", out.stderr[-500:]
    assert [q.name for q in find_images(f"{shots}/**/*.jpg")] == ["p"]


@pytest.mark.parametrize("pattern, names", [
    ("**/*.jpg", ["a", "s/b", "s/t/c"]),
    ("*/*.jpg", ["s/b"]),
    ("s/**/*.jpg", ["b", "t/c"]),
    ("**/c.jpg", ["s/t/c"]),
    ("**", ["a", "s/b", "s/t/c"]),
])
def test_double_star_globs_match_as_glob_does(tmp_path, monkeypatch, pattern, names):
    for f in ("a.jpg", "s/b.jpg", "s/t/c.jpg", ".hidden/d.jpg", "s/.e.jpg"):
        small_pano(tmp_path / f)
    monkeypatch.chdir(tmp_path)
    assert [q.name for q in find_images(pattern)] == names


# ----------------------------------------------------------------------------- the pictures folder


def test_images_all_in_the_pictures_folder_say_so(tmp_path):
    shots = tmp_path / "shots"
    for i in range(4):
        small_pano(shots / f"p{i}.jpg")
    with pytest.raises(InputError, match=r"the 4 image file\(s\) .* are in the --save-vis folder .*shots"):
        find_images(shots, exclude=[shots])
    res = runner.invoke(app, ["run", "--images", str(shots), "--maps", str(fake_maps(tmp_path)), "--save-vis",
                              str(shots), "-o", str(tmp_path / "r.json")])
    assert "in the --save-vis folder" in error_line(res)


def test_some_images_in_the_pictures_folder_are_a_warning(tmp_path):
    small_pano(tmp_path / "shots" / "p.jpg")
    small_pano(tmp_path / "shots" / "vis" / "p.jpg")
    said = []
    assert [q.name for q in find_images(tmp_path / "shots", [tmp_path / "shots" / "vis"], said.append)] == ["p"]
    assert said and "1 image file(s) in the --save-vis folder" in said[0]


# ----------------------------------------------------------------------------- refusals


@pytest.mark.parametrize("args, says", [
    (["--images", ""], "--images is empty"),
    (["--images", " "], "--images is empty"),
    (["--maps", ""], "--maps is empty"),
    (["--save-vis", ""], "--save-vis is empty"),
])
def test_empty_paths_are_refused(tmp_path, monkeypatch, args, says):
    small_pano(tmp_path / "shots" / "p.jpg")
    monkeypatch.chdir(tmp_path)
    base = {"--images": "shots", "--maps": str(fake_maps(tmp_path)), "-o": "r.json"}
    for k, v in zip(args[::2], args[1::2]):
        base[k] = v
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["run", *[x for kv in base.items() for x in kv]])
    assert says in assert_clean_failure(res, tmp_path, before)


def test_empty_root_is_refused(tmp_path):
    res = runner.invoke(app, ["run", "--root", "", "-o", str(tmp_path / "r.json")])
    assert "--root is empty" in error_line(res)


def test_resume_of_an_absent_file_keeps_the_users_csv(tmp_path):
    small_pano(tmp_path / "shots" / "p.jpg")
    (tmp_path / "mine.csv").write_text("my,own\n1,2\n")
    before = snapshot(tmp_path)
    res = runner.invoke(app, ["run", "--images", str(tmp_path / "shots"), "--maps", str(fake_maps(tmp_path)),
                              "-o", str(tmp_path / "mine.json"), "--resume"])
    line = error_line(res)
    assert "mine.csv" in line and "--overwrite" in line
    assert snapshot(tmp_path) == {**before, "maps": snapshot(tmp_path)["maps"], "maps/room.h5":
                                  snapshot(tmp_path)["maps/room.h5"]}
    assert (tmp_path / "mine.csv").read_text() == "my,own\n1,2\n"


def test_default_output_never_replaces_another_folders_results(demo_dataset, tmp_path, monkeypatch):
    """day1/pano, then day2/pano: both would write results/images_pano.json; the second is refused."""
    monkeypatch.chdir(tmp_path)
    maps = demo_dataset / "maps" / "synthroom_1.h5"
    for day in ("day1", "day2"):
        small_pano(tmp_path / day / "pano" / "p.jpg")
    first = runner.invoke(app, ["run", "--images", "day1/pano", "--maps", str(maps)])
    out = tmp_path / "results" / "images_pano.json"
    assert out.exists(), first.output
    kept = out.read_bytes()
    res = runner.invoke(app, ["run", "--images", "day2/pano", "--maps", str(maps)])
    line = error_line(res)
    assert "images_pano.json holds the results of another --images" in line and "day1" in line and "-o" in line
    assert out.read_bytes() == kept
    again = runner.invoke(app, ["run", "--images", "day1/pano/", "--maps", str(maps)])  # the same folder: replaced
    assert "another --images" not in again.output


def test_cli_resume_with_another_folder_is_refused(demo_dataset, tmp_path):
    for day in ("day1", "day2"):
        small_pano(tmp_path / day / "p.jpg")
    maps = str(demo_dataset / "maps" / "synthroom_1.h5")
    out = tmp_path / "r.json"
    runner.invoke(app, ["run", "--images", str(tmp_path / "day1"), "--maps", maps, "-o", str(out)])
    assert out.exists()
    kept = out.read_bytes()
    res = runner.invoke(app, ["run", "--images", str(tmp_path / "day2"), "--maps", maps, "-o", str(out), "--resume"])
    assert "other options (images_path)" in error_line(res)
    assert out.read_bytes() == kept


def test_cli_resume_never_mixes_an_image_run_into_a_dataset_run(demo_dataset, tmp_path):
    out = tmp_path / "r.json"
    with ResultsWriter(out, meta={"dataset": "synthetic", "device": "cpu"}) as w:
        w.add(QueryResult(image="a.jpg", scene="synthroom_1", split="robot", name="robot/a", t_error_m=0.1,
                          r_error_deg=1.0, R=np.eye(3).tolist(), t=[0.0, 0.0, 1.0]))
        w.finish()
    kept = out.read_bytes()
    small_pano(tmp_path / "shots" / "p.jpg")
    res = runner.invoke(app, ["run", "--images", str(tmp_path / "shots"), "--maps",
                              str(demo_dataset / "maps" / "synthroom_1.h5"), "-o", str(out), "--resume",
                              "--resume-any-options"])
    assert "holds the results of a dataset run and this is an --images run" in error_line(res)
    assert out.read_bytes() == kept


# ----------------------------------------------------------------------------- counts


def test_image_run_counts_a_pose_its_verdict_calls_failed_as_failed():
    rs = [QueryResult(image="a.jpg", scene="m", split="images", name="a", status="ok", verdict="confident"),
          QueryResult(image="b.jpg", scene="m", split="images", name="b", status="ok", verdict="failed"),
          QueryResult(image="c.jpg", scene="m", split="images", name="c", status="coarse", verdict="failed"),
          QueryResult(image="d.jpg", scene="m", split="images", name="d", status="failed", verdict="failed")]
    s = summarize(rs)
    assert (s["localized"], s["coarse_only"], s["failed"]) == (1, 0, 3)
    assert s["maps"]["m"] == {"count": 4, "ok": 1, "coarse": 0, "failed": 3}
