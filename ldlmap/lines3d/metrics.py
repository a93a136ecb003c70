"""Precision and recall of extracted segments against true edges."""

from __future__ import annotations

import numpy as np

from ldlmap.lines3d.params import check_lines


def sample_segments(L: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along each segment every ``step`` (at least 2 per segment) and their segment index."""
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    k = np.maximum(2, np.ceil(length / step).astype(np.int64) + 1)
    seg = np.repeat(np.arange(len(L)), k)
    first = np.cumsum(k) - k
    f = (np.arange(k.sum()) - first[seg] + 0.5) / k[seg]  # bin centres: each point = equal length
    return L[seg, 0] + f[:, None] * (L[seg, 1] - L[seg, 0]), seg


def covered_samples(samples: np.ndarray, sdir: np.ndarray, ref: np.ndarray, dist: float, cos_t: float) -> np.ndarray:
    """For each sample point: is there a reference segment within ``dist`` and the angle?"""
    a, b = ref[:, 0], ref[:, 1]
    v = b - a
    vv = np.maximum(np.einsum("ij,ij->i", v, v), 1e-18)
    rdir = v / np.sqrt(vv)[:, None]
    out = np.zeros(len(samples), bool)
    block = max(1, int(2e6 // max(len(ref), 1)))
    for s in range(0, len(samples), block):
        x = samples[s:s + block]
        t = np.clip(((x[:, None, :] - a[None]) * v[None]).sum(-1) / vv[None], 0.0, 1.0)
        dd = np.linalg.norm(x[:, None, :] - (a[None] + t[..., None] * v[None]), axis=2)
        par = np.abs(sdir[s:s + block] @ rdir.T) >= cos_t
        out[s:s + block] = np.any((dd <= dist) & par, axis=1)
    return out


def line_precision_recall(pred: np.ndarray, gt: np.ndarray, dist: float = 0.05, angle_deg: float = 5.0,
                          min_cover: float = 0.7, step: float = 0.01) -> tuple[float, float]:
    """Segment-level precision and recall of ``pred`` against ``gt`` (both (N, 2, 3)).

    A ground-truth segment is found when at least ``min_cover`` of its length lies within
    ``dist`` of a predicted segment whose direction is within ``angle_deg``; precision is the
    same with the roles swapped. Lengths are measured by sampling points every ``step``.
    Returns ``(precision, recall)``; an empty set scores 0 (1 when both are empty).
    """
    P, G = check_lines(pred), check_lines(gt)
    if len(P) == 0 or len(G) == 0:
        both_empty = float(len(P) == 0 and len(G) == 0)
        return both_empty, both_empty
    cos_t = np.cos(np.radians(angle_deg))

    def frac(A: np.ndarray, B: np.ndarray) -> np.ndarray:
        x, seg = sample_segments(A, step)
        da = A[:, 1] - A[:, 0]
        da = da / np.maximum(np.linalg.norm(da, axis=1, keepdims=True), 1e-12)
        cov = covered_samples(x, da[seg], B, dist, cos_t)
        return np.bincount(seg, cov, len(A)) / np.bincount(seg, minlength=len(A))

    precision = float(np.mean(frac(P, G) >= min_cover))
    recall = float(np.mean(frac(G, P) >= min_cover))
    return precision, recall
