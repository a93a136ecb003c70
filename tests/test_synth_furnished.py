"""The ``furnished`` preset: dense furniture, layout line files of the shell alone, cameras in the
band, kinds recorded (ldlmap/synth/furnished.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ldlmap.io.linefiles import read_lines
from ldlmap.synth.edges import mesh_edges
from ldlmap.synth.furnished import (CAMERA_BAND_M, FUNCTIONS, MIN_OBJECTS, SHAPES, furnished_spec, layout_spec,
                                    room_function, room_shape)
from ldlmap.synth.generate import generate_dataset
from ldlmap.synth.scene import build_scene
from ldlmap.synth.shapes import classify_room
from ldlmap.synth.spec import object_footprint

MIN_PER_M2 = 0.3  # furniture pieces per square metre of floor, at least


def _area(fp) -> float:
    p = np.asarray(fp)
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1))))


def _inside_object(point: np.ndarray, spec, margin: float = 0.02) -> bool:
    """Whether ``point`` lies in (or on) one of ``spec``'s furniture boxes."""
    for obj in spec.objects:
        rect = object_footprint(obj)
        c = rect.mean(axis=0)
        ux, uy = rect[1] - rect[0], rect[3] - rect[0]
        lx, ly = np.linalg.norm(ux), np.linalg.norm(uy)
        d = point[:2] - c
        if (abs(d @ ux / lx) <= lx / 2 + margin and abs(d @ uy / ly) <= ly / 2 + margin
                and point[2] <= obj.size[2] + margin):
            return True
    return False


def _on_walls(point: np.ndarray, fp: np.ndarray, tol: float = 0.01) -> bool:
    a, b = fp, np.roll(fp, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", point[:2] - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    return bool(np.min(np.linalg.norm(a + t[:, None] * ab - point[:2], axis=1)) < tol)


@pytest.mark.parametrize("index", range(1, len(SHAPES) + 1))
def test_rooms_are_dense_and_their_layout_is_the_shell(index):
    spec = furnished_spec(7, index)
    assert spec.name.startswith(room_function(index))
    assert len(spec.objects) >= MIN_OBJECTS
    assert len(spec.objects) / _area(spec.footprint) >= MIN_PER_M2
    shape = room_shape(index)
    assert classify_room(spec) == ("box" if shape == "apartment" else shape)
    fp = np.asarray(spec.footprint)
    layout = mesh_edges(build_scene(layout_spec(spec)))
    full = mesh_edges(build_scene(spec))
    assert len(layout) >= 12
    for seg in layout:
        mid = seg.mean(axis=0)
        # every layout line is a crease of the shell: on a wall, or where the ceiling bends
        assert _on_walls(mid, fp) or mid[2] > spec.ceiling_height - 0.01, seg
        assert not _inside_object(mid, spec), seg
    furniture = [seg for seg in full if _inside_object(seg.mean(axis=0), spec)]
    assert len(furniture) >= 4 * MIN_OBJECTS  # the room's true edges hold the furniture the layout has not


def test_preset_writes_layouts_kinds_and_cameras_in_the_band(tmp_path):
    out = tmp_path / "furnished"
    generate_dataset(out, "furnished", [], seed=3, progress=False, illumination=False, width=64, per_split=3,
                     scenes=2)
    meta = json.loads((out / "dataset.json").read_text())
    assert meta["preset"] == "furnished"
    heights = []
    for i, scene in enumerate(meta["scenes"], start=1):
        assert scene["function"] == room_function(i) and scene["function"] in FUNCTIONS
        assert scene["shape"] == room_shape(i) and scene["kind"] in ("box", "sloped")
        lines = read_lines(out / scene["layout"])
        assert len(lines) == scene["layout_lines"] < scene["gt_lines"]
        for split in ("robot", "handheld"):
            for pose in sorted((out / f"{split}_pose" / f"{split}_{scene['name']}_scene_1").glob("*.txt")):
                rt = np.loadtxt(pose)
                heights.append(rt[2, 3])
                assert np.degrees(np.arccos(min(1.0, abs(rt[2, 2])))) < 3.5  # upright
    assert len(heights) == 12
    assert CAMERA_BAND_M[0] - 1e-6 <= min(heights) and max(heights) <= CAMERA_BAND_M[1] + 1e-6
