"""View retrieval for the feature refinement: which rendered views of a map look like the query.

The feature refinement (:mod:`ldlloc.refine.features`) matches the query only with the views that
serve the search's top-K candidates; when they all stand in the wrong room (a building's floor
map, the search's best pose metres away) PnP has nothing to work with. :class:`ViewIndex` ranks
every view of the map by a bag of visual words: a vocabulary of ``words`` centres found by
spherical k-means (:func:`spherical_kmeans`) on a sample of the map's own descriptors, each view a tf-idf
histogram of its descriptors' nearest words (unit length), the query's likewise; views are ranked
by cosine similarity. Built once per map, the first time it is needed (no map format change).
:func:`ldlloc.refine.features.refine_by_retrieval` matches the query with the ``shortlist``
best-ranked views, runs spherical PnP on the ``views`` of them with the most matches and keeps a
pose :func:`accept_retrieved` accepts (which also judges the feature refinement's own poses:
:meth:`ldlloc.pipeline.Localizer.localize` falls back to retrieval when it would not accept them).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ldlmap.core.lazy import lazy_module

sparse = lazy_module("scipy.sparse")

# The "verified pose" rule: a PnP pose of at least VERIFIED_INLIERS inliers whose line loss is at least
# VERIFIED_LINE_SHARE of the search's best (losses are negative inlier counts) is backed by the features
# and the lines both; a pose in the wrong room explains few of the image's lines (docs/measurements.md#retrieval).
# The retrieval accepts its poses by it (RetrievalParams) and across maps only verified poses compete
# (ldlloc.confidence.verified).
VERIFIED_INLIERS = 15
VERIFIED_LINE_SHARE = 0.7


@dataclass(frozen=True)
class RetrievalParams:
    """Retrieval fallback of the feature refinement (:func:`ldlloc.refine.features.refine_candidates`)."""

    views: int = 5
    """PnP runs on the matches of this many shortlisted views with the most matches (0: no retrieval)."""
    shortlist: int = 20
    """Views most like the query by the words, all matched (docs/measurements.md#retrieval)."""
    words: int = 1024
    """Visual words of the map's vocabulary (k-means on its own descriptors)."""
    train_descriptors: int = 20000
    """K-means runs on at most this many of the map's descriptors (a fixed sample)."""
    iterations: int = 10
    """K-means iterations."""
    min_inliers: int = VERIFIED_INLIERS
    """A retrieved PnP pose needs this many inliers (the verified-pose rule)."""
    min_line_share: float = VERIFIED_LINE_SHARE
    """And a line loss of at least this share of the search's best (the verified-pose rule)."""
    seed: int = 0
    """K-means seed (reproducible vocabularies)."""


def descriptor_space(descriptors: np.ndarray) -> np.ndarray:
    """Float32 descriptors on the unit sphere: Hellinger-mapped (RootSIFT) when all are non-negative
    (SIFT's histograms), else L2-normalised (learned descriptors)."""
    d = np.asarray(descriptors, dtype=np.float32)
    if d.size and d.min() >= 0:
        d = np.sqrt(d / np.maximum(d.sum(axis=1, keepdims=True), 1e-12))
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def spherical_kmeans(x: np.ndarray, k: int, iterations: int, rng: np.random.Generator) -> np.ndarray:
    """(k, D) unit centres of the unit rows of ``x``: Lloyd's iterations with the assignment by the
    largest dot product: one matrix product, much faster than scipy's ``kmeans2``), started from ``k``
    distinct rows; an emptied centre restarts at a random row."""
    k = max(1, min(k, len(x)))
    centres = x[rng.choice(len(x), k, replace=False)].copy()
    for _ in range(iterations):
        label = nearest_words(x, centres)
        sums = member_sums(label, x, k)
        empty = np.bincount(label, minlength=k) == 0
        sums[empty] = x[rng.choice(len(x), int(empty.sum()))]
        centres = sums / np.maximum(np.linalg.norm(sums, axis=1, keepdims=True), 1e-12)
    return centres.astype(np.float32)


def member_sums(label: np.ndarray, x: np.ndarray, k: int) -> np.ndarray:
    """(k, D) sums of the rows of ``x`` by ``label`` (a sparse one-hot product; ``np.add.at`` is slower)."""
    one_hot = sparse.csr_matrix((np.ones(len(label), np.float32), (label, np.arange(len(label)))), shape=(k, len(label)))
    return np.asarray(one_hot @ x, dtype=np.float32)


def nearest_words(desc: np.ndarray, vocabulary: np.ndarray, chunk: int = 8192) -> np.ndarray:
    """Index of the nearest vocabulary word of each (unit) descriptor (largest dot product)."""
    out = np.empty(len(desc), dtype=np.int64)
    for s in range(0, len(desc), chunk):
        out[s:s + chunk] = np.argmax(desc[s:s + chunk] @ vocabulary.T, axis=1)
    return out


class ViewIndex:
    """Bag-of-visual-words (tf-idf) vectors of a map's rendered views (module docstring)."""

    def __init__(self, map_features, params: RetrievalParams = RetrievalParams()):
        desc = descriptor_space(map_features.descriptors)
        rng = np.random.default_rng(params.seed)
        sample = desc[np.sort(rng.choice(len(desc), min(len(desc), params.train_descriptors), replace=False))]
        self.vocabulary = spherical_kmeans(sample, params.words, params.iterations, rng)
        k = len(self.vocabulary)
        V = map_features.num_views
        view_of = np.repeat(np.arange(V), np.diff(np.asarray(map_features.offsets)))
        counts = np.bincount(view_of * k + nearest_words(desc, self.vocabulary), minlength=V * k).reshape(V, k)
        # idf: a word in every view tells nothing; one in few views tells much
        self.idf = np.log((V + 1.0) / (1.0 + (counts > 0).sum(0)))
        self.vectors = self._unit(counts * self.idf)  # (V, k)

    @staticmethod
    def _unit(x: np.ndarray) -> np.ndarray:
        return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)

    def similarity(self, query_descriptors: np.ndarray) -> np.ndarray:
        """(V,) cosine similarity of each view's tf-idf vector with the query's."""
        words = nearest_words(descriptor_space(query_descriptors), self.vocabulary)
        q = np.bincount(words, minlength=len(self.idf)).astype(np.float64) * self.idf
        return self.vectors @ self._unit(q)

    def rank(self, query_descriptors: np.ndarray) -> np.ndarray:
        """View indices, most similar to the query first."""
        return np.argsort(-self.similarity(query_descriptors), kind="stable")


@dataclass
class RetrievalContext:
    """What the retrieval fallback needs beside the query and the map's features: the map's
    :class:`ViewIndex`, the line loss of poses (``loss(R (M, 3, 3), t (M, 3)) -> (M,)``, the
    search's exact loss, :func:`ldlloc.search.pose_search.score_poses`) and the search's best loss."""

    index: ViewIndex
    loss: Callable[[np.ndarray, np.ndarray], np.ndarray]
    search_loss: float


def accept_retrieved(num_inliers: int, loss: float, search_loss: float, params: RetrievalParams) -> bool:
    """Whether a retrieved PnP pose replaces the search's: enough inliers, and a line loss of at least
    ``min_line_share`` of the search's best (losses are negative inlier counts, lower is better)."""
    return bool(num_inliers >= params.min_inliers and np.isfinite(loss) and loss <= params.min_line_share * search_loss)
