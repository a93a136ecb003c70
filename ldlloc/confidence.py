"""How far to trust a localization, from what it already knows (never the ground truth).

:func:`assess` turns a :class:`ldlloc.pipeline.Localization` into ``confidence`` in [0, 1], a
``verdict`` (``confident | ambiguous | failed``) and the ``competitors``: the search's poses
distinct from the final one (another position, a 180-degree twin, a 90-degree turn, another up
axis) whose loss comes close to it. The signals (:func:`confidence_signals`):

- ``gap``: the search loss of the best distinct candidate over that of the final pose's own
  start, ``(L_comp - L_own) / |L_own|`` (inlier losses are negative counts, lower is better),
  clipped to [-1, 1]; 1 when every candidate is the same pose. Negative when the final pose did
  not start from the search's best (the geometric refinement chose it on map-line support);
- ``support``: the map-line support of the final pose
  (:func:`ldlloc.refine.geometric.map_line_support`): the share of the map's lines, seen from
  there, that lie on an image line; the inlier loss counts the other way round;
- ``support_gap``: ``support`` minus the best distinct candidate's support (what tells a
  symmetric twin apart);
- ``margin``: the geometric refinement's selection score of the final pose (its loss over the
  best's plus its support) over the best refined pose distinct from it
  (``Localization.selection_margin``), clipped to [-1, 0.5]; 0.5 when none came within reach, 0
  where no such selection ran (feature refinement and its fallback);
- ``features``: 1 when the feature refinement (PnP) made the final pose; ``refined``: 1 when a
  refinement was kept (0: the coarse pose); ``inliers``: PnP inliers (recorded, not weighted);
- a pose of the retrieval fallback (``Localization.retrieval``: PnP on views far from every
  candidate) started from no candidate: its ``gap`` is the best distinct candidate's loss over
  its own exact loss, every candidate distinct from it counts (the search's best too), and
  ``features`` is its ``feature_share`` (:func:`ldlloc.refine.features.refine_by_retrieval`): 1
  only when its PnP is as strongly supported as the refinement's plausibility guard asks of a pose
  far from every candidate, less in proportion below (``retrieved``: 1, recorded);
- ``pnp_rival``: the inliers of the best PnP pose distinct from the final one over the final
  pose's (``Localization.pnp_rival``; 0: none), and ``map_rival`` the same for the feature poses
  of the other maps (:func:`assess_across`). A rival at :data:`RIVAL_SHARE` or more (an identical
  room's copy explains the features as well) takes the ``features`` signal away: the features
  then do not single one pose out (docs/measurements.md#pnp-rival).

Two checks need no fitting:

- ``physical`` (:func:`ldlloc.refine.geometric.physical_poses`): 0 when the final pose stands
  where no camera can (farther from every candidate translation than the map's spacing allows:
  under a floor, above the camera band, inside a wall). Its confidence is 0 and its verdict
  ``failed``; the geometric selection never picks such a pose when a physical one was refined;
- ``tie``: 1 when a refined pose distinct from the final one (``Localization.refined_rivals``:
  a 180-degree twin of a symmetric room, an identical room's copy) scores within
  :data:`TWIN_NOISE` of it, within its map or across the maps (:func:`assess_across`): the lines
  do not tell them apart, so the verdict is at most ``ambiguous``, with the rival named;
- ``copies``: how many copies of the pose's room (:mod:`ldlloc.refine.copies`: the lines the image
  confirms there, found again elsewhere in the pose's map or the other maps under a turn by a
  multiple of 90 degrees and a translation, with a pose there that explains the image about as
  well: :func:`ldlloc.refine.copies.find_copies`) :func:`add_copies` found: an identical room
  one image cannot tell apart by its lines. A confident verdict then becomes ``ambiguous`` (a
  doubtful pose stays ``failed`` where the rest says so), each copy named (``copy``: its map and
  position), unless the features single the pose out (:func:`features_decide`: strong PnP, no rival
  on any map; rooms whose lines repeat but whose textures differ).

``confidence = sigmoid(MODEL . signals)``, a logistic fitted on synthetic data and checked on the
real ZInD home (docs/measurements.md#confidence; ``bench/bench_confidence.py --fit`` refits it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ldlmap.core.geometry import angle_from_trace_deg
from ldlloc.refine.copies import find_copies
from ldlloc.refine.geometric import GeometricParams, map_line_support, physical_poses, selection_scores
from ldlloc.refine.retrieval import RetrievalParams, accept_retrieved

SAME_T_M = 0.5  # a candidate within 0.5 m and 20 deg of the final pose (or of its start) is that pose
SAME_R_DEG = 20.0  # (the search keeps its top K 0.35 m / 5 deg apart: nearby ones are one pose's neighbours)
COMPETITOR_GAP = 0.1  # a distinct candidate whose loss is within 10 % of the final pose's start competes
MAX_COMPETITORS = 3
UP_AXIS_DEG = 20.0  # a relative rotation whose axis is within this of the world's z is a turn about the up axis


@dataclass(frozen=True)
class ConfidenceModel:
    """``confidence = sigmoid(bias + sum(weights[k] * signals[k]))``; ``confident`` at or above
    ``confident_at``; else ``ambiguous`` when a competitor is named and the confidence is at least
    ``failed_below``; else ``failed``."""

    bias: float
    weights: dict[str, float]
    confident_at: float
    failed_below: float = 0.05  # below this, a pose is rarely right: not a candidate (docs/measurements.md#confidence)

    def confidence(self, signals: dict[str, float]) -> float:
        if float(signals.get("physical", 1.0)) < 0.5:  # no camera stands there: no fitting needed
            return 0.0
        signals = effective_signals(signals)
        z = self.bias + sum(w * float(signals.get(k, 0.0)) for k, w in self.weights.items())
        return float(1.0 / (1.0 + np.exp(-np.clip(z, -50, 50))))


# Fitted by `bench/bench_confidence.py --fit` on the synthetic sets only (256 poses; docs/measurements.md#confidence):
# a logistic with non-negative weights, L2-regularized on the standardized signals and folded back to raw
# weights. ``confident_at``: the smallest confidence above which >= 98 % of the synthetic poses are within
# 0.25 m / 5 deg (the confidence's target). The refit judged leave-one-kind-out (docs/measurements.md#confidence)
# is not adopted yet.
MODEL = ConfidenceModel(bias=-8.429, weights={"gap": 2.75, "support": 0.0, "support_gap": 0.0, "margin": 24.325,
                                              "features": 8.198, "refined": 5.613}, confident_at=0.602)
SIGNALS = ("gap", "support", "support_gap", "margin", "features", "refined")
NO_CONTENDER_MARGIN = 0.5  # ``margin`` when no distinct refined pose came within the selection's reach (its
# support_within, 0.25, plus a support gap); the signal is clipped to it


TWIN_NOISE = 0.05  # a distinct refined pose whose selection score is within this of the final pose's ties with it
# (docs/measurements.md#confidence: the lines do not tell a symmetric room's twin or a copy apart)


RIVAL_SHARE = 0.5  # a distinct PnP pose with half the final pose's inliers or more: the features do not single it out
# A feature pose is verified by the retrieval's acceptance rule (VERIFIED_INLIERS, VERIFIED_LINE_SHARE in
# ldlloc.refine.retrieval); across maps only verified poses compete with it (docs/measurements.md#verified-across-maps)
VERIFIED_RULE = RetrievalParams()  # its defaults are the rule

COPY_WHY = "copy of this room"  # how a competitor that is a copy of the pose's room begins its ``why`` (add_copies)


def effective_signals(signals: dict[str, float]) -> dict[str, float]:
    """The signals the model weighs: with several maps (``map_margin`` present, :func:`assess_across`)
    the selection margin is the smaller of the margin within the pose's map and across the maps; a
    PnP rival of :data:`RIVAL_SHARE` or more (``pnp_rival``, ``map_rival``), or another map's verified
    twin (``map_twin``, :func:`assess_across`), zeroes ``features``."""
    out = dict(signals)
    if "map_margin" in signals:
        out["margin"] = min(float(signals.get("margin", 0.0)), float(signals["map_margin"]))
    if features_rivalled(signals):
        out["features"] = 0.0
    return out


def features_rivalled(signals: dict[str, float]) -> bool:
    """Whether the features see the pose's place elsewhere too: a PnP rival of :data:`RIVAL_SHARE` or
    more (``pnp_rival``, ``map_rival``) or another map's verified twin (``map_twin``)."""
    return (max(float(signals.get("pnp_rival", 0.0)), float(signals.get("map_rival", 0.0))) >= RIVAL_SHARE
            or float(signals.get("map_twin", 0.0)) > 0)


