"""View retrieval, the feature refinement's fallback (ldlloc.refine.retrieval, refine_by_retrieval)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ldlloc.refine.retrieval import RetrievalParams, ViewIndex, accept_retrieved


def _views(words_per_view: np.ndarray, dim: int = 16, seed: int = 0):
    """A feature table whose view v holds noisy copies of the descriptors of ``words_per_view[v]``."""
    from ldlmap.map.contents import MapFeatures

    rng = np.random.default_rng(seed)
    protos = rng.random((words_per_view.max() + 1, dim)) * 200
    desc, offsets = [], [0]
    for words in words_per_view:
        desc.append(np.clip(protos[words] + rng.normal(0, 3, (len(words), dim)), 0, 255))
        offsets.append(offsets[-1] + len(words))
    desc = np.concatenate(desc).astype(np.uint8)
    n, V = len(desc), len(words_per_view)
    return MapFeatures(backend="sift", view_centers=np.zeros((V, 3)), offsets=np.array(offsets),
                       xyz=np.zeros((n, 3), np.float32), keypoints=np.zeros((n, 2), np.float32),
                       scores=np.ones(n, np.float32), descriptors=desc, translation_view=np.zeros(1, int)), protos


def test_view_index_ranks_the_view_that_shares_the_query_words_first():
    # 6 views of 40 words each from 6 disjoint sets of 40 (rooms that look different); the query
    # holds half the words of view 4 and a few of view 1
    words = np.arange(240).reshape(6, 40)
    mf, protos = _views(words)
    index = ViewIndex(mf, RetrievalParams(words=64, iterations=8))
    query = np.clip(protos[np.r_[words[4, :20], words[1, :3]]], 0, 255).astype(np.uint8)
    order = index.rank(query)
    assert order[0] == 4 and order[1] == 1
    sim = index.similarity(query)
    assert sim[4] > 0.5 and sim[[0, 2, 3, 5]].max() < 0.5 * sim[1]


def test_accept_retrieved_wants_inliers_and_line_loss():
    p = RetrievalParams(min_inliers=15, min_line_share=0.7)
    # losses are negative inlier counts: -200 explains 200 of the image's lines' points
    assert accept_retrieved(30, -180.0, -250.0, p)  # 0.72 of the search's best
    assert not accept_retrieved(30, -60.0, -250.0, p)  # the wrong room explains few lines
    assert not accept_retrieved(14, -260.0, -250.0, p)  # too few inliers
    assert not accept_retrieved(30, float("nan"), -250.0, p)


def test_retrieval_finds_the_room_when_every_candidate_view_sees_another(demo_dataset):
    """One map of two rooms far apart (the demo's two rooms, the second 40 m away in the feature
    table): every candidate translation of the first room is served by a view of the second, as when
    the search's top K all stand in the wrong room of a floor. Without retrieval PnP finds nothing
    (the features of the other room do not match); with it the query's own room's views are found
    and the pose ends within 0.1 m / 5 deg."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlmap.datasets import open_dataset
    from ldlmap.map.contents import MapFeatures
    from ldlmap.map.mapfile import read_map
    from ldlloc.pipeline import LocalizeParams, Localizer, load_image

    a = read_map(demo_dataset / "maps" / "synthroom_1.h5", load_cloud=False)
    b = read_map(demo_dataset / "maps" / "synthroom_2.h5", load_cloud=False).features
    fa = a.features
    far = np.array([40.0, 0.0, 0.0], np.float32)
    a.features = MapFeatures(
        backend=fa.backend, view_centers=np.concatenate([fa.view_centers, b.view_centers + far]),
        offsets=np.concatenate([fa.offsets, b.offsets[1:] + fa.offsets[-1]]),
        xyz=np.concatenate([fa.xyz, b.xyz + far]), keypoints=np.concatenate([fa.keypoints, b.keypoints]),
        scores=np.concatenate([fa.scores, b.scores]), descriptors=np.concatenate([fa.descriptors, b.descriptors]),
        translation_view=fa.num_views + fa.translation_view % b.num_views,  # the other room's views
        width=fa.width, height=fa.height, extraction=fa.extraction)
    ds = open_dataset(demo_dataset, "omniscenes")
    queries = ds.queries("robot", scene="synthroom_1")[:1] + ds.queries("handheld", scene="synthroom_1")[:1]
    params = LocalizeParams()
    without = Localizer(a, replace(params, refine=replace(params.refine, retrieval=RetrievalParams(views=0))))
    with_retrieval = Localizer(a, params)
    for q in queries:
        img = load_image(q.image)
        r = without.localize(img)
        assert r.refine_method != "features" and r.retrieval is None, r.message
        r = with_retrieval.localize(img)
        t_err = translation_error(r.center, q.center)
        r_err = rotation_error_deg(r.rot_cam_from_world, q.rot_cam_from_world)
        assert r.refine_method == "features" and r.retrieval is not None, r.message
        assert r.retrieval["view"] < fa.num_views and t_err < 0.1 and r_err < 5.0, (q.name, t_err, r_err, r.message)


class _SameIndexMatcher:
    """Matches query feature i with view feature i (each view holds the query's points in order)."""

    def match_views(self, query, query_size, views, view_size, ratio=0.8):
        return [np.stack([np.arange(len(v)), np.arange(len(v))], 1) for v in views]


