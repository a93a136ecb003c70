"""Localize a walk: ``localize_walk(frames, maps, params) -> list[FrameOutcome]`` (offline: the whole walk).

1. Each frame is localized alone (:func:`ldlloc.batch.which_map.localize_on_maps`: every map
   searched, the best refined), or, with tracking on (dense frames: videos), first near the pose
   the walk predicts (:mod:`ldlloc.walk.track`: the prediction refined from lines, else a search
   restricted to its neighbourhood), falling back to the global search when the tracked pose is
   lost (not refined, or explaining too few of the lines the last global frame's pose explained).
   Its hypotheses (:mod:`ldlloc.walk.hypotheses`) are kept, not its image.
2. The most likely path over the hypotheses (:func:`ldlloc.walk.viterbi.best_path` with the
   motion model of :mod:`ldlloc.walk.motion`) chooses one pose per frame, with its margin (the
   smaller of the path's and the path's with every copy of a frame's room its image found at its
   own pose's cost: :mod:`ldlloc.walk.copies`).
3. Where the path chose another pose than the image's own, the frame takes it: another map's
   refined pose as it is, a search pose after a search and refinement near it (the image read
   again). :func:`ldlloc.confidence.walk_judgement` gives each frame its confidence and verdict
   and says whether the walk (not its image) decided it; the image's own judgement stays beside it.

Offline, not online: a tour is localized after it was shot, and the whole walk lets a later
frame (the corridor it came out into) decide an earlier one (the copy of a room it was in).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Iterable

import numpy as np

from ldlmap.core.errors import InputError, LdlError
from ldlloc.batch.which_map import TOP_MAPS, MapChoice, MapEntry, MapSet, localize_on_maps, poses_loss
from ldlloc.confidence import MODEL, distinct, no_surer_than, sound_where_moved, walk_judgement
from ldlloc.pipeline import Localization, Localizer, SearchNear
from ldlloc.walk.copies import copies_undecided, even_copies, reachable_pose, room_copies
from ldlloc.walk.hypotheses import MAX_HYPOTHESES, Hypotheses, from_choice, joined
from ldlloc.walk.lattice import LatticeParams, lattice_poses
from ldlloc.walk.motion import FreeSpace, MotionParams, transition_costs
from ldlloc.walk.relative import (RelativeParams, disagreement, floor_under, inverse, panorama_features, poses_along,
                                  relative_pose)
from ldlloc.walk.track import (TorchThreads, TrackBasis, TrackParams, check_due, check_track_params, is_lost,
                               next_basis, overruled, own_loss, predict, track)
from ldlloc.walk.viterbi import best_path, margin

TIE_COST = 0.01  # nats: what a pose the image named as its competitor costs more than its own (ties: its own)
MIN_FRAMES = 2  # a walk of one frame is a single image (the runs refuse it)


@dataclass(frozen=True)
class WalkParams:
    """How a walk is localized (defaults: a capture tour)."""

    motion: MotionParams = field(default_factory=MotionParams)
    top_maps: int = TOP_MAPS  # maps refined per frame after the ranking (several maps)
    track: bool = False  # dense frames (videos): each frame first tracked near the walk's prediction
    tracking: TrackParams = field(default_factory=TrackParams)  # how (ldlloc.walk.track)
    gap_radius_m: float = 4.5  # a frame whose image was not confident is searched again within this radius of the
    max_gap_radius_m: float = 12.0  # confident frames before and after it, times their distance in frames (at most
    # this)
    lattice: LatticeParams = field(default_factory=LatticeParams)  # ... and on a fine lattice of translations there
    # (ldlloc.walk.lattice: the map's candidates are too sparse for a frame of few lines)
    near_radius_m: float = 0.6  # a search pose the path chose is searched again within this radius ...
    near_cone_deg: float = 10.0  # ... and this cone, then refined
    max_hypotheses: int = MAX_HYPOTHESES
    walls: bool = True  # no step through a wall: the maps' free space (ldlloc.walk.motion.FreeSpace) ...
    scan_walls: bool = False  # ... a scan map's stored footprint too (off: it made the walk sure of wrong paths on a
    # held-out building; docs/benchmarks.md#walks-synthetic-building)
    relative: bool = True  # the motion between consecutive images where one needs more (:func:`relate`) ...
    relative_fit: RelativeParams = field(default_factory=RelativeParams)  # ... fitted so (ldlloc.walk.relative)
    max_tilt_level_deg: float = 45.0  # a frame's own rotation levels its bearings when it tilts less than this
    relative_rot_deg: float = 5.0  # a path's step between two related frames whose turn differs from theirs by more ...
    relative_dir_deg: float = 20.0  # ... or whose direction does by more than this (steps of at least ...
    relative_min_step_m: float = 0.3  # ... this: a shorter one's direction is a coarse pose's noise) ...
    relative_length_share: float = 0.25  # ... or whose length does by more than this share of theirs (the floor's) ...
    relative_cost: float = 8.0  # ... costs more, up to this at twice them (more than a frame's pose that explains
    # a third fewer lines: images that agree on their motion outweigh a map that lacks what both show)


VIDEO = WalkParams(track=True, motion=MotionParams(turn_deg=30.0), relative=False)  # a video: frames a few tenths of
# a second apart (the free step from the walking speed and their time apart), tracked, turning little between frames
# (its lost frames are blurred: the prediction stands for them, no image matching)


@dataclass(frozen=True)
class WalkFrame:
    """One frame of a walk: its name, how to read it (RGB panorama), its time (s) and upright prior."""

    name: str
    load: Callable[[], np.ndarray]
    time: float | None = None
    max_tilt_deg: float | None = None


@dataclass
class FrameOutcome:
    """A frame's localization after the walk, with its image's own judgement beside it."""

    frame: WalkFrame
    loc: Localization | None = None  # the final localization (None: the frame failed)
    entry: MapEntry | None = None  # the map its pose is in
    choice: MapChoice | None = None  # the frame's own (single-image or tracked) choice of map
    error: str | None = None  # why it failed
    tracked: bool = False  # found by tracking (else global)
    checked: bool = False  # tracked, and also localized globally to check the track (ldlloc.walk.track.check_due)
    track_basis: TrackBasis | None = None  # what the next frame's prediction starts from (tracking)
    single_confidence: float | None = None  # the image's own judgement
    single_verdict: str | None = None
    single_pose: tuple[np.ndarray, np.ndarray] | None = None  # (R, t) of the image's own pose
    competitors: list = field(default_factory=list)  # the poses its image named as competing ({R, t, ...})
    walk_decided: bool = False
    walk_margin: float | None = None  # nats (inf: no distinct pose in the frame's hypotheses)
    relative: tuple | None = None  # (the previous WalkFrame, its RelativePose to this one, the step's length in m or
    # None) where fitted (:func:`relate`)
    hypotheses: Hypotheses | None = field(default=None, repr=False)
    copies: Hypotheses | None = field(default=None, repr=False)  # every copy of its room its image found
    # (:func:`ldlloc.walk.copies.room_copies`), for the walk's margins
    even: tuple | None = field(default=None, repr=False)  # (hypotheses, copies, the two joined): ldlloc.walk.copies


def localize_walk(frames: Iterable, maps: MapSet, params: WalkParams = WalkParams(),
                  progress: Callable[[int, FrameOutcome], None] | None = None) -> list[FrameOutcome]:
    """Localize ``frames`` (in walk order) against ``maps`` as one walk (module docstring): each a
    :class:`WalkFrame`, or a ``(WalkFrame, image)`` pair whose image the first pass takes (a
    video's decoder: frames are read once, in order). ``progress(index, outcome)``: after each
    frame's own localization. A frame that cannot be localized gets its ``error`` and the walk goes
    on around it."""
    check_track_params(params.tracking)
    index = {id(e): i for i, e in enumerate(maps.entries)}
    trackers: dict[int, Localizer] = {}  # the localizers tracked frames are refined with, per map
    outcomes: list[FrameOutcome] = []
    ref_loss: float | None = None  # the last trusted global frame's loss: what a tracked pose must come near
    threads = TorchThreads()
    free = free_space(maps, params)  # no step through a wall
    try:
        for i, item in enumerate(frames):
            out, ref_loss = localize_frame(item, outcomes[-1] if outcomes else None, maps, params, ref_loss,
                                           trackers, index, threads, free)
            outcomes.append(out)
            if progress:
                progress(i, out)
    finally:
        threads.restore()
    augment(outcomes, maps, params)
    decide(outcomes, maps, params, free)
    return outcomes


def localize_frame(item, prev: FrameOutcome | None, maps: MapSet, params: WalkParams, ref_loss: float | None,
                   trackers: dict[int, Localizer], index: dict[int, int], threads: TorchThreads | None = None,
                   free: FreeSpace | None = None) -> tuple[FrameOutcome, float | None]:
    """One frame's own localization (the first pass): tracked from the walk's prediction (its basis
    carried by ``prev``, the frame before it: :func:`ldlloc.walk.track.predict`) or global, its
    hypotheses kept and its image dropped (:func:`lighten`). ``item``: a :class:`WalkFrame` or a
    ``(WalkFrame, image)`` pair; ``ref_loss``: the last trusted global frame's loss (returned updated);
    ``index``: ``id(MapEntry) -> index``; ``threads``: the walk's torch threads (None: this call's,
    restored before it returns). A frame localized globally where the walk predicted a pose also
    gets that pose as a hypothesis (its image may have failed: too few lines, motion blur), and where
    its image named copies of its room or was not confident, the track goes on from the pose the walk
    reaches (:func:`reached`; ``free``: the maps' free space). A frame that cannot be localized gets its ``error``."""
    fr, img = item if isinstance(item, tuple) else (item, None)
    out = FrameOutcome(fr)
    own_threads = threads is None
    threads = TorchThreads() if threads is None else threads
    pred = predict(prev, params.tracking) if params.track and prev is not None else None
    start = None  # where the track goes on from, when not the frame's own pose (reached)
    try:
        img = fr.load() if img is None else img
        got = track(img, pred, fr.max_tilt_deg, params.tracking, ref_loss, trackers, threads)
        out.checked = check_due(got, pred, params.tracking)
        checked = overruled(img, got, maps, fr.max_tilt_deg, params.top_maps, params.tracking, threads) \
            if out.checked else None
        if got is None or checked is not None:
            threads.restore()
            got = None  # a global frame
            loc, choice = checked or localize_on_maps(img, maps, fr.max_tilt_deg, params.top_maps)
        else:
            loc, choice = got
            out.tracked = bool(loc.refined)  # else lost (ldlloc.walk.track.is_lost): the prediction
        out.loc, out.choice, out.entry = loc, choice, choice.chosen.entry
        out.hypotheses = from_choice(choice, index, params.max_hypotheses)
        out.single_confidence, out.single_verdict = loc.confidence, loc.verdict
        out.single_pose = (np.asarray(loc.rot_cam_from_world, float), np.asarray(loc.center, float))
        out.competitors = list(loc.competitors)
        if got is None and loc.verdict != "failed":
            ref_loss = own_loss(choice)
        out.copies = room_copies(loc, out.entry, maps.entries, index, loc.arcs, out.hypotheses)
        if got is None and pred is not None and checked is None:
            loss = poses_loss(pred.entry.localizer, loc.arcs, pred.rot_cam_from_world[None], pred.center[None])
            out.hypotheses = joined(out.hypotheses, index[id(pred.entry)], pred.rot_cam_from_world[None],
                                    pred.center[None], loss)
            start = reached(out, pred, prev, index, params, free)
        elif checked is not None:  # an overruled track: its prediction was doubted, not its floor or its door
            start = reached(out, pred, prev, index, params, free, copies_only=True)
    except LdlError as exc:
        out.error = str(exc)
    except Exception as exc:  # noqa: BLE001 - one frame's failure (cv2.error, a decoder's), not the walk's
        out.error = f"internal error ({type(exc).__name__}: {exc})"
    finally:
        if own_threads:
            threads.restore()
    if start is not None:  # the pose the walk reached, not the image's own
        out.track_basis = TrackBasis(maps.entries[start[0]], start[1], start[2], sure=out.single_confidence,
                                     sure_verdict=out.single_verdict)
    else:
        out.track_basis = next_basis(prev, out, params.tracking) if params.track else None
    lighten(out)
    return out, ref_loss


def reached(out: FrameOutcome, pred, prev: FrameOutcome, index: dict[int, int], params: WalkParams,
            free: FreeSpace | None, copies_only: bool = False) -> tuple[int, np.ndarray, np.ndarray] | None:
    """Frame ``out``, localized globally where the walk predicted ``pred`` (:class:`ldlloc.walk.track.Prediction`;
    ``prev`` the frame before), in a room its image found copies of or not ``confident`` of its pose:
    ``(map index, R, t)`` of the pose among its hypotheses (the prediction among them) and those copies
    that the walk reaches from its last trusted pose (:func:`ldlloc.walk.copies.reachable_pose`), which
    then joins the frame's hypotheses; None when the image's own pose is as reachable, or the image is
    confident of it (a confident image overrules the walk: the walk may be the one that is lost).
    ``copies_only`` (a frame whose track a check overruled): among the image's own pose and the copies of
    its room alone, the one the walk reaches most cheaply (they explain the image's lines alike: a building's
    identical floors; the track had the floor right and the pose wrong, seed 4044's frame 240)."""
    if out.entry is None or out.copies is None and (copies_only or out.single_verdict == "confident"):
        return None
    dt = None if out.frame.time is None or prev.frame.time is None else out.frame.time - prev.frame.time
    R, t = pred.last
    poses = even_copies(out).hypotheses
    own = np.flatnonzero(~distinct(*out.single_pose, poses.rot_cam_from_world, poses.center)
                         & (poses.map_index == index[id(out.entry)]))
    if not len(own):
        return None
    # the candidates: every pose, or the own pose and the copies (appended after the frame's hypotheses)
    keep = np.r_[own[:1], np.arange(len(out.hypotheses), len(poses))] if copies_only else np.arange(len(poses))
    j = reachable_pose(poses.take(keep), 0 if copies_only else int(own[0]), (index[id(pred.entry)], R, t),
                       pred.frames, params.motion, dt, free, 0.0 if copies_only else None)
    if j is None:
        return None
    j = int(keep[j])
    if j >= len(out.hypotheses):  # a copy: among the frame's poses from now on
        out.hypotheses = joined(out.hypotheses, int(poses.map_index[j]), poses.rot_cam_from_world[j][None],
                                poses.center[j][None], poses.loss[j:j + 1])
    return int(poses.map_index[j]), poses.rot_cam_from_world[j], poses.center[j]


def lighten(out: FrameOutcome) -> None:
    """Drop what a frame's records do not need (its arcs, candidate rotations, the other maps'
    localizations): a walk's memory grows by its hypotheses and records only."""
    if out.choice is None:
        return
    for o in out.choice.ranked:
        o.searched = None
        if o.loc is not None and o is not out.choice.chosen:
            o.loc = None
    out.loc.arcs, out.loc.rotations, out.loc.arc_groups, out.loc.query_features = None, None, None, None


def augment(outcomes: list[FrameOutcome], maps: MapSet, params: WalkParams) -> None:
    """Frames whose image was not confident (not tracked either) get more hypotheses: the top-K of a
    search near the confident frames before and after them (on their maps, within ``gap_radius_m``
    per frame apart): the pose a search over the whole map lost among distractors (furniture the
    map lacks) is often the best of the few near where the walk was."""
    index = {id(e): i for i, e in enumerate(maps.entries)}
    cache: dict = {}
    for a, b in zip(outcomes[:-1], outcomes[1:]):
        relate(a, b, maps, index, params, cache)
    sure = [i for i, o in enumerate(outcomes) if is_anchor(o)]
    for i, o in enumerate(outcomes):
        if not needs_more(o):
            continue
        near = [a for a in sure if a < i][-1:] + [a for a in sure if a > i][:1]
        augment_frame(o, [anchor_of(a - i, outcomes[a]) for a in near], index, maps, params)


def is_anchor(o: FrameOutcome) -> bool:
    """Whether frame ``o``'s own pose anchors the searches of :func:`augment`: its image was confident, or
    would be but for copies of its room (a building's identical floors: right up to which copy, and the
    walk chooses the copy)."""
    if o.loc is None:
        return False
    copies = float((getattr(o.loc, "confidence_signals", None) or {}).get("copies", 0.0))
    return o.single_verdict == "confident" or (o.single_verdict == "ambiguous" and copies > 0
                                               and (o.single_confidence or 0.0) >= MODEL.confident_at)


def needs_more(o: FrameOutcome) -> bool:
    """Whether :func:`augment` searches again for frame ``o``: it has hypotheses, its image was not
    confident and it was not tracked."""
    return o.hypotheses is not None and o.single_verdict != "confident" and not o.tracked


def anchor_of(gap: int, o: FrameOutcome) -> tuple[int, MapEntry, np.ndarray]:
    """Confident frame ``o`` as an anchor of :func:`augment_frame`: ``gap`` frames away, its map and own centre."""
    return gap, o.entry, np.asarray(o.loc.center, float)


def augment_frame(o: FrameOutcome, anchors: list[tuple[int, MapEntry, np.ndarray]], index: dict[int, int],
                  maps: MapSet, params: WalkParams) -> None:
    """:func:`augment` of one frame: ``anchors`` the confident frames before and after it, each
    ``(frames apart, its map, its own centre)`` (:func:`anchor_of`); ``index``: ``id(MapEntry) -> index``."""
    if not anchors:
        return
    try:
        img = o.frame.load()
        lines = maps.entries[0].localizer.detect_lines(img)
    except LdlError:
        return
    for gap, entry, center in anchors:
        radius = min(params.gap_radius_m * abs(gap), params.max_gap_radius_m)
        loz = entry.localizer
        try:
            s = loz.search(img, o.frame.max_tilt_deg, lines, near=SearchNear(center, None, radius))
        except InputError:
            continue
        c = s.out
        o.hypotheses = joined(o.hypotheses, index[id(entry)], c.candidates_rot, c.candidates_center,
                              c.candidates_loss)
        if params.lattice.spacing_m > 0:  # the anchor's neighbourhood more finely than the map's candidates
            R, t, loss = lattice_poses(s.arcs, loz, center, radius, c.candidates_rot, params.lattice)
            o.hypotheses = joined(o.hypotheses, index[id(entry)], R, t, loss)


def relate(prev: FrameOutcome | None, cur: FrameOutcome, maps: MapSet, index: dict[int, int], params: WalkParams,
           cache: dict) -> None:
    """The motion between consecutive frames ``prev`` and ``cur`` (:func:`ldlloc.walk.relative.relative_pose`)
    where one needs more (:func:`needs_more`), the other anchors (:func:`is_anchor`) and their images
    agree on one: kept on ``cur`` for the
    path's steps (:func:`relative_costs`), and the poses along it from the one that anchors
    (:func:`is_anchor`) join the other's hypotheses (:func:`along`). ``index``: ``id(MapEntry) -> index``;
    ``cache``: the frames' features by ``id(WalkFrame)`` (the last two kept)."""
    if not params.relative or prev is None or prev.hypotheses is None or cur.hypotheses is None:
        return
    if not (needs_more(prev) and is_anchor(cur) or needs_more(cur) and is_anchor(prev)):
        return  # between two frames the map does not place, agreeing on their motion may move both wrong
    try:
        fa, fb = (features_of(o.frame, cache, params) for o in (prev, cur))
    except LdlError:
        return
    fits = [relative_pose(fa, fb, params.relative_fit, *levels) for levels in
            ((level_of(prev, params), level_of(cur, params)), (None, None))]  # levelled by their own poses, or as taken
    fits = [f for f in fits if f is not None]
    if not fits:
        return
    rel = max(fits, key=lambda f: f.inliers)  # an image's own rotation may be tilted wrong: the levelling more agree with
    cur.relative = (prev.frame, rel, step_length(prev, rel))
    if needs_more(cur) and is_anchor(prev):
        along(cur, prev, rel, maps, index, params)
    if needs_more(prev) and is_anchor(cur):
        along(prev, cur, inverse(rel), maps, index, params)


def features_of(frame: WalkFrame, cache: dict, params: WalkParams) -> tuple[np.ndarray, np.ndarray]:
    """A frame's :func:`ldlloc.walk.relative.panorama_features` (its image read again), cached by frame."""
    key = id(frame)
    if key not in cache:
        for old in list(cache)[:-1]:  # the last frame's stay: its successor is related to it
            del cache[old]
        cache[key] = panorama_features(frame.load(), params.relative_fit)
    return cache[key]


def step_length(o: FrameOutcome, rel) -> float | None:
    """The length (m) of the step ``rel`` from frame ``o``: its length in camera heights times the height
    of ``o``'s own pose above the floor of its map (:func:`ldlloc.walk.relative.floor_under`); None when unknown."""
    if rel.per_height is None or o.loc is None or o.entry is None:
        return None
    c = np.asarray(o.loc.center, float)
    floor = floor_under(o.entry.localizer.map.lines, c)
    return None if floor is None else rel.per_height * (c[2] - floor)


def along(o: FrameOutcome, anchor: FrameOutcome, rel, maps: MapSet, index: dict[int, int], params: WalkParams) -> None:
    """Frame ``o``'s poses along its motion ``rel`` (a :class:`ldlloc.walk.relative.RelativePose`) from
    confident frame ``anchor``, as long as the floor under the anchor says
    (:func:`ldlloc.walk.relative.poses_along`), scored with their exact line loss, join its hypotheses
    on the anchor's map. Nothing where the step's length is unknown (no floor seen, none in the map)."""
    entry, loz = anchor.entry, anchor.entry.localizer
    length = step_length(anchor, rel)
    if length is None:
        return
    R, C = poses_along(rel, np.asarray(anchor.loc.rot_cam_from_world, float), np.asarray(anchor.loc.center, float),
                       length)
    try:
        arcs = frame_arcs(o.frame, loz)
    except LdlError:
        return
    o.hypotheses = joined(o.hypotheses, index[id(entry)], R, C, poses_loss(loz, arcs, R, C))


def frame_arcs(frame: WalkFrame, loz: Localizer) -> np.ndarray:
    """The lines of ``frame``'s image (read again) as ``loz`` sees them: its arcs after the rotation stage,
    within the frame's tilt bound (the localizer's when it has none)."""
    tilt = loz.params.max_tilt_deg if frame.max_tilt_deg is None else frame.max_tilt_deg
    return loz.rotation_stage(loz.detect_lines(frame.load()), tilt).arcs


def level_of(o: FrameOutcome, params: WalkParams) -> np.ndarray | None:
    """Frame ``o``'s own rotation where it may level its bearings (it tilts less than
    ``max_tilt_level_deg``: a rotation found a quarter turn off about a horizontal axis does not), else
    None. :func:`relate` fits the motion levelled so and as taken (an upright camera whose own pose
    tilts wrong) and keeps the fit more matches agree with."""
    R = np.asarray(o.single_pose[0], float)
    return R if np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))) < params.max_tilt_level_deg else None


