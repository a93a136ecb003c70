"""Refinement of the top-K poses with local features (paper section 3.4).

For each candidate pose, the map keypoints of the rendered view serving its translation are
matched with the query's features by the backend's matcher (mutual nearest neighbour + ratio
test, or LightGlue over batches of views; one matching per distinct view). A match supports a
candidate when the 3D point, seen from the candidate pose, lies within ``support_angle`` of the query keypoint's bearing; the candidate with
the most supporting matches wins (ties: more raw matches, then the better search rank). The
matches of the best-supported distinct views (``pnp_views``) go to spherical PnP-RANSAC (pycolmap
``EQUIRECTANGULAR``) and the pose with the most inliers is kept. When PnP fails, or its pose is
far (``max_shift_m`` / ``max_turn_deg``) from every one of the K candidates without strong
support (``strong_inliers``, ``strong_ratio``), the coarse pose is kept and flagged. The best PnP
pose distinct from the kept one (another copy of an identical room explains the features as well)
is kept as its ``rival``: PnP is tried on one more view, of a candidate distinct from the kept pose,
when none of the tried views gave a distinct pose (:mod:`ldlloc.confidence` weighs it).

When no plausible PnP pose comes out, :func:`refine_by_retrieval` is the fallback: the map's views
most like the query by a bag of visual words (:mod:`ldlloc.refine.retrieval`), wherever they stand,
give PnP poses that are kept only when their line loss is about as good as the search's best.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ldlmap.core.geometry import bearing_from_pixel, cam_from_world, normalize, rotation_error_deg
from ldlmap.core.lazy import lazy_module
from ldlmap.features import Features
from ldlloc.confidence import distinct
from ldlloc.refine.pnp import PnPParams, estimate_pose_spherical
from ldlloc.refine.retrieval import RetrievalContext, RetrievalParams, accept_retrieved
from ldlloc.search.ldf import distance_function

torch = lazy_module("torch")


@dataclass(frozen=True)
class RefineParams:
    """Feature-based refinement parameters."""

    ratio: float = 0.8
    """Lowe's ratio test."""
    support_angle_deg: float = 6.0
    """A match supports a candidate when it reprojects this close (deg)."""
    max_shift_m: float = 1.0
    """A PnP pose further than this from every candidate is implausible (unless strongly supported)."""
    max_turn_deg: float = 30.0
    """A PnP pose turned more than this from every candidate is implausible (unless strongly supported)."""
    strong_inliers: int = 60
    """Strong support: at least this many PnP inliers, making up strong_ratio of the matches."""
    strong_ratio: float = 0.5
    """Strong support: the share of the matches that the strong_inliers must make up."""
    pnp_views: int = 5
    """PnP is tried on the matches of this many best-supported distinct views."""
    privacy_radius: float = 0.05
    """Privacy mode: keep features within this (rad) of principal lines."""
    pnp: PnPParams = field(default_factory=PnPParams)
    """The spherical PnP-RANSAC's settings."""
    retrieval: RetrievalParams = field(default_factory=RetrievalParams)
    """Fallback where the candidates' views give no plausible pose: PnP on the views most like the query."""


@dataclass
class Refinement:
    """The refined pose (or the coarse one, flagged) and match statistics."""

    rot_cam_from_world: np.ndarray
    center: np.ndarray
    refined: bool
    candidate: int  # index of the chosen top-K candidate
    num_matches: int
    num_inliers: int
    message: str = ""
    rival_rot: np.ndarray | None = None  # the best PnP pose distinct from this one (ldlloc.confidence.distinct)
    rival_center: np.ndarray | None = None
    rival_inliers: int = 0  # its inliers (0: no distinct PnP pose)
    rival_candidate: int = -1  # the top-K candidate whose view gave it
    retrieved: dict | None = None  # the pose came from view retrieval: {view, rank, inliers, loss, search_loss,
    # feature_share} (refine_by_retrieval)


def keep_near_lines(keypoints_uv: np.ndarray, arcs: np.ndarray, width: int, height: int,
                    radius: float = 0.05) -> np.ndarray:
    """Boolean mask of keypoints within ``radius`` radians of any of ``arcs`` (privacy mode)."""
    if len(keypoints_uv) == 0 or len(arcs) == 0:
        return np.zeros(len(keypoints_uv), dtype=bool)
    x = torch.as_tensor(bearing_from_pixel(keypoints_uv, width, height), dtype=torch.float32)
    d = distance_function(x, torch.as_tensor(np.asarray(arcs), dtype=torch.float32))
    return (d < radius).cpu().numpy()


def _match_distinct_views(query_feats, query_size: tuple[int, int], views: np.ndarray, map_features, backend,
                          ratio: float) -> dict[int, np.ndarray]:
    """Matches of the query with each of the map ``views`` in one backend call (learned matchers
    batch them), as ``(query row, map keypoint row)`` pairs indexing the whole map table."""
    slices = [map_features.view_slice(int(v)) for v in views]
    feats = [Features(map_features.keypoints[sl], map_features.scores[sl], map_features.descriptors[sl])
             for sl in slices]
    found = backend.match_views(query_feats, query_size, feats, (map_features.width, map_features.height),
                                ratio=ratio)
    return {int(v): m + np.array([0, sl.start]) for v, sl, m in zip(views, slices, found)}


