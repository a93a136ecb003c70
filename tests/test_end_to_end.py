"""End to end on a synthetic demo dataset: accuracy of pose search and of the full pipeline.

The dataset comes from ``ldlmap synth --preset demo`` and the maps from ``ldlmap prepare`` with
SIFT (fixture ``demo_dataset``); every query is localized with the library pipeline that
``ldlloc run`` uses (fixture ``demo_localized``), and the accuracy targets are asserted per split.
"""

from __future__ import annotations

import numpy as np
import pytest

from ldlmap.core.geometry import rotation_error_deg, translation_error

pytestmark = pytest.mark.xdist_group("end_to_end")  # one worker localizes the queries (``localized``)
MAIN_SPLITS = ("robot", "handheld", "extreme")
OTHER_SPLITS = ("change_robot", "change_handheld", "extreme_intensity", "extreme_gamma", "extreme_white_balance")


@pytest.fixture(scope="module")
def localized(demo_localized):
    rows = []
    for q, r in demo_localized.values():
        if r is None:  # counts as a failed query (not localized, truth not among candidates)
            rows.append({"split": q.split, "name": q.name, "t_err": np.inf, "r_err": np.inf,
                         "top20_ok": False, "rot_best": np.inf, "num_rotations": 0})
            continue
        cand_t = np.linalg.norm(r.candidates_center - q.center, axis=1)
        cand_r = np.array([rotation_error_deg(R, q.rot_cam_from_world) for R in r.candidates_rot])
        rows.append({
            "split": q.split, "name": q.name,
            "t_err": translation_error(r.center, q.center),
            "r_err": rotation_error_deg(r.rot_cam_from_world, q.rot_cam_from_world),
            "top20_ok": bool(np.any((cand_t < 0.5) & (cand_r < 10.0))),
            "rot_best": min(rotation_error_deg(R, q.rot_cam_from_world) for R in r.rotations),
            "num_rotations": r.num_rotations,
        })
    return rows


def accuracy(rows, split):
    sel = [r for r in rows if r["split"] == split]
    assert len(sel) == 10
    return float(np.mean([(r["t_err"] < 0.1) and (r["r_err"] < 5.0) for r in sel]))


@pytest.mark.parametrize("split", MAIN_SPLITS)
def test_accuracy_main_splits(localized, split):
    assert accuracy(localized, split) >= 0.9


@pytest.mark.parametrize("split", OTHER_SPLITS)
def test_accuracy_change_and_illumination_splits(localized, split):
    assert accuracy(localized, split) >= 0.85


def test_median_translation_error(localized):
    assert np.median([r["t_err"] for r in localized]) <= 0.05


def test_pose_search_top20_contains_the_truth(localized):
    # Before refinement: the best of the top-20 lies within 0.5 m and 10 degrees.
    assert np.mean([r["top20_ok"] for r in localized]) >= 0.95


def test_rotation_candidates_contain_the_truth(localized):
    assert np.mean([r["rot_best"] < 3.0 for r in localized]) >= 0.95
    assert np.median([r["num_rotations"] for r in localized if r["num_rotations"]]) <= 50


def test_features_seen_again_at_the_pose_and_not_without_views(demo_dataset, demo_localized):
    """``Localizer.inliers_at`` (the copies' check, ``ldlloc.confidence.copy_rival``): PnP of a query's
    features with the map's views nearest its true pose finds it again; with no view that far away it
    finds nothing, and says so (inf); the other room's map, at a pose there, finds few."""
    from ldlmap.map.mapfile import read_map
    from ldlloc.pipeline import Localizer

    q, loc = next((q, r) for q, r in demo_localized.values()
                  if q.split == "robot" and r is not None and r.refine_method == "features")
    own = Localizer(read_map(demo_dataset / "maps" / f"{q.scene}.h5", load_cloud=False))
    n, near = own.inliers_at(loc, q.rot_cam_from_world, q.center)
    assert n >= 30 and near < 3.0
    assert own.inliers_at(loc, q.rot_cam_from_world, q.center, beyond=1e3) == (0, float("inf"))
    other_scene = next(s for s in ("synthroom_1", "synthroom_2") if s != q.scene)
    other = Localizer(read_map(demo_dataset / "maps" / f"{other_scene}.h5", load_cloud=False))
    T = other.map.translations
    assert other.inliers_at(loc, q.rot_cam_from_world, T[len(T) // 2])[0] < 0.5 * n