def relative_costs(a: FrameOutcome, b: FrameOutcome, params: WalkParams) -> np.ndarray | float:
    """(H_a, H_b) what each step from a pose of frame ``a`` to one of the next frame ``b`` costs more for
    disagreeing with the motion between their images (``b.relative``): 0 within ``relative_rot_deg`` and
    ``relative_dir_deg`` (and the length within ``relative_length_share``), ``relative_cost`` beyond twice
    them; 0 where no motion was fitted."""
    if b.relative is None or b.relative[0] is not a.frame:
        return 0.0
    ha, hb = a.hypotheses, b.hypotheses
    rot, ang = disagreement(b.relative[1], ha.rot_cam_from_world, ha.center, hb.rot_cam_from_world, hb.center,
                            params.relative_min_step_m)
    x = np.maximum(rot / params.relative_rot_deg, ang / params.relative_dir_deg)
    length = b.relative[2]
    if length is not None:  # the step's length, where the floor told it
        dist = np.linalg.norm(ha.center[:, None] - hb.center[None], axis=2)
        x = np.maximum(x, np.abs(dist - length) / max(params.relative_length_share * length, params.relative_min_step_m))
    return params.relative_cost * np.clip(x - 1.0, 0.0, 1.0)


def emission_costs(o: FrameOutcome, params: WalkParams) -> np.ndarray:
    """A frame's costs of its poses: from their losses (:meth:`Hypotheses.emission_costs`); a pose
    distinct from its image's own costs at least as much as that one (the image chose it on more than
    its loss: refinement, map-line support, PnP), plus the anchor cost (its image was confident, or would
    be but for copies of its room: :func:`is_anchor`) or the own cost (it was not); the copies and other
    competitors the image named cost next to nothing more (the walk chooses among them)."""
    h, m = o.hypotheses, params.motion
    e = h.emission_costs(m.emission_weight)
    other = distinct(*o.single_pose, h.rot_cam_from_world, h.center)
    own = float(np.min(e[~other])) if (~other).any() else 0.0
    extra = np.full(len(h), m.anchor_cost if is_anchor(o) else m.own_cost)
    if o.single_verdict != "confident":  # the poses the image named as its competitors: next to no extra cost
        for c in o.competitors:  # (a tie goes to the image's own pose)
            named = ~distinct(np.asarray(c["R"], float), np.asarray(c["t"], float), h.rot_cam_from_world, h.center)
            extra[named] = TIE_COST
    return np.where(other, np.maximum(e, own) + extra, e)


