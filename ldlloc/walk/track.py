"""Tracking a dense walk (a video): each frame localized near where the walk predicts it.

Three steps, cheapest first, each checked before the frame takes its pose:

1. **Lines from the prediction** (:func:`track_by_lines`): the pose predicted from the last two
   frames (constant velocity, :func:`predict`) is refined from the frame's lines alone
   (:func:`ldlloc.refine.geometric.refine_and_keep`, a short refinement: few rounds from a small
   association angle, wider after lost frames; from the prediction, the last pose and a ring of starts
   around the prediction, the start whose refinement fits the frame's line points best kept
   (:func:`best_fit`), then refined once more from where it ended), the lines extracted at a reduced width
   (``TrackParams.width``), the camera's height held near the last trusted pose's (:func:`height_band`). No
   vanishing points, no candidate rotations, no search, no features.
2. **A restricted search** (:func:`track_by_search`): the map's candidate translations within
   ``radius_m`` per frame since the last trusted pose of the prediction and its candidate rotations
   within ``cone_deg`` (the distance fields subset, not the full search filtered), refined as
   ``TrackParams.refine`` says.
3. Neither holds: the frame is **lost** (:func:`lost_frame`: the predicted pose, unrefined,
   ``failed``; no search) while fewer than ``max_lost`` frames in a row were, and always when it has
   fewer than ``min_lines`` lines (a blurred frame, on which every search fails at seconds each);
   tracking resumes from the last trusted pose, the restricted search's radius growing with the
   frames lost. After ``max_lost`` lost frames in a row the caller localizes the frame globally.

Then a check (:func:`check_due`, :func:`overruled`): the first frame tracked again after
``check_after_lost`` lost frames, and every ``check_every``-th frame of a track that is not ``confident``,
is also localized globally; where that pose is another that explains more of its lines (``check_gain`` times
more where its image is not confident), it is a global frame (the walk goes on from the copy of its room
it reaches: :func:`ldlloc.walk.localize.reached`).

A tracked pose holds when it was refined and explains at least ``TrackParams.keep`` of the lines
that the last trusted global frame's pose explained (its exact line loss; the losses of lines
found at different widths compare: docs/measurements.md#walks).

The prediction needs the walk's last trusted pose and velocity only: each frame carries them
(:class:`TrackBasis`, :func:`next_basis`) for the next, so a walk decided as a stream
(:mod:`ldlloc.walk.stream`) tracks from the frame before alone.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ldlmap.core.errors import InputError, LdlError
from ldlmap.core.frame import is_identity
from ldlmap.core.lazy import lazy_module
from ldlloc.batch.which_map import (MapChoice, MapEntry, MapOption, MapSet, final_pose_loss, localize_on_maps,
                                    poses_loss)
from ldlloc.confidence import NO_CONTENDER_MARGIN, assess, distinct, no_surer_than
from ldlloc.lines2d import filter_by_length, query_keep_ratio
from ldlloc.pipeline import Localization, Localizer, QueryLines, SearchNear, rotation_prior_name
from ldlloc.refine.geometric import GeometricResult, refine_and_keep

cv2 = lazy_module("cv2")
torch = lazy_module("torch")

TRACK_REFINES = ("light", "same", "geometric")


@dataclass(frozen=True)
class TrackParams:
    """How the frames of a dense walk are tracked (module docstring)."""

    lines: bool = True  # first refine the predicted pose from lines alone (step 1)
    width: int = 512  # step 1 extracts the lines at this width (a wider frame is resized; 0: as it is)
    rounds: int = 4  # step 1's association rounds ...
    assoc_deg: float = 6.0  # ... from this association angle, the rotation free from the first (the prediction is
    # a few degrees and centimetres off) ...
    ring: int = 4  # ... from the prediction, the last pose and this many starts around the prediction ...
    ring_m: float = 0.15  # ... this far from it (xy): a prediction a step off can fall into a minimum 0.1-0.2 m wide
    polish: bool = True  # ... and the best refined again from where it ended, kept where it then fits better
    climb_m: float = 0.15  # ... the camera rising or sinking at most this per frame since the last trusted pose (a
    # stair's rise a step; a walker's camera keeps its height: lines of another room drew it down 1 m in 4 frames;
    # 0: not held)
    radius_m: float = 0.75  # step 2: candidate translations within this of the prediction ...
    cone_deg: float = 15.0  # ... and candidate rotations within this of its rotation
    refine: str = "light"  # how step 2's pose is refined: light (features in one query frame, PnP on 2 views, no
    # retrieval fallback: the tracked pose is near) | same (as the global localization) | geometric (lines alone)
    keep: float = 0.7  # a tracked pose explaining fewer lines than this share of the last global frame's is lost
    max_step_m: float = 0.75  # a step (per frame) longer than this is not extrapolated (the last pose is the prediction)
    lookback: int = 10  # frames back to the last trusted pose (a frame that failed or was lost is not tracked from)
    min_lines: int = 20  # a frame with fewer lines (step 1's, after the length filter) is lost at once: no search
    max_lost: int = 6  # frames lost in a row (each tracked at a growing radius) before a global search
    check_after_lost: int = 2  # a frame tracked again after this many lost frames or more is also localized globally
    # (:func:`check_due`, :func:`overruled`: a track resumed after a fast turn can lock onto a room's 180-degree twin,
    # as sure as its start; 0: never) ...
    check_every: int = 25  # ... and every this many-th frame of a track that is not confident (lost ones count;
    # 0: never) ...
    check_gain: float = 1.2  # ... taking the global pose where its lines explain more than the tracked pose's,
    # this many times more where its image is not confident (a building's track turned 90 degrees explained
    # 0.6-0.8 of the truth's lines for 100 frames: docs/benchmarks.md)


class TorchThreads:
    """torch's CPU threads for a walk: one (a pose and a hundred lines: more threads only wait on each
    other, 3-10 times slower on a busy 2-core machine: docs/measurements.md#walks), switched once
    (:meth:`one`; switching costs about 10 ms) and given back by :meth:`release`. ``pinned``: held for
    the whole walk (a stream: one switch per walk, searches included); else :meth:`restore` gives the
    caller's count back before a search or a global localization (one frame's work)."""

    def __init__(self, pinned: bool = False) -> None:
        self.caller: int | None = None  # the caller's count while switched to one
        self.pinned = pinned

    def one(self) -> None:
        if self.caller is None:
            self.caller = torch.get_num_threads()
            if self.caller != 1:
                torch.set_num_threads(1)

    def restore(self) -> None:
        if not self.pinned:
            self.release()

    def release(self) -> None:
        if self.caller is not None:
            if self.caller != 1:
                torch.set_num_threads(self.caller)
            self.caller = None


def check_track_params(p: TrackParams) -> None:
    """One-line InputError for an unknown refinement of the restricted search."""
    if p.refine not in TRACK_REFINES:
        raise InputError(f"unknown track refine {p.refine!r}; valid: {', '.join(TRACK_REFINES)}")


@dataclass(frozen=True)
class Prediction:
    """Where the walk expects its next frame: a pose on one map, from ``frames`` frames after the last trusted one."""

    entry: MapEntry
    rot_cam_from_world: np.ndarray
    center: np.ndarray
    frames: int  # 1: the last frame was trusted
    last: tuple[np.ndarray, np.ndarray]  # the last trusted pose (R, t)
    age: int = 0  # unsure frames since the last global frame or check, before this one
    sure: float | None = None  # the image's own confidence and verdict at the global frame the track started from
    sure_verdict: str | None = None  # (TrackBasis.sure, sure_verdict)


@dataclass(frozen=True)
class TrackBasis:
    """What a frame hands on to the next one's prediction: the walk's last trusted pose (on ``entry``'s
    map), its velocity per frame (``step`` metres, ``turn`` a rotation; None: not known) and the
    frames since that pose (0: this frame's own)."""

    entry: MapEntry
    rot_cam_from_world: np.ndarray
    center: np.ndarray
    step: np.ndarray | None = None
    turn: np.ndarray | None = None
    since: int = 0
    sure: float | None = None  # the image's own confidence at the last frame localized globally (None: not known) ...
    sure_verdict: str | None = None  # ... and its verdict
    age: int = 0  # unsure frames since the last global frame or check, this one included (:func:`check_due`)


def trusted(o) -> bool:
    """Whether a frame's pose may be tracked from: tracked, or localized globally and not ``failed``
    (a frame read back from a results file to resume a walk: its pose and map only)."""
    return (getattr(o, "loc", None) is not None and getattr(o, "entry", None) is not None
            and (getattr(o, "tracked", False) or getattr(o, "single_verdict", None) != "failed"))


def basis_of(prev) -> TrackBasis | None:
    """The basis frame ``prev`` hands on: its own (:func:`next_basis`), else its pose as it is (a frame
    read back from a results file to resume a walk), else None."""
    b = getattr(prev, "track_basis", None)
    if b is not None or not trusted(prev):
        return b
    return TrackBasis(prev.entry, np.asarray(prev.loc.rot_cam_from_world, float), np.asarray(prev.loc.center, float))


def next_basis(prev, out, p: TrackParams) -> TrackBasis | None:
    """The basis frame ``out`` hands on (``prev``: the frame before it): a trusted frame's own pose with
    the velocity since the last trusted pose (on the same map, at most ``max_step_m`` a frame; its turn
    when that pose was the frame before); else the last basis one frame older (None beyond ``lookback``).
    ``sure``, ``sure_verdict``: a global frame's own confidence and verdict, carried along the frames tracked from it."""
    b = basis_of(prev) if prev is not None else None
    if not trusted(out):
        return aged(b, p)
    R, t = np.asarray(out.loc.rot_cam_from_world, float), np.asarray(out.loc.center, float)
    tracked = getattr(out, "tracked", False)
    if tracked:
        sure, said = (None, None) if b is None else (b.sure, b.sure_verdict)
    else:
        sure, said = getattr(out, "single_confidence", None), getattr(out, "single_verdict", None)
    age = b.age + unsure(out.loc, b.sure, b.sure_verdict) if tracked and b is not None and \
        not getattr(out, "checked", False) else 0
    if b is None or b.entry is not out.entry:
        return TrackBasis(out.entry, R, t, sure=sure, sure_verdict=said, age=age)
    k = b.since + 1
    step = (t - b.center) / k
    if np.linalg.norm(step) > p.max_step_m:
        return TrackBasis(out.entry, R, t, sure=sure, sure_verdict=said, age=age)
    return TrackBasis(out.entry, R, t, step, R @ b.rot_cam_from_world.T if k == 1 else None, sure=sure,
                      sure_verdict=said, age=age)


def aged(b: TrackBasis | None, p: TrackParams) -> TrackBasis | None:
    """Basis ``b`` handed on by a frame that is not tracked from (lost, failed): one frame older (and one unsure
    frame more), None beyond ``p.lookback``."""
    return None if b is None or b.since + 1 >= p.lookback else replace(b, since=b.since + 1, age=b.age + 1)


def predict(prev, p: TrackParams) -> Prediction | None:
    """The pose of the frame after ``prev`` (the walk's last frame): its basis (:func:`next_basis`) moved on
    (:func:`predicted_from`); None without a basis (no trusted frame in the last ``lookback``)."""
    b = basis_of(prev)
    return None if b is None else predicted_from(b)


def predicted_from(b: TrackBasis) -> Prediction:
    """The pose of the frame after basis ``b``'s frames: its pose moved on at the walk's velocity for every
    frame since (constant velocity: a video's kept frames are evenly spaced; the turn too when known);
    without a velocity the basis pose itself."""
    k = b.since + 1
    R, t = b.rot_cam_from_world, b.center
    if b.step is None:
        return Prediction(b.entry, R, t, k, (R, t), b.age, b.sure, b.sure_verdict)
    Rp = R
    if b.turn is not None:  # the same turn again, kept a rotation
        U, _, Vt = np.linalg.svd(np.linalg.matrix_power(b.turn, k) @ R)
        Rp = U @ Vt
    return Prediction(b.entry, Rp, t + k * b.step, k, (R, t), b.age, b.sure, b.sure_verdict)


def starts(pred: Prediction, p: TrackParams) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The poses step 1 refines, (S, 3, 3) and (S, 3), and what each is: the prediction, the last
    trusted pose when it is another (a velocity that a wrong pose skewed must not carry the walk
    away), and ``p.ring`` poses ``p.ring_m`` around the prediction at its rotation."""
    Rp, tp = pred.rot_cam_from_world, pred.center
    rots, centers, names = [Rp], [tp], ["predicted pose"]
    R, t = pred.last
    if not (np.allclose(R, Rp) and np.allclose(t, tp)):
        rots, centers, names = rots + [R], centers + [t], names + ["last pose"]
    a = 2 * np.pi * np.arange(p.ring) / max(p.ring, 1)
    ring = tp + p.ring_m * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    return (np.concatenate([np.stack(rots), np.repeat(Rp[None], p.ring, 0)]), np.concatenate([np.stack(centers), ring]),
            names + [f"pose {p.ring_m:g} m beside the predicted one"] * p.ring)


def best_fit(kept: np.ndarray, g: GeometricResult) -> int:
    """The refined start that fits the frame's lines best: the most line points matched in the last
    round, each counted by how near its line it lies (``GeometricResult.fit``), then the smallest median
    residual; among the kept ones when any is. The exact loss counts arcs, too coarse for the 0.1-0.2 m
    between two minima of a small frame; a bare count of matched points prefers a corridor's pose 0.2-0.5 m
    along it that matches a few more points loosely
    (docs/benchmarks.md#the-tracker-alone-a-finer-fit-refined-twice-2026-11-28-session-22)."""
    order = np.lexsort((g.residual_deg, -np.asarray(g.fit), ~np.asarray(kept)))
    return int(order[0])


def height_band(pred: Prediction, p: TrackParams, band: tuple[float, float] | None) -> tuple[float, float] | None:
    """The world z a tracked camera may take: within ``p.climb_m`` per frame of the last trusted pose's
    height, inside the map's camera-height ``band`` (None: unknown) where the two meet (``climb_m`` 0:
    the map's band alone)."""
    if p.climb_m <= 0:
        return band
    z, dz = float(pred.last[1][2]), p.climb_m * pred.frames
    lo, hi = z - dz, z + dz
    if band is not None and max(lo, band[0]) <= min(hi, band[1]):
        lo, hi = max(lo, band[0]), min(hi, band[1])
    return lo, hi


def tracking_lines(img: np.ndarray, loz: Localizer, width: int) -> QueryLines:
    """The frame's 2D lines at ``width`` (a wider frame resized with area averaging; 0: as it is)."""
    if 0 < width < img.shape[1]:
        img = cv2.resize(img, (int(width), int(width) // 2), interpolation=cv2.INTER_AREA)
    return loz.detect_lines(img)


def frame_arcs(img: np.ndarray, entry: MapEntry, p: TrackParams) -> tuple[np.ndarray, dict[str, float]]:
    """The frame's arcs as the tracker uses them (:func:`tracking_lines`, then ``entry``'s map's length
    filter) and the seconds it took (``lines2d``)."""
    loz = entry.localizer
    tick = time.perf_counter()
    lines = tracking_lines(img, loz, p.width)
    secs = {"lines2d": time.perf_counter() - tick}
    return filter_by_length(lines.arcs, query_keep_ratio(loz.map.kept_ratio, loz.params.lines2d)), secs


def refined_starts(arcs: np.ndarray, R0: np.ndarray, t0: np.ndarray, pred: Prediction, p: TrackParams,
                   assoc_deg: float) -> tuple[GeometricResult, np.ndarray, np.ndarray]:
    """Step 1's short line refinement of the starts ``R0``, ``t0`` on the prediction's map from the association
    angle ``assoc_deg``: the refined poses, which were kept, their exact losses (:func:`refine_and_keep`)."""
    loz, m = pred.entry.localizer, pred.entry.localizer.map
    geo = replace(loz.params.geometric, rounds=p.rounds, assoc_deg=assoc_deg, fixed_rotation_rounds=0, wide_poses=0)
    return refine_and_keep(arcs, R0, t0, m.nearest_translation(t0), len(t0), m, geo, loz.params.search, loz.device,
                           loz.params.principal.group_tol, height_band=height_band(pred, p, m.camera_height_band))


def track_by_lines(arcs: np.ndarray, secs: dict[str, float], pred: Prediction, p: TrackParams, ref_loss: float,
                   max_tilt_deg: float | None = None) -> tuple[Localization, MapChoice] | None:
    """Step 1: the predicted pose refined on its map from the frame's lines ``arcs`` (:func:`frame_arcs`)
    alone; None when the refinement was not kept or its pose explains too few lines (:class:`TrackParams`).
    After lost frames the first association angle grows with the frames since the last trusted pose
    (at most the single-image refinement's)."""
    entry = pred.entry
    loz, m = entry.localizer, entry.localizer.map
    R0, t0, names = starts(pred, p)
    assoc = min(p.assoc_deg * pred.frames, max(p.assoc_deg, loz.params.geometric.assoc_deg))
    tick = time.perf_counter()
    g, kept, loss = refined_starts(arcs, R0, t0, pred, p, assoc)
    k = best_fit(kept, g)

    def holds(kept_: bool, loss_: float) -> bool:  # refined, explaining enough of the lines
        return bool(kept_) and not loss_ > p.keep * ref_loss

    if not holds(kept[k], loss[k]):
        return None
    k0, twice = k, ""
    if p.polish:  # refined once more from where it ended: 4 rounds can stop 0.1-0.2 m short of the minimum
        g2, kept2, loss2 = refined_starts(arcs, g.rotations[k:k + 1], g.centers[k:k + 1], pred, p, p.assoc_deg)
        if holds(kept2[0], loss2[0]) and g2.fit[0] > g.fit[k]:
            g, loss, k, twice = g2, loss2, 0, " twice"
    secs = {**secs, "refine": time.perf_counter() - tick}
    R, t = g.rotations[k], g.centers[k]
    loc = Localization(R, t, R0[k0], t0[k0], R[None], t[None], secs, num_rotations=0, num_lines=len(arcs), refined=True,
                       num_matches=int(g.matched[k]), refine_method="geometric",
                       refine_residual_deg=float(g.residual_deg[k]), arcs=arcs,
                       candidates_loss=np.array([loss[k]]), rotation_prior=rotation_prior_name(max_tilt_deg),
                       input_to_map=None if is_identity(m.input_to_map) else m.input_to_map,
                       selection_margin=NO_CONTENDER_MARGIN,
                       message=f"tracked: the {names[k0]} refined from lines{twice} ({int(g.matched[k])} "
                               f"line points, median residual {float(g.residual_deg[k]):.2f} deg)")
    tick = time.perf_counter()
    assess(loc, m, support_deg=loz.params.geometric.support_deg)
    secs["confidence"] = time.perf_counter() - tick
    secs["total"] = sum(secs.values())
    opt = MapOption(entry, float(loss[k]), loc, loss=float(loss[k]), searched=loc)
    return loc, MapChoice(opt, [opt], seconds=dict(secs))


LOST = "lost"  # the message of a lost frame's localization starts with it (:func:`is_lost`)


def lost_frame(arcs: np.ndarray, secs: dict[str, float], pred: Prediction, max_tilt_deg: float | None,
               why: str) -> tuple[Localization, MapChoice]:
    """Step 3 without a search: the frame takes the predicted pose, not refined, ``failed`` (confidence
    0), its only hypothesis (the walk's path keeps it); ``why``: why tracking lost it."""
    entry, m = pred.entry, pred.entry.localizer.map
    R, t = pred.rot_cam_from_world, pred.center
    loss = float(poses_loss(entry.localizer, arcs, R[None], t[None])[0]) if len(arcs) else 0.0
    loc = Localization(R, t, R, t, R[None], t[None], {**secs, "total": sum(secs.values())}, num_rotations=0,
                       num_lines=len(arcs), refined=False, candidates_loss=np.array([loss]),
                       rotation_prior=rotation_prior_name(max_tilt_deg),
                       input_to_map=None if is_identity(m.input_to_map) else m.input_to_map, confidence=0.0,
                       verdict="failed", message=f"{LOST}: {why}; the pose the walk predicted ({pred.frames} frame(s) "
                                                 "after its last trusted pose), not refined")
    opt = MapOption(entry, loss, loc, loss=loss)
    return loc, MapChoice(opt, [opt], seconds=dict(loc.seconds))


def is_lost(loc) -> bool:
    """Whether a frame's localization is a lost frame's (:func:`lost_frame`)."""
    return loc is not None and not loc.refined and loc.message.startswith(f"{LOST}: ")


def restricted_localizer(entry: MapEntry, refine: str, cache: dict[int, Localizer]) -> Localizer:
    """The localizer that refines step 2's poses on ``entry``'s map (``refine``: :class:`TrackParams`), made once."""
    if refine == "same" or entry.localizer.refine_mode == "geometric":
        return entry.localizer
    if id(entry) not in cache:
        loz, p = entry.localizer, entry.localizer.params
        if refine == "light":
            p = replace(p, max_query_frames=1, refine=replace(p.refine, pnp_views=2,
                                                              retrieval=replace(p.refine.retrieval, views=0)))
        else:
            p = replace(p, refine_mode="geometric")
        cache[id(entry)] = Localizer(loz.map, p, loz.device)
    return cache[id(entry)]


def track_by_search(img: np.ndarray, pred: Prediction, p: TrackParams, ref_loss: float,
                    max_tilt_deg: float | None, cache: dict[int, Localizer]) -> tuple[Localization, MapChoice] | None:
    """Step 2: the frame searched near the predicted pose on its map and refined; None when no
    candidate lies there or the pose is not refined, failed, or explains too few lines."""
    entry = pred.entry
    loz = restricted_localizer(entry, p.refine, cache)
    near = SearchNear(pred.center, pred.rot_cam_from_world, p.radius_m * pred.frames, p.cone_deg)
    try:
        s = loz.search(img, max_tilt_deg, near=near)
    except InputError:
        return None
    loc = loz.localize(img, max_tilt_deg, searched=s)
    loss = final_pose_loss(loz, loc)
    if not loc.refined or loc.verdict == "failed" or loss > p.keep * ref_loss:
        return None
    opt = MapOption(entry, float(s.best_loss), loc, loss=loss, searched=loc)
    return loc, MapChoice(opt, [opt], seconds=dict(loc.seconds))


def track(img: np.ndarray, pred: Prediction | None, max_tilt_deg: float | None, p: TrackParams,
          ref_loss: float | None, cache: dict[int, Localizer], threads: TorchThreads
          ) -> tuple[Localization, MapChoice] | None:
    """The frame tracked from the walk's prediction ``pred``: step 1, else step 2, else lost (module
    docstring; a lost frame's localization is not refined: :func:`is_lost`); None when there is
    nothing to track from (no prediction, no trusted global frame yet) or ``max_lost`` frames in a
    row were lost before this one (the caller searches globally)."""
    if pred is None or ref_loss is None:
        return None
    threads.one()
    arcs, secs = frame_arcs(img, pred.entry, p)
    if p.lines:
        got = track_by_lines(arcs, secs, pred, p, ref_loss, max_tilt_deg)
        if got is not None:
            return got
    if len(arcs) < p.min_lines:
        return lost_frame(arcs, secs, pred, max_tilt_deg, f"{len(arcs)} lines, fewer than {p.min_lines}")
    if pred.frames > p.max_lost:
        threads.restore()
        return None
    threads.restore()
    got = track_by_search(img, pred, p, ref_loss, max_tilt_deg, cache)
    if got is not None:
        return got
    return lost_frame(arcs, secs, pred, max_tilt_deg, "neither its lines nor a search near the prediction held")


def unsure(loc, sure: float | None, sure_verdict: str | None) -> bool:
    """Whether a tracked frame's localization ``loc`` is not ``confident``: its own verdict, no surer than its
    track's start (``sure``, ``sure_verdict``: :func:`ldlloc.confidence.no_surer_than`)."""
    return no_surer_than(loc.confidence, loc.verdict, sure, sure_verdict)[1] != "confident"


def check_due(got: tuple[Localization, MapChoice] | None, pred: Prediction | None, p: TrackParams) -> bool:
    """Whether a tracked frame (``got``: :func:`track`'s, from ``pred``) is also localized globally
    (:func:`overruled`): the first frame tracked again after ``p.check_after_lost`` lost frames or more (a track
    resumed after a fast turn can lock onto a room's 180-degree twin, as sure as its start), and the
    ``p.check_every``-th frame since the last global frame or check that is not ``confident`` (:func:`unsure`;
    lost frames count: a track turned 90 degrees in a building's symmetric corridors held for 100 frames; a
    demo room's track, sure but for a frame now and then, is checked rarely)."""
    if got is None or pred is None or not got[0].refined:
        return False
    if 0 < p.check_after_lost < pred.frames:  # pred.frames: the lost frames before this one, plus one
        return True
    return 0 < p.check_every <= pred.age + 1 and unsure(got[0], pred.sure, pred.sure_verdict)


def overruled(img: np.ndarray, got: tuple[Localization, MapChoice], maps: MapSet, max_tilt_deg: float | None,
              top_maps: int, p: TrackParams, threads: TorchThreads) -> tuple[Localization, MapChoice] | None:
    """The check of a tracked frame (``got``; :func:`check_due`): the frame localized globally on every map of
    ``maps`` (:func:`ldlloc.batch.which_map.localize_on_maps`); that localization when its pose is distinct from
    the tracked one and its lines explain more (lower exact loss): where its image is ``confident``, any more;
    else ``p.check_gain`` times the tracked pose's. None: the tracked pose stands (docs/benchmarks.md)."""
    threads.restore()
    try:
        loc, choice = localize_on_maps(img, maps, max_tilt_deg, top_maps)
    except LdlError:  # the check found nothing: the tracked pose stands
        return None
    if not loc.refined or loc.verdict == "failed":
        return None
    R, t = np.asarray(got[0].rot_cam_from_world, float), np.asarray(got[0].center, float)
    entry = got[1].chosen.entry
    if choice.chosen.entry is entry and not distinct(loc.rot_cam_from_world, loc.center, R[None], t[None])[0]:
        return None
    tracked = float(poses_loss(entry.localizer, loc.arcs, R[None], t[None])[0])
    return (loc, choice) if own_loss(choice) < (tracked if loc.verdict == "confident" else p.check_gain * tracked) \
        else None


def own_loss(choice: MapChoice) -> float:
    """The loss of the chosen map's final pose (its exact loss; lower is better)."""
    o = choice.chosen
    return float(o.loss) if o.loss is not None else final_pose_loss(o.entry.localizer, o.loc)
