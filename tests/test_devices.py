"""Localization on every device the machine has: the CPU always, and CUDA where a GPU is present.

Each device must reach the demo's accuracy on its own, and a GPU must find the CPU's poses (the
pose search and the refinement run in torch on the device; float sums in another order may move a
refined pose by a fraction of a millimetre, never to another place).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlloc.pipeline import LocalizeParams, Localizer, load_image
from ldlloc.search.pose_search import SearchParams
from ldlmap.core.geometry import rotation_error_deg, translation_error
from ldlmap.datasets import open_dataset
from ldlmap.map.mapfile import read_map

pytestmark = pytest.mark.xdist_group("end_to_end")  # shares the demo maps' worker with test_end_to_end
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
SPLITS = {"default": ("robot", "extreme"), "exact_lines": ("robot",)}  # the exact search costs ~2 s a query on a CPU


# The product's defaults (distance fields, refined by features), and the torch-heavy variant: the
# exact search (line distance functions computed per query) refined by lines alone.
VARIANTS = {"default": LocalizeParams(),
            "exact_lines": LocalizeParams(search=SearchParams(use_fields=False), refine_mode="geometric")}


def _localize_all(root, device: str, variant: str) -> dict[str, tuple[np.ndarray, np.ndarray, float, float]]:
    """query name -> (center, rotation, translation error, rotation error) on ``device`` with ``VARIANTS[variant]``."""
    ds, out = open_dataset(root, "omniscenes"), {}
    for scene in ds.scenes():
        loc = Localizer(read_map(root / "maps" / f"{scene}.h5", load_cloud=False), VARIANTS[variant], device=device)
        for q in [q for split in SPLITS[variant] for q in ds.queries(split, scene=scene)]:
            r = loc.localize(load_image(q.image))
            out[q.name] = (r.center, r.rot_cam_from_world, translation_error(r.center, q.center),
                           rotation_error_deg(r.rot_cam_from_world, q.rot_cam_from_world))
    return out


@pytest.fixture(scope="module")
def on_cpu(demo_localized):
    """variant -> the CPU's results: the default's are the shared ``demo_localized`` poses of its
    splits, the others made by the first test that needs them."""
    default = {name: (q, r) for name, (q, r) in demo_localized.items() if q.split in SPLITS["default"]}
    assert all(r is not None for _, r in default.values()), "a query's search failed"  # as _localize_all raises
    return {"default": {name: (r.center, r.rot_cam_from_world, translation_error(r.center, q.center),
                               rotation_error_deg(r.rot_cam_from_world, q.rot_cam_from_world))
                        for name, (q, r) in default.items()}}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("device", DEVICES)
def test_localizes_on_every_device(demo_dataset, on_cpu, device, variant):
    if variant not in on_cpu:
        on_cpu[variant] = _localize_all(demo_dataset, "cpu", variant)
    here = on_cpu[variant] if device == "cpu" else _localize_all(demo_dataset, device, variant)
    on_cpu = on_cpu[variant]
    assert here.keys() == on_cpu.keys() and len(here) >= 10
    ok = [t < 0.1 and r < 5.0 for _, _, t, r in here.values()]
    assert np.mean(ok) >= 0.9, {k: v[2:] for k, v in here.items()}
    # The same poses as the CPU's: within a centimetre and a tenth of a degree.
    for name, (center, rot, _, _) in here.items():
        assert np.linalg.norm(center - on_cpu[name][0]) < 0.01, (name, device)
        assert rotation_error_deg(rot, on_cpu[name][1]) < 0.1, (name, device)


@pytest.mark.parametrize("device", DEVICES)
def test_run_on_every_device(demo_dataset, tmp_path, device):
    """``ldlloc run --device D`` records the device and localizes the robot split of one scene."""
    out = tmp_path / "r.json"
    res = CliRunner().invoke(loc_app, ["run", "--root", str(demo_dataset), "--split", "robot", "--scene",
                                       "synthroom_1", "--device", device, "--output", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert data["meta"]["device"] == device
    rows = data["queries"]
    assert len(rows) == 5
    assert np.mean([r["t_error_m"] < 0.1 and r["r_error_deg"] < 5.0 for r in rows]) >= 0.8, rows
