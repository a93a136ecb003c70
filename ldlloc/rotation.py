"""2D principal directions (vanishing points) and candidate rotations (paper sec. 3.2).

Vanishing points. Every 2D arc lies on a great circle with unit normal ``n``; the circle passes
through a sphere point ``d`` (and ``-d``) when ``n . d = 0``. Candidate directions are the
vertices of a half icosphere (level 5: 5121 directions, ~1.8 degrees apart). A candidate gets a
vote from each arc with ``|n . d| < vote_tol`` (0.05, ~2.9 degrees), weighted by the arc's
length in radians (long arcs are reliable; many tiny noisy arcs should not outvote them). The
winner is refined to the least-squares direction of its voters (the eigenvector of
``sum w n n^T`` with the smallest eigenvalue, i.e. the point closest to all their great
circles), its voters (w.r.t. the refined direction) are removed, and the voting repeats
``k_2d`` = 20 times or until no arc is left.

Rotations. For every triplet of 2D directions whose pairwise angles match those of the 3 map
principal directions (up to sign, within ``ortho_tol_deg``), and every assignment of the triplet
to the 3D directions (3! permutations) and signs (2^3), Kabsch gives the rotation R (world to
camera) minimising ``sum_i |R p3d_i - s_i p2d_pi(i)|^2``. Proper rotations whose mean squared
residual is below ``residual_tol`` are kept, sorted by residual, and near-duplicates (angle
below ``dedup_deg``) are dropped, keeping the lowest residual. For a Manhattan scene every
physical rotation appears with its 24 relabelings: they are all kept, since the decomposed
distance functions tell them apart. Nothing here assumes right angles: the triplet's angles are
the map's own, so an Atlanta frame (the vertical and two horizontals at e.g. 45 degrees) is
matched by triplets at those angles, with fewer relabelings (4 per physical rotation
when the horizontals are not perpendicular).

More than three map directions (an Atlanta frame of the vertical and 3-6 horizontals):
every triplet of map directions that is not coplanar (the vertical and two horizontals; three
horizontals fix no tilt from angles alone) is matched as above, the rotations of all are pooled
and de-duplicated together with the rotations of pairs (any two non-parallel matched directions fix
a rotation; the perpendicular pairs, i.e. the vertical and each horizontal, are matched to pairs of
vanishing points at 90 deg, so a view of the vertical and one wall direction, where no triplet
matches, still gets its rotation), and each candidate then pairs every map direction ``j`` with the vanishing
point nearest ``R p_j`` (within ``ortho_tol_deg``; -1 when none), so arcs are grouped for all K
directions (:func:`rotation_labels`: through that vanishing point, or through ``R p_j`` itself
where none was voted). A sloped ceiling's inclined directions (maps of kind "sloped") take part in
that pairing only: the rotations come from the vertical and the horizontals (:func:`frame_rows`),
which every such room has, as they would without the slope (a Manhattan frame's triplets alone),
so the inclined rows group the slope's arcs without multiplying the candidates. A 3-direction map
uses triplets only; where they match nothing (:func:`pair_candidates`, the pipeline's fallback)
its perpendicular pairs give the rotations, the unseen direction unpaired.

Upright prior (:func:`filter_by_tilt`, ``ldlloc localize/run --max-tilt DEG``): an option beyond
the paper, whose rotation is free. The camera's up axis is camera +z, in the world
``R.T @ e_z`` (the last row of ``R``); its tilt is the angle to the world's up ``e_z``,
``arccos(R[2, 2])``. Of a Manhattan scene's 24 relabelings of one physical rotation, only the 4
turns about z keep the camera upright, so the prior removes the candidates that lie the camera on
its side (which real panoramas, taken upright, never are).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations, permutations, product

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import angle_from_trace_deg, half_icosphere_points
from ldlmap.lines3d.principal import FrameParams

ARC_GROUP_TOL = 0.05  # an arc joins the principal group of direction p when |n . p| < this (n: its
# great circle's normal): the one arc-group tolerance of rotations, pose scoring and geometric refinement


@dataclass(frozen=True)
class PrincipalParams:
    """Parameters of vanishing-point voting and rotation candidates."""

    k_2d: int = 20
    """k_2D: number of 2D principal directions (vanishing points)."""
    vote_tol: float = 0.05
    """|n . d| below this: the arc's great circle passes through d (votes for it)."""
    icosphere_level: int = 5
    """Candidate directions: the half icosphere of this level."""
    ortho_tol_deg: float = 6.0
    """2D triplet angles must match the 3D triplet's within this."""
    residual_tol: float = 0.01
    """Largest mean squared Kabsch residual (chord^2; 0.01 ~ 5.7 deg rms)."""
    dedup_deg: float = 2.5
    """Rotations closer than this are duplicates."""
    group_tol: float = ARC_GROUP_TOL
    """An arc joins principal group i when |n . p_i| < this."""


