"""Principal 3D directions of a line map by voting (DESIGN.md 5.2, paper supp. "Principal
Direction Computation").

Every line votes for the bins of a half icosphere (level 5: 5121 directions, ~2.2 degrees apart)
within ``vote_angle_deg`` of its direction, with weight = its length (long lines are the reliable
structure of a room; counting lines instead lets clutter of many short pieces win). The best bin
is refined by the length-weighted mean of the sign-aligned directions within
``refine_angle_deg`` of it; lines with ``|cos| > cos_thresh`` to the refined direction are
removed and the vote repeats, ``k`` times (k3D = 3). With ``k = 3`` the triplet is made
right-handed by flipping the third direction when ``det < 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.errors import InputError
from ldlmap.geometry import half_icosphere_points, normalize


@dataclass(frozen=True)
class Principal3DParams:
    """Parameters of :func:`principal_directions_3d`."""

    sphere_level: int = 5  # icosphere level of the voting grid (halved)
    vote_angle_deg: float = 3.0  # a line votes for every bin this close to its direction
    refine_angle_deg: float = 5.0  # inliers averaged to refine the winning bin
    cos_thresh: float = 0.95  # lines with |cos| above this to a found direction are removed


def line_directions(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (N, 3) and lengths (N,) of segments (N, 2, 3)."""
    L = np.asarray(lines, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (2, 3):
        raise InputError(f"lines must have shape (N, 2, 3), got {L.shape}")
    if not np.all(np.isfinite(L)):
        raise InputError("lines contain NaN or infinite coordinates")
    v = L[:, 1] - L[:, 0]
    length = np.linalg.norm(v, axis=1)
    return normalize(v), length


def _any_perpendicular(d: np.ndarray) -> np.ndarray:
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    return normalize(np.cross(d, a))


def principal_directions_3d(lines: np.ndarray, k: int = 3,
                            params: Principal3DParams = Principal3DParams()) -> np.ndarray:
    """Top ``k`` (k_3D, paper default 3) line directions (k, 3), rows unit vectors, right-handed when ``k == 3``.

    When the lines run out before ``k`` directions are found (e.g. all lines in two directions)
    the missing ones are completed orthogonally (cross product / any perpendicular).
    """
    d, w = line_directions(lines)
    keep = w > 1e-9
    d, w = d[keep], w[keep]
    if len(d) == 0:
        raise InputError("no (non-degenerate) lines to estimate principal directions from")
    if k < 1:
        raise InputError(f"k must be >= 1, got {k}")
    bins = half_icosphere_points(params.sphere_level)
    cos_vote = np.cos(np.radians(params.vote_angle_deg))
    cos_ref = np.cos(np.radians(params.refine_angle_deg))
    found: list[np.ndarray] = []
    alive = np.ones(len(d), bool)
    for _ in range(k):
        if not alive.any():
            break
        da, wa = d[alive], w[alive]
        score = np.zeros(len(bins))
        block = max(1, int(2e6 // len(bins)))
        for s in range(0, len(da), block):
            c = np.abs(da[s:s + block] @ bins.T)
            score += (wa[s:s + block, None] * (c >= cos_vote)).sum(axis=0)
        top = bins[int(np.argmax(score))]
        c = da @ top
        inl = np.abs(c) >= cos_ref
        p = normalize((np.sign(c[inl]) * wa[inl])[:, None].T @ da[inl])[0] if inl.any() else top
        found.append(p)
        alive &= np.abs(d @ p) <= params.cos_thresh
    while len(found) < k:
        if len(found) == 1:
            found.append(_any_perpendicular(found[0]))
        elif len(found) == 2:
            found.append(normalize(np.cross(found[0], found[1])))
        else:  # k > 3 and no lines left: repeat the last direction's perpendicular
            found.append(_any_perpendicular(found[-1]))
    P = np.stack(found[:k])
    if k == 3 and np.linalg.det(P) < 0:
        P[2] = -P[2]
    return P


def assign_line_groups(directions_of_lines: np.ndarray, principal: np.ndarray,
                       cos_thresh: float = 0.95) -> np.ndarray:
    """Group index (N,) of each line: the principal direction with the largest ``|cos|`` when it
    exceeds ``cos_thresh`` (a line joins group j when ``|d . p_j| > 0.95``), else -1."""
    D = normalize(np.asarray(directions_of_lines, dtype=np.float64))
    Pd = normalize(np.asarray(principal, dtype=np.float64))
    if D.ndim != 2 or D.shape[1] != 3 or Pd.ndim != 2 or Pd.shape[1] != 3:
        raise InputError("directions must have shapes (N, 3) and (k, 3)")
    if len(D) == 0:
        return np.zeros(0, np.int64)
    c = np.abs(D @ Pd.T)
    best = np.argmax(c, axis=1)
    return np.where(c[np.arange(len(D)), best] > cos_thresh, best, -1).astype(np.int64)
