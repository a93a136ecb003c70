"""Pose search: rank all N_t x N_r poses by line distance functions and keep the top K.

Paper section 3.3. The 3D lines keep the principal group the map assigned
them (index j of ``map.principal_directions``); under a candidate rotation, 2D group ``j`` holds
the arcs through the vanishing point that the rotation matched to 3D direction ``j``, so group
``j`` in 2D always pairs with group ``j`` in 3D.

Two paths rank the same poses:

* exact (``use_fields=False``): :func:`ldlloc.search.ldf.ldf_3d` evaluates every 3D line at every
  pose (rotation invariance: lines projected once per translation, query points rotated);
* fast (``use_fields=True``, the default when the map has distance fields): bilinear look-ups
  in the map's precomputed fields (:mod:`ldlloc.search.fields`), one fused gather for all
  N_t x N_r x |Q| x 3 values. It holds the decomposed functions only, so the undecomposed
  ablation (``decompose=False``) always runs the exact path.

The fast path then re-scores (``SearchParams.rescore``, default 64): the best ``rescore`` poses
by field loss get their exact loss (:func:`ldlloc.search.ldf.ldf_3d_at`: the same functions as
``ldf_3d`` at just those poses, lines projected once per distinct translation) and the
``top_k`` by exact loss are returned, ties in the field order. The returned losses are then
exact, and equal the exact path's top-K whenever its top-K poses are among the field's best
``rescore`` (the interpolation error, largest on the kinks of the functions, moves an inlier
count by a few terms at most: docs/measurements.md#fields-accuracy). ``rescore=0`` returns the field losses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.map.visibility import coverage_at
from ldlloc.rotation import ARC_GROUP_TOL, arc_normals
from ldlloc.search import ldf
from ldlloc.search.fields import inlier_loss_from_fields

torch = lazy_module("torch")

MAX_TOP_K = 1000  # top_k: each kept pose is refined; more than this is a typo, not a method


def check_top_k(top_k: int, name: str = "top_k") -> None:
    """A one-line InputError unless ``top_k`` is in [1, :data:`MAX_TOP_K`] (``name``: how the caller calls it)."""
    if not 1 <= top_k <= MAX_TOP_K:
        raise InputError(f"{name} must be an integer in [1, {MAX_TOP_K}], got {top_k}")


@dataclass(frozen=True)
class SearchParams:
    """Parameters of the pose search (paper defaults)."""

    top_k: int = 20
    """K: poses kept for refinement, 1 to MAX_TOP_K."""
    tau: float = 0.1
    """Inlier threshold of the loss (radians)."""
    loss: str = "inlier"
    """inlier (the paper's) | l1 | l2 | huber | median (ablations)."""
    decompose: bool = True
    """Decomposed distance functions (eq. 5) or not (eq. 4)."""
    query_level: int = 1
    """Icosphere level of the query points Q (1: 42 points)."""
    chunk_translations: int = 4
    """Translations per batch of the exact path (cache-sized on a CPU; raise it on CUDA)."""
    use_fields: bool | None = None
    """Fast look-ups in the map's distance fields; None: when the map has them and decompose is on."""
    rescore: int = 64
    """Fast path: the best this many poses by field loss get their exact loss (0: field losses)."""
    rescore_lines: int = 700
    """A map of more lines re-scores proportionally fewer poses (docs/measurements.md#rescore-lines)."""
    rescore_query_level: int | None = 2
    """Query points of the exact re-scoring (None: query_level); 2 sees door frames that tell twins apart."""
    coverage_cap: float = 2.0
    """Coverage maps: inliers over the covered directions / their share, at most this factor (1: off)."""
    diverse_translation: float = 0.35
    """Top-K diversity: a pose is dropped when a better one is this near (m) and diverse_rotation_deg near (0: off)."""
    diverse_rotation_deg: float = 5.0
    """Top-K diversity's angle (deg): with diverse_translation, the top K are not near-copies of one pose (0: off)."""


@dataclass
class SearchResult:
    """Top-K poses, best first."""

    rotations: np.ndarray  # (K, 3, 3) world -> camera
    centers: np.ndarray  # (K, 3)
    translation_index: np.ndarray  # (K,) index into the map's translations
    rotation_index: np.ndarray  # (K,) index into the candidate rotations
    losses: np.ndarray  # (K,)


def search_poses(arcs2d: np.ndarray, labels2d: np.ndarray, rotations: np.ndarray, lines3d: np.ndarray,
                 line_groups: np.ndarray, translations: np.ndarray, params: SearchParams = SearchParams(),
                 device: str = "cpu", fields=None, visibility: np.ndarray | None = None,
                 coverage: np.ndarray | None = None, num_groups: int = 3) -> SearchResult:
    """Rank every (translation, rotation) pair and return the ``top_k`` poses, best first.

    ``arcs2d`` (N, 2, 3) are the query's (length-filtered) arcs in the camera frame and
    ``labels2d`` (N_r, N) their principal group under each rotation
    (:func:`ldlloc.rotation.labels_for_rotations`); ``rotations`` (N_r, 3, 3) the candidate
    rotations; ``lines3d`` (L, 2, 3) with ``line_groups`` (L,) from the map; ``translations``
    (N_t, 3). ``fields``: the map's :class:`ldlloc.search.fields.DistanceFields` (or None), used as
    ``params.use_fields`` says. ``visibility`` (N_t, L) bool: the lines seen from each translation
    (maps with walls; the fields were computed with it), None: all. ``coverage`` (N_t, G + 1, 2G)
    bool: the directions that meet a mapped surface from each translation
    (:func:`ldlmap.map.visibility.coverage_fields`), used by the re-scoring (``coverage_cap``).
    ``num_groups``: the map's principal directions K (3; more for an Atlanta frame of several
    horizontals): one decomposed function per direction.
    """
    if len(rotations) == 0:
        raise InputError("no candidate rotations (too few lines in the panorama?)")
    if len(arcs2d) == 0:
        raise InputError("no 2D lines detected in the panorama")
    dt = torch.float32
    Q = ldf.query_points(params.query_level, device=device, dtype=dt)
    arcs_t = torch.as_tensor(np.asarray(arcs2d), dtype=dt, device=device)
    if params.decompose:
        f2d = ldf.decomposed_distance_2d(Q, arcs_t, torch.as_tensor(np.asarray(labels2d), device=device), num_groups)
        groups3d = np.asarray(line_groups)
    else:  # eq. 4: one distance function over all lines
        f2d = ldf.decomposed_distance_2d(Q, arcs_t, torch.zeros(len(arcs2d), dtype=torch.long, device=device), 1)
        groups3d = np.zeros(len(lines3d), dtype=np.int64)
        num_groups = 1
    fast = use_fields_for(params, fields)
    if fast:
        if fields.num_translations != len(translations):
            raise InputError(f"distance fields hold {fields.num_translations} translations, "
                             f"the search has {len(translations)}")
        f3d = fields.ldf_3d(Q, rotations)  # (N_r, Q, G, N_t)
        if params.loss == "inlier":
            loss = inlier_loss_from_fields(f2d, f3d, params.tau)
        else:
            loss = ldf.pose_loss(f2d, f3d.permute(3, 0, 2, 1).to(dt), kind=params.loss, tau=params.tau)
    else:
        f3d = ldf.ldf_3d(Q, rotations, translations, lines3d, groups3d, num_groups=num_groups,
                         chunk=params.chunk_translations, device=device, dtype=dt, visibility=visibility)
        loss = ldf.pose_loss(f2d, f3d, kind=params.loss, tau=params.tau, decompose=True)
    rescore = fast and params.rescore > 0
    want = rescored_poses(params, len(lines3d)) if rescore else params.top_k  # at least top_k
    diverse = params.diverse_translation > 0 and params.diverse_rotation_deg > 0
    ti, ri, lv = ldf.top_k_poses(loss, 8 * want if diverse else want)
    if diverse:
        keep = diverse_subset(np.asarray(translations)[ti.cpu().numpy()], np.asarray(rotations)[ri.cpu().numpy()],
                              want, params.diverse_translation, params.diverse_rotation_deg)
        keep_t = torch.as_tensor(keep, device=ti.device)
        ti, ri, lv = ti[keep_t], ri[keep_t], lv[keep_t]
    if rescore:  # exact losses of the best field poses; the stable sort keeps the field order on ties
        level = params.rescore_query_level
        if level is not None and level != params.query_level:  # 2D functions on the denser points,
            # for the rotations of the re-scored poses only (decompose is on: the fields hold groups)
            Q = ldf.query_points(level, device=device, dtype=dt)
            uniq, inv = torch.unique(ri, return_inverse=True)
            lab = torch.as_tensor(np.asarray(labels2d), device=device)[uniq]
            f2d_at = ldf.decomposed_distance_2d(Q, arcs_t, lab, num_groups)[inv]
        else:
            f2d_at = f2d[ri] if f2d.dim() == 3 else f2d
        f3d = ldf.ldf_3d_at(Q, rotations, translations, lines3d, groups3d, ti, ri, num_groups=num_groups,
                            device=device, dtype=dt, visibility=visibility)
        lv = _rescored_loss(f2d_at, f3d, Q, np.asarray(rotations)[ri.cpu().numpy()], ti.cpu().numpy(), coverage, params)
        order = torch.sort(lv, stable=True).indices[:params.top_k]
        ti, ri, lv = ti[order], ri[order], lv[order]
    ti, ri = ti.cpu().numpy(), ri.cpu().numpy()
    return SearchResult(rotations=np.asarray(rotations)[ri], centers=np.asarray(translations)[ti],
                        translation_index=ti, rotation_index=ri, losses=lv.cpu().numpy())


def search_map(arcs2d: np.ndarray, labels2d: np.ndarray, rotations: np.ndarray, ldl_map,
               params: SearchParams = SearchParams(), device: str = "cpu", fields=None,
               translation_index: np.ndarray | None = None) -> SearchResult:
    """The pose search stage on a map (an :class:`ldlmap.map.contents.LdlMap`: its lines, groups,
    principal directions, candidate translations, visibility and coverage), :func:`search_poses`.
    ``translation_index``: search only these of the map's candidate translations (their fields,
    visibility and coverage); the result's translation indices are the whole map's."""
    m = ldl_map
    if translation_index is None:
        return search_poses(arcs2d, labels2d, rotations, m.lines, m.line_groups, m.translations, params, device,
                            fields=fields, visibility=m.visibility, coverage=m.coverage,
                            num_groups=len(m.principal_directions))
    ti = np.asarray(translation_index)
    res = search_poses(arcs2d, labels2d, rotations, m.lines, m.line_groups, m.translations[ti], params, device,
                       fields=None if fields is None else fields.subset(ti),
                       visibility=None if m.visibility is None else m.visibility[ti],
                       coverage=None if m.coverage is None else m.coverage[ti], num_groups=len(m.principal_directions))
    res.translation_index = ti[res.translation_index]
    return res


def score_on_map(arcs2d: np.ndarray, rotations: np.ndarray, centers: np.ndarray, ldl_map,
                 params: SearchParams = SearchParams(), device: str = "cpu", group_tol: float = ARC_GROUP_TOL,
                 translation_index: np.ndarray | None = None) -> np.ndarray:
    """Exact losses (M,) of poses on a map (:func:`score_poses`), each seen from the candidate
    translation ``translation_index`` (None: the map's candidate translation nearest to it)."""
    m = ldl_map
    ti = m.nearest_translation(centers) if translation_index is None else translation_index
    return score_poses(arcs2d, rotations, centers, m.lines, m.line_groups, m.principal_directions, ti, params,
                       m.visibility, m.coverage, device, group_tol)


def line_loss(arcs2d: np.ndarray, ldl_map, params: SearchParams = SearchParams(), device: str = "cpu",
              group_tol: float = ARC_GROUP_TOL):
    """``loss(R (M, 3, 3), t (M, 3)) -> (M,)``: :func:`score_on_map` of these arcs, each pose seen
    from the candidate translation nearest to it."""

    def loss(R: np.ndarray, t: np.ndarray) -> np.ndarray:
        return score_on_map(arcs2d, R, t, ldl_map, params, device, group_tol)

    return loss


def score_poses(arcs2d: np.ndarray, rotations: np.ndarray, centers: np.ndarray, lines3d: np.ndarray,
                line_groups: np.ndarray, principal3d: np.ndarray, translation_index: np.ndarray,
                params: SearchParams = SearchParams(), visibility: np.ndarray | None = None,
                coverage: np.ndarray | None = None, device: str = "cpu", group_tol: float = ARC_GROUP_TOL) -> np.ndarray:
    """Exact inlier losses (M,) of arbitrary poses (e.g. refined ones), as the re-scoring computes
    them: decomposed functions on the re-scoring's query points, each arc grouped by the principal
    direction its great circle passes through under the pose (``|n . R p_g| < group_tol``), the
    lines seen from (and the coverage of) the candidate translation ``translation_index`` (M,)
    each pose came from."""
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    C = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    ti = np.asarray(translation_index, dtype=np.int64).reshape(-1)
    labels = pose_labels(arcs2d, R, principal3d, group_tol)  # (M, N)
    dt = torch.float32
    Q = ldf.query_points(params.rescore_query_level or params.query_level, device=device, dtype=dt)
    arcs_t = torch.as_tensor(np.asarray(arcs2d), dtype=dt, device=device)
    ng = len(np.asarray(principal3d))
    f2d = ldf.decomposed_distance_2d(Q, arcs_t, torch.as_tensor(labels, device=device), ng)  # (M, G, Q)
    vis = None if visibility is None else np.asarray(visibility)[ti]
    f3d = ldf.ldf_3d_at(Q, R, C, lines3d, line_groups, np.arange(len(R)), np.arange(len(R)), num_groups=ng,
                        device=device, dtype=dt, visibility=vis)
    return _rescored_loss(f2d, f3d, Q, R, ti, coverage, replace(params, loss="inlier")).cpu().numpy().astype(np.float64)


def pose_labels(arcs2d: np.ndarray, rotations: np.ndarray, principal3d: np.ndarray,
                group_tol: float = ARC_GROUP_TOL) -> np.ndarray:
    """(M, N) principal group of each arc under each rotation (M, 3, 3): the direction ``g`` its
    great circle passes through (``|n . R p_g| < group_tol``), -1 for none."""
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    normals, _ = arc_normals(arcs2d)
    c = np.abs(np.einsum("ni,mig->mng", normals, R @ np.asarray(principal3d, dtype=np.float64).T))  # |n . R p_g|
    ok = (np.min(c, axis=2) < group_tol) & (np.linalg.norm(normals, axis=1) > 0)[None]
    return np.where(ok, np.argmin(c, axis=2), -1)


def _rescored_loss(f2d, f3d, Q, rotations: np.ndarray, translation_index: np.ndarray, coverage, params: SearchParams):
    """Loss of M poses from their functions (M, G, Q): over the covered directions (maps with
    coverage, inlier loss, ``coverage_cap`` > 1; :func:`covered_inlier_loss`) or the plain loss."""
    if coverage is not None and params.loss == "inlier" and params.coverage_cap > 1:
        return covered_inlier_loss(f2d, f3d, Q, rotations, translation_index, coverage, params.tau, params.coverage_cap)
    return ldf.pose_loss(f2d, f3d.unsqueeze(0), kind=params.loss, tau=params.tau)[0]


def covered_inlier_loss(f2d, f3d, Q, rotations: np.ndarray, translation_index: np.ndarray, coverage: np.ndarray,
                        tau: float, cap: float):
    """Inlier loss of M poses counted over the query points whose world direction meets a mapped
    surface, divided by their share (at most ``cap``): ``-(inliers on covered points) / max(share,
    1 / cap)``. Equals the plain inlier loss where the map covers every direction.

    ``f2d`` (M, G, Q) or (G, Q), ``f3d`` (M, G, Q), ``Q`` (Q, 3) camera-frame points,
    ``rotations`` (M, 3, 3), ``translation_index`` (M,), ``coverage`` (N_t, G' + 1, 2G').
    """
    dirs = np.einsum("qi,mij->mqj", Q.detach().cpu().numpy().astype(np.float64), rotations)  # R^T q
    covered = torch.as_tensor(coverage_at(coverage, translation_index, dirs), device=f3d.device)  # (M, Q)
    inl = ((f2d - f3d).abs() < tau) & covered[:, None, :]
    share = covered.to(f3d.dtype).mean(1).clamp(min=1.0 / cap)
    return -inl.sum((1, 2)).to(f3d.dtype) / share


def rescored_poses(params: SearchParams, num_lines: int) -> int:
    """Poses the fast path re-scores exactly: ``params.rescore``, scaled down by
    ``rescore_lines / num_lines`` for maps of more lines, never below ``top_k``."""
    n = int(params.rescore)
    if params.rescore_lines > 0 and num_lines > params.rescore_lines:
        n = n * int(params.rescore_lines) // int(num_lines)
    return max(int(params.top_k), n)


def diverse_subset(centers: np.ndarray, rotations: np.ndarray, k: int, min_distance: float,
                   min_angle_deg: float) -> np.ndarray:
    """Indices of up to ``k`` poses, in the given (best-first) order, none of which lies within
    ``min_distance`` metres and ``min_angle_deg`` of a better kept pose (greedy suppression).

    ``centers`` (M, 3), ``rotations`` (M, 3, 3). Keeps the top-K from being near-copies of one
    pose, so that a pose and its symmetric twin both reach refinement.
    """
    C = np.asarray(centers, dtype=np.float64)
    R = np.asarray(rotations, dtype=np.float64).reshape(len(C), 9)
    d2, cos_min = float(min_distance) ** 2, np.cos(np.radians(min_angle_deg))
    suppressed = np.zeros(len(C), dtype=bool)
    keep: list[int] = []
    while len(keep) < k and not suppressed.all():  # at most k rounds, each vectorized over M
        i = int(np.argmin(suppressed))  # the best pose not yet suppressed
        keep.append(i)
        near = (np.sum((C - C[i]) ** 2, axis=1) < d2) & ((R @ R[i] - 1.0) / 2.0 > cos_min)  # trace(R_i^T R_m)
        suppressed |= near
        suppressed[i] = True
    return np.array(keep, dtype=np.int64)


def use_fields_for(params: SearchParams, fields) -> bool:
    """Whether the search runs on distance fields (see :attr:`SearchParams.use_fields`).

    Raises InputError when ``use_fields=True`` cannot be honoured (no fields, or the
    undecomposed ablation, which the decomposed fields cannot give).
    """
    if params.use_fields is False:
        return False
    if params.use_fields is None:
        return fields is not None and params.decompose
    if fields is None:
        raise InputError("use_fields=True but the map has no distance fields: rebuild it with distance fields "
                         "or use the exact search")
    if not params.decompose:
        raise InputError("distance fields hold the decomposed functions only: the undecomposed ablation "
                         "needs the exact search (use_fields=False)")
    return True
