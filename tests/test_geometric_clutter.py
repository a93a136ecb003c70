"""The geometric refinement's robust weights (ldlloc.refine.geometric: GeometricParams.kernel,
length_power, the second kernel of the default plan) on clutter: image lines that the layout map
does not hold; and the twins of a pose in a symmetric room (ldlloc.refine.copies.room_twins)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import cam_from_world, normalize, rotation_from_axis_angle
from ldlloc.refine.copies import room_twins
from ldlloc.refine.geometric import KERNELS, GeometricParams, mixture_weights, refine_poses_geometric, refinement_plan
from tests.test_confidence import BOX, _arcs, _box_map, _rz

W, D, H = 4.0, 3.5, 2.6  # the room, metres


def box_edges(lo, hi) -> np.ndarray:
    """The 12 edges (12, 2, 3) of an axis-aligned box."""
    P = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return np.array([[P[i], P[j]] for i in range(8) for j in range(i + 1, 8) if np.sum(P[i] != P[j]) == 1])


def kitchen_view(t: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The arcs a camera at ``t`` sees in a furnished box room: the creases (the floor creases behind
    the cabinets and the corners' lower parts hidden), cabinet runs with doors, a table, a sofa, a shelf."""
    segs = []
    for s in box_edges((0, 0, 0), (W, D, H)):
        if s[0, 2] == s[1, 2] == 0 and (s[0, 1] == s[1, 1] == 0 or s[0, 0] == s[1, 0] == 0):
            continue  # behind the cabinets
        if s[0, 2] != s[1, 2] and (s[0, 0] == 0 or s[0, 1] == 0):
            s = np.array([[s[0, 0], s[0, 1], 0.9], [s[0, 0], s[0, 1], H]])
        f = np.linspace(0, 1, 4)[:, None]
        pts = s[0] + f * (s[1] - s[0])
        segs += [np.stack([a, b]) for a, b in zip(pts[:-1], pts[1:])]  # a crease in three detections
    for lo, hi in (((0, 0, 0.1), (W - 0.6, 0.6, 0.9)), ((0, 0.6, 0.1), (0.6, D - 0.5, 0.9)),
                   ((1.6, 1.9, 0.72), (2.8, 2.7, 0.76)), ((W - 0.9, 1.2, 0.0), (W - 0.05, 3.2, 0.8)),
                   ((1.0, D - 0.35, 0.0), (2.2, D - 0.05, 1.9))):
        segs += list(box_edges(lo, hi))
    segs += [np.array([[x, 0.6, 0.1], [x, 0.6, 0.9]]) for x in np.arange(0.5, W - 0.6, 0.5)]
    segs += [np.array([[0.6, y, 0.1], [0.6, y, 0.9]]) for y in np.arange(1.1, D - 0.5, 0.5)]
    segs += [np.array([[1.0, D - 0.35, z], [2.2, D - 0.35, z]]) for z in (0.45, 0.85, 1.25, 1.6)]
    S = np.array(segs)
    return normalize(cam_from_world(S.reshape(-1, 3), R, t)).reshape(-1, 2, 3)


def test_the_outlier_process_leaves_clutter_unweighted_and_a_far_start_its_pull():
    """A pose whose points fit tightly (30 at 0.2 deg) among clutter spread over the window (300 within
    +-8 deg): each clutter point weighs a quarter of a fitting one at most. A start far off (all points
    spread 3 deg): they keep most of their pull."""
    rng = np.random.default_rng(0)
    s = np.sin(np.radians(1.0))
    tight = np.r_[rng.normal(0, np.radians(0.2), 30), rng.uniform(-1, 1, 300) * np.radians(8)]
    spread = rng.normal(0, np.radians(3.0), 60)
    r = torch.zeros((2, 330), dtype=torch.float64)
    r[0], r[1, :60] = torch.as_tensor(tight), torch.as_tensor(spread)
    valid = torch.zeros((2, 330), dtype=torch.bool)
    valid[0], valid[1, :60] = True, True
    scale = torch.tensor([[s], [4 * s]], dtype=torch.float64)  # a late round's scale, the first round's
    w = mixture_weights(r, valid, scale,
                         torch.full((2, 1), np.sin(np.radians(8.0)), dtype=torch.float64), np.sin(np.radians(0.5)))
    assert float(w[0, :30].mean()) > 4 * float(w[0, 30:].mean())
    assert float(w[1, :60].mean()) > 0.6 and float(w[1, 60:].abs().max()) == 0


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_start_at_the_truth_stays_among_furniture(kernel):
    """From the true pose in a kitchen whose floor creases the cabinets hide, the refinement stays
    within 2 cm with every kernel (the layout map holds the 12 creases alone)."""
    lines = box_edges((0, 0, 0), (W, D, H))
    groups = np.argmax(np.abs(lines[:, 1] - lines[:, 0]), axis=1)
    rng = np.random.default_rng(1)
    for t in ([1.8, 1.7, 1.45], [2.5, 1.5, 1.6], [2.8, 2.3, 1.5]):
        t = np.asarray(t)
        R = rotation_from_axis_angle(np.array([0, 0, 1.0]), rng.uniform(0, 2 * np.pi))
        arcs = kitchen_view(t, R)
        res = refine_poses_geometric(arcs, R[None], t[None], lines, groups, np.eye(3),
                                     params=GeometricParams(kernel=kernel), height_band=(0.3, 2.2))
        assert res.accepted[0] and np.linalg.norm(res.centers[0] - t) < 0.02, (kernel, res.centers[0] - t)


