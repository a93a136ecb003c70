"""A walk as a stream: each frame decided a fixed lag after it and handed on (written) at once;
a killed walk resumed from its last written frame (:func:`stream_walk`, :func:`resume_state`).

Frames are decided in blocks of :data:`BLOCK` (frames kB to kB + B - 1), once the frame ``lag``
after the block's last is localized (or the walk has ended): their poses are those of the most
likely path (:func:`ldlloc.walk.localize.walk_path`) over the frames kB - ``lag`` to kB + B - 1 +
``lag``, starting from the decided pose of the last frame before them (the anchor: the walk's
prefix, fixed once written). A block's path is searched once (its cost grows with the window,
2 lag + B frames: a block spares B - 1 of those searches). Frames before f are not fixed within the window (only the
anchor is), so a frame's margin weighs the paths that change the frames around it too, as the
whole walk's does. A walk of at most ``lag`` + 1 frames is decided over the whole walk, exactly
as :func:`ldlloc.walk.localize.localize_walk` (offline) decides it. The searches near confident
frames (:func:`ldlloc.walk.localize.augment_frame`) run when the first confident frame after a
frame arrives, or when the frame is decided.

Memory: the hypotheses of fewer than 2 (``lag`` + B) frames and the localizations of the frames not
yet decided (at most ``lag`` + B), never the images, whatever the walk's length.

A frame's decision depends on the frames of its window, on the anchor, and on the state the
first pass carries from frame to frame (the previous frame's own pose and map for tracking,
the last global frame's loss, the last confident frame): all in the written records
(``walk.single_pose``, ``walk.single_map``, ``walk.basis``, ``walk.ref_loss``, the record's pose and map). A
resumed walk (:func:`resume_state`) localizes again the ``lag`` frames (rounded to whole blocks)
before its first unwritten block (their hypotheses: the window's past) without writing them, and
goes on from the tracking basis the frame before them handed on (``walk.basis``: the last trusted
pose, the walk's velocity, the frames since): its records equal an uninterrupted run's.

torch runs on one thread for the whole walk (:class:`ldlloc.walk.track.TorchThreads`, switched
once, given back when the stream ends or is abandoned).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator

import numpy as np

from ldlmap.core.errors import InputError
from ldlloc.batch.which_map import MapSet
from ldlloc.record import QueryResult
from ldlloc.walk.hypotheses import one_pose
from ldlloc.walk.localize import (FrameOutcome, WalkFrame, WalkParams, augment_frame, free_space, is_anchor,
                                  localize_frame, needs_more, relate, settle, walk_margins, walk_path)
from ldlloc.walk.track import TorchThreads, TrackBasis, is_lost

LAG = 100  # frames: a frame is decided once this many after it are localized (a walk of lag + 1 frames or fewer:
# decided as a whole, offline); its window also holds this many before it
BLOCK = 10  # frames decided together, over one window (frames kB .. kB + B - 1): a tenth of the path searches


@dataclass
class OwnPose:
    """A written frame's own pose, as tracking reads the previous frame's localization."""

    rot_cam_from_world: np.ndarray
    center: np.ndarray


@dataclass
class Slot:
    """A frame in the stream: its index in the walk, its outcome, what the first pass carried past it."""

    index: int
    out: FrameOutcome
    ref_loss: float | None  # the last global frame's loss after this frame (tracking's reference)
    before: tuple | None  # the last confident frame before it: (index, map, own centre)
    pending: bool  # still to be searched near the confident frames around it (augment)
    written: bool = False  # decided and written before (a resumed walk's past)
    final: FrameOutcome | None = None  # once decided: its pose as a one-pose frame (the anchor after it)


@dataclass
class Resume:
    """Where a walk goes on (:func:`resume_state`): frames ``start`` .. ``written`` - 1 are localized
    again as the window's past, then frames from ``written`` on are decided and handed on."""

    start: int = 0
    written: int = 0
    prev: FrameOutcome | None = None  # frame start - 1 (tracking's previous frame)
    ref_loss: float | None = None
    confident: tuple | None = None  # the last confident frame before start
    anchor: FrameOutcome | None = None  # the last decided frame with a pose before start
    finals: dict[int, FrameOutcome] = field(default_factory=dict)  # decided poses of frames start .. written - 1


def fixed_frame(frame: WalkFrame, R, t, map_index: int) -> FrameOutcome:
    """A decided pose as a frame of one hypothesis (the anchor of the windows after it)."""
    R, t = np.asarray(R, float), np.asarray(t, float)
    return FrameOutcome(frame, hypotheses=one_pose(map_index, R, t, -1.0, True), single_pose=(R, t),
                        single_verdict="confident")


def _no_image():
    raise InputError("a decided frame's image is not read again")