@dataclass(frozen=True)
class RotationCandidates:
    """Candidate rotations (world to camera) and how each was obtained.

    ``R @ principal3d[j] ~ signs[j] * vp2d[triplets[j]]`` for each candidate and each map
    direction j that a vanishing point matches (``triplets[j] >= 0``; always, with 3 directions).
    """

    rotations: np.ndarray  # (N_r, 3, 3)
    triplets: np.ndarray  # (N_r, K) int: index into vp2d matched to 3D direction j (-1: none, K > 3 only)
    signs: np.ndarray  # (N_r, K) +-1
    residuals: np.ndarray  # (N_r,) mean squared residual of the alignment

    def __len__(self) -> int:
        return int(len(self.rotations))

    def subset(self, keep: np.ndarray) -> "RotationCandidates":
        """The candidates selected by ``keep`` (a mask or indices), in that order."""
        return RotationCandidates(self.rotations[keep], self.triplets[keep], self.signs[keep], self.residuals[keep])


# ------------------------------------------------------------------------------------- helpers


def _check_arcs(arcs: np.ndarray) -> np.ndarray:
    arcs = np.asarray(arcs, dtype=np.float64)
    if arcs.ndim != 3 or arcs.shape[1:] != (2, 3):
        raise InputError(f"arcs must have shape (N, 2, 3), got {arcs.shape}")
    if not np.isfinite(arcs).all():
        raise InputError("arcs contain NaN or infinite values")
    return arcs