def rotation_kind(R_final: np.ndarray, R_other: np.ndarray) -> str:
    """What turns one camera into the other: ``180-degree twin``, ``90-degree rotation``,
    ``N-degree rotation`` (about the world's up axis) or ``other up axis``."""
    M = np.asarray(R_final, float).T @ np.asarray(R_other, float)  # a rotation of the world frame
    angle = float(angle_from_trace_deg(np.trace(M)))
    if angle < SAME_R_DEG:
        return "same rotation"
    axis = np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    if np.linalg.norm(axis) < 1e-6:  # 180 degrees: the axis from the symmetric part
        w, v = np.linalg.eigh((M + M.T) / 2)
        axis = v[:, np.argmax(w)]
    axis = axis / max(np.linalg.norm(axis), 1e-12)
    if abs(axis[2]) < np.cos(np.radians(UP_AXIS_DEG)):
        return "other up axis"
    if angle > 135:
        return "180-degree twin"
    if 45 < angle <= 135:
        return "90-degree rotation"
    return f"{angle:.0f}-degree rotation"


def why(R_final, t_final, R_other, t_other) -> str:
    """A competitor's reason in words: ``other position`` (>= 0.5 m away, with its turn when it is
    turned too) or the rotation that separates it (:func:`rotation_kind`)."""
    d = float(np.linalg.norm(np.asarray(t_other, float) - np.asarray(t_final, float)))
    kind = rotation_kind(R_final, R_other)
    if d >= SAME_T_M:
        return f"other position ({d:.1f} m)" + ("" if kind == "same rotation" else f", {kind}")
    return kind