class WalkStream:
    """The stream of one walk (module docstring): :meth:`push` each frame in order, then
    :meth:`finish`; each returns the blocks of frames decided, in order (:class:`Slot`)."""

    def __init__(self, maps: MapSet, params: WalkParams, lag: int = LAG, resume: Resume | None = None,
                 progress: Callable[[int, FrameOutcome], None] | None = None, block: int | None = None):
        block = BLOCK if block is None else block
        for name, v in (("lag", lag), ("block", block)):
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputError(f"a walk's {name} must be a whole number of frames >= 1, got {v!r}")
        r = resume or Resume()
        self.maps, self.params, self.lag, self.block, self.progress = maps, params, lag, block, progress
        self.index = {id(e): i for i, e in enumerate(maps.entries)}
        self.trackers: dict = {}
        self.next = self.decide_next = r.start
        self.written, self.prev, self.ref_loss, self.confident = r.written, r.prev, r.ref_loss, r.confident
        self.anchor, self.finals = r.anchor, dict(r.finals)
        self.slots: deque[Slot] = deque()
        self.costs: dict = {}
        self.even_costs: dict = {}  # the same with every copy of a room at its image's own pose's cost (walk_margins)
        self.features: dict = {}  # the last frames' image features (ldlloc.walk.localize.relate)
        self.free = free_space(maps, params)  # no step through a wall
        self.threads = TorchThreads(pinned=True)  # torch on one thread for the whole walk (:meth:`close`)

    def push(self, item) -> list[list[Slot]]:
        """Localize the next frame (a :class:`WalkFrame` or ``(WalkFrame, image)``); the blocks decided now."""
        i = self.next
        self.next += 1
        prev = self.slots[-1].out if self.slots else self.prev
        self.threads.one()
        out, self.ref_loss = localize_frame(item, prev, self.maps, self.params, self.ref_loss, self.trackers,
                                            self.index, self.threads, self.free)
        relate(prev, out, self.maps, self.index, self.params, self.features)  # the motion from the frame before
        slot = Slot(i, out, self.ref_loss, self.confident, needs_more(out) and not is_lost(out.loc), i < self.written)
        if is_anchor(out):
            here = (i, out.entry, np.asarray(out.loc.center, float))
            for s in self.slots:
                if s.pending:
                    self._augment(s, [here])
            self.confident = here
        self.slots.append(slot)
        if self.progress is not None and not slot.written:
            self.progress(i, out)
        done: list[list[Slot]] = []
        while self.decide_next + self.block - 1 <= i - self.lag:  # the block's last frame has lag frames after it
            done.append(self._decide_block())
        return [b for b in done if b]

    def finish(self) -> list[list[Slot]]:
        """The walk has ended: the frames not yet decided, decided (block by block)."""
        for s in self.slots:
            if s.pending:
                self._augment(s, [])
        done: list[list[Slot]] = []
        while self.decide_next < self.next:
            done.append(self._decide_block())
        return [b for b in done if b]

    def close(self) -> None:
        """Give torch's threads back to the caller (the walk ended or was abandoned)."""
        self.threads.release()

    def _augment(self, s: Slot, after: list[tuple]) -> None:
        near = ([s.before] if s.before is not None else []) + after
        augment_frame(s.out, [(a - s.index, entry, c) for a, entry, c in near], self.index, self.maps, self.params)
        s.pending = False

    def _decide_block(self) -> list[Slot]:
        """Decide the block of frames from ``decide_next`` over its window; the frames written before
        (a resumed walk) are left out."""
        b = self.decide_next
        self.decide_next = end = min(b + self.block, self.next)
        while self.slots[0].index < b - self.lag:  # out of the window: its decided pose anchors the rest
            old = self.slots.popleft()
            if old.final is not None:
                self.anchor = old.final
        block = [self.slots[i - self.slots[0].index] for i in range(b, end)]
        for s in block:
            if s.pending:
                self._augment(s, [])
            if s.written:
                s.final = self.finals.pop(s.index, None)
        todo = [s for s in block if not s.written]
        mine = {id(s.out) for s in todo if s.out.hypotheses is not None and len(s.out.hypotheses)}
        if not mine:
            return todo
        window = [s.out for s in self.slots if s.out.hypotheses is not None and len(s.out.hypotheses)]
        live = ([self.anchor] if self.anchor is not None else []) + window
        if self.anchor is not None:
            for c in (self.costs, self.even_costs):
                c[id(self.anchor.hypotheses)] = (self.anchor.hypotheses, np.zeros(1))
        path = walk_path(live, self.params, self.costs, self.free)
        margins = walk_margins(live, path, self.params, self.free, self.even_costs)
        for k, o in enumerate(live):
            if id(o) in mine:
                settle(o, path.choice[k], margins[k], self.maps, self.params)
        for s in todo:
            if id(s.out) in mine:
                s.final = fixed_frame(WalkFrame(s.out.frame.name, _no_image, s.out.frame.time),
                                      s.out.loc.rot_cam_from_world, s.out.loc.center, self.index[id(s.out.entry)])
        held = {id(x.hypotheses) for x in live} | {id(x.even[2]) for x in live if x.even is not None}
        self.costs, self.even_costs = ({k: v for k, v in c.items()
                                        if (k in held if isinstance(k, int) else k[0] in held and k[1] in held)}
                                       for c in (self.costs, self.even_costs))
        return todo


