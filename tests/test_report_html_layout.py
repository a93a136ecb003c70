"""The HTML report reads well: legends hold their whole labels (``extreme_white_balance``, not
``extreme_white_bal``) inside the plot, an error CDF's axis spans the decades of its data (errors under
1 cm: 0.001-0.1 m with the 0.1 m threshold, not 0.001-10 m), long query names wrap between their
parts, the camera centre is labelled x / y / z in metres, and a thumbnail opens its panorama."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlloc.report.plots import LEGEND_CHAR_W, cdf_svg, log_axis
from tests._results_files import record, write_panorama, write_results

runner = CliRunner()
SPLITS = ("extreme_white_balance", "change_handheld")


@pytest.fixture
def page(tmp_path) -> str:
    records = []
    for i, split in enumerate(SPLITS * 2):
        image = write_panorama(tmp_path / "shots" / f"p{i}.jpg")
        records.append(record(f"{split}/synthroom_1_scene_{i}/0000", image, t=(0.85, 4.8, 1.26), split=split,
                              t_error_m=0.002 + 0.001 * i, r_error_deg=0.1 + 0.05 * i))
    results = write_results(tmp_path / "r.json", records)
    res = runner.invoke(loc_app, ["report", str(results), "--html", str(tmp_path / "page.html")])
    assert res.exit_code == 0, res.output
    return (tmp_path / "page.html").read_text()


def _svgs(page: str) -> list[str]:
    return re.findall(r"<svg .*?</svg>", page, flags=re.S)


def test_legends_hold_whole_labels_inside_the_plot(page):
    for svg in _svgs(page)[-2:]:  # the two CDFs, legends by split
        width = float(re.search(r'width="(\d+)"', svg).group(1))
        for label in SPLITS:
            m = re.search(rf'<text x="([\d.]+)"[^>]*>{label}</text>', svg)
            assert m is not None, f"{label} not whole in the legend"
            assert float(m.group(1)) + LEGEND_CHAR_W * len(label) <= width


# (values, threshold, the axis expected)
AXES = [
    ([0.002, 0.004, 0.009], 0.1, (0.001, 0.1)),
    ([0.002, 0.004, 0.009], None, (0.001, 0.01)),
    ([0.3, 2.5, np.inf], 0.1, (0.1, 10.0)),
    ([0.01], None, (0.01, 0.1)),
    ([0.0, np.inf], None, (0.001, 10.0)),  # nothing to fit: the given range
]


@pytest.mark.parametrize("values, threshold, axis", AXES)
def test_log_axis_fits_the_data(values, threshold, axis):
    assert log_axis([np.array(values)], 0.001, 10.0, threshold) == pytest.approx(axis)


def test_translation_axis_of_centimetre_errors_stops_at_the_threshold(page):
    translation = next(s for s in _svgs(page) if "translation error" in s)
    ticks = re.findall(r'text-anchor="middle" font-size="10">([\d.e-]+)</text>', translation)
    assert ticks == ["0.001", "0.01", "0.1"], ticks
    svg = cdf_svg({"a": np.array([0.002, 0.004])}, "t", "m", 0.001, 10.0, 0.1)
    assert ">10</text>" not in svg and ">1</text>" not in svg


def test_query_names_wrap_between_their_parts(page):
    assert "extreme_<wbr>white_<wbr>balance/<wbr>synthroom_<wbr>1_<wbr>scene_<wbr>0/<wbr>0000" in page
    assert "overflow-wrap:anywhere" not in page  # no break inside a word


def test_camera_centre_is_labelled(page):
    assert "camera centre (m)" in page
    assert re.search(r"<i>x</i> 0\.85<br><i>y</i> 4\.80<br><i>z</i> 1\.26", page)


def test_thumbnails_open_the_panorama(page, tmp_path):
    links = re.findall(r'<a href="(file://[^"]+)"[^>]*><img class="thumb"', page)
    assert len(links) == 4
    assert {Path(link[len("file://"):]) for link in links} == {(tmp_path / "shots" / f"p{i}.jpg").resolve()
                                                                for i in range(4)}