def distinct(R: np.ndarray, t: np.ndarray, Rs: np.ndarray, ts: np.ndarray) -> np.ndarray:
    """(K,) whether each pose (Rs, ts) is another pose than (R, t): SAME_T_M or more away, or
    turned SAME_R_DEG or more."""
    Rs, ts = np.asarray(Rs, float).reshape(-1, 3, 3), np.asarray(ts, float).reshape(-1, 3)
    d = np.linalg.norm(ts - np.asarray(t, float), axis=1)
    trace = np.einsum("kij,ij->k", Rs, np.asarray(R, float))  # trace(R^T Rk) = sum(R * Rk)
    return (d >= SAME_T_M) | (angle_from_trace_deg(trace) >= SAME_R_DEG)


def refined_rivals(k: int, rots: np.ndarray, centers: np.ndarray, loss: np.ndarray, score: np.ndarray,
                   limit: int = MAX_COMPETITORS) -> tuple[float, list[dict[str, Any]]]:
    """The geometric selection's margin and rivals: pose ``k`` won among refined poses (``rots``,
    ``centers``) on ``score`` (:func:`ldlloc.refine.geometric.selection_scores`; ``loss`` their exact
    losses). The margin is its score over the best distinct pose's (:data:`NO_CONTENDER_MARGIN`
    when none came within reach); the rivals are the best distinct poses within reach, one per
    place (poses refined to the same place count once), best first, at most ``limit``:
    ``{"R", "t", "loss", "score_gap"}``."""
    rots, centers, score = np.asarray(rots, float), np.asarray(centers, float), np.asarray(score, float)
    other = distinct(rots[k], centers[k], rots, centers) & np.isfinite(score)
    if not other.any():
        return NO_CONTENDER_MARGIN, []
    out: list[dict[str, Any]] = []
    for j in np.flatnonzero(other)[np.argsort(-score[other], kind="stable")]:
        if len(out) >= limit:
            break
        if out and not distinct(rots[j], centers[j], [r["R"] for r in out], [r["t"] for r in out]).all():
            continue
        out.append({"R": rots[j], "t": centers[j], "loss": float(loss[j]), "score_gap": float(score[k] - score[j])})
    return float(score[k] - score[other].max()), out


def own_candidate(loc) -> int:
    """Index of the top-K candidate that the final pose started from (its coarse pose)."""
    Rs, ts = np.asarray(loc.candidates_rot, float), np.asarray(loc.candidates_center, float)
    diff = (np.abs(Rs - np.asarray(loc.coarse_rot, float)).sum((1, 2))
            + np.abs(ts - np.asarray(loc.coarse_center, float)).sum(1))
    return int(np.argmin(diff))


def distinct_candidates(loc) -> np.ndarray:
    """Indices of the top-K candidates that are not the final pose (nor its start), best loss first."""
    Rs, ts = np.asarray(loc.candidates_rot, float), np.asarray(loc.candidates_center, float)
    if len(Rs) == 0:
        return np.zeros(0, dtype=int)
    other = distinct(loc.rot_cam_from_world, loc.center, Rs, ts)
    if not getattr(loc, "retrieval", None):  # a retrieved pose did not start from a candidate
        other &= distinct(loc.coarse_rot, loc.coarse_center, Rs, ts)
    idx = np.flatnonzero(other)
    if loc.candidates_loss is None:
        return idx
    return idx[np.argsort(np.asarray(loc.candidates_loss, float)[idx], kind="stable")]


def own_loss(loc) -> float:
    """The loss of the final pose's start: its candidate's search loss, or the retrieved pose's own
    exact loss (``Localization.retrieval``); NaN when unknown."""
    ret = getattr(loc, "retrieval", None)
    if ret:
        return float(ret["loss"])
    if loc.candidates_loss is None or len(loc.candidates_loss) == 0:
        return float("nan")
    return float(np.asarray(loc.candidates_loss, float)[own_candidate(loc)])