def decide(outcomes: list[FrameOutcome], maps: MapSet, params: WalkParams, free: FreeSpace | None = None) -> None:
    """Choose the walk's path over the frames that have hypotheses and give each its pose and judgement
    (``free``: the maps' free space, found here when None)."""
    live = [o for o in outcomes if o.hypotheses is not None and len(o.hypotheses)]
    if not live:
        return
    free = free_space(maps, params) if free is None else free
    path = walk_path(live, params, free=free)
    for o, j, m in zip(live, path.choice, walk_margins(live, path, params, free)):
        settle(o, j, m, maps, params)
        o.hypotheses, o.copies, o.even = None, None, None  # not needed any more


def free_space(maps: MapSet, params: WalkParams) -> FreeSpace | None:
    """The free space of the walk's maps (:class:`ldlloc.walk.motion.FreeSpace`, scans' footprints with
    ``scan_walls``); None with ``walls`` off or where the map set holds no maps (a stand-in without localizers)."""
    found = [getattr(getattr(e, "localizer", None), "map", None) for e in maps.entries]
    return FreeSpace.of_maps(found, params.scan_walls) if params.walls and found and None not in found else None


def walk_path(live: list[FrameOutcome], params: WalkParams, costs: dict | None = None, free: FreeSpace | None = None):
    """The most likely path (:func:`ldlloc.walk.viterbi.best_path`) over ``live`` frames (each with
    hypotheses). ``costs``: a cache of emission and transition costs by hypotheses object, for
    windows that overlap (:mod:`ldlloc.walk.stream`); ``free``: the maps' free space (no step through
    a wall; None: walls not known)."""
    costs = {} if costs is None else costs

    def em(o: FrameOutcome) -> np.ndarray:
        key = id(o.hypotheses)
        if key not in costs:
            costs[key] = (o.hypotheses, emission_costs(o, params))
        return costs[key][1]

    def trans(f: int) -> np.ndarray:
        a, b = live[f - 1], live[f]
        key = (id(a.hypotheses), id(b.hypotheses))
        if key not in costs:
            dt = None if a.frame.time is None or b.frame.time is None else b.frame.time - a.frame.time
            costs[key] = (a.hypotheses, b.hypotheses, transition_costs(a.hypotheses, b.hypotheses, params.motion, dt,
                                                                       free) + relative_costs(a, b, params))
        return costs[key][-1]

    return best_path([em(o) for o in live], trans)


