"""Threaded LSD in ldlloc.lines2d gives the same arcs as one thread."""

from __future__ import annotations

import numpy as np

from ldlmap.core.geometry import rotation_from_axis_angle
from ldlloc import lines2d
from tests.test_lines2d import render_box_room


def test_threaded_detection_equals_single_thread():
    img = render_box_room(rotation_from_axis_angle(np.array([0.3, -0.2, 1.0]), 0.7), np.array([0.4, 0.3, 1.3]),
                          256, 128)
    one = lines2d.detect_lines(img, lines2d.Lines2DParams(lsd_threads=1))
    assert len(one) >= 8
    for k in (2, 3):
        np.testing.assert_array_equal(lines2d.detect_lines(img, lines2d.Lines2DParams(lsd_threads=k)), one)
    np.testing.assert_array_equal(lines2d.detect_lines(img), one)  # auto