def relative_gap(loss_other: float, loss_own: float) -> float:
    """``(loss_other - loss_own) / |loss_own|`` clipped to [-1, 1] (1: the own loss is 0 and the other worse)."""
    scale = abs(loss_own)
    if scale < 1e-12:
        return 0.0 if loss_other <= loss_own else 1.0
    return float(np.clip((loss_other - loss_own) / scale, -1.0, 1.0))


def confidence_signals(loc, ldl_map, support_deg: float = 1.0) -> tuple[dict[str, float], np.ndarray]:
    """The signals of a localization (module docstring) and its distinct candidates (indices, best first)."""
    others = distinct_candidates(loc)
    losses = None if loc.candidates_loss is None else np.asarray(loc.candidates_loss, float)
    own = own_loss(loc)
    gap = 1.0
    if len(others) and losses is not None and np.isfinite(own):
        gap = relative_gap(float(losses[others[0]]), own)
    R = [np.asarray(loc.rot_cam_from_world, float)]
    t = [np.asarray(loc.center, float)]
    if len(others):
        R.append(np.asarray(loc.candidates_rot, float)[others[0]])
        t.append(np.asarray(loc.candidates_center, float)[others[0]])
    R, t = np.stack(R), np.stack(t)
    vis = None
    if getattr(ldl_map, "visibility", None) is not None:
        vis = ldl_map.visibility[ldl_map.nearest_translation(t)]
    arcs = loc.arcs if loc.arcs is not None else np.zeros((0, 2, 3))
    support = map_line_support(arcs, R, t, ldl_map.lines, ldl_map.line_groups, vis, support_deg)
    m = loc.selection_margin  # None: no selection among refined poses ran (feature refinement, its fallback)
    signals = {"gap": gap, "support": float(support[0]),
               "support_gap": float(support[0] - support[1]) if len(support) > 1 else float(support[0]),
               "margin": 0.0 if m is None else float(np.clip(m, -1.0, NO_CONTENDER_MARGIN)),
               "features": feature_signal(loc),
               "refined": float(bool(loc.refined)), "inliers": float(loc.num_inliers),
               "pnp_rival": rival_share(loc), "retrieved": float(bool(getattr(loc, "retrieval", None))),
               "physical": float(physical_poses(np.asarray(loc.center, float)[None], ldl_map)[0]),
               "tie": float(bool(tied_rivals(loc)) or (m is not None and m <= TWIN_NOISE))}  # m: the best distinct
    # refined pose's score gap (Localizer._refine_geometric), the tie's rule whether or not its rivals were kept
    signals = {k: v if np.isfinite(v) else 0.0 for k, v in signals.items()}  # a NaN loss says nothing
    return signals, others


def feature_signal(loc) -> float:
    """``features``: 1 for a PnP pose, a retrieved one's ``feature_share`` (module docstring), else 0."""
    if not str(loc.refine_method).startswith("features"):
        return 0.0
    ret = getattr(loc, "retrieval", None)
    return float(ret["feature_share"]) if ret else 1.0


def rival_share(loc) -> float:
    """The inliers of the feature refinement's best distinct PnP pose over the final pose's (0: none)."""
    rival = getattr(loc, "pnp_rival", None)
    if not rival or not str(loc.refine_method).startswith("features") or loc.num_inliers <= 0:
        return 0.0
    return float(rival["inliers"]) / float(loc.num_inliers)


def rival_dict(loc) -> dict[str, Any] | None:
    """The PnP rival (:func:`rival_share` at :data:`RIVAL_SHARE` or more) as a competitor, else None."""
    if rival_share(loc) < RIVAL_SHARE:
        return None
    rival = loc.pnp_rival
    R, t = np.asarray(rival["R"], float), np.asarray(rival["t"], float)
    k, losses = int(rival.get("candidate", -1)), loc.candidates_loss
    loss = float(losses[k]) if losses is not None and 0 <= k < len(losses) else None  # its view's search loss
    return {"R": np.round(R, 8).tolist(), "t": np.round(t, 6).tolist(),
            "loss": loss if loss is not None and np.isfinite(loss) else None,
            "why": f"{why(loc.rot_cam_from_world, loc.center, R, t)}, PnP {int(rival['inliers'])} inliers "
                   f"against {int(loc.num_inliers)}", "inliers": int(rival["inliers"])}


