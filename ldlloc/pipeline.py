"""Localize one panorama against an LDL map: ``Localizer(map).localize(image) -> Localization``.

Stages (timed; each one call, the map-dependent ones taking the map): ``lines2d`` (LSD on crops, arcs:
:meth:`Localizer.detect_lines`), ``rotation`` (:meth:`Localizer.rotation_stage`: the adaptive
length filter, the longest fraction of the arcs equal to the map's kept ratio within bounds
(``query_keep_ratio``); vanishing points and candidate rotations, then the optional upright prior
``max_tilt_deg``), ``search`` (:func:`ldlloc.search.pose_search.search_map`: line distance functions
over N_t x N_r poses, top K), ``refine`` (query features, matching, spherical PnP; or lines alone,
:func:`ldlloc.refine.geometric.refine_and_keep`), ``confidence`` (how far to trust the pose,
:func:`ldlloc.confidence.assess`), ``total``."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, check_choice, require_file
from ldlmap.core.frame import is_identity, pose_to_input, pose_to_map
from ldlmap.core.geometry import half_icosphere_points, rotation_error_deg
from ldlmap.core.lazy import lazy_module
from ldlmap.core.signals import import_pycolmap
from ldlmap.core.timing import StageClock
from ldlmap.features import backend_for
from ldlmap.features.sphere import extract_in_map_frame
from ldlmap.io.imagefile import image_header_size, read_image
from ldlloc.confidence import assess, refined_rivals
from ldlloc.lines2d import Lines2DParams, detect_lines, filter_by_length, query_keep_ratio
from ldlloc.refine.copies import room_twins
from ldlloc.refine.features import RefineParams, inliers_near, keep_near_lines, refine_by_retrieval, refine_candidates
from ldlloc.refine.geometric import (KERNELS, GeometricParams, map_line_support, physical_poses, refine_and_keep,
                                     refinement_plan, selection_scores)
from ldlloc.refine.retrieval import RetrievalContext, ViewIndex, accept_retrieved
from ldlloc.rotation import (FREE_TILT_DEG, PrincipalParams, RotationCandidates, assign_arcs_to_principal,
                             candidate_rotations, check_max_tilt, filter_by_tilt, frame_rows, pair_candidates,
                             rotation_labels, vanishing_points)
from ldlloc.search.fields import DistanceFields
from ldlloc.search.ldf import check_loss
from ldlloc.search.pose_search import SearchParams, check_top_k, line_loss, search_map

cv2 = lazy_module("cv2")

# Default upright prior (max camera-up tilt, degrees) for queries marked upright (``Query.upright``, ZInD)
# when no ``--max-tilt`` is given: room for an unlevel tripod and a map a few degrees off, none for a
# 90-degree relabeling of a Manhattan frame.
UPRIGHT_MAX_TILT_DEG = 10.0


def rotation_prior_name(max_tilt_deg: float | None) -> str:
    """``"free"`` (no bound, or a bound of 180 degrees or more) or e.g. ``"upright<=10deg"``."""
    if max_tilt_deg is None or max_tilt_deg >= FREE_TILT_DEG:
        return "free"
    return f"upright<={max_tilt_deg:g}deg"


@dataclass(frozen=True)
class LocalizeParams:
    """All localization parameters (each stage's own dataclass holds the paper's defaults)."""

    lines2d: Lines2DParams = field(default_factory=Lines2DParams)
    """Stage 1: 2D line detection and the query's kept ratio."""
    principal: PrincipalParams = field(default_factory=PrincipalParams)
    """Stage 2: vanishing points and candidate rotations."""
    search: SearchParams = field(default_factory=SearchParams)
    """Stage 3: the pose search."""
    refine: RefineParams = field(default_factory=RefineParams)
    """Stage 4, features: matching, spherical PnP and the retrieval fallback."""
    features: str | None = None
    """Feature backend; None: the map's."""
    weights: str | None = None
    """SuperPoint checkpoint (path)."""
    do_refine: bool = True
    """False: stop after the pose search."""
    refine_mode: str = "auto"
    """auto (features on a map with them, geometric where they fail) | features | geometric | both | none."""
    geometric: GeometricParams = field(default_factory=GeometricParams)
    """Stage 4, lines alone: the geometric refinement."""
    privacy: bool = False
    """Refine only with query features near principal-direction lines."""
    query_frame: str = "map"
    """Query features from: map (turned upright like the map's views) | image (docs/measurements.md#query-frame)."""
    max_query_frames: int = 3
    """query_frame map: at most this many frames, for candidates whose up axes lie frame_split_deg apart."""
    frame_split_deg: float = 45.0
    """Candidate up axes this far apart get frames of their own (docs/measurements.md#query-frames)."""
    max_keypoints: int | None = None
    """Query features (None: the backend's query_keypoints)."""
    vp_keep_ratio: float = 0.2
    """Vanishing points from the longest max(kept ratio, this) of the lines (docs/measurements.md#vp-keep-ratio)."""
    max_tilt_deg: float | None = None
    """Upright prior: candidate rotations whose camera up is within this of the world's (None or >= 180: free)."""


