"""`ldlloc report --html`: one self-contained page, opened in headless Chromium (Debian's `chromium`
package, installed by `make install`): the screenshot is not blank and shows a query's thumbnail,
the DOM holds the queries' table worst first; missing images and maps are said in their rows."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app

pytestmark = pytest.mark.xdist_group("report_html")  # one worker runs ``run_results``
runner = CliRunner()
SCENE = "synthroom_1"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run"]


def _ok(args: list) -> str:
    res = runner.invoke(loc_app, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return res.output


def _error(args: list) -> str:
    res = runner.invoke(loc_app, [str(a) for a in args])
    assert res.exit_code == 1 and "Traceback" not in res.output, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    return lines[0]


def chromium() -> str:
    """Headless Chromium's program; the test FAILS (not skips) without it."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        pytest.fail("chromium is not installed: run `make install` (its sysdeps step installs Debian's chromium "
                    "package), or `apt-get install chromium`")
    return found


def open_page(page: Path, tmp: Path, size: tuple[int, int] = (1280, 2000)) -> tuple[np.ndarray, str]:
    """The page in headless Chromium: its screenshot (RGB) and its DOM after rendering."""
    import cv2

    base = [chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={tmp / 'chromium-profile'}"]
    shot = tmp / "shot.png"
    done = subprocess.run([*base, f"--screenshot={shot}", f"--window-size={size[0]},{size[1]}", page.as_uri()],
                          capture_output=True, text=True, timeout=180)
    assert done.returncode == 0 and shot.exists(), done.stderr[-2000:]
    dom = subprocess.run([*base, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=180)
    assert dom.returncode == 0, dom.stderr[-2000:]
    return cv2.cvtColor(cv2.imread(str(shot)), cv2.COLOR_BGR2RGB), dom.stdout


@pytest.fixture(scope="module")
def run_results(demo_dataset, tmp_path_factory) -> Path:
    """Results of `ldlloc run` on the robot and extreme splits of one demo scene, with a confidence
    and a verdict added to each record as the confidence step writes them."""
    folder = tmp_path_factory.mktemp("report_run")
    out = folder / "run.json"
    _ok(["run", "--root", demo_dataset, "--split", "robot", "--split", "extreme", "--scene", SCENE, "-o", out])
    data = json.loads(out.read_text())
    for i, q in enumerate(data["queries"]):
        q["confidence"] = round(0.1 + 0.8 * i / len(data["queries"]), 3)
        q["verdict"] = "confident" if q["confidence"] > 0.5 else "ambiguous"
    out.write_text(json.dumps(data))
    return out


def test_page_renders_in_chromium(run_results, tmp_path):
    import cv2

    from ldlloc.report.page import normalized_error

    page = tmp_path / "report.html"
    out = _ok(["report", run_results, "--html", page])
    assert f"wrote {page}" in out.replace("\n", "") and "by split" in out  # the tables are still printed
    html = page.read_text()
    # self-contained: nothing fetched from anywhere
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)|url\(\s*["']?(https?:|//)|<script|<link|@import""",
                         html, re.I)
    records = json.loads(run_results.read_text())["queries"]
    shot, dom = open_page(page, tmp_path)
    assert float(shot.std()) > 20.0  # not a blank page
    # names wrap at / and _ (line-break opportunities between their parts)
    rows = [n.replace("<wbr>", "") for n in re.findall(r'<tr class="query">.*?<b>(.+?)</b>', dom, re.S)]
    worst = sorted(records, key=lambda q: -normalized_error(q))
    assert rows == [q["name"] for q in worst] and len(rows) == len(records)
    assert 'id="queries"' in dom and "confidence (" in dom and "translation error, per split" in dom
    thumbs = re.findall(r'src="data:image/jpeg;base64,([^"]+)"', dom)
    assert len(thumbs) == len(records)
    # the first (worst) query's thumbnail is on screen, pixel for pixel
    first = cv2.imdecode(np.frombuffer(base64.b64decode(thumbs[0]), np.uint8), cv2.IMREAD_COLOR)
    first = cv2.cvtColor(first, cv2.COLOR_BGR2RGB)
    score = cv2.matchTemplate(shot, first, cv2.TM_CCOEFF_NORMED).max()
    assert score > 0.95, score


def test_missing_images_and_maps_are_said_in_their_rows(run_results, tmp_path):
    from ldlloc.report.page import normalized_error

    data = json.loads(run_results.read_text())
    worst = sorted(data["queries"], key=lambda q: -normalized_error(q))  # those that get a thumbnail first
    worst[0]["image"] = str(tmp_path / "gone.jpg")
    worst[1]["map"] = str(tmp_path / "nomap.h5")
    data["meta"]["root"] = str(tmp_path / "elsewhere")  # no maps folder either: no map for any query
    data["meta"].pop("maps", None)
    worst[2].update(status="failed", R=None, t=None, message="no lines found")
    results = tmp_path / "broken.json"
    results.write_text(json.dumps(data))
    page = tmp_path / "broken.html"
    limit = len(data["queries"]) - 1
    _ok(["report", results, "--html", page, "--max-thumbnails", limit])
    shot, dom = open_page(page, tmp_path)
    assert float(shot.std()) > 20.0
    assert "image not found" in dom and "gone.jpg" in dom
    assert "map not found" in dom and "nomap.h5" in dom
    assert "no pose: no lines drawn" in dom and "no lines found" in dom
    assert dom.count(f"thumbnail left out (--max-thumbnails {limit})") == 1
    assert len(re.findall(r'<tr class="query">', dom)) == len(data["queries"])


def test_images_run_without_ground_truth(run_results, tmp_path):
    """An image run (no ground truth): no accuracy section, queries by confidence, lowest first."""
    data = json.loads(run_results.read_text())
    for q in data["queries"]:
        q.update(split="images", t_error_m=None, r_error_deg=None)
    results = tmp_path / "images.json"
    results.write_text(json.dumps(data))
    page = tmp_path / "images.html"
    _ok(["report", results, "--html", page])
    html = page.read_text()
    assert "Accuracy per split" not in html and "per split" not in html and "confidence (" in html
    rows = [n.replace("<wbr>", "") for n in re.findall(r'<tr class="query">.*?<b>(.+?)</b>', html, re.S)]
    assert rows == [q["name"] for q in sorted(data["queries"], key=lambda q: q["confidence"])]


def test_bad_html_options_are_one_line_errors(run_results, tmp_path):
    assert "--html must name a .html file" in _error(["report", run_results, "--html", tmp_path / "r.txt"])
    other = tmp_path / "mine.html"
    other.write_text("<html>my notes</html>")
    assert "exists and is not an HTML report" in _error(["report", run_results, "--html", other])
    assert other.read_text() == "<html>my notes</html>"
    assert "--max-thumbnails" in _error(["report", run_results, "--html", tmp_path / "a.html", "--max-thumbnails",
                                         "-1"])
    page = tmp_path / "again.html"
    _ok(["report", run_results, "--html", page])
    _ok(["report", run_results, "--html", page])  # its own page is replaced without asking