def walk_margins(live: list[FrameOutcome], path, params: WalkParams, free: FreeSpace | None = None,
                 costs: dict | None = None) -> list[float]:
    """Each frame's margin on ``path`` (the :func:`walk_path` over ``live``): how much more the best path
    through another of its poses costs (:func:`ldlloc.walk.viterbi.margin`). Where images found copies of
    their rooms, or a frame's poses stand on several floors, the smaller of that and the same margin on
    a second path that knows only what the walk saw: every copy at its image's own pose's cost
    (:func:`ldlloc.walk.copies.even_copies`: the walk is sure of a copy only for where it went) and a
    change of floor by the stairs free (:func:`evidence_motion`: sure of a floor only for what the images
    say, not for the floor changes the path did not pay), over the frames searched on every map alone (a
    chain of tracked frames follows the place it started from and would vouch for it: :func:`followed`).
    ``costs``: the cost cache of that second path (:func:`walk_path`)."""
    def of(marginals: np.ndarray, h: Hypotheses, j: int) -> float:
        return margin(marginals, j, distinct(h.rot_cam_from_world[j], h.center[j], h.rot_cam_from_world, h.center))

    out = [of(path.marginals[f], o.hypotheses, j) for f, (o, j) in enumerate(zip(live, path.choice))]
    even = [even_copies(o) for o in live]
    floors = any(np.ptp(o.hypotheses.center[:, 2]) >= params.motion.floor_dz_m for o in live)
    if not floors and all(e is o for e, o in zip(even, live)) and not any(map(followed, live)):
        return out
    seen = [f for f, o in enumerate(live) if not followed(o)]  # a tracked frame follows a place, it does not compare them
    if not seen:
        return out
    other = walk_path([even[f] for f in seen], evidence_motion(params), costs, free)
    for k, f in enumerate(seen):
        out[f] = min(out[f], of(other.marginals[k], even[f].hypotheses, path.choice[f]))
    return out