def test_retrieved_pose_in_one_of_two_identical_rooms_has_the_other_as_rival():
    """Two copies of a room 6 m apart, one view each: retrieval finds both, PnP puts the camera in
    each, the one kept has the other as its rival with as many inliers (the confidence's
    ``pnp_rival``: the features do not single one copy out)."""
    from ldlmap.core import geometry as geo
    from ldlmap.features import Features
    from ldlmap.map.contents import MapFeatures
    from ldlloc.refine.features import RefineParams, refine_by_retrieval
    from ldlloc.refine.retrieval import RetrievalContext

    rng = np.random.default_rng(3)
    P = rng.random((300, 3)) * [5.0, 4.0, 2.6]
    c0, shift, W, H = np.array([2.0, 1.5, 1.4]), np.array([6.0, 0.0, 0.0]), 1024, 512
    R0 = geo.rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.7)
    desc = rng.integers(0, 255, (300, 16)).astype(np.uint8)
    query = Features(geo.project_to_pixels(P, R0, c0, W, H).astype(np.float32), np.ones(300, np.float32), desc)
    mf = MapFeatures(backend="sift", view_centers=np.stack([c0, c0 + shift]), offsets=np.array([0, 300, 600]),
                     xyz=np.concatenate([P, P + shift]).astype(np.float32), keypoints=np.zeros((600, 2), np.float32),
                     scores=np.ones(600, np.float32), descriptors=np.concatenate([desc, desc]),
                     translation_view=np.array([0]))
    params = RefineParams()
    ctx = RetrievalContext(ViewIndex(mf, RetrievalParams(words=32)), lambda R, t: np.full(len(R), -100.0), -100.0)
    ref = refine_by_retrieval(query, (W, H), mf, _SameIndexMatcher(), params, ctx)
    assert ref is not None and ref.refined and ref.num_inliers >= 290 and ref.retrieved["feature_share"] == 1.0
    assert ref.rival_inliers >= 0.95 * ref.num_inliers
    assert np.allclose(sorted([ref.center[0], ref.rival_center[0]]), [c0[0], c0[0] + 6.0], atol=0.01)
    # a line loss far below the search's best (the wrong room) keeps nothing
    ctx = RetrievalContext(ctx.index, lambda R, t: np.full(len(R), -20.0), -100.0)
    assert refine_by_retrieval(query, (W, H), mf, _SameIndexMatcher(), params, ctx) is None


def test_retrieval_runs_pnp_on_the_views_with_most_matches_not_the_words_best(monkeypatch):
    """The words rank a room's own view below other rooms' views (a floor of rooms alike:
    own views 8th-25th); PnP on the best word-ranked views alone then finds no pose. With the
    shortlist matched, the view with the most matches gives the pose."""
    from types import SimpleNamespace

    from ldlmap.core import geometry as geo
    from ldlmap.features import Features
    from ldlmap.map.contents import MapFeatures
    from ldlloc.refine import features as feat
    from ldlloc.refine.features import RefineParams, refine_by_retrieval
    from ldlloc.refine.retrieval import RetrievalContext

    rng = np.random.default_rng(5)
    P = rng.random((200, 3)) * [5.0, 4.0, 2.6]
    c0, W, H = np.array([2.0, 1.5, 1.4]), 1024, 512
    R0 = geo.rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.4)
    desc = rng.integers(0, 255, (200, 16)).astype(np.uint8)
    query = Features(geo.project_to_pixels(P, R0, c0, W, H).astype(np.float32), np.ones(200, np.float32), desc)
    V = 8  # view 7 sees the room (its points are the query's); views 0-6 see elsewhere (random points)
    xyz = np.concatenate([rng.random((200, 3)) * 20 for _ in range(V - 1)] + [P]).astype(np.float32)
    mf = MapFeatures(backend="sift", view_centers=np.zeros((V, 3)), offsets=np.arange(V + 1) * 200, xyz=xyz,
                     keypoints=np.zeros((V * 200, 2), np.float32), scores=np.ones(V * 200, np.float32),
                     descriptors=np.tile(desc, (V, 1)), translation_view=np.array([0]))
    counts = {v: 20 for v in range(V - 1)} | {V - 1: 150}  # few matches elsewhere (their PnP fails), many here

    def match_views(query_feats, size, views, map_features, backend, ratio):  # the counts above, per view
        return {int(v): np.stack([np.arange(counts[int(v)]), np.arange(counts[int(v)]) + int(v) * 200], 1)
                for v in views}

    index = SimpleNamespace(rank=lambda d: np.arange(V))  # the words put the room's own view last
    ctx = RetrievalContext(index, lambda R, t: np.full(len(R), -100.0), -100.0)
    monkeypatch.setattr(feat, "_match_distinct_views", match_views)
    few = RefineParams(retrieval=RetrievalParams(views=5, shortlist=5))  # the words' best 5 only
    assert refine_by_retrieval(query, (W, H), mf, None, few, ctx) is None
    ref = refine_by_retrieval(query, (W, H), mf, None, RefineParams(), ctx)  # shortlist 20: all 8 matched
    assert ref is not None and ref.retrieved["view"] == V - 1 and ref.retrieved["rank"] == V - 1
    assert ref.num_inliers >= 140 and np.linalg.norm(ref.center - c0) < 0.01
