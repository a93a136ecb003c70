"""Translations between a map's candidates, scored where the walk says a frame is.

A floor map's candidate translations fill its camera band (0.3-2.2 m above the floor) sparsely:
800 over a 27 x 11 m floor stand about 0.9 m apart, and the one nearest a frame's true position
is a median 0.45 m from it, so a frame with few lines scores its true pose below look-alikes
(docs/benchmarks.md, "Walks: synthetic building"). Around a confident frame of the walk,
:func:`lattice_poses` scores a fine lattice of translations at that frame's height (a walk is shot
at one height; the stairs change floors, not the camera's height above them), only where the map
has candidates near (its free space), at the frame's best rotations of the search near there: a
coarse inlier loss on the search's query points first (every lattice pose), then the exact loss
(:func:`ldlloc.search.pose_search.score_on_map`) of the best; the best of those, diverse, are
the frame's extra hypotheses. No map rebuild: the lattice is scored from the map's lines.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlloc.search.pose_search import diverse_subset, pose_labels, score_on_map, search_poses

spatial = lazy_module("scipy.spatial")

STOREY_M = 1.5  # map candidates within this height of the lattice tell its free space (not another floor's)


@dataclass(frozen=True)
class LatticeParams:
    """How :func:`lattice_poses` densifies a search near a confident frame (``spacing_m`` 0: off, the default:
    at 0.2 m it puts the true pose among a building walk's hypotheses far more often, but the walk's path
    did not gain from it: docs/benchmarks.md, "Walks: synthetic building")."""

    spacing_m: float = 0.0  # lattice spacing in xy (a true position is within spacing / sqrt(2) of a point); 0: off
    max_points: int = 1200  # at most about this many lattice points: a coarser lattice beyond (cost bounded)
    reach_m: float = 0.6  # a lattice point within this (xy) of a map candidate is free space
    rotations: int = 4  # the distinct rotations of the search's best poses scored at every point
    rescore: int = 64  # the best this many by the coarse loss get their exact loss
    keep: int = 20  # poses kept (diverse, best exact loss first)


def lattice_translations(translations: np.ndarray, center: np.ndarray, radius: float, p: LatticeParams) -> np.ndarray:
    """(N, 3) lattice points within ``radius`` (xy) of ``center`` at its height, ``p.spacing_m``
    apart (coarser when more than ``p.max_points`` would be free), each within ``p.reach_m`` (xy)
    of one of the map's candidate ``translations`` at about that height (:data:`STOREY_M`)."""
    T = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(center, dtype=np.float64)
    near = T[np.abs(T[:, 2] - c[2]) <= STOREY_M, :2]
    if len(near) == 0 or radius <= 0 or p.spacing_m <= 0:
        return np.zeros((0, 3))
    tree = spatial.cKDTree(near)
    spacing = float(p.spacing_m)
    while True:  # at most a few rounds: each coarsens by the share of points over the bound
        n = int(np.floor(radius / spacing))
        g = np.arange(-n, n + 1) * spacing
        P = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        P = P[np.einsum("ij,ij->i", P, P) <= radius * radius] + c[:2]
        d, _ = tree.query(P, k=1)
        P = P[d <= p.reach_m]
        if len(P) <= p.max_points * 1.05:
            break
        spacing *= float(np.sqrt(len(P) / p.max_points))
    return np.c_[P, np.full(len(P), c[2])]


def lattice_poses(arcs: np.ndarray, localizer, center: np.ndarray, radius: float, rotations: np.ndarray,
                  p: LatticeParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best poses of the lattice (:func:`lattice_translations`) around ``center`` within ``radius``
    on ``localizer``'s map for the frame's length-filtered ``arcs``, at the first ``p.rotations``
    distinct of ``rotations`` (the search's poses, best first): (K, 3, 3), (K, 3) and their exact
    losses (K,), best first; empty when no lattice point is free."""
    m, sp = localizer.map, localizer.params.search
    T = lattice_translations(m.translations, center, radius, p)
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    if len(T) == 0 or len(R) == 0 or len(arcs) == 0:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0)
    R = R[diverse_subset(np.zeros((len(R), 3)), R, p.rotations, 1.0, sp.diverse_rotation_deg)]
    tol = localizer.params.principal.group_tol
    labels = pose_labels(arcs, R, m.principal_directions, tol)
    vis = None if m.visibility is None else np.asarray(m.visibility)[m.nearest_translation(T)]
    coarse = search_poses(arcs, labels, R, m.lines, m.line_groups, T, replace(sp, use_fields=False, top_k=p.rescore),
                          localizer.device, fields=None, visibility=vis, num_groups=len(m.principal_directions))
    loss = score_on_map(arcs, coarse.rotations, coarse.centers, m, sp, localizer.device, tol)
    order = np.argsort(loss, kind="stable")
    Rk, tk, lk = coarse.rotations[order], coarse.centers[order], loss[order]
    keep = diverse_subset(tk, Rk, p.keep, sp.diverse_translation, sp.diverse_rotation_deg)
    return Rk[keep], tk[keep], lk[keep]