def tied_rivals(loc) -> list[dict[str, Any]]:
    """The refined rivals (``Localization.refined_rivals``) within :data:`TWIN_NOISE` of the final
    pose's selection score as competitors, ``why`` naming the twin or the other place."""
    return [{"R": np.round(np.asarray(r["R"], float), 8).tolist(), "t": np.round(np.asarray(r["t"], float), 6).tolist(),
             "loss": float(r["loss"]),
             "why": f"{why(loc.rot_cam_from_world, loc.center, r['R'], r['t'])}, refined, score within "
                    f"{r['score_gap']:.3f}"}
            for r in (getattr(loc, "refined_rivals", None) or []) if r["score_gap"] <= TWIN_NOISE]


def competitor_dicts(loc, others: np.ndarray, max_gap: float = COMPETITOR_GAP,
                     limit: int = MAX_COMPETITORS) -> list[dict[str, Any]]:
    """The distinct candidates whose loss is within ``max_gap`` of the final pose's start, best
    first: ``{"R", "t", "loss", "why"}``."""
    if loc.candidates_loss is None or len(others) == 0:
        return []
    losses = np.asarray(loc.candidates_loss, float)
    own = own_loss(loc)
    out = []
    for i in others[:limit]:
        if relative_gap(float(losses[i]), own) > max_gap:
            break
        R, t = np.asarray(loc.candidates_rot, float)[i], np.asarray(loc.candidates_center, float)[i]
        out.append({"R": np.round(R, 8).tolist(), "t": np.round(t, 6).tolist(), "loss": float(losses[i]),
                    "why": why(loc.rot_cam_from_world, loc.center, R, t)})
    return out


def verdict_for(confidence: float | None, competitors: list, model: ConfidenceModel = MODEL,
                rival: bool = False, tie: bool = False) -> str:
    """``confident`` at or above the model's threshold unless a refined rival ties with the pose
    (``tie``); else ``ambiguous`` when competitors are named and the pose is still plausible
    (``failed_below``), or when a PnP ``rival`` explains the features as well or a refined one ties
    (the pose is right up to which copy or twin); else ``failed`` (no pose, a pose the model gives
    little chance, or a doubtful one with nothing to offer beside it)."""
    if confidence is None:
        return "failed"
    if confidence >= model.confident_at and not tie:
        return "confident"
    return "ambiguous" if competitors and (confidence >= model.failed_below or rival or tie) else "failed"


def judge(signals: dict[str, float], competitors: list, model: ConfidenceModel = MODEL) -> tuple[float, str]:
    """``(confidence, verdict)`` of a pose from its signals and named competitors: the model's
    confidence, 0 and ``failed`` where no camera stands (``physical`` 0), a PnP rival or another
    map's verified twin, and a tie, as :func:`verdict_for` weighs them; a copy of the pose's room
    (``copies``) makes a confident pose ``ambiguous`` (a doubtful one stays as the rest judges it) unless
    the features decide (:func:`features_decide`)."""
    conf = model.confidence(signals)
    if float(signals.get("physical", 1.0)) < 0.5:
        return 0.0, "failed"
    verdict = verdict_for(conf, competitors, model, rival=features_rivalled(signals),
                          tie=float(signals.get("tie", 0.0)) > 0)
    if verdict == "confident" and float(signals.get("copies", 0.0)) > 0 and not features_decide(signals):
        verdict = "ambiguous"  # the lines repeat there and nothing else tells: right up to which copy at best
    return conf, verdict


def features_decide(signals: dict[str, float]) -> bool:
    """Whether the features single the pose out where its lines repeat (a copy of its room by the
    lines alone): a PnP pose as strongly supported as the refinement's plausibility guard asks
    (``features`` 1) with no PnP rival of :data:`RIVAL_SHARE` on any map nor another map's verified
    twin (:func:`effective_signals` keeps ``features``), nor at its copies on the same footing
    (``copy_rival``, :func:`copy_rival`). A copy that looks the same (an identical room's textures)
    gives such a rival, so the features then decide nothing."""
    return (float(effective_signals(signals).get("features", 0.0)) >= 1.0
            and float(signals.get("copy_rival", 0.0)) < RIVAL_SHARE)


def assess(loc, ldl_map, support_deg: float = 1.0, model: ConfidenceModel = MODEL,
           inliers_at: Callable | None = None) -> None:
    """Set ``confidence``, ``verdict``, ``competitors`` and ``confidence_signals`` on ``loc``;
    ``inliers_at(loc, R, t, beyond)``: PnP of its features at a pose of ``ldl_map``
    (:meth:`ldlloc.pipeline.Localizer.inliers_at`), for the copies of its room (:func:`add_copies`)."""
    signals, others = confidence_signals(loc, ldl_map, support_deg)
    loc.confidence_signals = {k: round(v, 6) for k, v in signals.items()}
    rival = rival_dict(loc)
    named = ([rival] if rival else []) + tied_rivals(loc)
    named = named[:MAX_COMPETITORS]
    loc.competitors = named + [c for c in competitor_dicts(loc, others, limit=MAX_COMPETITORS - len(named))
                               if not named or distinct(c["R"], c["t"], [n["R"] for n in named],
                                                        [n["t"] for n in named]).all()]
    conf, loc.verdict = judge(loc.confidence_signals, loc.competitors, model)
    loc.confidence = round(conf, 6)
    add_copies(loc, ldl_map, [(None, ldl_map)], support_deg, model,
               None if inliers_at is None else lambda name, R, t, beyond=0.0: inliers_at(loc, R, t, beyond))


