"""Upright prior (``--max-tilt``), top-K candidates in the outputs, and old results files.

``filter_by_tilt`` on hand-made rotations; localization of the synthetic demo dataset's robot
split (cameras within 2 degrees of upright) under a 10-degree bound; the ``--json`` output of
``ldlloc localize``; ``--max-tilt`` validation; batch runs recording the prior per query.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlloc.record import QueryResult, best_candidate, first_good_rank
from ldlloc.batch.results import ResultsWriter, load_results, read_results_data
from ldlloc.pipeline import UPRIGHT_MAX_TILT_DEG, LocalizeParams, Localizer, load_image, rotation_prior_name
from ldlloc.rotation import RotationCandidates, camera_tilt_deg, filter_by_tilt
from ldlmap.datasets import open_dataset
from ldlmap.core.errors import InputError
from ldlmap.core.geometry import rotation_error_deg, translation_error
from ldlmap.map.mapfile import read_map
from tests._hostile import error_line

runner = CliRunner()
TILTS = (0.0, 5.0, 30.0, 90.0)


def tilted(tilt_deg: float, yaw_deg: float, axis: str) -> np.ndarray:
    """World-to-camera R of a camera turned by ``yaw`` about the world z, then tilted by ``tilt``
    about a horizontal camera axis (its up axis, R.T @ e_z, is ``tilt`` from the world's up)."""
    cam_from_world = Rotation.from_euler(axis, tilt_deg, degrees=True) * Rotation.from_euler("z", yaw_deg, degrees=True)
    return cam_from_world.as_matrix()


def hand_made() -> RotationCandidates:
    R = np.array([tilted(t, 37.0 * i, "xy"[i % 2]) for i, t in enumerate(TILTS)])
    n = len(R)
    return RotationCandidates(R, np.arange(3 * n).reshape(n, 3), np.ones((n, 3)), np.linspace(0, 1e-3, n))


def test_camera_tilt_of_hand_made_rotations():
    rots = hand_made()
    np.testing.assert_allclose(camera_tilt_deg(rots.rotations), TILTS, atol=1e-9)
    # The up axis in the world is R.T @ e_z; upside down is 180 degrees.
    up = np.einsum("nji,j->ni", rots.rotations, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(np.degrees(np.arccos(np.clip(up[:, 2], -1, 1))), TILTS, atol=1e-9)
    assert camera_tilt_deg(np.diag([1.0, -1.0, -1.0])) == pytest.approx(180.0)


@pytest.mark.parametrize("bound, kept", [(10.0, [0, 5]), (5.0, [0, 5]), (4.9, [0]), (30.0, [0, 5, 30]),
                                         (89.0, [0, 5, 30]), (90.0, TILTS), (180.0, TILTS)])
def test_filter_by_tilt_keeps_the_candidates_within_the_bound(bound, kept):
    rots = hand_made()
    out = filter_by_tilt(rots, bound)
    idx = [TILTS.index(t) for t in kept]
    assert len(out) == len(kept)
    np.testing.assert_array_equal(out.rotations, rots.rotations[idx])  # order kept, fields in step
    np.testing.assert_array_equal(out.triplets, rots.triplets[idx])
    np.testing.assert_array_equal(out.signs, rots.signs[idx])
    np.testing.assert_array_equal(out.residuals, rots.residuals[idx])


def test_filter_by_tilt_edge_cases():
    rots = hand_made()
    assert len(filter_by_tilt(rots, 0.0)) == 1  # only the exactly upright one
    sideways = filter_by_tilt(RotationCandidates(rots.rotations[3:], rots.triplets[3:], rots.signs[3:],
                                                 rots.residuals[3:]), 45.0)
    assert len(sideways) == 0 and sideways.triplets.shape == (0, 3)
    assert len(filter_by_tilt(sideways, 10.0)) == 0
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(InputError):
            filter_by_tilt(rots, bad)
    assert rotation_prior_name(None) == "free" and rotation_prior_name(180.0) == "free"
    assert rotation_prior_name(10.0) == "upright<=10deg" and rotation_prior_name(2.5) == "upright<=2.5deg"


def test_best_candidate_and_first_good_rank():
    t = [0.1, 2.0, 0.3, 0.05]
    r = [175.0, 3.0, 8.0, 12.0]
    assert best_candidate(t, r) == 2  # smallest t among those within 10 deg (1 and 2)
    assert first_good_rank(t, r) == 3  # 1-based
    assert best_candidate([1.0, 2.0], [40.0, 20.0]) == 1  # none within 10 deg: smallest rotation error
    assert first_good_rank([1.0, 2.0], [40.0, 20.0]) is None
    assert best_candidate([], []) is None and first_good_rank([], []) is None


# ------------------------------------------------------------------------- on the demo dataset


@pytest.fixture(scope="module")
def robot_upright(demo_dataset):
    """Every robot query localized with a 10-degree upright prior (rows of errors and outputs)."""
    ds = open_dataset(demo_dataset, "omniscenes")
    rows = []
    for scene in ds.scenes():
        loc = Localizer(read_map(demo_dataset / "maps" / f"{scene}.h5", load_cloud=False),
                        LocalizeParams(max_tilt_deg=UPRIGHT_MAX_TILT_DEG))
        for q in ds.queries(["robot"], scene):
            rows.append((q, loc.localize(load_image(q.image))))
    return rows


@pytest.mark.xdist_group("upright_prior")  # one worker localizes the robot split (``robot_upright``)
def test_upright_prior_keeps_the_robot_split_accurate(robot_upright):
    assert len(robot_upright) == 10
    ok = [translation_error(r.center, q.center) < 0.1
          and rotation_error_deg(r.rot_cam_from_world, q.rot_cam_from_world) < 5 for q, r in robot_upright]
    assert np.mean(ok) >= 0.9


@pytest.mark.xdist_group("upright_prior")
def test_every_candidate_respects_the_tilt_bound(robot_upright):
    for _, r in robot_upright:
        assert r.rotation_prior == "upright<=10deg"
        assert len(r.rotations) == r.num_rotations > 0
        assert camera_tilt_deg(r.rotations).max() <= UPRIGHT_MAX_TILT_DEG + 1e-6
        assert camera_tilt_deg(r.candidates_rot).max() <= UPRIGHT_MAX_TILT_DEG + 1e-6
        assert r.candidates_loss.shape == (len(r.candidates_rot),) and np.isfinite(r.candidates_loss).all()
        assert np.all(np.diff(r.candidates_loss) >= 0)


def test_per_query_tilt_overrides_the_params(demo_dataset):
    ds = open_dataset(demo_dataset, "omniscenes")
    q = next(q for q in ds.queries(["extreme"]) if 25 < camera_tilt_deg(q.rot_cam_from_world) < 50)
    loc = Localizer(read_map(demo_dataset / "maps" / f"{q.scene}.h5", load_cloud=False),
                    LocalizeParams(max_tilt_deg=5.0))
    img = load_image(q.image)
    free = loc.localize(img, max_tilt_deg=180.0)  # the call's bound wins over the params'
    assert free.rotation_prior == "free" and camera_tilt_deg(free.rotations).max() > 5.0
    # A camera tilted by 25-50 degrees: no relabeling of the room's axes is within the params'
    # 5-degree bound, with any number of lines.
    with pytest.raises(InputError, match="no candidate rotation is within the tilt bound of 5 deg") as exc:
        loc.localize(img)
    assert "\n" not in str(exc.value)
    with pytest.raises(InputError, match="tilt"):
        loc.localize(img, max_tilt_deg=0.0)


def test_run_uses_the_upright_default_and_records_the_prior(demo_dataset, tmp_path):
    from ldlloc.batch.run import max_tilt_for, run_queries

    ds = open_dataset(demo_dataset, "omniscenes")
    qs = [q for q in ds.queries(["robot"], "synthroom_1")][:2]
    upright = [SimpleNamespace(**{**vars(q), "upright": True}) for q in qs]
    assert max_tilt_for(qs[0], LocalizeParams()) == (UPRIGHT_MAX_TILT_DEG if getattr(qs[0], "upright", False) else None)
    assert max_tilt_for(upright[0], LocalizeParams()) == UPRIGHT_MAX_TILT_DEG
    assert max_tilt_for(upright[0], LocalizeParams(max_tilt_deg=180.0)) == 180.0  # --max-tilt wins
    out = tmp_path / "res.json"
    params = LocalizeParams(do_refine=False)
    results = run_queries(upright, demo_dataset / "maps", out, params)
    assert [r.rotation_prior for r in results] == ["upright<=10deg"] * 2
    for r in results:
        assert len(r.candidates) == 20 and set(r.candidates[0]) == {"R", "t", "loss"}
        assert r.first_good_rank == 1 and r.best_candidate_t_error_m < 0.5 and r.best_candidate_r_error_deg < 10
    data = json.loads(out.read_text())
    assert data["meta"]["max_tilt_deg"] is None and data["meta"]["upright_max_tilt_deg"] == UPRIGHT_MAX_TILT_DEG
    assert len(data["queries"][0]["candidates"]) == 20 and data["summary"]["search"]["topk_0.5m_10deg"] == 1.0
    assert "candidates" not in out.with_suffix(".csv").read_text().splitlines()[0]
    # --max-tilt 180 on upright queries: free rotation, recorded as such.
    results = run_queries(upright[:1], demo_dataset / "maps", tmp_path / "free.json",
                          LocalizeParams(do_refine=False, max_tilt_deg=180.0))
    assert results[0].rotation_prior == "free"
    assert json.loads((tmp_path / "free.json").read_text())["meta"]["max_tilt_deg"] == 180.0


# ----------------------------------------------------------------------------------------- CLI


def test_localize_json_lists_the_top_k_candidates(demo_dataset):
    map_path = demo_dataset / "maps" / "synthroom_1.h5"
    img = sorted((demo_dataset / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[0]
    res = runner.invoke(loc_app, ["localize", str(map_path), str(img), "--json", "--top-k", "7",
                                  "--max-tilt", "10", "--no-refine", "--threads", "1"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["rotation_prior"] == "upright<=10deg"
    cands = out["candidates"]
    assert len(cands) == 7
    losses = [c["loss"] for c in cands]
    assert all(math.isfinite(v) for v in losses) and losses == sorted(losses)
    for c in cands:
        R = np.array(c["R"])
        assert R.shape == (3, 3) and len(c["t"]) == 3
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-6)
        assert camera_tilt_deg(R) <= 10.0 + 1e-6
    # Without refinement the estimate is the best candidate.
    np.testing.assert_allclose(out["t"], cands[0]["t"], atol=1e-6)


@pytest.mark.parametrize("tilt", ["0", "500", "-3", "nan"])
def test_bad_max_tilt_is_error_line(demo_dataset, tilt):
    map_path = demo_dataset / "maps" / "synthroom_1.h5"
    img = sorted((demo_dataset / "robot_pano" / "robot_synthroom_1_scene_1").glob("*.jpg"))[0]
    line = error_line(runner.invoke(loc_app, ["localize", str(map_path), str(img), "--max-tilt", tilt]))
    assert "--max-tilt" in line
    line = error_line(runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--max-tilt", tilt]))
    assert "--max-tilt" in line


def test_bad_map_level_is_error_line(demo_dataset):
    line = error_line(runner.invoke(loc_app, ["run", "--root", str(demo_dataset), "--map-level", "house"]))
    assert "--map-level" in line


# ------------------------------------------------------------------------------- results files


def test_results_file_without_the_new_fields_still_loads(tmp_path):
    old = {"image": "a.jpg", "scene": "room_1", "split": "robot", "name": "robot/a", "R": np.eye(3).tolist(),
           "t": [0.0, 0.0, 1.0], "t_error_m": 0.02, "r_error_deg": 0.5, "seconds": {"total": 1.0},
           "num_rotations": 12, "num_matches": 30, "num_inliers": 20, "refined": True, "status": "ok", "message": ""}
    path = tmp_path / "old.json"
    path.write_text(json.dumps({"meta": {"dataset": "omniscenes"}, "summary": {}, "queries": [old]}))
    rs, meta = load_results(path)
    assert meta == {"dataset": "omniscenes"} and len(rs) == 1
    r = rs[0]
    assert r.t_error_m == 0.02 and r.rotation_prior == "free" and r.candidates == []
    assert r.best_candidate_t_error_m is None and r.best_candidate_r_error_deg is None and r.first_good_rank is None
    # Resuming onto it keeps the old record and writes the new fields beside it.
    w = ResultsWriter(path, meta={"device": "cpu"}, resume=True)
    w.add(QueryResult(image="b.jpg", scene="room_1", split="robot", name="robot/b", status="failed",
                      rotation_prior="upright<=10deg"))
    data = read_results_data(path)  # the JSON with the records of its journal (the run goes on)
    assert [q["rotation_prior"] for q in data["queries"]] == ["free", "upright<=10deg"]
    assert "search" not in data["summary"]  # no query kept candidates
