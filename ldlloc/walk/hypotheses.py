"""One frame's hypotheses: the poses a walk may choose from, over every map.

For each map that was searched, its top-K search poses; for each map that was refined, its
final pose too (:class:`ldlloc.batch.which_map.MapChoice`). Losses are the line-distance
inlier losses (negative inlier counts, lower is better): the same query lines for every map,
so they compare across maps and poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlloc.confidence import distinct

MAX_HYPOTHESES = 48  # per frame: the final poses and the best search poses (memory bounded in a walk's length)


@dataclass
class Hypotheses:
    """The poses of one frame (H of them), best loss first among the search poses."""

    map_index: np.ndarray  # (H,) int: index of the map (MapSet.entries)
    rot_cam_from_world: np.ndarray  # (H, 3, 3)
    center: np.ndarray  # (H, 3)
    loss: np.ndarray  # (H,) lower is better
    final: np.ndarray  # (H,) bool: a map's refined final pose (else a coarse search pose)

    def __len__(self) -> int:
        return len(self.loss)

    def take(self, idx: np.ndarray) -> "Hypotheses":
        """The poses at ``idx`` (indices or a mask), in that order."""
        return Hypotheses(self.map_index[idx], self.rot_cam_from_world[idx], self.center[idx], self.loss[idx],
                          self.final[idx])

    def emission_costs(self, weight: float) -> np.ndarray:
        """(H,) the cost of each pose from its image alone: ``weight * (1 - loss / best)``, 0 for the
        best loss of the frame, ``weight`` for a pose that explains no line (losses are negative)."""
        best = float(np.min(self.loss)) if len(self.loss) else 0.0
        if best >= 0:  # no inlier anywhere: the image says nothing
            return np.zeros(len(self.loss))
        return weight * np.clip(1.0 - self.loss / best, 0.0, 1.0)


def from_choice(choice, map_index: dict[int, int], limit: int = MAX_HYPOTHESES) -> Hypotheses:
    """The hypotheses of a frame localized on several maps (or one): ``choice`` a
    :class:`ldlloc.batch.which_map.MapChoice` whose options carry their search (``searched``);
    ``map_index``: ``id(MapEntry) -> index``. A search pose that is the same pose as its map's final
    one (:func:`ldlloc.confidence.distinct`) is left out: the final pose stands for it."""
    idx, R, t, loss, final = [], [], [], [], []
    for o in choice.ranked:
        k = map_index[id(o.entry)]
        finals = []
        if o.loc is not None:
            own = o.loss if o.loss is not None else float(np.min(o.loc.candidates_loss))
            idx.append(k), R.append(np.asarray(o.loc.rot_cam_from_world, float))
            t.append(np.asarray(o.loc.center, float)), loss.append(float(own)), final.append(True)
            finals.append(len(R) - 1)
        s = o.searched
        if s is None or s.candidates_loss is None:
            continue
        Rs, ts = np.asarray(s.candidates_rot, float), np.asarray(s.candidates_center, float)
        keep = np.ones(len(Rs), dtype=bool)
        for f in finals:
            keep &= distinct(R[f], t[f], Rs, ts)
        for i in np.flatnonzero(keep):
            idx.append(k), R.append(Rs[i]), t.append(ts[i])
            loss.append(float(s.candidates_loss[i])), final.append(False)
    h = Hypotheses(np.array(idx, dtype=np.int64), np.array(R, dtype=np.float64).reshape(-1, 3, 3),
                   np.array(t, dtype=np.float64).reshape(-1, 3), np.array(loss, dtype=np.float64),
                   np.array(final, dtype=bool))
    return bounded(h, limit)


def one_pose(map_index: int, R, t, loss: float = 0.0, final: bool = False) -> Hypotheses:
    """A single pose (``R`` cam-from-world, centre ``t``) on map ``map_index`` as hypotheses."""
    return Hypotheses(np.array([map_index], dtype=np.int64), np.asarray(R, float)[None], np.asarray(t, float)[None],
                      np.array([float(loss)]), np.array([bool(final)]))


def joined(h: Hypotheses, map_index: int | np.ndarray, rots: np.ndarray, centers: np.ndarray,
           losses: np.ndarray) -> Hypotheses:
    """``h`` with more (coarse) poses appended: of one map (``map_index`` an int) or each of its own (an array)."""
    n = len(losses)
    return Hypotheses(np.r_[h.map_index, np.broadcast_to(np.asarray(map_index, dtype=np.int64), (n,))],
                      np.concatenate([h.rot_cam_from_world, np.asarray(rots, float).reshape(-1, 3, 3)]),
                      np.concatenate([h.center, np.asarray(centers, float).reshape(-1, 3)]),
                      np.r_[h.loss, np.asarray(losses, float)], np.r_[h.final, np.zeros(n, dtype=bool)])


def bounded(h: Hypotheses, limit: int) -> Hypotheses:
    """At most ``limit`` hypotheses: every final pose, then the search poses of lowest loss (stable)."""
    if len(h) <= limit:
        return h
    order = np.lexsort((h.loss, ~h.final))[:limit]  # finals first, then by loss
    order = np.sort(order)
    return Hypotheses(h.map_index[order], h.rot_cam_from_world[order], h.center[order], h.loss[order], h.final[order])
