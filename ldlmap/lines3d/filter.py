"""The paper's length filter: drop segments shorter than ``lambda (b_x + b_y + b_z) / 3`` of the
scene's robust box, keeping at least / at most a number of the longest lines.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.lines3d.params import check_lines, check_points


def robust_bounds(points: np.ndarray, percentiles: tuple[float, float] = (2.0, 98.0),
                  margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Box (min, max) of the bulk of ``points`` (N, 3): the extremes of the points that lie, on
    every axis, within ``margin`` of the ``percentiles``' span beyond them.

    A scan or line map has its walls at the extremes, so a clean one gets its full bounding box
    (the paper's); a few far outlier points or segments (SfM) fall outside and are ignored.
    """
    P = check_points(points)
    lo, hi = np.percentile(P, percentiles, axis=0)
    pad = margin * (hi - lo)
    inside = np.all((P >= lo - pad) & (P <= hi + pad), axis=1)
    return (P[inside].min(0), P[inside].max(0)) if inside.any() else (lo, hi)


def length_threshold(bounds_min: np.ndarray, bounds_max: np.ndarray, lam: float = 0.1) -> float:
    """The paper's length threshold ``lambda (b_x + b_y + b_z) / 3`` for a bounding box."""
    b = np.asarray(bounds_max, dtype=np.float64) - np.asarray(bounds_min, dtype=np.float64)
    if b.shape != (3,) or not np.all(np.isfinite(b)) or np.any(b < 0):
        raise InputError("bounding box must be two finite 3-vectors with max >= min")
    return float(lam * b.sum() / 3.0)


def filter_by_length(lines: np.ndarray, bounds_min: np.ndarray, bounds_max: np.ndarray, lam: float = 0.1,
                     min_keep: int = 0, max_keep: int | None = None,
                     min_length_share: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Drop segments shorter than ``lam * (b_x + b_y + b_z) / 3`` (paper, lambda = 0.1).

    Floor and cap, for maps the paper's threshold does not fit: keep at least ``min(min_keep, N)``
    lines and at least the longest lines holding ``min_length_share`` of the total line length
    (a dense SfM map of short pieces keeps almost nothing under the threshold), and at most
    ``max_keep`` (huge maps), the longest first; the returned threshold is then the shortest
    kept length. Returns ``(kept_lines (M, 2, 3), kept_mask (N,) bool, threshold)``; the kept
    ratio that the 2D filter matches is ``kept_mask.mean()``.
    """
    L = check_lines(lines)
    thr = length_threshold(bounds_min, bounds_max, lam)
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    mask = length >= thr
    order = np.argsort(-length, kind="stable")
    floor = min(int(min_keep), len(L))
    if min_length_share > 0 and len(L):
        share = np.cumsum(length[order]) / max(float(length.sum()), 1e-300)
        floor = max(floor, min(int(np.searchsorted(share, min(min_length_share, 1.0) - 1e-12)) + 1, len(L)))
    if mask.sum() < floor:
        mask[order[:floor]] = True
        thr = float(length[order[floor - 1]])
    if max_keep is not None and mask.sum() > max_keep:
        if max_keep < 1:
            raise InputError(f"max_keep must be >= 1, got {max_keep}")
        mask = np.zeros(len(L), bool)
        mask[order[:max_keep]] = True
        thr = float(length[order[max_keep - 1]])
    return L[mask], mask, thr
