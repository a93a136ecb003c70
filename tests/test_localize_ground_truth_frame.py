"""`localize --gt` on a map built from another frame (`--scale 0.001`: a scan in millimetres): the
ground truth, given in the map's input frame as datasets store it, is compared in the map frame, as
`run` compares it (one rule: :meth:`ldlloc.pipeline.Localization.truth_in_map_frame`)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app

runner = CliRunner()
TRUE_CENTER = np.array([0.3, -0.4, -0.1])  # metres, map frame


@pytest.fixture(scope="module")
def scaled_map(tmp_path_factory):
    """A box room scanned in millimetres, its map built with ``scale=0.001``, and a panorama rendered
    at :data:`TRUE_CENTER` (metres) with its pose file in millimetres (the input frame)."""
    import cv2

    from ldlmap.core.geometry import rotation_from_axis_angle
    from ldlmap.io.cloud import PointCloud
    from ldlmap.io.pointcloud import write_point_cloud
    from ldlmap.map.build import BuildParams, build_map
    from ldlmap.map.render import PointRenderer, RenderParams
    from tests._room_cloud import box_room

    tmp = tmp_path_factory.mktemp("scaled_map")
    P, _ = box_room(seed=0, density=800, size=(5.0, 4.0, 2.6))
    P = P - np.round(np.median(P, axis=0))
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
    colors = (60 + 180 * np.abs(np.asarray(pc.normals))).astype(np.uint8)  # edges show in renders
    write_point_cloud(tmp / "mm.ply", PointCloud(P * 1000.0, colors))
    report = build_map(tmp / "mm.ply", tmp / "mm.h5", params=BuildParams().replaced(features="none", num_translations=100,
                                                                          distance_fields=False, scale=0.001))
    R = rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.4)
    img = PointRenderer(P, colors, RenderParams(width=512, height=256)).render(R, TRUE_CENTER).rgb
    cv2.imwrite(str(tmp / "q.png"), img[..., ::-1])
    np.savetxt(tmp / "q_mm.txt", np.hstack([R, 1000.0 * TRUE_CENTER[:, None]]))
    return report.path, tmp / "q.png", tmp / "q_mm.txt"


def test_ground_truth_of_a_scaled_map_is_compared_in_metres(scaled_map):
    map_path, pano, gt = scaled_map
    res = runner.invoke(loc_app, ["localize", str(map_path), str(pano), "--gt", str(gt), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert np.linalg.norm(np.array(out["t"]) - TRUE_CENTER) < 0.1  # the pose is right (map frame, metres) ...
    assert out["t_error_m"] < 0.1 and out["localized"], out  # ... and so is its error against the truth
    assert abs(out["t_error_m"] - np.linalg.norm(np.array(out["t"]) - TRUE_CENTER)) < 1e-6