def release(slot: Slot) -> None:
    """Drop what a decided frame's record needed (its localization and map choice): the window keeps
    only its hypotheses."""
    slot.out.loc = slot.out.choice = None


def stream_walk(frames: Iterable, maps: MapSet, params: WalkParams, lag: int = LAG, resume: Resume | None = None,
                progress: Callable[[int, FrameOutcome], None] | None = None,
                at_end: Callable[[int], None] | None = None, block: int | None = None) -> Iterator[list[Slot]]:
    """The decided frames of a walk as they are decided, a block at a time, in order (:class:`WalkStream`;
    the frames written before are left out); ``frames`` from frame ``resume.start`` on. ``at_end(count)``:
    called with the walk's frame count once its frames are all localized, before the last ones are
    decided (it may refuse the walk). Write a block at once: a kill then leaves whole blocks."""
    stream = WalkStream(maps, params, lag, resume, progress, block)
    try:
        for item in frames:
            yield from _handed_on(stream.push(item))
        if at_end is not None:
            at_end(stream.next)
        yield from _handed_on(stream.finish())
    finally:
        stream.close()


def _handed_on(blocks: list[list[Slot]]) -> Iterator[list[Slot]]:
    """``blocks`` yielded in turn, each released (:func:`release`) once its consumer has written it."""
    for got in blocks:
        yield got
        for slot in got:
            release(slot)


def basis_from_record(b: dict | None, by_path: dict) -> TrackBasis | None:
    """A written frame's tracking basis (``walk.basis``: :func:`basis_record`) on the map of that path in
    ``by_path``; None when not written (earlier files) or its map is not among the walk's."""
    if not b or str(b.get("map")) not in by_path:
        return None
    turn = b.get("turn")
    return TrackBasis(by_path[str(b["map"])], np.asarray(b["R"], float), np.asarray(b["t"], float),
                      None if b.get("step") is None else np.asarray(b["step"], float),
                      None if turn is None else np.asarray(turn, float), int(b.get("since", 0)), b.get("sure"),
                      b.get("sure_verdict"), int(b.get("age", 0)))


def basis_record(b: TrackBasis | None) -> dict | None:
    """A frame's tracking basis as its record's ``walk.basis`` (what the next frame predicts from)."""
    if b is None:
        return None
    return {"map": str(b.entry.path), "R": b.rot_cam_from_world.tolist(), "t": b.center.tolist(),
            "step": None if b.step is None else b.step.tolist(), "turn": None if b.turn is None else b.turn.tolist(),
            "since": b.since, "sure": b.sure, "sure_verdict": b.sure_verdict, "age": b.age}


def resume_state(records: list[QueryResult | None], maps: MapSet, lag: int = LAG, block: int | None = None
                 ) -> Resume | None:
    """How a walk goes on from its records in the results file (``records[i]``: frame i's, None when
    not written): after its written blocks of frames (a prefix of the walk; a block cut short by a
    full disk is decided again), None to run it whole (nothing written, or only failed frames: they
    are retried, or records without the stream's state: written by an earlier ldlloc)."""
    written = next((i for i, r in enumerate(records) if r is None), len(records))
    block = BLOCK if block is None else block
    written = written // block * block
    done = records[:written]
    if not done or all(r.status == "failed" for r in done) or any(
            r.walk is None or "ref_loss" not in r.walk for r in done):
        return None
    by_path = {str(e.path): e for e in maps.entries}
    index = {id(e): i for i, e in enumerate(maps.entries)}
    start = max(0, (written - lag) // block * block)  # a block's start: the stream decides as it did

    def own(r: QueryResult) -> tuple | None:
        pose, entry = r.walk.get("single_pose"), by_path.get(str(r.walk.get("single_map")))
        return None if pose is None or entry is None else (np.asarray(pose["R"], float), np.asarray(pose["t"], float),
                                                          entry)

    def final(i: int) -> FrameOutcome | None:
        r = done[i]
        if own(r) is None or r.R is None or r.map not in by_path:
            return None
        return fixed_frame(WalkFrame(r.name, _no_image, r.walk.get("time")), r.R, r.t, index[id(by_path[r.map])])

    state = Resume(start, written, finals={i: x for i in range(start, written) if (x := final(i)) is not None})
    if start:
        last = done[start - 1]
        got = own(last)
        state.prev = None if got is None else FrameOutcome(WalkFrame(last.name, _no_image), loc=OwnPose(*got[:2]),
                                                           entry=got[2])
        basis = basis_from_record(last.walk.get("basis"), by_path)
        if basis is not None:  # tracking goes on as it did (else from the frame's own pose)
            state.prev = FrameOutcome(WalkFrame(last.name, _no_image), track_basis=basis)
        state.ref_loss = last.walk.get("ref_loss")
        sure = [i for i in range(start) if done[i].walk.get("single_verdict") == "confident" and own(done[i])]
        if sure:
            _, t, entry = own(done[sure[-1]])
            state.confident = (sure[-1], entry, t)
        state.anchor = next((x for i in range(start - 1, -1, -1) if (x := final(i)) is not None), None)
    return state