def followed(o: FrameOutcome) -> bool:
    """Whether frame ``o`` was tracked from the walk's prediction (or lost by tracking), not searched on every map."""
    return bool(o.tracked) or is_lost(o.loc)


def evidence_motion(params: WalkParams) -> WalkParams:
    """``params`` with a change of floor costing nothing but its ``off_stairs_cost`` (where some map shows
    stairs and the change is away from them): the second path of :func:`walk_margins`. On the open-door building a walk kept every frame on one floor, its stairwell
    frames `confident` by the two floor changes it had not paid (docs/benchmarks.md#walks-synthetic-building)."""
    return replace(params, motion=replace(params.motion, floor_cost=0.0))


def settle(o: FrameOutcome, j: int, walk_margin: float, maps: MapSet, params: WalkParams) -> None:
    """Give frame ``o`` the pose its path chose (hypothesis ``j``; ``walk_margin``: how much more the best
    path through another of its poses costs, :func:`walk_margins`) and its judgement
    (:func:`ldlloc.confidence.walk_judgement`)."""
    h = o.hypotheses
    R, t = h.rot_cam_from_world[j], h.center[j]
    o.walk_margin = walk_margin
    tracked = followed(o)  # before the walk moves it
    copies = tracked and copies_undecided(o.loc)  # a track follows one copy of its room: it cannot tell them apart
    changed = bool(distinct(R, t, o.single_pose[0][None], o.single_pose[1][None])[0])
    pose_ok = bool(o.loc.refined)
    if changed:
        pose_ok = move_to(o, maps.entries[int(h.map_index[j])], R, t, params) and sound_where_moved(o.loc)
    conf, verdict, o.walk_decided = walk_judgement(o.single_confidence, o.single_verdict, o.walk_margin,
                                                   changed, pose_ok)
    if tracked and o.track_basis is not None:  # no surer than the global frame its track started from
        conf, verdict = no_surer_than(conf, verdict, o.track_basis.sure, o.track_basis.sure_verdict)
    if copies and verdict == "confident":  # nor than its own image, which named copies of its room
        conf, verdict = min(conf, float(o.single_confidence or 0.0)), "ambiguous"
    o.loc.confidence, o.loc.verdict = conf, verdict
    if o.walk_decided and changed:  # the image's own pose is the walk's competitor
        R0, t0 = o.single_pose
        o.loc.competitors = [{"R": np.round(R0, 8).tolist(), "t": np.round(t0, 6).tolist(), "loss": None,
                              "why": "the image's own pose (the walk chose another)"}]