def refine_candidates(query_feats, query_size: tuple[int, int], rotations: np.ndarray, centers: np.ndarray,
                      translation_index: np.ndarray, map_features, backend,
                      params: RefineParams = RefineParams()) -> Refinement:
    """Pick the best of the K candidate poses by feature matches and refine it with PnP.

    ``query_feats``: :class:`ldlmap.features.Features` of the query (possibly privacy-filtered);
    ``rotations`` (K, 3, 3), ``centers`` (K, 3), ``translation_index`` (K,) of the search result;
    ``map_features``: :class:`ldlmap.map.contents.MapFeatures`; ``backend`` matches descriptors.
    """
    W, H = query_size
    K = len(rotations)
    coarse = Refinement(rotations[0], centers[0], False, 0, 0, 0)
    if K == 0:
        return coarse
    if len(query_feats) == 0:
        coarse.message = "no query features"
        return coarse
    bearings = bearing_from_pixel(query_feats.keypoints, W, H)  # (Nq, 3)
    views = map_features.translation_view[np.asarray(translation_index)]
    cos_support = np.cos(np.radians(params.support_angle_deg))
    matches_by_view = _match_distinct_views(query_feats, (W, H), np.unique(views), map_features, backend,
                                            params.ratio)
    support = np.zeros(K, dtype=np.int64)
    raw = np.zeros(K, dtype=np.int64)
    for k in range(K):  # K = 20 candidates, at most K distinct views matched
        m = matches_by_view[int(views[k])]
        raw[k] = len(m)
        if len(m):
            p = normalize(cam_from_world(map_features.xyz[m[:, 1]].astype(np.float64), rotations[k], centers[k]))
            support[k] = int(np.sum(np.einsum("ij,ij->i", p, bearings[m[:, 0]]) > cos_support))
    order = np.lexsort((np.arange(K), -raw, -support))
    best = int(order[0])
    out = Refinement(rotations[best], centers[best], False, best, int(raw[best]), 0)
    # PnP on the matches of the best-supported distinct views; keep the pose with most inliers.
    tried, results = set(), []

    def pnp(k: int) -> None:
        v = int(views[k])
        tried.add(v)
        m = matches_by_view[v]
        if len(m) >= params.pnp.min_inliers:
            res = estimate_pose_spherical(query_feats.keypoints[m[:, 0]], map_features.xyz[m[:, 1]], W, H, params.pnp)
            if res is not None:
                results.append((int(res.inliers.sum()), int(k), len(m), res))

    for k in order:
        if int(views[k]) not in tried and len(tried) < params.pnp_views:
            pnp(int(k))
    if not results:
        out.message = f"too few matches ({raw[best]})" if raw[best] < params.pnp.min_inliers else "PnP-RANSAC failed"
        return out
    top = max(results, key=lambda r: (r[0], -r[1]))[3]
    if not any(distinct(top.rot_cam_from_world, top.center, r[3].rot_cam_from_world, r[3].center)[0] for r in results):
        other = [int(k) for k in order if int(views[k]) not in tried
                 and distinct(top.rot_cam_from_world, top.center, rotations[k], centers[k])[0]]
        if other:  # one view of another place (an identical room's copy) tells whether the features single one out
            pnp(other[0])
    inliers, k, n_matches, res = max(results, key=lambda r: (r[0], -r[1]))
    out.num_inliers, out.num_matches = inliers, n_matches
    # Plausible: close to one of the search's K poses, or so strongly supported that the search
    # itself must have missed (a well-supported PnP pose beats a wrong coarse one).
    shift = np.linalg.norm(centers - res.center, axis=1)
    turn = np.array([rotation_error_deg(res.rot_cam_from_world, R) for R in rotations])
    near = (shift <= params.max_shift_m) & (turn <= params.max_turn_deg)
    strong = inliers >= params.strong_inliers and inliers >= params.strong_ratio * n_matches
    if not near.any() and not strong:
        out.message = (f"refinement moved the pose implausibly far ({shift.min():.2f} m from the nearest candidate) "
                       f"with only {inliers} inliers")
        return out
    out.candidate = int(np.argmax(near)) if near.any() else k
    out.rot_cam_from_world, out.center, out.refined = res.rot_cam_from_world, res.center, True
    rivals = [r for r in results if distinct(res.rot_cam_from_world, res.center, r[3].rot_cam_from_world,
                                             r[3].center)[0]]
    if rivals:
        n, k_rival, _, rival = max(rivals, key=lambda r: (r[0], -r[1]))
        out.rival_rot, out.rival_center, out.rival_inliers, out.rival_candidate = (
            rival.rot_cam_from_world, rival.center, n, k_rival)
    return out