def add_copies(loc, own_map, maps: list, support_deg: float = 1.0, model: ConfidenceModel = MODEL,
               inliers_at: Callable | None = None) -> None:
    """Look for copies of the room ``loc``'s pose stands in (:func:`ldlloc.refine.copies.find_copies`)
    on ``maps`` (``(name, map)``; name None: the pose's own map ``own_map``); each found is named as a
    competitor (``copy``: ``{"map", "t"}``; ``map`` too when it is another map), ``copies`` counts all
    found so far, and the verdict is judged again (:func:`judge`: at most ``ambiguous``). Where the
    features would single the pose out (:func:`features_decide`), ``inliers_at(name, R, t, beyond)``
    (PnP of its features at a pose of map ``name``, None: its own) gives ``copy_rival``
    (:func:`copy_rival`). A pose that is not refined, or stands where no camera can, is not looked at."""
    sig = loc.confidence_signals
    if not loc.refined or loc.arcs is None or float(sig.get("physical", 1.0)) < 0.5:
        return
    found = find_copies(loc.arcs, loc.rot_cam_from_world, loc.center, own_map, maps,
                        float(sig.get("support", 0.0)), support_deg)
    if not found:
        return
    named = []
    for f in found:
        where = f["map"] if f["map"] is not None else getattr(own_map, "name", None) or "this map"
        d = float(np.linalg.norm(f["t"] - np.asarray(loc.center, float)))
        c = {"R": np.round(f["R"], 8).tolist(), "t": np.round(f["t"], 6).tolist(), "loss": None,
             "why": f"{COPY_WHY} on {where}, {d:.1f} m away" + (f", turned {f['turn_deg']} deg" if f["turn_deg"]
                                                                      else "")
             + f", map-line support {f['support']:.3f} against {float(sig.get('support', 0.0)):.3f}",
             "copy": {"map": where, "t": np.round(f["t"], 3).tolist()}}
        if f["map"] is not None:
            c["map"] = f["map"]
        named.append(c)
    keep = [c for c in loc.competitors if "copy" in c or distinct(c["R"], c["t"], [n["R"] for n in named],
                                                                   [n["t"] for n in named]).all()]
    loc.competitors = (named + keep)[:max(MAX_COMPETITORS, len(named))]
    loc.confidence_signals = {**sig, "copies": float(sig.get("copies", 0.0)) + len(found),
                              **copy_rival(loc, found, inliers_at)}
    conf, loc.verdict = judge(loc.confidence_signals, loc.competitors, model)
    loc.confidence = round(conf, 6)


def copy_rival(loc, found: list[dict], inliers_at: Callable | None) -> dict[str, float]:
    """``{"copy_rival": share}`` where the features would single ``loc`` out among its room's copies
    ``found`` (:func:`features_decide`): for each copy, PnP at its pose with its map's views nearest it
    (``inliers_at(map, R, t)``: inliers, the nearest view's distance) over PnP at ``loc``'s own pose with
    its own map's views no nearer than that (``inliers_at(None, R, t, beyond)``): the features compared
    on the same footing, not on where each map happened to render a view. 1 where the own pose finds
    no inliers so (the features cannot tell); copies tried until one reaches :data:`RIVAL_SHARE`. Empty
    otherwise."""
    sig = loc.confidence_signals
    if inliers_at is None or not loc.num_inliers or not features_decide(sig):
        return {}
    R0, t0 = np.asarray(loc.rot_cam_from_world, float), np.asarray(loc.center, float)
    best = float(sig.get("copy_rival", 0.0))
    for f in found:
        if best >= RIVAL_SHARE:
            break
        n, near = inliers_at(f["map"], f["R"], f["t"])
        own = inliers_at(None, R0, t0, near)[0] if np.isfinite(near) else 0
        best = max(best, n / own if own else 1.0)
    return {"copy_rival": round(best, 6)}