def test_an_unknown_kernel_is_refused():
    lines = box_edges((0, 0, 0), (W, D, H))
    groups = np.argmax(np.abs(lines[:, 1] - lines[:, 0]), axis=1)
    t, R = np.array([1.8, 1.7, 1.45]), np.eye(3)
    with pytest.raises(InputError, match="unknown refinement kernel"):
        refine_poses_geometric(kitchen_view(t, R), R[None], t[None], lines, groups, np.eye(3),
                               params=GeometricParams(kernel="tukey"))


def pieces(seg: np.ndarray, n: int) -> list[np.ndarray]:
    """A segment (2, 3) detected as ``n`` pieces."""
    f = np.linspace(0, 1, n + 1)[:, None]
    pts = seg[0] + f * (seg[1] - seg[0])
    return [np.stack([a, b]) for a, b in zip(pts[:-1], pts[1:])]


def railed_view(t: np.ndarray, R: np.ndarray) -> np.ndarray:
    """A room whose floor creases the furniture hides, with a picture rail 0.25 m under the ceiling along
    three walls (detected in five pieces each, the ceiling creases in three): the rails look like the
    ceiling creases of a camera 0.25 m higher."""
    segs, rails = [], 0
    for s in box_edges((0, 0, 0), (W, D, H)):
        if s[0, 2] == s[1, 2] == 0:  # hidden
            continue
        segs += pieces(s, 3)
        if s[0, 2] == s[1, 2] and rails < 3:
            segs += pieces(s - [0, 0, 0.25], 5)
            rails += 1
    S = np.array(segs)
    return normalize(cam_from_world(S.reshape(-1, 3), R, t)).reshape(-1, 2, 3)


def test_the_default_plan_keeps_the_truth_where_huber_slides():
    """Started at the truth in the railed room, Huber's weights take the rails for the ceiling creases and
    slide the camera 0.25 m up (the layout bench's slides: clutter near a crease outweighs it in the
    first, wide rounds); the default plan (:func:`refinement_plan`) also refines the start with
    Geman-McClure weights, which stay at the truth, so the truth is among the poses that compete."""
    lines = box_edges((0, 0, 0), (W, D, H))
    groups = np.argmax(np.abs(lines[:, 1] - lines[:, 0]), axis=1)
    rng = np.random.default_rng(1)
    for t in ([1.8, 1.7, 1.45], [2.8, 2.3, 1.5]):
        t = np.asarray(t)
        R = rotation_from_axis_angle(np.array([0, 0, 1.0]), rng.uniform(0, 2 * np.pi))
        cand, assoc, kernels = refinement_plan(1)
        Rs, ts = np.repeat(R[None], len(cand), 0), np.repeat(t[None], len(cand), 0)
        res = refine_poses_geometric(railed_view(t, R), Rs, ts, lines, groups, np.eye(3), height_band=(0.3, 2.2),
                                     assoc_deg=assoc, kernels=kernels)
        err = np.linalg.norm(res.centers - t, axis=1)
        huber = np.array(kernels) == "huber"
        assert huber.any() and (err[huber] > 0.2).all(), err  # Huber slides up to the rails
        assert res.accepted.all() and err.min() < 0.01, (kernels, err)


def test_a_symmetric_room_names_its_twin():
    """In a box seen from off its centre, the pose's twin half a turn about the box's centre is found from
    the lines the image confirms (no search candidate needed); a box room is not square, so no quarter turn."""
    m = _box_map()
    R0, t = _rz(30), BOX / 2 + [0.6, 0.9, -0.3]
    twins = room_twins(_arcs(m, R0, t), R0, t, m)
    assert len(twins) == 1
    (Rt, tt), = twins
    assert np.allclose(Rt, R0 @ _rz(180), atol=1e-9) and np.allclose(tt, BOX * [1, 1, 0] - t * [1, 1, -1], atol=0.02)