def inliers_near(query_feats, query_size: tuple[int, int], R: np.ndarray, t: np.ndarray, map_features, backend,
                 params: RefineParams = RefineParams(), beyond: float = 0.0) -> tuple[int, float]:
    """PnP of the query's features with the map's ``pnp_views`` rendered views nearest pose ``(R, t)``
    among those at least ``beyond`` metres from it, refined near it (:func:`refine_candidates` with
    that pose for each view): its inliers (0: no pose near it), and how far the nearest of those views
    stands (inf: none). How strongly the features see the place there, on a footing ``beyond`` sets."""
    if not len(query_feats):
        return 0, float("inf")
    t = np.asarray(t, float)
    dist = np.linalg.norm(map_features.view_centers - t, axis=1)
    views = np.argsort(dist, kind="stable")
    serves = map_features.translation_view[None, :] == views[:, None]  # (V, N_t): the translations each view serves
    keep = (dist[views] >= beyond) & serves.any(1)  # refine_candidates reaches a view through a translation it serves
    views, serves = views[keep][:params.pnp_views], serves[keep][:params.pnp_views]
    if not len(views):
        return 0, float("inf")
    serving = np.argmax(serves, axis=1)  # a translation per view
    k = len(views)
    ref = refine_candidates(query_feats, query_size, np.repeat(np.asarray(R, float)[None], k, 0),
                            np.repeat(t[None], k, 0), serving, map_features, backend, params)
    return (int(ref.num_inliers) if ref.refined else 0), float(dist[views[0]])


def refine_by_retrieval(query_feats, query_size: tuple[int, int], map_features, backend, params: RefineParams,
                        ctx: RetrievalContext) -> Refinement | None:
    """The retrieval fallback (module docstring): the ``params.retrieval.shortlist`` views most like the
    query (:meth:`ldlloc.refine.retrieval.ViewIndex.rank`) are matched with it and PnP runs on the
    matches of the ``params.retrieval.views`` of them with the most matches; of the poses that
    :func:`ldlloc.refine.retrieval.accept_retrieved` accepts, the one with the best line loss (ties:
    more inliers), its ``rival`` the retrieved pose distinct from it with the most inliers (accepted
    or not). None when none is accepted. ``candidate`` of the result is 0 (the search's best);
    ``retrieved["feature_share"]``: its inliers over ``strong_inliers`` and its inlier ratio over
    ``strong_ratio``, the smaller, at most 1 (the confidence's ``features`` signal for it,
    :mod:`ldlloc.confidence`)."""
    W, H = query_size
    rp = params.retrieval
    if rp.views <= 0 or len(query_feats) == 0:
        return None
    shortlist = ctx.index.rank(query_feats.descriptors)[:max(rp.views, rp.shortlist)]
    matches = _match_distinct_views(query_feats, (W, H), shortlist, map_features, backend, params.ratio)
    # the match counts single out the room's own views where the words alone often do not
    by_matches = np.argsort([-len(matches[int(v)]) for v in shortlist], kind="stable")[:rp.views]
    found = []
    for rank in by_matches:
        v = int(shortlist[rank])
        m = matches[v]
        if len(m) < max(params.pnp.min_inliers, rp.min_inliers):
            continue
        res = estimate_pose_spherical(query_feats.keypoints[m[:, 0]], map_features.xyz[m[:, 1]], W, H, params.pnp)
        if res is not None:
            found.append((v, int(rank), len(m), int(res.inliers.sum()), res))
    if not found:
        return None
    losses = ctx.loss(np.stack([f[4].rot_cam_from_world for f in found]), np.stack([f[4].center for f in found]))
    ok = [(float(loss), f) for loss, f in zip(losses, found)
          if accept_retrieved(f[3], float(loss), ctx.search_loss, rp)]
    if not ok:
        return None
    loss, (v, rank, n_matches, inliers, res) = min(ok, key=lambda x: (x[0], -x[1][3]))
    # how near its support comes to the strong support that the plausibility guard asks of a PnP pose
    # far from every candidate (1: as strong)
    share = min(1.0, inliers / max(params.strong_inliers, 1),
                inliers / max(n_matches, 1) / max(params.strong_ratio, 1e-9))
    out = Refinement(res.rot_cam_from_world, res.center, True, 0, n_matches, inliers,
                     f"retrieval: view {v} (rank {rank + 1}), {inliers} inliers of {n_matches} matches, line loss "
                     f"{loss:.0f} against the search's {ctx.search_loss:.0f}",
                     retrieved={"view": v, "rank": rank, "inliers": inliers, "loss": loss,
                                "search_loss": float(ctx.search_loss), "feature_share": round(share, 6)})
    # the retrieved views of an identical room's copies give their own poses: the best distinct one is the rival
    rivals = [f for f in found if distinct(res.rot_cam_from_world, res.center, f[4].rot_cam_from_world, f[4].center)[0]]
    if rivals:
        rival = max(rivals, key=lambda f: (f[3], -f[1]))
        out.rival_rot, out.rival_center, out.rival_inliers = rival[4].rot_cam_from_world, rival[4].center, rival[3]
    return out