def verified(loc, loss: float) -> bool:
    """Whether ``loc`` is a PnP pose the features and the lines both back: ``VERIFIED_INLIERS`` inliers
    or more and an exact line loss ``loss`` of at least ``VERIFIED_LINE_SHARE`` of its map's search
    best (losses are negative inlier counts; the retrieval's acceptance rule,
    :func:`ldlloc.refine.retrieval.accept_retrieved` with its defaults)."""
    if not str(loc.refine_method).startswith("features"):
        return False
    ret = getattr(loc, "retrieval", None)
    best = float(ret["search_loss"]) if ret else (
        float(np.min(loc.candidates_loss)) if loc.candidates_loss is not None and len(loc.candidates_loss) else np.nan)
    return bool(np.isfinite(best) and accept_retrieved(loc.num_inliers, loss, best, VERIFIED_RULE))


def assess_across(locs: list, losses: list[float], names: list[str], params=None, model: ConfidenceModel = MODEL) -> None:
    """Judge one panorama's refined localizations on several maps together (``ldlloc run --images
    --maps DIR``), after :func:`assess` judged each within its map: the maps' final poses compete
    as the refined poses of one map do (:func:`ldlloc.refine.geometric.selection_scores` on their
    exact losses, ``losses``, and map-line supports; the maps' losses compare: same query lines).
    Each gets ``map_margin``: its score over the best pose of another map that is distinct from it
    (poses that agree, maps sharing a frame, confirm each other), -1 when its loss is out of the
    selection's reach, :data:`NO_CONTENDER_MARGIN` when no other map competes. The confidence then
    uses the smaller margin (:func:`effective_signals`), and the other maps' poses whose loss is
    within :data:`COMPETITOR_GAP` are named as competitors (``map``: the map's name). A feature pose
    also gets ``map_rival``: the PnP inliers of the other maps' distinct feature poses over its own
    (their best; an identical room on another floor), whose maps are named when it reaches
    :data:`RIVAL_SHARE`. A :func:`verified` feature pose competes only with the other maps' verified
    poses, and a pose that is not verified cannot win against a distinct verified one (its
    ``map_margin`` is -1, the verified pose its competitor): as within a map, where the geometric
    refinement runs only where the features fail, lines alone do not outvote PnP. A verified pose
    with a distinct verified pose on another map whose loss is within :data:`COMPETITOR_GAP`
    (``map_twin`` 1: an identical room's copy, whatever their inliers) loses its ``features``
    signal and is named with it. Calling it
    again on a subset of the maps recomputes all of this from the in-map assessment."""
    params = params or GeometricParams()
    support = np.array([float(loc.confidence_signals.get("support", 0.0)) for loc in locs])
    losses = np.asarray(losses, dtype=np.float64)
    physical = np.array([float(loc.confidence_signals.get("physical", 1.0)) >= 0.5 for loc in locs])
    score = selection_scores(losses, params, lambda idx: support[idx], physical)
    sure = np.array([verified(loc, loss) for loc, loss in zip(locs, losses)])
    score_sure = np.full(len(locs), -np.inf)  # the verified poses' scores among themselves
    if sure.any():
        score_sure[sure] = selection_scores(losses[sure], params, lambda idx: support[np.flatnonzero(sure)[idx]])
    R = np.stack([np.asarray(loc.rot_cam_from_world, float) for loc in locs])
    t = np.stack([np.asarray(loc.center, float) for loc in locs])
    # PnP inliers of the maps' feature poses (0: not a feature pose): a copy in another map rivals them
    inliers = np.array([float(loc.num_inliers) if str(loc.refine_method).startswith("features") else 0.0
                        for loc in locs])
    for i, loc in enumerate(locs):
        other = distinct(R[i], t[i], R, t)
        other[i] = False
        pool, sc = (sure, score_sure) if sure[i] else (np.ones(len(locs), bool), score)
        reach = other & pool & np.isfinite(sc)
        if not np.isfinite(sc[i]) or (not sure[i] and (other & sure).any()):  # out of reach, or PnP outvotes it
            margin = -1.0
        elif reach.any():
            margin = float(np.clip(sc[i] - sc[reach].max(), -1.0, NO_CONTENDER_MARGIN))
        else:
            margin = NO_CONTENDER_MARGIN
        share = inliers / inliers[i] if inliers[i] > 0 else np.zeros(len(locs))
        map_rival = float(share[other].max()) if other.any() else 0.0
        # a verified pose of another map, elsewhere, that explains the lines as well: an identical room's copy
        twin = sure[i] and bool(np.any([relative_gap(float(losses[j]), float(losses[i])) <= COMPETITOR_GAP
                                        for j in np.flatnonzero(other & sure)]))
        # a line pose (the geometric selection ran) whose copy on another map scores within the noise ties with it
        tied = (reach & (np.abs(sc[i] - sc) <= TWIN_NOISE)) if loc.selection_margin is not None and np.isfinite(sc[i]) \
            else np.zeros(len(locs), bool)
        loc.confidence_signals = {**loc.confidence_signals, "map_margin": round(margin, 6),
                                  "map_rival": round(map_rival, 6), "map_twin": float(twin),
                                  "tie": float(bool(tied_rivals(loc)) or tied.any())}
        own = [c for c in loc.competitors if "map" not in c]
        across = [j for j in np.flatnonzero(other)[np.argsort(losses[other], kind="stable")]
                  if (pool[j] and relative_gap(float(losses[j]), float(losses[i])) <= COMPETITOR_GAP)
                  or share[j] >= RIVAL_SHARE or (sure[j] and not sure[i]) or tied[j]][:MAX_COMPETITORS]
        loc.competitors = own + [{"R": np.round(R[j], 8).tolist(), "t": np.round(t[j], 6).tolist(),
                                  "loss": float(losses[j]), "why": f"map {names[j]}" + (
                                      f", {why(R[i], t[i], R[j], t[j])} scoring within {abs(sc[i] - sc[j]):.3f}"
                                      if tied[j] else ""), "map": names[j]} for j in across]
        conf, loc.verdict = judge(loc.confidence_signals, loc.competitors, model)
        loc.confidence = round(conf, 6)