def move_to(o: FrameOutcome, entry: MapEntry, R: np.ndarray, t: np.ndarray, params: WalkParams) -> bool:
    """Give frame ``o`` the pose the walk chose on ``entry``'s map: searched and refined near it
    (its image read again); the coarse pose itself when that fails. Returns whether the pose is refined."""
    loz = entry.localizer
    # a lattice pose (ldlloc.walk.lattice) may stand farther than the radius from every candidate: the nearest one
    reach = float(np.linalg.norm(loz.map.translations[loz.map.nearest_translation(t[None])[0]] - t))
    near = SearchNear(t, R, max(params.near_radius_m, reach + 1e-6), params.near_cone_deg)
    try:
        img = o.frame.load()
        loc = loz.localize(img, o.frame.max_tilt_deg, searched=loz.search(img, o.frame.max_tilt_deg, near=near))
    except LdlError as exc:
        o.loc.rot_cam_from_world, o.loc.center, o.loc.refined = R, t, False
        o.loc.message = f"the walk's pose (coarse: {exc})"
        o.entry = entry
        return False
    loc.arcs, loc.rotations, loc.arc_groups, loc.query_features = None, None, None, None
    loc.message = f"the walk's pose, {loc.message}"
    o.loc, o.entry = loc, entry
    return bool(loc.refined)
