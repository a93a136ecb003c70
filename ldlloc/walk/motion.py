"""What a walking person can do between two frames: the transition costs of a walk's path.

A step costs nothing up to a free length (a tour: the metres between shots; a video: a walking
speed times the frames' time apart), then its extra length over a step scale, capped at the jump
cost: a jump of 8-12 m between two tour shots (a room skipped) is unlikely, not impossible. A change
of floor (a height change of :attr:`MotionParams.floor_dz_m` or more) costs more than any jump: floors change only on stairs
or in a lift, rarely. With ``turn_deg`` (videos: the camera turns little between frames) a
rotation costs its angle over it, capped the same way. Costs are negative log-likelihoods
(nats), added to the frames' emission costs (:mod:`ldlloc.walk.hypotheses`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MotionParams:
    """The motion model of a walk (defaults: a capture tour of photos)."""

    free_m: float = 5.0  # a step this long or shorter costs nothing (tours: shots 0.6-5 m apart) ...
    speed_mps: float = 1.4  # ... with times (videos): this walking speed times the frames' time apart ...
    min_free_m: float = 0.3  # ... but at least this (a frame's pose error)
    step_m: float = 1.5  # beyond the free length, each step_m more costs 1 ...
    jump_cost: float = 4.0  # ... up to this: a jump (8-12 m between tour shots) stays possible
    floor_dz_m: float = 1.5  # a height change of this or more is a change of floor ...
    floor_cost: float = 8.0  # ... and costs this (stairs or a lift: rare, but a walk may take them)
    turn_deg: float | None = None  # videos: a turn of this many degrees costs 1 (None: turns are free, tours)
    emission_weight: float = 20.0  # a frame's pose that explains no line costs this (the best pose 0)
    anchor_cost: float = 6.0  # a pose distinct from a frame's own confident pose costs this more (less than two jumps:
    # a confident pose in the wrong copy of a room, reached and left by jumps, still gives way)
    own_cost: float = 0.5  # ... or this when it was not, unless the image named that pose as its competitor (a copy
    # of a room it cannot tell from its own pose costs nothing more: the motion decides)


def free_length(params: MotionParams, dt: float | None) -> float:
    """Metres a step may cover for free: ``free_m``, or with a time gap ``dt`` (s) the walking speed times it."""
    if dt is None or not np.isfinite(dt) or dt <= 0:
        return params.free_m
    return max(params.min_free_m, params.speed_mps * float(dt))


def transition_costs(prev, cur, params: MotionParams, dt: float | None = None) -> np.ndarray:
    """(H_prev, H_cur) costs of moving from each pose of ``prev`` to each of ``cur`` (both
    :class:`ldlloc.walk.hypotheses.Hypotheses`); ``dt``: their time apart in seconds (None: unknown)."""
    d = prev.center[:, None, :] - cur.center[None, :, :]
    dist = np.linalg.norm(d, axis=2)
    cost = np.clip((dist - free_length(params, dt)) / params.step_m, 0.0, params.jump_cost)
    if params.turn_deg is not None:
        c = np.einsum("aij,bij->ab", prev.rot_cam_from_world, cur.rot_cam_from_world)  # trace(Ra^T Rb)
        ang = np.degrees(np.arccos(np.clip((c - 1.0) / 2.0, -1.0, 1.0)))
        cost = np.minimum(cost + ang / params.turn_deg, params.jump_cost)
    return np.where(np.abs(d[:, :, 2]) >= params.floor_dz_m, params.floor_cost, cost)