def arc_normals(arcs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit great-circle normals (N, 3) and arc lengths in radians (N,).

    Degenerate arcs (zero length or antipodal ends) get a zero normal and length 0 or pi.
    """
    arcs = _check_arcs(arcs)
    s, e = arcs[:, 0], arcs[:, 1]
    n = np.cross(s, e)
    nn = np.linalg.norm(n, axis=1)
    length = np.arctan2(nn, np.sum(s * e, axis=1))
    normals = np.where(nn[:, None] > 1e-9, n / np.maximum(nn, 1e-12)[:, None], 0.0)
    return normals, length


def _refine_direction(normals: np.ndarray, weights: np.ndarray, d0: np.ndarray) -> np.ndarray:
    """Direction closest to all great circles: smallest eigenvector of sum w n n^T, sign of d0."""
    M = (normals * weights[:, None]).T @ normals
    _, vecs = np.linalg.eigh(M)
    d = vecs[:, 0]
    return d if d @ d0 >= 0 else -d


# ------------------------------------------------------------------------------ vanishing points


def vanishing_points(arcs: np.ndarray, k: int = 20, params: PrincipalParams = PrincipalParams(),
                     return_counts: bool = False):
    """Top-``k`` 2D principal directions (unit, camera frame) by greedy voting.

    Returns (k', 3) with k' <= k (fewer when the arcs run out), ordered by votes; with
    ``return_counts`` also the (k',) weighted vote of each.
    """
    normals, length = arc_normals(arcs)
    valid = np.linalg.norm(normals, axis=1) > 0
    normals, weight = normals[valid], length[valid]
    cands = np.asarray(half_icosphere_points(params.icosphere_level), dtype=np.float32)
    # Incidence of every arc with every candidate, computed once: (N, C) bool. Votes are
    # computed once and then decremented by the rows of removed arcs only.
    incident = np.abs(normals.astype(np.float32) @ cands.T) < params.vote_tol
    w32 = weight.astype(np.float32)
    score = w32 @ incident.astype(np.float32) if len(w32) else np.zeros(len(cands), np.float32)
    alive = np.ones(len(normals), dtype=bool)
    dirs, votes = [], []
    for _ in range(int(k)):  # k greedy rounds (k = 20), each vectorized
        if not alive.any():
            break
        best = int(np.argmax(score))
        if score[best] <= 1e-6:
            break
        voters = alive & incident[:, best]
        d = _refine_direction(normals[voters], weight[voters], cands[best].astype(np.float64))
        # Remove the arcs through the refined direction (and the original voters).
        voters |= alive & (np.abs(normals @ d) < params.vote_tol)
        alive &= ~voters
        dirs.append(d)
        votes.append(float(score[best]))
        score = score - w32[voters] @ incident[voters].astype(np.float32)
    out = np.array(dirs, dtype=np.float64).reshape(-1, 3)
    return (out, np.array(votes)) if return_counts else out


# ------------------------------------------------------------------------------------ rotations


_PERMS = np.array(list(permutations(range(3))), dtype=np.int64)  # (6, 3)
_SIGNS = np.array(list(product((1.0, -1.0), repeat=3)))  # (8, 3)


def _kabsch(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Proper rotations R (M, 3, 3) minimising sum_i |R a_i - b_i|^2 and the mean residuals (M,).

    ``A``, ``B``: (M, 3, 3) with the vectors as rows.
    """
    H = np.einsum("mia,mib->mab", A, B)  # sum_i a_i b_i^T
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    d[d == 0] = 1.0
    D = np.zeros_like(H)
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = V @ D @ np.swapaxes(U, 1, 2)
    res = np.mean(np.sum((np.einsum("mab,mib->mia", R, A) - B) ** 2, axis=-1), axis=-1)
    return R, res


MIN_TRIPLET_DET = 0.2  # map triplets with |det| below this are (near) coplanar: not matched (K > 3)


def candidate_rotations(vp2d: np.ndarray, principal3d: np.ndarray,
                        ortho_tol_deg: float | None = None, residual_tol: float | None = None,
                        params: PrincipalParams = PrincipalParams(), seed: np.ndarray | None = None
                        ) -> RotationCandidates:
    """Candidate rotations from 2D vanishing points and the map's K >= 3 principal directions.

    Args:
        vp2d: (k, 3) unit 2D principal directions (camera frame), e.g. :func:`vanishing_points`.
        principal3d: (K, 3) unit 3D principal directions (world frame), one per row.
        ortho_tol_deg, residual_tol: override ``params`` (see :class:`PrincipalParams`).
        seed: (K,) bool, K > 3 only: the map directions whose triplets and pairs give rotations
            (:func:`frame_rows`: the vertical and the horizontals); the others (a sloped ceiling's
            inclined directions) are only paired with vanishing points. None: all.

    Returns:
        :class:`RotationCandidates` sorted by residual (possibly empty).
    """
    vp = np.asarray(vp2d, dtype=np.float64)
    P = np.asarray(principal3d, dtype=np.float64)
    if vp.ndim != 2 or vp.shape[1] != 3:
        raise InputError(f"2D principal directions must have shape (k, 3), got {vp.shape}")
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 3:
        raise InputError(f"3D principal directions must have shape (K, 3) with K >= 3, got {P.shape}")
    if not (np.isfinite(vp).all() and np.isfinite(P).all()):
        raise InputError("principal directions contain NaN or infinite values")
    if len(P) > 3:
        return _candidates_of_many(vp, P, ortho_tol_deg, residual_tol, params, seed)
    ortho = params.ortho_tol_deg if ortho_tol_deg is None else ortho_tol_deg
    rtol = params.residual_tol if residual_tol is None else residual_tol
    vp = vp / np.maximum(np.linalg.norm(vp, axis=1, keepdims=True), 1e-12)
    P = P / np.maximum(np.linalg.norm(P, axis=1, keepdims=True), 1e-12)
    empty = _empty(3)
    if len(vp) < 3:
        return empty
    tri = np.array(list(combinations(range(len(vp)), 3)), dtype=np.int64)  # (T, 3), T <= 1140
    # Pairwise angles (as lines, in [0, 90] deg) of each 2D triplet vs the 3D triplet, per
    # permutation: 2D pair (perm[a], perm[b]) must match 3D pair (a, b).
    def line_angles(V: np.ndarray) -> np.ndarray:  # (..., 3, 3) -> (..., 3) for pairs 01, 02, 12
        c = np.abs(np.stack([np.sum(V[..., 0, :] * V[..., 1, :], -1), np.sum(V[..., 0, :] * V[..., 2, :], -1),
                             np.sum(V[..., 1, :] * V[..., 2, :], -1)], -1))
        return np.degrees(np.arccos(np.clip(c, 0.0, 1.0)))

    ang3 = line_angles(P)  # (3,)
    V2 = vp[tri][:, _PERMS]  # (T, 6, 3, 3): row j = 2D direction assigned to 3D direction j
    ok = np.all(np.abs(line_angles(V2) - ang3) < ortho, axis=-1)  # (T, 6)
    ti, pi = np.nonzero(ok)
    if len(ti) == 0:
        return empty
    # Every sign combination of the surviving (triplet, permutation) pairs.
    B = V2[ti, pi][:, None] * _SIGNS[None, :, :, None]  # (M, 8, 3, 3)
    M = B.shape[0] * 8
    A = np.broadcast_to(P, (M, 3, 3))
    R, res = _kabsch(A, B.reshape(M, 3, 3))
    keep = res < rtol
    triplets = np.repeat(tri[ti][np.arange(len(ti))[:, None], _PERMS[pi]], 8, axis=0)[keep]
    signs = np.tile(_SIGNS, (len(ti), 1))[keep]
    R, res = R[keep], res[keep]
    order = np.argsort(res, kind="stable")
    R, res, triplets, signs = R[order], res[order], triplets[order], signs[order]
    keep = _distinct(R, params.dedup_deg)
    return RotationCandidates(R[keep], triplets[keep].astype(np.int64), signs[keep], res[keep])


def frame_rows(principal3d: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0),
               tol_deg: float = FrameParams.horizontal_deg) -> np.ndarray:
    """(K,) bool: the map directions within ``tol_deg`` of ``up`` or of horizontal (the map
    frame's up is z): the vertical and the horizontals, not a sloped ceiling's inclined directions."""
    P = np.asarray(principal3d, dtype=np.float64)
    u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    c = np.abs(P @ u) / np.maximum(np.linalg.norm(P, axis=1), 1e-12)
    return (c < np.sin(np.radians(tol_deg))) | (c > np.cos(np.radians(tol_deg)))


def _empty(k: int) -> RotationCandidates:
    return RotationCandidates(np.zeros((0, 3, 3)), np.zeros((0, k), np.int64), np.zeros((0, k)), np.zeros(0))


def _distinct(R: np.ndarray, dedup_deg: float) -> np.ndarray:
    """Mask of the rotations (N, 3, 3), in their order, that are not within ``dedup_deg`` of an
    earlier kept one (greedy, vectorized over all pairs)."""
    keep = np.ones(len(R), dtype=bool)
    if len(R):
        tr = np.einsum("aij,bij->ab", R, R)  # trace(R_a^T R_b)
        close = angle_from_trace_deg(tr) < dedup_deg
        for i in range(len(R)):  # N_r ~ 10-1000 candidates, a cheap loop over candidates
            if keep[i]:
                dup = close[i].copy()
                dup[: i + 1] = False
                keep &= ~dup
    return keep


def _pair_rotations(vp: np.ndarray, P: np.ndarray, ortho: float, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (M, 3, 3) and residuals (M,) from pairs: every perpendicular pair of map
    directions (the vertical and each horizontal) matched to every pair of vanishing points at 90
    deg (within ``ortho``), both orders and all signs; the third vector of each side is the cross
    product of the two. Where a view shows the vertical and one wall direction only, no triplet
    of vanishing points matches, but a pair does."""
    sin_tol = np.sin(np.radians(ortho))
    pa, pb = np.nonzero(np.triu(np.abs(P @ P.T) < sin_tol, 1))
    va, vb = np.nonzero(np.abs(vp @ vp.T) < sin_tol)  # both orders (the matrix is symmetric)
    if not len(pa) or not len(va):
        return np.zeros((0, 3, 3)), np.zeros(0)
    A = np.stack([P[pa], P[pb], np.cross(P[pa], P[pb])], 1)  # (Pm, 3, 3)
    signs = np.array(list(product((1.0, -1.0), repeat=2)))  # (4, 2)
    a = vp[va][None] * signs[:, None, :1]  # (4, Vm, 3)
    b = vp[vb][None] * signs[:, None, 1:]
    B = np.stack([a, b, np.cross(a, b)], 2).reshape(-1, 3, 3)  # (4 Vm, 3, 3)
    AA = np.repeat(A, len(B), 0)
    BB = np.tile(B, (len(A), 1, 1))
    R, res = _kabsch(AA, BB)
    keep = res < rtol
    return R[keep], res[keep]


def _candidates_of_many(vp: np.ndarray, P: np.ndarray, ortho_tol_deg: float | None, residual_tol: float | None,
                        params: PrincipalParams, seed: np.ndarray | None = None) -> RotationCandidates:
    """:func:`candidate_rotations` for K > 3 map directions: every non-coplanar triplet of the
    ``seed`` map directions matched, the rotations pooled in residual order and de-duplicated, then
    every map direction paired with the vanishing point nearest its image (see the module docstring)."""
    P = P / np.maximum(np.linalg.norm(P, axis=1, keepdims=True), 1e-12)
    vp = vp / np.maximum(np.linalg.norm(vp, axis=1, keepdims=True), 1e-12)
    ortho = params.ortho_tol_deg if ortho_tol_deg is None else ortho_tol_deg
    rows = np.arange(len(P)) if seed is None or np.count_nonzero(seed) < 3 else np.flatnonzero(seed)
    if len(rows) == 3:  # a Manhattan (or 3-direction Atlanta) frame and inclined rows: its own triplets only
        c = candidate_rotations(vp, P[rows], ortho_tol_deg, residual_tol, params)
        rots, res = [c.rotations], [c.residuals]
    else:
        rots, res = [], []
        for trip in combinations(rows.tolist(), 3):
            if abs(np.linalg.det(P[list(trip)])) < MIN_TRIPLET_DET:
                continue
            c = candidate_rotations(vp, P[list(trip)], ortho_tol_deg, residual_tol, params)
            rots.append(c.rotations)
            res.append(c.residuals)
        rtol = params.residual_tol if residual_tol is None else residual_tol
        pair_rots, pair_res = _pair_rotations(vp, P[rows], ortho, rtol)
        rots.append(pair_rots)
        res.append(pair_res)
    return _matched(np.concatenate(rots), np.concatenate(res), vp, P, ortho, params.dedup_deg)


def pair_candidates(vp2d: np.ndarray, principal3d: np.ndarray, params: PrincipalParams = PrincipalParams()
                    ) -> RotationCandidates:
    """Candidate rotations from perpendicular pairs alone (:func:`_pair_rotations`), each map
    direction paired with its nearest vanishing point (-1 when none): the fallback of a 3-direction
    map whose triplets match nothing (a corridor seen along its length: the vertical and the
    corridor's direction as vanishing points, the cross direction's lines too short to vote)."""
    P = np.asarray(principal3d, dtype=np.float64)
    P = P / np.maximum(np.linalg.norm(P, axis=1, keepdims=True), 1e-12)
    vp = np.asarray(vp2d, dtype=np.float64).reshape(-1, 3)
    vp = vp / np.maximum(np.linalg.norm(vp, axis=1, keepdims=True), 1e-12)
    R, res = _pair_rotations(vp, P, params.ortho_tol_deg, params.residual_tol)
    return _matched(R, res, vp, P, params.ortho_tol_deg, params.dedup_deg)


def _matched(R: np.ndarray, res: np.ndarray, vp: np.ndarray, P: np.ndarray, ortho: float,
             dedup_deg: float) -> RotationCandidates:
    """Rotations (M, 3, 3) sorted by residual and de-duplicated, each map direction paired with the
    vanishing point nearest its image (within ``ortho`` deg; -1 when none)."""
    if not len(R):
        return _empty(len(P))
    order = np.argsort(res, kind="stable")
    R, res = R[order], res[order]
    keep = _distinct(R, dedup_deg)
    R, res = R[keep], res[keep]
    img = np.einsum("rab,kb->rka", R, P)  # (N_r, K, 3): R p_j
    dots = np.einsum("rka,va->rkv", img, vp)  # (N_r, K, V)
    best = np.abs(dots).argmax(-1)
    cos = np.take_along_axis(dots, best[..., None], -1)[..., 0]
    matched = np.abs(cos) >= np.cos(np.radians(ortho))
    triplets = np.where(matched, best, -1).astype(np.int64)
    signs = np.where(cos < 0, -1.0, 1.0)
    return RotationCandidates(R, triplets, signs, res)


# ------------------------------------------------------------------------------------- grouping


def assign_arcs_to_principal(arcs: np.ndarray, dirs: np.ndarray, tol: float = ARC_GROUP_TOL) -> np.ndarray:
    """Principal group of each arc: (N,) int in {0, 1, 2}, -1 for none.

    An arc joins group i when its great circle passes through ``dirs[i]`` (``|n . p_i| < tol``),
    taking the smallest ``|n . p_i|`` of the three.
    """
    normals, _ = arc_normals(arcs)
    D = np.asarray(dirs, dtype=np.float64)
    if D.ndim != 2 or D.shape[1] != 3:
        raise InputError(f"principal directions must have shape (k, 3), got {D.shape}")
    c = np.abs(normals @ D.T)
    g = np.argmin(c, axis=1) if len(D) else np.zeros(len(normals), np.int64)
    ok = (np.take_along_axis(c, g[:, None], 1)[:, 0] < tol) & (np.linalg.norm(normals, axis=1) > 0)
    return np.where(ok, g, -1).astype(np.int64)


def rotation_labels(arcs: np.ndarray, vp2d: np.ndarray, rots: RotationCandidates, principal3d: np.ndarray,
                    tol: float = ARC_GROUP_TOL) -> np.ndarray:
    """2D group labels per rotation candidate, (N_r, N) int, for the map's K principal directions:
    :func:`labels_for_rotations` with 3 all matched; otherwise arc ``l`` joins group ``j`` when its great
    circle passes (the smallest of the K ``|n . p|``, below ``tol``) through the vanishing point
    matched to direction ``j``, or through ``R p_j`` where none was matched; -1 otherwise."""
    P = np.asarray(principal3d, dtype=np.float64)
    if len(P) == 3 and np.all(rots.triplets >= 0):
        return labels_for_rotations(arcs, vp2d, rots.triplets, tol)
    normals, _ = arc_normals(arcs)
    vp = np.asarray(vp2d, dtype=np.float64).reshape(-1, 3)
    img = np.einsum("rab,kb->rka", rots.rotations, P)  # (N_r, K, 3)
    trip = np.asarray(rots.triplets, dtype=np.int64)
    if len(vp):
        img = np.where((trip >= 0)[..., None], vp[np.clip(trip, 0, None)], img)
    c = np.abs(np.einsum("na,rka->rnk", normals, img))  # (N_r, N, K)
    g = np.argmin(c, axis=2)
    ok = (np.min(c, axis=2) < tol) & (np.linalg.norm(normals, axis=1) > 0)[None, :]
    return np.where(ok, g, -1).astype(np.int64)


def labels_for_rotations(arcs: np.ndarray, vp2d: np.ndarray, triplets: np.ndarray,
                         tol: float = ARC_GROUP_TOL) -> np.ndarray:
    """2D group labels per rotation candidate, (N_r, N) int.

    ``labels[r, l] = j`` when arc ``l`` passes through ``vp2d[triplets[r, j]]`` (the smallest of
    the three ``|n . p|``, below ``tol``), so 2D group ``j`` pairs with 3D principal direction
    ``j`` under rotation ``r``; -1 otherwise.
    """
    normals, _ = arc_normals(arcs)
    trip = np.asarray(triplets, dtype=np.int64)
    if trip.ndim != 2 or trip.shape[1] != 3:
        raise InputError(f"triplets must have shape (N_r, 3), got {trip.shape}")
    c = np.abs(normals @ np.asarray(vp2d, dtype=np.float64).T)  # (N, k)
    ct = c[:, trip]  # (N, N_r, 3)
    g = np.argmin(ct, axis=2)
    ok = (np.min(ct, axis=2) < tol) & (np.linalg.norm(normals, axis=1) > 0)[:, None]
    return np.where(ok, g, -1).T.astype(np.int64)


# --------------------------------------------------------------------------------- upright prior

FREE_TILT_DEG = 180.0  # the largest tilt: a bound of this or more is free rotation


def check_max_tilt(max_tilt_deg: float | None, name: str = "max_tilt_deg") -> None:
    """A one-line InputError unless the upright prior's bound is None (free) or in (0, :data:`FREE_TILT_DEG`]
    degrees (``name``: how the caller calls it)."""
    if max_tilt_deg is not None and not (0.0 < max_tilt_deg <= FREE_TILT_DEG):
        raise InputError(f"{name} must be in (0, {FREE_TILT_DEG:g}] degrees, got {max_tilt_deg:g}")


def camera_tilt_deg(rotations: np.ndarray) -> np.ndarray:
    """Tilt of the camera's up axis from the world's up, in degrees, per rotation.

    ``rotations``: (N, 3, 3) or (3, 3), world to camera. The camera's up axis in the world is
    ``R.T @ e_z`` = ``R[2, :]``, so the tilt is ``arccos(R[2, 2])`` in [0, 180].
    """
    R = np.asarray(rotations, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise InputError(f"rotations must have shape (N, 3, 3), got {R.shape}")
    return np.degrees(np.arccos(np.clip(R[..., 2, 2], -1.0, 1.0)))


def filter_by_tilt(rots: RotationCandidates, max_tilt_deg: float,
                   camera_up: np.ndarray | None = None) -> RotationCandidates:
    """The candidates whose camera up axis (``R.T @ e_z``) is within ``max_tilt_deg`` of the world up.

    ``camera_up``: the world's up axis as the camera recorded it, in the camera frame (a 360
    camera's gravity, :func:`ldlmap.io.panorama_meta.camera_up`); then the bound is on the angle
    between ``R @ e_z`` and it, i.e. around the recorded pitch and roll instead of around level.
    Order is kept. ``max_tilt_deg >= 180`` keeps every candidate (the paper's free rotation).
    Raises InputError for a negative or non-finite bound.
    """
    tilt = float(max_tilt_deg)
    if not np.isfinite(tilt) or tilt < 0:
        raise InputError(f"the tilt bound must be a finite angle >= 0 degrees, got {max_tilt_deg}")
    if tilt >= FREE_TILT_DEG or len(rots) == 0:
        return rots
    if camera_up is None:
        return rots.subset(camera_tilt_deg(rots.rotations) <= tilt + 1e-9)
    up = np.asarray(camera_up, dtype=np.float64).reshape(3)
    up = up / np.linalg.norm(up)
    off = np.degrees(np.arccos(np.clip(rots.rotations[:, :, 2] @ up, -1.0, 1.0)))  # R @ e_z: world up in the camera
    return rots.subset(off <= tilt + 1e-9)
