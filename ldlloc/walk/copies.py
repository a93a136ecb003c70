"""Identical rooms in a walk: every copy of its room a frame's image found, weighed in the walk's margins.

A frame in one of several identical rooms (a hotel's rooms, an office row, a building's floors) has
its own pose refined in one copy, the one its refinement happened to land in among identical lines
and textures, and the other copies only as coarse search poses or not at all: the walk's path may
then choose a copy for what the refinement did, not for where the walk went. The walk's poses stay
as its path chooses them, but its margins (what a frame's verdict rests on) are also measured with
every copy the image found joined at the image's own pose's cost (:func:`even_copies`, used by
:func:`ldlloc.walk.localize.walk_margins`): a frame is sure of a copy only where the walk's motion
(the door it came in by, the walls, the floors) tells it, not its image.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ldlloc.confidence import features_decide
from ldlloc.refine.copies import find_copies
from ldlloc.walk.hypotheses import Hypotheses, joined, one_pose
from ldlloc.walk.motion import FreeSpace, MotionParams, straight_walk_costs


def copies_undecided(loc) -> bool:
    """Whether the image of refined pose ``loc`` named copies of its room and its features do not single
    the pose out among them (:func:`ldlloc.confidence.features_decide`): the walk must weigh the copies."""
    sig = (getattr(loc, "confidence_signals", None) or {}) if loc is not None else {}
    return loc is not None and bool(loc.refined) and float(sig.get("copies", 0.0)) > 0 and not features_decide(sig)


def room_copies(loc, entry, entries: list, index: dict[int, int], arcs: np.ndarray | None,
                hypotheses: Hypotheses) -> Hypotheses | None:
    """The poses of every copy of the room ``loc``'s pose stands in that its image's lines find on the
    walk's maps (:func:`ldlloc.refine.copies.find_copies`, not limited to the few its record names):
    ``entries`` the maps (``MapSet.entries``), ``entry`` its own map's, ``index`` ``id(MapEntry) -> index``,
    ``arcs`` its image's lines; each at the loss of its own pose (the final pose on its map among the
    frame's ``hypotheses``). None unless :func:`copies_undecided`."""
    if entry is None or arcs is None or not copies_undecided(loc):
        return None
    loz = entry.localizer
    maps = [(None, loz.map)] + [(e.scene, e.localizer.map) for e in entries if e is not entry]
    found = find_copies(arcs, np.asarray(loc.rot_cam_from_world, float), np.asarray(loc.center, float), loz.map,
                        maps, float(loc.confidence_signals.get("support", 0.0)), loz.params.geometric.support_deg,
                        limit=None)
    if not found:
        return None
    h = hypotheses
    own = h.final & (h.map_index == index[id(entry)])
    loss = float(np.min(h.loss[own] if own.any() else h.loss))
    by_scene = {e.scene: i for i, e in enumerate(entries)}
    k = [index[id(entry)] if f["map"] is None else by_scene[f["map"]] for f in found]
    n = len(found)
    return Hypotheses(np.array(k, dtype=np.int64), np.stack([f["R"] for f in found]).astype(np.float64),
                      np.stack([f["t"] for f in found]).astype(np.float64), np.full(n, loss),
                      np.zeros(n, dtype=bool))


def reachable_pose(poses: Hypotheses, own: int, last: tuple[int, np.ndarray, np.ndarray], frames: int,
                   motion: MotionParams, dt: float | None, free: FreeSpace | None,
                   margin: float | None = None) -> int | None:
    """Which of a relocalized frame's ``poses`` (its hypotheses and the copies of its room its image found,
    ``own`` its image's own pose among them) the walk takes on from: the least cost of the pose's lines
    (:meth:`Hypotheses.emission_costs`) and of the walk from its last trusted pose ``last`` (``(map index,
    R, t)``, ``frames`` frames of ``dt`` seconds before; None: unknown; :func:`ldlloc.walk.motion.straight_walk_costs`),
    where the own pose costs ``margin`` more (default: a change of floor away from the stairs,
    ``motion.off_stairs_cost``): the walk that came down the corridor took one door, not a room at the
    corridor's far end or on another floor. None otherwise: a frame that truly climbed a floor by the stairs keeps its image's
    floor (the motion cannot tell, the image's floor stands)."""
    start = one_pose(*last)
    cost = poses.emission_costs(motion.emission_weight) + straight_walk_costs(start, poses, frames, motion, dt, free)
    j = int(np.argmin(cost))
    return j if cost[own] - cost[j] > (motion.off_stairs_cost if margin is None else margin) else None


def even_copies(o):
    """Frame ``o`` (a :class:`ldlloc.walk.localize.FrameOutcome`) with every copy of its room
    (``o.copies``: :func:`room_copies`) among its hypotheses, after its own, each named as its image's
    competitor (it costs what the image's own pose does: only the walk tells them apart); ``o`` itself
    when it has none. The joined hypotheses are kept on ``o`` (``o.even``) while its own and its copies
    stay the same (one object: the walk's cost caches key on it)."""
    if o.copies is None or o.hypotheses is None:
        return o
    c = o.copies
    if o.even is None or o.even[0] is not o.hypotheses or o.even[1] is not c:
        o.even = (o.hypotheses, c, joined(o.hypotheses, c.map_index, c.rot_cam_from_world, c.center, c.loss))
    named = [{"R": R, "t": t} for R, t in zip(c.rot_cam_from_world, c.center)]
    return replace(o, hypotheses=o.even[2], competitors=list(o.competitors) + named)
