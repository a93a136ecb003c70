"""Scene spec: validation, TOML round trip, presets, random and changed specs."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.synth import presets as P
from ldlmap.synth import spec as S

ROOT = Path(__file__).resolve().parents[1]


def base() -> dict:
    return {
        "name": "room",
        "footprint": [[0, 0], [6, 0], [6, 3], [3.5, 3], [3.5, 5], [0, 5]],
        "ceiling_height": 2.8,
        "objects": [{"kind": "table", "center": [1.8, 2.2], "size": [1.4, 0.8, 0.75]},
                    {"kind": "box", "center": [5, 1], "size": [0.5, 0.5, 0.5], "yaw_deg": 30}],
        "openings": [{"kind": "door", "wall": 4, "offset": 0.6, "width": 0.9, "height": 2.1},
                     {"kind": "window", "wall": 0, "offset": 1.0, "width": 1.4, "height": 1.1}],
        "posters": [{"wall": 3, "offset": 0.5, "bottom": 1.2, "width": 0.8, "height": 0.6}],
    }


def test_valid_and_defaults():
    spec = S.spec_from_dict(base())
    assert spec.objects[0].material == "wood" and spec.openings[1].sill == 0.9 and spec.openings[0].sill == 0.0
    assert spec.capture.width == 1024 and spec.capture.height == 512
    assert spec.scan.noise_std == 0.005 and spec.capture.illumination.white_balance == (0.7, 0.9, 0.8)


def _bad(mutate, field: str):
    d = base()
    mutate(d)
    with pytest.raises(InputError) as info:
        S.spec_from_dict(d)
    msg = str(info.value)
    assert field in msg and "\n" not in msg, msg


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.pop("ceiling_height"), "ceiling_height"),
    (lambda d: d.pop("name"), "name"),
    (lambda d: d["objects"][0].pop("size"), "objects[0].size"),
    (lambda d: d.update(colour="red"), "colour"),
    (lambda d: d["openings"][0].update(color=1), "openings[0].color"),
    (lambda d: d.update(footprint=[[0, 0], [1, 1], [1, 0], [0, 1]]), "footprint"),  # bow tie
    (lambda d: d.update(footprint=[[0, 0], [1, 0]]), "footprint"),
    (lambda d: d.update(footprint=[[0, 0], [1, 0], [1, 1], [1, 0]]), "footprint"),  # repeated
    (lambda d: d.update(footprint=[[0, 0], [1, 0], [2, 0]]), "footprint"),  # zero area
    (lambda d: d.update(footprint=[[0, 0], [4, 0], [4, 4], [2, 4], [2, -1], [0, 4]]), "footprint"),
    (lambda d: d["objects"][0].update(center=[5, 4]), "objects[0]"),  # in the missing corner of the L
    (lambda d: d["objects"][1].update(center=[5.9, 1]), "objects[1]"),  # pokes through a wall
    (lambda d: d["objects"][1].update(center=[2.0, 2.2]), "objects[1]"),  # overlaps the table
    (lambda d: d["objects"][0].update(size=[1, 0, 1]), "objects[0].size"),
    (lambda d: d["objects"][0].update(size=[1, 1, 3.5]), "objects[0].size"),
    (lambda d: d["objects"][0].update(kind="piano"), "objects[0].kind"),
    (lambda d: d["objects"][0].update(material="gold"), "objects[0].material"),
    (lambda d: d["openings"][0].update(offset=3.0), "openings[0]"),  # runs past the wall end
    (lambda d: d["openings"][0].update(wall=9), "openings[0].wall"),
    (lambda d: d["openings"][1].update(height=2.5), "openings[1]"),  # above the ceiling
    (lambda d: d["openings"][1].update(width=-1.0), "openings[1].width"),
    (lambda d: d["posters"][0].update(width=5.0), "posters[0]"),
    (lambda d: d["posters"].append({"wall": 0, "offset": 1.2, "bottom": 1.0, "width": 0.5, "height": 0.5}),
     "posters[1]"),  # overlaps the window
    (lambda d: d.update(ceiling_height="high"), "ceiling_height"),
    (lambda d: d.update(ceiling_height=-1), "ceiling_height"),
    (lambda d: d.update(objects={"kind": "box"}), "objects"),
    (lambda d: d.update(capture={"width": 1000, "height": 512}), "capture.width"),
    (lambda d: d.update(capture={"robot": {"count": 1.5}}), "capture.robot.count"),
    (lambda d: d.update(scan={"noise_std": -0.1}), "scan.noise_std"),
    (lambda d: d.update(scan={"uneven": 2.0}), "scan.uneven"),
])
def test_invalid(mutate, field):
    _bad(mutate, field)


def test_self_intersection_message():
    d = base()
    d["footprint"] = [[0, 0], [1, 1], [1, 0], [0, 1]]
    d["objects"], d["openings"], d["posters"] = [], [], []
    with pytest.raises(InputError, match="self-intersecting"):
        S.spec_from_dict(d)


def test_clockwise_footprint_is_reversed_with_walls_remapped():
    d = base()
    ccw = S.spec_from_dict(d)
    cw = copy.deepcopy(d)
    cw["footprint"] = d["footprint"][::-1]
    k = len(d["footprint"])
    lengths = ccw.wall_lengths()
    for item in cw["openings"] + cw["posters"]:
        w = item["wall"]
        item["wall"] = (k - 2 - w) % k
        item["offset"] = float(lengths[w] - item["offset"] - item["width"])
    spec = S.spec_from_dict(cw)
    assert spec.openings == ccw.openings and spec.posters == ccw.posters
    assert spec.footprint == ccw.footprint


def test_round_trip_dict_toml(tmp_path):
    for spec in (S.spec_from_dict(base()), P.random_spec("demo", 3), P.random_spec("standard", 4, 2)):
        d = S.spec_to_dict(spec)
        assert S.spec_from_dict(d) == spec
        text = S.dump_spec_toml(spec)
        assert S.spec_from_dict(tomllib.loads(text)) == spec
        p = tmp_path / f"{spec.name}.toml"
        p.write_text(text)
        assert S.load_spec(p) == spec


def test_load_spec_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        S.load_spec(tmp_path / "nope.toml")
    p = tmp_path / "bad.toml"
    p.write_text("name = [unclosed\n")
    with pytest.raises(InputError, match="invalid TOML"):
        S.load_spec(p)


def test_every_dataset_spec_loads():
    files = sorted((ROOT / "datasets" / "synthetic").glob("*.toml"))
    assert any(f.name == "l_room.toml" for f in files)
    for f in files:
        spec = S.load_spec(f)
        assert len(spec.footprint) >= 3
    lroom = S.load_spec(ROOT / "datasets" / "synthetic" / "l_room.toml")
    # The documentation example uses every field (nothing left at an implicit default).
    raw = tomllib.loads((ROOT / "datasets" / "synthetic" / "l_room.toml").read_text())

    def keys(d: dict, prefix: str = "") -> set[str]:
        out = set()
        for k, v in d.items():
            out.add(prefix + k)
            if isinstance(v, dict):
                out |= keys(v, prefix + k + ".")
            if isinstance(v, list) and v and isinstance(v[0], dict):
                for item in v:
                    out |= keys(item, prefix + k + ".")
        return out

    assert keys(raw) == keys(S.spec_to_dict(lroom))
    assert {o.kind for o in lroom.objects} == set(S.OBJECT_KINDS)


def test_random_spec_determinism_and_variety():
    a, b = P.random_spec("demo", 1), P.random_spec("demo", 1)
    assert a == b
    footprints = {P.random_spec("demo", s).footprint for s in range(8)}
    assert len(footprints) == 8
    assert P.random_spec("demo", 1).objects != P.random_spec("demo", 2).objects
    assert P.random_spec("demo", 1, 0) != P.random_spec("demo", 1, 1)
    specs = [P.random_spec("standard", s) for s in range(30)]
    nonortho = 0
    for sp in specs:
        fp = np.asarray(sp.footprint)
        e = np.roll(fp, -1, axis=0) - fp
        nonortho += bool(np.any(np.min(np.abs(e), axis=1) > 1e-6))
        ext = np.ptp(fp, axis=0)
        assert 2.0 < ext.min() and ext.max() <= 8.0 + 1e-9
        assert 2.5 <= sp.ceiling_height <= 3.2
        assert 1 <= sum(o.kind == "door" for o in sp.openings) <= 2
        assert 1 <= len(sp.posters) <= 4
        assert 3 <= len(sp.objects) <= 7
    assert 0 < nonortho < len(specs)
    assert len({len(sp.footprint) for sp in specs}) >= 3  # rectangles, L, T/U/Z shapes


def test_presets():
    demo = P.random_spec("demo", 0)
    assert demo.capture.width == 1024 and demo.capture.robot.count == 3
    assert P.PRESETS["demo"]["scenes"] == 2
    with pytest.raises(InputError, match="demo"):
        P.random_spec("huge", 0)


def test_changed_spec():
    spec = P.random_spec("demo", 5)
    changed = P.changed_spec(spec, np.random.default_rng(0))
    assert changed != spec
    S.validate_spec(changed)
    assert changed.footprint == spec.footprint
    assert P.changed_spec(spec, np.random.default_rng(0)) == changed
    kept = set(spec.objects) & set(changed.objects)
    ch = spec.capture.change
    assert len(kept) <= len(spec.objects) - ch.removed


def test_partial_sub_table_keeps_the_split_defaults():
    from ldlmap.synth.spec import CaptureSpec
    from ldlmap.synth.presets import random_spec

    spec = random_spec("demo", 3)
    assert spec.capture.extreme.count == 3
    assert spec.capture.extreme.max_tilt_deg == CaptureSpec().extreme.max_tilt_deg == 180.0
    assert spec.capture.extreme.blur_px > 0
    assert spec.capture.handheld.camera_height == CaptureSpec().handheld.camera_height