WALK_MARGIN = 3.0  # nats: a walk singles a frame's pose out when every path through a distinct pose of that frame
# costs this much more than the chosen path (ldlloc.walk.viterbi.margin); its confidence is then the model's threshold


def walk_confidence(margin: float, model: ConfidenceModel = MODEL) -> float:
    """The walk's confidence in a frame's pose from its path margin (nats): ``model.confident_at`` at
    :data:`WALK_MARGIN`, a logistic in the margin around it (1 for a frame no other pose competes with)."""
    if not np.isfinite(margin):
        return 1.0
    ca = model.confident_at
    z = float(margin) - WALK_MARGIN + np.log(ca / (1.0 - ca))
    return float(1.0 / (1.0 + np.exp(-np.clip(z, -50, 50))))


def sound_where_moved(loc, model: ConfidenceModel = MODEL) -> bool:
    """Whether a frame's image, searched and refined again at the pose a walk moved it to (``loc``), judges
    that pose as sure as a confident one, whatever copies of its room it names (the walk chooses among
    those): its confidence reaches the model's threshold. The walk's motion places a frame within a step
    or two; only its image places it within a tenth of a metre."""
    return loc is not None and loc.confidence is not None and float(loc.confidence) >= model.confident_at


def no_surer_than(confidence: float, verdict: str, sure: float | None, sure_verdict: str | None = None,
                  model: ConfidenceModel = MODEL) -> tuple[float, str]:
    """A tracked frame's ``(confidence, verdict)`` no surer than ``sure``, the image's own confidence at the
    global frame its track started from (None: not known, unchanged), and not ``confident`` where that
    image's verdict ``sure_verdict`` was not (copies of its room: the track follows one). Tracking follows
    one place from there, and a chain of tracked frames makes a walk's path margin large whatever place it
    follows: only a global search compares places (a video through a building's identical floors: 127 of 194 confident
    poses wrong before, docs/benchmarks.md#a-video-through-the-building-2026-11-27)."""
    if verdict == "confident" and sure_verdict not in (None, "confident"):
        confidence, verdict = (confidence if sure is None else min(confidence, round(float(sure), 6))), "ambiguous"
    if sure is None or confidence <= sure:
        return confidence, verdict
    capped = round(float(sure), 6)
    if verdict == "confident" and capped < model.confident_at:
        return capped, "ambiguous"
    return capped, verdict


def walk_judgement(single_confidence: float | None, single_verdict: str | None, margin: float, changed: bool,
                   pose_ok: bool, model: ConfidenceModel = MODEL) -> tuple[float, str, bool]:
    """A walk frame's ``(confidence, verdict, walk_decided)`` from its single-image judgement and the
    walk's (one rule for every walk): a frame whose image was confident and whose pose the walk kept
    stays as it is. Otherwise the walk decides (``walk_decided``) when it moved the pose
    (``changed``) or when it singles the image's pose out (its ``margin``): ``confident`` when the
    walk's confidence (:func:`walk_confidence`) reaches the threshold and the pose was refined
    (``pose_ok``; a moved pose also :func:`sound_where_moved`), else ``ambiguous`` when there is a
    pose, else ``failed``. A frame the walk leaves undecided keeps its image's judgement."""
    single = 0.0 if single_confidence is None else float(single_confidence)
    if not changed and single_verdict == "confident":
        return single, "confident", False
    walk = walk_confidence(margin, model)
    if not changed and (walk < model.confident_at or not pose_ok):
        return single, single_verdict or "failed", False
    if walk >= model.confident_at and pose_ok:
        return round(max(walk, single) if not changed else walk, 6), "confident", True
    return round(walk, 6), "ambiguous", True  # the walk moved the pose but does not single it out
