"""The local-feature protocol shared by all backends, and batched nearest-neighbour matching.

Keypoints use the continuous pixel coordinates of :mod:`ldlmap.core.geometry`: integer grid lines are
pixel corners, so the centre of pixel (column c, row r) is ``(c + 0.5, r + 0.5)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol, Sequence, runtime_checkable

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module

torch = lazy_module("torch")

Metric = Literal["l2", "cosine"]


@dataclass(frozen=True)
class Features:
    """Local features of one image."""

    keypoints: np.ndarray  # (K, 2) float32 continuous pixel coordinates (u, v), centre = +0.5
    scores: np.ndarray  # (K,) float32 detector confidence (higher is better)
    descriptors: np.ndarray  # (K, D) in the backend's storage dtype (uint8 SIFT, float16 SuperPoint)

    def __len__(self) -> int:
        return int(len(self.keypoints))

    def subset(self, keep: np.ndarray) -> "Features":
        """The features selected by a boolean mask or an index array."""
        return Features(self.keypoints[keep], self.scores[keep], self.descriptors[keep])


@runtime_checkable
class FeatureBackend(Protocol):
    """A detector/descriptor with its own matcher (the matcher travels with the backend: mutual
    nearest neighbours + ratio test for SIFT and SuperPoint, LightGlue for learned features)."""

    name: str  # registry name, recorded in maps and results
    descriptor_dtype: np.dtype  # storage dtype of descriptors
    query_keypoints: int  # keypoints a query panorama keeps by default

    def extract(self, image_rgb: np.ndarray, mask: np.ndarray | None = None,
                max_keypoints: int | None = None) -> Features:
        """Detect and describe keypoints in an (H, W, 3) uint8 RGB image (``mask``: (H, W), 0 = skip)."""
        ...

    def match_views(self, query: Features, query_size: tuple[int, int], views: Sequence[Features],
                    view_size: tuple[int, int], ratio: float = 0.8) -> list[np.ndarray]:
        """Match the query's features with each map view's: one (M_v, 2) int64 array of index
        pairs ``(i in query, j in view v)`` per view. Sizes are ``(width, height)`` in pixels
        (learned matchers read keypoint positions); ``ratio`` is the nearest-neighbour ratio test."""
        ...


class DescriptorMatching:
    """``match_views`` for backends that match descriptors alone (``self.match(desc_a, desc_b, ratio)``)."""

    def match_views(self, query: Features, query_size: tuple[int, int], views: Sequence[Features],
                    view_size: tuple[int, int], ratio: float = 0.8) -> list[np.ndarray]:
        return [self.match(query.descriptors, v.descriptors, ratio=ratio) for v in views]


def check_image(image_rgb: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Validate an RGB uint8 image and an optional mask of the same size."""
    img = np.asarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 8 or img.shape[1] < 8:
        raise InputError(f"image must have shape (H, W, 3) with H, W >= 8, got {img.shape}")
    if img.dtype != np.uint8:
        raise InputError(f"image must be uint8 RGB, got dtype {img.dtype}")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != img.shape[:2]:
            raise InputError(f"mask must have shape {img.shape[:2]}, got {mask.shape}")
        mask = mask.astype(bool)
    return img, mask


def top_k(scores: np.ndarray, k: int | None) -> np.ndarray:
    """Indices of the ``k`` highest scores, best first (all, sorted, when ``k`` is None)."""
    order = np.argsort(-np.asarray(scores), kind="stable")
    return order if k is None or k <= 0 else order[:k]


def mutual_nn_match(desc_a: np.ndarray, desc_b: np.ndarray, *, metric: Metric = "l2",
                    ratio: float = 0.8, mutual: bool = True, device: str = "cpu",
                    chunk: int = 4096) -> np.ndarray:
    """Nearest-neighbour matches with Lowe's ratio test and an optional mutual check (torch).

    ``metric="l2"`` compares Euclidean distances; ``"cosine"`` L2-normalises the descriptors and
    uses the chordal distance ``sqrt(2 - 2 cos)``, so the ratio test reads the same for both.
    The distance matrix is built in row chunks so memory stays bounded for large sets.

    Returns:
        (M, 2) int64 pairs ``(i, j)``: ``b[j]`` is the nearest neighbour of ``a[i]``, passes
        ``d1 < ratio * d2`` (skipped when ``ratio >= 1`` or ``b`` has a single descriptor) and,
        with ``mutual``, ``a[i]`` is also the nearest neighbour of ``b[j]``.
    """
    a = np.asarray(desc_a)
    b = np.asarray(desc_b)
    if a.ndim != 2 or b.ndim != 2 or (len(a) and len(b) and a.shape[1] != b.shape[1]):
        raise InputError(f"descriptor sets must be (N, D) with equal D, got {a.shape} and {b.shape}")
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    dev = torch.device(device)
    ta = torch.from_numpy(a.astype(np.float32)).to(dev)
    tb = torch.from_numpy(b.astype(np.float32)).to(dev)
    if not (torch.isfinite(ta).all() and torch.isfinite(tb).all()):
        raise InputError("descriptors contain NaN or infinite values")
    if metric == "cosine":
        ta = torch.nn.functional.normalize(ta, dim=1)
        tb = torch.nn.functional.normalize(tb, dim=1)
    elif metric != "l2":
        raise InputError(f"unknown descriptor metric {metric!r}; valid: l2, cosine")
    sq_b = (tb * tb).sum(1)
    k = min(2, len(b))
    best_d, best_j = [], []
    col_min = torch.full((len(b),), float("inf"), device=dev)
    col_arg = torch.zeros(len(b), dtype=torch.int64, device=dev)
    for s in range(0, len(a), chunk):
        blk = ta[s:s + chunk]
        d2 = ((blk * blk).sum(1, keepdim=True) + sq_b[None] - 2.0 * blk @ tb.T).clamp_min_(0.0)
        vals, inds = torch.topk(d2, k, dim=1, largest=False)
        best_d.append(vals)
        best_j.append(inds)
        cmin, carg = d2.min(dim=0)
        better = cmin < col_min
        col_min = torch.where(better, cmin, col_min)
        col_arg = torch.where(better, carg + s, col_arg)
    d = torch.cat(best_d).sqrt()
    j = torch.cat(best_j)
    ok = torch.ones(len(a), dtype=torch.bool, device=dev)
    if ratio < 1.0 and k == 2:
        ok &= d[:, 0] < ratio * d[:, 1]
    if mutual:
        ok &= col_arg[j[:, 0]] == torch.arange(len(a), device=dev)
    i = torch.nonzero(ok).squeeze(1)
    return torch.stack([i, j[i, 0]], dim=1).cpu().numpy().astype(np.int64)


def backend_config(kind: type, config, opts: dict, what: str):
    """A backend's config dataclass ``kind`` from ``config`` (an instance, a dict or None) with the
    keyword ``opts`` on top; an unknown option is a one-line :class:`InputError` naming ``what``."""
    base = config if isinstance(config, kind) else kind(**(config or {}))
    try:
        return kind(**{**base.__dict__, **opts})
    except TypeError as exc:
        raise InputError(f"invalid {what} option: {exc}") from None