@dataclass
class Localization:
    """The result of localizing one panorama."""

    rot_cam_from_world: np.ndarray
    center: np.ndarray
    coarse_rot: np.ndarray  # best pose of the search alone
    coarse_center: np.ndarray
    candidates_rot: np.ndarray  # (K, 3, 3) top-K poses
    candidates_center: np.ndarray  # (K, 3)
    seconds: dict[str, float]
    num_rotations: int
    num_lines: int
    refined: bool
    num_matches: int = 0
    num_inliers: int = 0
    num_query_features: int = 0  # query features used for matching (fewer in privacy mode)
    message: str = ""
    refine_method: str = "none"  # features | geometric | features+geometric | none (what made the final pose)
    refine_residual_deg: float | None = None  # geometric: median angle of the matched line points
    arcs: np.ndarray | None = None  # the filtered 2D arcs used (camera frame)
    query_features: tuple | None = field(default=None, repr=False)  # (Features, (W, H)) the feature refinement
    # matched (the copies' check, Localizer.inliers_at; dropped with the arcs)
    arc_groups: np.ndarray | None = None  # principal group of each arc under the chosen rotation
    rotations: np.ndarray | None = None  # (N_r, 3, 3) all candidate rotations (after the prior)
    candidates_loss: np.ndarray | None = None  # (K,) search loss of each top-K pose (lower is better)
    rotation_prior: str = "free"  # "free" or "upright<=Xdeg" (see rotation_prior_name)
    input_to_map: np.ndarray | None = None  # the map's input -> map similarity when not the identity
    selection_margin: float | None = None  # geometric refinement: the winner's selection score (-loss / max|loss|
    # + map-line support) over the best refined pose distinct from it (ldlloc.confidence.distinct); None: no
    # selection ran (feature refinement, or its geometric fallback)
    refined_rivals: list = field(default_factory=list)  # geometric refinement: the best refined poses distinct from
    # the final one, {R, t, loss, score_gap} (ldlloc.confidence.refined_rivals: a twin within the noise is named)
    pnp_rival: dict | None = None  # feature refinement: the best PnP pose distinct from the final one, {R, t,
    # inliers, candidate} (an identical room's copy; ldlloc.refine.features.Refinement.rival_inliers)
    retrieval: dict | None = None  # the feature pose came from view retrieval, {view, rank, inliers, loss,
    # search_loss, feature_share} (ldlloc.refine.features.refine_by_retrieval)
    confidence: float | None = None  # how far to trust the pose, in [0, 1] (ldlloc.confidence)
    verdict: str | None = None  # confident | ambiguous | failed
    competitors: list = field(default_factory=list)  # distinct poses of nearly the same loss: {R, t, loss, why}
    confidence_signals: dict = field(default_factory=dict)  # what the confidence was computed from

    @property
    def status(self) -> str:
        return "ok" if self.refined else "coarse"

    def input_frame_pose(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The final pose ``(R, t)`` in the map's input frame (SfM maps), None when it is the map's."""
        if self.input_to_map is None:
            return None
        return pose_to_input(self.rot_cam_from_world, self.center, self.input_to_map)

    def truth_in_map_frame(self, rot_cam_from_input: np.ndarray, center_input: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
        """A ground-truth pose as datasets store it (the map's input frame) in the map's frame, where
        this pose and its errors (metres) are: moved by ``input_to_map`` on maps built from another
        frame (``--up``, ``--scale``), as it is otherwise."""
        if self.input_to_map is None:
            return np.asarray(rot_cam_from_input, dtype=np.float64), np.asarray(center_input, dtype=np.float64)
        return pose_to_map(rot_cam_from_input, center_input, self.input_to_map)

    def candidate_dicts(self, digits: int | None = None) -> list[dict]:
        """The top-K search poses, best first: ``[{"R": 3x3, "t": [3], "loss": float}, ...]``.

        ``digits``: round R to ``digits + 2`` and t to ``digits`` decimals (None: no rounding).
        """
        Rs = np.asarray(self.candidates_rot, dtype=np.float64)
        ts = np.asarray(self.candidates_center, dtype=np.float64)
        losses = (np.full(len(Rs), np.nan) if self.candidates_loss is None
                  else np.asarray(self.candidates_loss, dtype=np.float64))
        if digits is not None:
            Rs, ts = np.round(Rs, digits + 2), np.round(ts, digits)
        return [{"R": R.tolist(), "t": t.tolist(), "loss": float(v)} for R, t, v in zip(Rs, ts, losses)]


REFINE_MODES = ("auto", "features", "geometric", "both", "none")
QUERY_FRAMES = ("image", "map")


def check_localize_params(params: LocalizeParams, names: dict[str, str] | None = None) -> None:
    """A one-line InputError for the first parameter out of its range or set (the loss, top K, refinement,
    query frame, tilt bound); ``names``: what the messages call them by field name (default: the field
    names; the command line passes its options). Cheap: call it before any work."""
    n = names or {}
    check_loss(params.search.loss, n.get("loss", "loss"))
    check_top_k(params.search.top_k, n.get("top_k", "top_k"))
    check_choice(params.refine_mode, REFINE_MODES, n.get("refine_mode", "refine_mode"))
    check_choice(params.query_frame, QUERY_FRAMES, n.get("query_frame", "query_frame"))
    check_max_tilt(params.max_tilt_deg, n.get("max_tilt_deg", "max_tilt_deg"))
    for key in ("kernel", "second_kernel"):  # the geometric refinement's weights
        check_choice(getattr(params.geometric, key), KERNELS, n.get(key, key))


WORK_WIDTH = 2048  # panoramas wider than this are resized to WORK_WIDTH x WORK_WIDTH / 2 on reading:
# the defaults' resolution; more only costs time (docs/measurements.md#work-width)
MAX_PANORAMA_WIDTH = 16384  # larger panoramas are refused before decoding (16384 x 8192: 400 MB decoded)
MIN_PANORAMA_WIDTH = 64  # smaller ones hold no lines to speak of


def load_image(path: str | Path) -> np.ndarray:
    """Read an RGB panorama (uint8, W = 2 H) at the working resolution: one wider than
    :data:`WORK_WIDTH` is resized to it (``INTER_AREA``) right after decoding. Grey, 16-bit and
    RGBA images are converted; missing, unreadable, empty, corrupt, truncated, absurdly large or
    tiny images, and those not 2:1, are one-line :class:`InputError`\\ s."""
    p = require_file(path, "image")
    if not os.access(p, os.R_OK):
        raise InputError(f"cannot read image (permission denied): {p}")
    if p.stat().st_size == 0:
        raise InputError(f"image file is empty: {p}")
    header = image_header_size(p)
    if header is not None and max(header) > MAX_PANORAMA_WIDTH:  # before decoding it (EXIF may turn it)
        _check_panorama_size(header, p)
    img = read_image(p, cv2.IMREAD_COLOR)  # through Python's open(): any file name (cv2.imread crashes on some)
    if img is None:
        raise InputError(f"cannot decode image (corrupt or unsupported format): {p}")
    _check_panorama_size((img.shape[1], img.shape[0]), p)
    if img.shape[1] > WORK_WIDTH:
        img = cv2.resize(img, (WORK_WIDTH, WORK_WIDTH // 2), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _check_panorama_size(size: tuple[int, int], p: Path) -> None:
    """One-line errors for a (width, height) that is too large, not 2:1 or too small."""
    w, h = size
    if max(w, h) > MAX_PANORAMA_WIDTH:
        raise InputError(f"panorama too large: {p} is {w}x{h} (at most {MAX_PANORAMA_WIDTH}x"
                         f"{MAX_PANORAMA_WIDTH // 2}; it is resized to {WORK_WIDTH}x{WORK_WIDTH // 2} anyway)")
    if w != 2 * h:
        raise InputError(f"not an equirectangular panorama (width must be 2 x height): {p} is {w}x{h}")
    if w < MIN_PANORAMA_WIDTH:
        raise InputError(f"panorama too small: {p} is {w}x{h} (at least {MIN_PANORAMA_WIDTH}x{MIN_PANORAMA_WIDTH // 2})")


def query_frame_groups(rotations: np.ndarray, max_frames: int = 3, split_deg: float = 45.0
                       ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Frames to extract a query's features in, for candidate rotations (K, 3, 3) best first: the
    best's, then each next one whose camera up axis (``R e_z``) is more than ``split_deg`` from every
    frame's so far, at most ``max_frames``; with the candidates (indices) whose up axis is nearest
    to each frame's. Rotations about the up axis only roll the panorama: they share a frame."""
    R = np.asarray(rotations, dtype=np.float64)
    up = R[:, :, 2]
    frames = [0]
    cos = np.cos(np.radians(split_deg))
    for i in range(1, len(R)):
        if len(frames) >= max(1, int(max_frames)):
            break
        if np.all(up[frames] @ up[i] < cos):
            frames.append(i)
    nearest = np.argmax(up @ up[frames].T, axis=1)
    return [(R[f], np.flatnonzero(nearest == j)) for j, f in enumerate(frames)]


def _check_panorama_array(image_rgb: np.ndarray) -> np.ndarray:
    img = np.asarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or img.shape[1] != 2 * img.shape[0]:
        raise InputError(f"panorama must be uint8 (H, 2H, 3), got {img.dtype} {img.shape}")
    return img


class QueryLines:
    """A panorama's 2D lines (stage 1: they do not depend on the map), detected once and shared by
    every map it is localized against, with its vanishing points voted once per length ratio."""

    def __init__(self, arcs: np.ndarray, seconds: float):
        self.arcs, self.seconds = arcs, float(seconds)  # all detected arcs; seconds the detection took
        self._vps: dict = {}

    @classmethod
    def detect(cls, img: np.ndarray, params: LocalizeParams) -> "QueryLines":
        tick = time.perf_counter()
        arcs = detect_lines(img, params.lines2d)
        if len(arcs) < 3:
            raise InputError(f"too few lines in the panorama ({len(arcs)} detected): a flat or empty image?")
        return cls(arcs, time.perf_counter() - tick)

    def vanishing_points(self, ratio: float, principal: PrincipalParams) -> np.ndarray:
        """The vanishing points of the longest ``ratio`` of the lines (cached: the same for every map)."""
        key = (float(ratio), principal)
        if key not in self._vps:
            self._vps[key] = vanishing_points(filter_by_length(self.arcs, ratio), principal.k_2d, principal)
        return self._vps[key]


@dataclass(frozen=True)
class SearchNear:
    """A restricted pose search (tracking a walk, :mod:`ldlloc.walk`): only the map's candidate
    translations within ``radius_m`` of ``center`` and the candidate rotations within ``cone_deg``
    of ``rot_cam_from_world``."""

    center: np.ndarray  # (3,) predicted camera centre
    rot_cam_from_world: np.ndarray | None  # (3, 3) predicted rotation (None: any rotation)
    radius_m: float = 0.75
    cone_deg: float = 15.0


@dataclass
class RotationStage:
    """:meth:`Localizer.rotation_stage`'s result: what the pose search runs on."""

    arcs: np.ndarray  # the length-filtered arcs the search uses
    rotations: RotationCandidates  # the candidate rotations (within the tilt bound)
    labels: np.ndarray  # (N_r, N) principal group of each arc under each candidate rotation
    translation_index: np.ndarray | None = None  # the map's candidate translations to search (None: all)


@dataclass
class Searched:
    """:meth:`Localizer.search`'s result: the coarse localization and what refinement needs."""

    out: Localization  # the search's best pose as a Localization (not refined yet)
    res: object  # ldlloc.search.pose_search.SearchResult: the top-K poses
    arcs: np.ndarray  # the length-filtered arcs the search used
    labels: np.ndarray  # (N_r, N) principal group of each arc under each candidate rotation

    @property
    def best_loss(self) -> float:
        """The search's best loss (lower is better): the cheap score of a map for this panorama."""
        return float(self.res.losses[0])


class Localizer:
    """Holds one map (and its feature backend) and localizes panoramas against it."""

    def __init__(self, ldl_map, params: LocalizeParams = LocalizeParams(), device: str = "cpu"):
        check_localize_params(params)
        self.map = ldl_map
        self.params = params
        self.device = device
        self.backend = None
        map_backend = ldl_map.features.backend if ldl_map.features is not None else None
        want = params.features or map_backend
        if params.features and map_backend and params.features != map_backend:
            raise InputError(f"map {ldl_map.name} was built with {map_backend} features, "
                             f"not {params.features}: rebuild it or drop --features")
        self.fields = None  # the map's distance fields, prepared once for the fast pose search
        self.view_index = None  # the map's view retrieval index (ldlloc.refine.retrieval), built when first needed
        if params.search.use_fields is not False:
            self.fields = DistanceFields.from_map(ldl_map, device)
        mode = params.refine_mode if params.do_refine else "none"
        # auto on a map with features: features, and the geometric refinement only where they fail
        # (a polish after PnP makes poses worse: docs/measurements.md#auto-refinement)
        self.fallback_geometric = mode == "auto" and map_backend is not None
        if mode == "auto":
            mode = "features" if map_backend is not None else "geometric"
        if mode in ("features", "both") and map_backend is None:
            raise InputError(f"map {ldl_map.name} has no features: feature refinement needs a map built with "
                             "features (use --refine geometric)")
        self.refine_mode = mode
        self.refine_enabled = mode in ("features", "both")
        if self.refine_enabled:
            self.backend = backend_for(want, params.weights, device, ldl_map.features.extraction)
        self._prepare()

    def _prepare(self) -> None:
        """One-time work done here, not in the first query's timed stages: the vanishing points'
        voting sphere and, for feature refinement, pycolmap's import (spherical PnP)."""
        half_icosphere_points(self.params.principal.icosphere_level)
        if self.refine_enabled:
            import_pycolmap()

    def _refine_and_keep(self, arcs: np.ndarray, rotations: np.ndarray, centers: np.ndarray,
                         translation_index: np.ndarray, n: int, assoc_deg: np.ndarray | None = None, kernels=None):
        """:func:`ldlloc.refine.geometric.refine_and_keep` of these poses on this localizer's map."""
        p = self.params
        return refine_and_keep(arcs, rotations, centers, translation_index, n, self.map, p.geometric, p.search,
                               self.device, p.principal.group_tol, assoc_deg, kernels)

    def _refine_geometric(self, out: "Localization", arcs: np.ndarray, res) -> None:
        """Refine the best of the top-K poses from lines alone; the winner has the best loss and
        map-line support together (:func:`ldlloc.refine.geometric.map_line_support`). The best
        ``GeometricParams.wide_poses`` are refined again with wider first associations
        (``wide_assoc_deg``), the best ``second_kernel_poses`` again with ``second_kernel``'s weights; all
        results compete (:func:`ldlloc.refine.geometric.refinement_plan`). The winner's twins in a
        symmetric room (:func:`ldlloc.refine.copies.room_twins`) join its rivals, never the winners."""
        m, p = self.map, self.params
        M = len(res.centers)
        plan, assoc, kernels = refinement_plan(M, p.geometric)
        nr = len(plan)  # the refined poses; the other candidates keep their coarse poses
        cand = np.r_[plan, np.arange(int(plan.max()) + 1, M)].astype(int)  # pose -> candidate
        g, kept, loss = self._refine_and_keep(arcs, res.rotations[cand], res.centers[cand],
                                              res.translation_index[cand], nr, assoc, kernels)
        rots, centers = res.rotations[cand], res.centers[cand]
        rots[:nr][kept[:nr]], centers[:nr][kept[:nr]] = g.rotations[kept[:nr]], g.centers[kept[:nr]]

        def support_of(top: np.ndarray) -> np.ndarray:  # the contenders' map-line support
            vis = None
            if m.visibility is not None:  # the lines seen from each pose's nearest candidate translation
                vis = m.visibility[m.nearest_translation(centers[top])]
            # poses refined as one (GeometricParams.merge_m) are the same pose: one support each
            _, first, back = np.unique(np.concatenate([rots[top].reshape(-1, 9), centers[top]], 1), axis=0,
                                       return_index=True, return_inverse=True)
            return map_line_support(arcs, rots[top[first]], centers[top[first]], m.lines, m.line_groups,
                                    None if vis is None else vis[first], p.geometric.support_deg)[back.reshape(-1)]

        score = selection_scores(loss, p.geometric, support_of, physical_poses(centers, m))  # unphysical poses drop out
        k = int(np.argmax(score))
        c = int(cand[k])
        twins = room_twins(arcs, rots[k], centers[k], m, p.geometric.support_deg)
        if twins:  # the winner's twins in a symmetric room compete as its rivals (never as the winner)
            tr, tc = np.array([r for r, _ in twins]), np.array([t for _, t in twins])
            loss = np.r_[loss, self._line_loss(arcs)(tr, tc)]
            rots, centers = np.concatenate([rots, tr]), np.concatenate([centers, tc])
            score = selection_scores(loss, p.geometric, support_of, physical_poses(centers, m))
        out.selection_margin, out.refined_rivals = refined_rivals(k, rots, centers, loss, score)
        out.coarse_rot, out.coarse_center = res.rotations[c], res.centers[c]
        out.rot_cam_from_world, out.center = rots[k], centers[k]
        out.arc_groups = assign_arcs_to_principal(arcs, (out.rot_cam_from_world @ m.principal_directions.T).T,
                                                  p.principal.group_tol)
        out.refined = bool(kept[k])
        out.refine_method = "geometric" if out.refined else "none"
        out.num_matches = int(g.matched[k]) if k < nr else 0
        out.refine_residual_deg = float(g.residual_deg[k]) if out.refined else None
        out.message = (f"geometric refinement of candidate {c + 1}: {out.num_matches} line points, median "
                       f"residual {out.refine_residual_deg:.2f} deg" if out.refined else
                       f"candidate {c + 1}: coarse pose kept (its geometric refinement diverged, matched too few line "
                       "points or explained less of the image)")

    def _line_loss(self, arcs: np.ndarray):
        """``loss(R (M, 3, 3), t (M, 3)) -> (M,)``: the exact line loss of poses, each seen from the
        candidate translation nearest to it (:func:`ldlloc.search.pose_search.line_loss`)."""
        return line_loss(arcs, self.map, self.params.search, self.device, self.params.principal.group_tol)

    def _retrieval_context(self, arcs: np.ndarray, res):
        """The retrieval fallback's context (:class:`ldlloc.refine.retrieval.RetrievalContext`): the map's
        view index (built on first use), the exact line loss of poses (:meth:`_line_loss`) and that loss
        of the search's best pose."""
        if self.view_index is None:
            self.view_index = ViewIndex(self.map.features, self.params.refine.retrieval)
        loss = self._line_loss(arcs)
        return RetrievalContext(self.view_index, loss, float(loss(res.rotations[:1], res.centers[:1])[0]))

    def _refine_features(self, img: np.ndarray, grouped_arcs: np.ndarray, res, arcs: np.ndarray):
        """Feature refinement of the top-K poses (:func:`ldlloc.refine.features.refine_candidates`); returns
        the refinement and the query features it used.

        With ``query_frame`` ``map`` the query's features are extracted in the frame of the best
        candidate's rotation and, for candidates whose camera up axis is more than
        ``frame_split_deg`` from every frame's so far (a flipped Manhattan twin of a free-rotation
        query), in theirs, at most ``max_query_frames``: each candidate is matched with the features
        of the frame nearest its up axis, frame after frame until one's candidates refine (the
        first frame's, usually: no extra cost), else the most PnP inliers win. When none refines, or
        the pose would not pass the retrieval's acceptance (:meth:`_accepted`), the retrieval
        fallback (:func:`ldlloc.refine.features.refine_by_retrieval`) matches the first frame's
        features with the map's views most like them (its accepted pose replaces a weak one). ``grouped_arcs``: the arcs of principal
        lines (the privacy filter's); ``arcs``: all the search's arcs (the retrieved poses' line loss)."""
        p, m = self.params, self.map
        H, W = img.shape[:2]
        k = self.backend.query_keypoints if p.max_keypoints is None else p.max_keypoints
        groups = (query_frame_groups(res.rotations, p.max_query_frames, p.frame_split_deg) if p.query_frame == "map"
                  else [(None, np.arange(len(res.rotations)))])
        best, best_key, first = None, None, None
        for R, idx in groups:
            feats = (self.backend.extract(img, max_keypoints=k) if R is None
                     else extract_in_map_frame(self.backend, img, R, max_keypoints=k))
            if p.privacy:
                feats = feats.subset(keep_near_lines(feats.keypoints, grouped_arcs, W, H, p.refine.privacy_radius))
            ref = refine_candidates(feats, (W, H), res.rotations[idx], res.centers[idx], res.translation_index[idx],
                                    m.features, self.backend, p.refine)
            ref.candidate = int(idx[ref.candidate])
            ref.rival_candidate = int(idx[ref.rival_candidate]) if ref.rival_candidate >= 0 else -1
            first = feats if first is None else first
            key = (ref.refined, ref.num_inliers)
            if best_key is None or key > best_key:  # ties: the frame of the better-ranked candidates
                best, best_key = (ref, feats), key
            if ref.refined:  # the next frames are tried only where this one's candidates failed
                break
        if (p.refine.retrieval.views > 0 and len(first)
                and (not best[0].refined or not self._accepted(best[0], arcs, res))):
            found = refine_by_retrieval(first, (W, H), m.features, self.backend, p.refine,
                                        self._retrieval_context(arcs, res))
            if found is not None:
                best = (found, first)
        return best

    def inliers_at(self, loc: "Localization", R: np.ndarray, t: np.ndarray, beyond: float = 0.0) -> tuple[int, float]:
        """:func:`ldlloc.refine.features.inliers_near` of ``loc``'s query features
        (:attr:`Localization.query_features`) at pose ``(R, t)`` of this map (the copies' check,
        :func:`ldlloc.confidence.copy_rival`); ``(0, inf)`` without features."""
        if self.backend is None or self.map.features is None or loc.query_features is None:
            return 0, float("inf")
        feats, size = loc.query_features
        return inliers_near(feats, size, R, t, self.map.features, self.backend, self.params.refine, beyond)

    def _accepted(self, ref, arcs: np.ndarray, res) -> bool:
        """Whether a candidate's PnP pose passes the retrieval's own acceptance (inliers, and a line loss
        near the search's best: :func:`ldlloc.refine.retrieval.accept_retrieved`); a weaker one (a few
        inliers in another room of the floor, a pose that explains few of the image's lines) gives way
        to a retrieved pose when there is one (docs/measurements.md#retrieval)."""
        loss = self._line_loss(arcs)
        R = np.stack([np.asarray(ref.rot_cam_from_world), res.rotations[0]])
        own, search = (float(v) for v in loss(R, np.stack([np.asarray(ref.center), res.centers[0]])))
        return accept_retrieved(ref.num_inliers, own, search, self.params.refine.retrieval)

    def _polish_geometric(self, out: "Localization", arcs: np.ndarray, translation_index: int) -> None:
        """``--refine both`` (and ``auto``'s fallback): refine the feature-refined (or coarse) pose from
        lines alone, kept as :meth:`_refine_and_keep` says."""
        g, kept, _ = self._refine_and_keep(arcs, out.rot_cam_from_world[None], out.center[None],
                                           np.array([translation_index]), 1)
        if kept[0]:
            out.rot_cam_from_world, out.center = g.rotations[0], g.centers[0]
            out.refine_residual_deg = float(g.residual_deg[0])
            out.refined = True
            out.refine_method = "features+geometric" if out.refine_method == "features" else "geometric"
            out.message += f"; geometric polish: median residual {out.refine_residual_deg:.2f} deg"
        else:
            out.message += "; geometric polish not kept"

    @property
    def feature_backend(self) -> str | None:
        return self.backend.name if self.backend is not None else None

    def detect_lines(self, image_rgb: np.ndarray) -> QueryLines:
        """Stage 1 of :meth:`localize` alone: the panorama's 2D lines, which do not depend on the map
        (share them between the maps a panorama is localized against: :meth:`search`'s ``lines``)."""
        return QueryLines.detect(_check_panorama_array(image_rgb), self.params)

    def search(self, image_rgb: np.ndarray, max_tilt_deg: float | None = None,
               lines: QueryLines | None = None, camera_up: np.ndarray | None = None, *,
               near: SearchNear | None = None) -> Searched:
        """Stages 1-3 of :meth:`localize` (2D lines, candidate rotations, pose search): the coarse
        :class:`Localization` and what refinement needs. ``lines``: the panorama's 2D lines from
        :meth:`detect_lines` (shared with other maps; their seconds are counted as ``lines2d``).
        ``camera_up``: the camera's own gravity (world up in the camera frame, from its XMP pose):
        the tilt bound is then around it (:func:`ldlloc.rotation.filter_by_tilt`). ``near``: search
        only near a predicted pose (:class:`SearchNear`); an InputError when no candidate lies there."""
        p, m = self.params, self.map
        img = _check_panorama_array(image_rgb)
        tilt = p.max_tilt_deg if max_tilt_deg is None else float(max_tilt_deg)
        check_max_tilt(tilt)
        if tilt is not None and tilt >= FREE_TILT_DEG:
            tilt = None
        lines = QueryLines.detect(img, p) if lines is None else lines
        secs: dict[str, float] = {"lines2d": lines.seconds}
        clock = StageClock(secs)
        rs = self.rotation_stage(lines, tilt, camera_up, near)
        arcs, rots, labels = rs.arcs, rs.rotations, rs.labels
        clock.lap("rotation")
        res = search_map(arcs, labels, rots.rotations, m, p.search, self.device, self.fields, rs.translation_index)
        clock.lap("search")
        best_r, best_t = res.rotations[0], res.centers[0]
        out = Localization(best_r, best_t, best_r, best_t, res.rotations, res.centers, secs,
                           num_rotations=len(rots), num_lines=len(arcs), refined=False, arcs=arcs,
                           arc_groups=labels[res.rotation_index[0]], rotations=rots.rotations,
                           candidates_loss=np.asarray(res.losses, dtype=np.float64),
                           rotation_prior=rotation_prior_name(tilt),
                           input_to_map=None if is_identity(m.input_to_map) else m.input_to_map)
        return Searched(out, res, arcs, labels)

    def rotation_stage(self, lines: QueryLines, tilt: float | None = None, camera_up: np.ndarray | None = None,
                       near: SearchNear | None = None) -> RotationStage:
        """Stage 2 of :meth:`localize`: the query's arcs for this map (the longest fraction, the map's
        kept ratio within ``Lines2DParams.keep_ratio_bounds``), its candidate rotations within the
        tilt bound ``tilt`` (degrees, None: free; around ``camera_up`` when given) and the arcs'
        principal groups under each; with ``near``, only the rotations and translations near it."""
        p, m = self.params, self.map
        keep = query_keep_ratio(m.kept_ratio, p.lines2d)  # the map's kept ratio within bounds
        arcs = filter_by_length(lines.arcs, keep)
        # Vanishing points from the longest lines first; more (shorter) lines only when those
        # do not give 3 directions that match the map's (within the tilt bound, if any).
        P = m.principal_directions
        makers = [lambda v: candidate_rotations(v, P, params=p.principal, seed=frame_rows(P))]
        if len(P) == 3:  # no triplet at any line ratio: perpendicular pairs (the vertical and one horizontal)
            makers.append(lambda v: pair_candidates(v, P, p.principal))
        found = 0
        for make in makers:
            for ratio in sorted({max(keep, p.vp_keep_ratio), 0.5, 1.0}):
                vps = lines.vanishing_points(ratio, p.principal)
                rots = make(vps)
                found = max(found, len(rots))
                if tilt is not None:
                    rots = filter_by_tilt(rots, tilt, camera_up)
                if len(rots):
                    break
            if found:
                break
        if len(rots) == 0 and found:
            raise InputError(f"no candidate rotation is within the tilt bound of {tilt:g} deg "
                             f"({found} found; raise --max-tilt, or 180 for free rotation)")
        if len(rots) == 0:
            raise InputError("no candidate rotation: the panorama's vanishing points do not match the map's")
        t_idx = None
        if near is not None:
            rots, t_idx = self._near(rots, near)
        labels = rotation_labels(arcs, vps, rots, P, p.principal.group_tol)
        return RotationStage(arcs, rots, labels, t_idx)

    def _near(self, rots, near: SearchNear):
        """The candidate rotations within ``near``'s cone and the indices of the map's candidate
        translations within its radius (one-line InputErrors when none is)."""
        T = np.asarray(self.map.translations, dtype=np.float64)
        t_idx = np.flatnonzero(np.linalg.norm(T - np.asarray(near.center, float), axis=1) <= near.radius_m)
        if len(t_idx) == 0:
            raise InputError(f"no candidate translation within {near.radius_m:g} m of the predicted pose")
        if near.rot_cam_from_world is not None:
            ang = np.array([rotation_error_deg(R, near.rot_cam_from_world) for R in rots.rotations])
            rots = rots.subset(ang <= near.cone_deg)
            if len(rots) == 0:
                raise InputError(f"no candidate rotation within {near.cone_deg:g} deg of the predicted pose")
        return rots, t_idx

    def localize(self, image_rgb: np.ndarray, max_tilt_deg: float | None = None, lines: QueryLines | None = None,
                 searched: Searched | None = None, camera_up: np.ndarray | None = None) -> Localization:
        """Localize an RGB panorama (H, W, 3) uint8; raises InputError when it cannot even search.

        ``max_tilt_deg``: the upright prior for this panorama, overriding
        ``params.max_tilt_deg`` (None: the params'; 180: free rotation). ``lines``: its 2D lines
        (:meth:`detect_lines`), ``searched``: its :meth:`search` on this map, when already done
        (several maps: ``ldlloc.batch.which_map``). ``seconds["total"]`` is the sum of the stages.
        """
        img = _check_panorama_array(image_rgb)
        if searched is None:
            searched = self.search(img, max_tilt_deg, lines, camera_up)
        out, res, arcs, labels = searched.out, searched.res, searched.arcs, searched.labels
        secs = out.seconds
        clock = StageClock(out.seconds)

        if self.refine_enabled:
            ref, feats = self._refine_features(img, arcs[out.arc_groups >= 0], res, arcs)
            out.num_query_features, out.query_features = len(feats), (feats, (img.shape[1], img.shape[0]))
            out.rot_cam_from_world, out.center = ref.rot_cam_from_world, ref.center
            out.coarse_rot, out.coarse_center = res.rotations[ref.candidate], res.centers[ref.candidate]
            out.arc_groups = labels[res.rotation_index[ref.candidate]]
            translation = res.translation_index[ref.candidate]
            out.retrieval = ref.retrieved
            if ref.retrieved:  # no candidate of the search is near the pose: its own arc groups and translation
                dirs = (ref.rot_cam_from_world @ self.map.principal_directions.T).T
                out.arc_groups = assign_arcs_to_principal(arcs, dirs, self.params.principal.group_tol)
                translation = int(self.map.nearest_translation(ref.center[None])[0])
            out.refined, out.num_matches, out.num_inliers, out.message = (
                ref.refined, ref.num_matches, ref.num_inliers, ref.message)
            out.refine_method = "features" if out.refined else "none"
            if out.refined and ref.rival_inliers:
                out.pnp_rival = {"R": ref.rival_rot, "t": ref.rival_center, "inliers": ref.rival_inliers,
                                 "candidate": ref.rival_candidate}
            if self.refine_mode == "both" or (self.fallback_geometric and not out.refined):
                self._polish_geometric(out, arcs, translation)
        elif self.refine_mode == "geometric":
            self._refine_geometric(out, arcs, res)
        else:
            out.message = "pose search only (no refinement)"
        clock.lap("refine")
        assess(out, self.map, support_deg=self.params.geometric.support_deg, inliers_at=self.inliers_at)
        clock.lap("confidence")
        secs["total"] = sum(v for k, v in secs.items() if k != "total")
        return out
