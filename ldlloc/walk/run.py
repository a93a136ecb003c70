"""Walk runs: ``ldlloc run --images ... --walk``, ``ldlloc run --root ... --walk`` and ``--video``.

A walk's frames are localized as a stream (:mod:`ldlloc.walk.stream`): each frame is decided a
fixed lag after it (``lag`` frames; a walk that short is decided as a whole) and its record
written at once (:class:`ldlloc.batch.results.ResultsWriter`: appended to the journal, O(1) per
frame whatever the walk's length). ``--resume`` goes on from a walk's last written frame
(:func:`ldlloc.walk.stream.resume_state`), skips the walks written whole and runs again those
whose frames all failed. Each record is the single-image run's record (the same fields, the
final pose) with ``walk``: its place in the walk, the image's own judgement and what the stream
carries past it (:func:`walk_fields`).

Dataset runs: one walk per scene (``--scene-unknown``: per folder of maps, a ZInD floor), its
queries in capture order (:func:`walk_order`: ZInD's panorama number).
"""

from __future__ import annotations

from dataclasses import replace
from itertools import islice
from pathlib import Path
from typing import Callable, Iterable, Iterator

from ldlmap.core.errors import InputError, LdlError
from ldlmap.io.imagefile import image_header_size
from ldlloc.record import QueryResult
from ldlloc.batch.images import ImageQuery, failed_image_result, image_result
from ldlloc.batch.results import ResultsWriter
from ldlloc.batch.run import failed_result, open_results, result_from_localization, tilt_bound_for
from ldlloc.batch.which_map import MapSet
from ldlloc.pipeline import LocalizeParams, load_image
from ldlloc.walk.localize import MIN_FRAMES, FrameOutcome, WalkFrame, WalkParams
from ldlloc.walk.order import natural_key, ordered
from ldlloc.walk.stream import LAG, Resume, Slot, basis_record, resume_state, stream_walk
from ldlloc.walk.track import is_lost
from ldlloc.walk.video import check_sampling, decoded_frames, frame_at, video_info


def walk_fields(slot: Slot, walk: str) -> dict:
    """A frame's ``walk`` record: the walk's name, the frame's index and time, whether the walk
    decided it, the image's own verdict, confidence, pose and map, the path margin (nats),
    the motion from the frame before (``relative``: :func:`relative_record`), tracking (``lost``:
    tracking lost the frame, its pose the walk's prediction:
    :func:`ldlloc.walk.track.is_lost`; ``checked``: also localized globally to check the track:
    :func:`ldlloc.walk.track.check_due`; ``basis``: what the next frame's prediction starts from), and
    the last global frame's loss (what a resumed walk's tracking goes on from)."""
    out = slot.out
    m = out.walk_margin
    return {"name": walk, "frame": slot.index, "time": out.frame.time, "walk_decided": bool(out.walk_decided),
            "single_verdict": out.single_verdict, "single_confidence": out.single_confidence,
            "margin": None if m is None else (round(m, 4) if m != float("inf") else "inf"), "tracked": out.tracked,
            "lost": is_lost(out.loc), "checked": out.checked,
            "basis": basis_record(out.track_basis),
            "single_pose": None if out.single_pose is None else {"R": out.single_pose[0].tolist(),
                                                                  "t": out.single_pose[1].tolist()},
            "single_map": None if out.choice is None else str(out.choice.chosen.entry.path),
            "ref_loss": slot.ref_loss, "relative": relative_record(out)}


def relative_record(out: FrameOutcome) -> dict | None:
    """The motion from the frame before, where its image and this one's agreed on it
    (:func:`ldlloc.walk.localize.relate`): that frame's name, the matches and inliers, the rotation
    (R_this R_before^T), the step's unit direction in the frame before's camera frame and its length
    (m; null: no floor seen); None where none was fitted."""
    if out.relative is None:
        return None
    before, rel, length = out.relative
    return {"from": before.name, "matches": rel.matches, "inliers": rel.inliers, "R": rel.rot.round(8).tolist(),
            "direction": rel.direction.round(6).tolist(), "length_m": None if length is None else round(length, 4)}


def walk_records(writer: ResultsWriter, groups: list[list[str]]) -> list[list[QueryResult | None]]:
    """The records ``writer`` holds (light: :func:`ldlloc.batch.results.light_record`) of each walk's
    frames (``groups``: each walk's names, in walk order; None: not written)."""
    have = {r.name: r for r in writer.light_results}
    return [[have.get(n) for n in names] for names in groups]


def written_whole(records: list[QueryResult | None]) -> bool:
    """Whether a walk's frames are all written (and not all failed: those are run again)."""
    return bool(records) and all(r is not None for r in records) and any(r.status != "failed" for r in records)


def walk_resume(records: list[QueryResult | None], maps: MapSet, lag: int) -> tuple[bool, Resume | None]:
    """Whether a walk is written whole (:func:`written_whole`: nothing to run), and else where it
    goes on (:func:`ldlloc.walk.stream.resume_state`; None: from its first frame)."""
    if written_whole(records):
        return True, None
    return False, resume_state(records, maps, lag)


def write_walk(writer: ResultsWriter, blocks: Iterable[list[Slot]], record: Callable[[Slot], QueryResult]) -> None:
    """Write each decided block's records as it comes (one journal write: a kill leaves whole blocks)."""
    for block in blocks:
        writer.extend([record(slot) for slot in block])


def choice_fields(out: FrameOutcome) -> dict:
    """The record's map fields: the map the walk's pose is in, the runner-up of the image's own choice."""
    rec = out.choice.record()
    if out.entry is not out.choice.chosen.entry:
        rec["map"] = str(out.entry.path)
    return rec


def check_frame_sizes(paths: list[Path]) -> None:
    """One-line error when a walk's photos are not all of one size (read from their headers). A photo
    whose header cannot be read (a truncated JPEG) is left to fail as its frame, as in a run of images."""
    sizes = {}
    for p in paths:
        try:
            size = image_header_size(p)
        except InputError:
            continue
        if size is not None:
            sizes.setdefault(size, p)
    if len(sizes) > 1:
        (a, pa), (b, pb) = list(sizes.items())[:2]
        raise InputError(f"a walk's frames must be of one size: {pa} is {a[0]}x{a[1]}, {pb} is {b[0]}x{b[1]}")


def walk_photos(queries: list, order: str = "name") -> tuple[list, list[float | None]]:
    """A walk's photos (:class:`ldlloc.batch.images.ImageQuery`) in ``order`` with their capture
    times; one-line errors for fewer than two, photos of different sizes, or ``time`` without times."""
    if len(queries) < MIN_FRAMES:
        raise InputError(f"--walk needs at least {MIN_FRAMES} photos, got {len(queries)}")
    queries, times = ordered(queries, order, lambda q: q.name, lambda q: q.image)
    check_frame_sizes([q.image for q in queries])
    return queries, times


def run_walk_images(queries: list, maps: MapSet, output: str | Path, params: LocalizeParams, walk: WalkParams,
                    order: str = "name", device: str = "cpu", resume: bool = False, meta: dict | None = None,
                    progress: Callable[[QueryResult], None] | None = None, any_options: bool = False,
                    say: Callable[[str], None] | None = None, name: str = "walk", lag: int = LAG) -> list[QueryResult]:
    """Localize ``queries`` (:class:`ldlloc.batch.images.ImageQuery`) as one walk in ``order``
    (name | time) against ``maps``, writing each frame's record once it is decided (``lag``).
    ``progress``: after each frame's own localization (its single-image record)."""
    queries, times = walk_photos(queries, order)
    meta = {**(meta or {}), "walk": walk_meta(order, walk, lag)}
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        whole, state = walk_resume(walk_records(writer, [[q.name for q in queries]])[0], maps, lag) if resume \
            else (False, None)
        if not whole:
            start = state.start if state else 0
            frames = [WalkFrame(q.name, (lambda p=q.image: load_image(p)), t, params.max_tilt_deg)
                      for q, t in zip(queries[start:], times[start:])]
            tell = None if progress is None else (
                lambda i, o: progress(image_frame_record(queries[i], Slot(i, o, None, None, False), params, name)))
            write_walk(writer, stream_walk(frames, maps, walk, lag, state, tell),
                       lambda s: image_frame_record(queries[s.index], s, params, name))
        writer.finish()
        return writer.results


def walk_meta(order: str, walk: WalkParams, lag: int) -> dict:
    """The results ``meta["walk"]`` of a walk run: its order, motion model, tracking and lag."""
    return {"order": order, "motion": vars(walk.motion), "track": walk.track, "lag": lag}


def image_frame_record(q, slot: Slot, params: LocalizeParams, walk: str) -> QueryResult:
    """An image frame's record (before the walk is decided: its single-image record, for progress)."""
    out = slot.out
    if out.loc is None:
        r = failed_image_result(q, params, out.error or "not localized", 0.0)
    else:
        r = replace(image_result(q, out.loc, out.choice), **choice_fields(out), scene=out.entry.scene)
    r.walk = walk_fields(slot, walk)
    return r


def walk_order(q) -> tuple:
    """A dataset query's place in its walk: the natural order of its file name's stem (ZInD's
    ``pano_<number>``: capture order), then its name."""
    return natural_key(Path(q.name).name), q.name


def walk_groups(queries: list, scene_unknown: bool) -> dict[str, list]:
    """A dataset run's walks: one per split and scene (``scene_unknown``: per split and folder of scenes), in
    walk order: a synthetic dataset's ``walk_tour`` and ``walk_video`` and its single-photo splits never mix."""
    groups: dict[str, list] = {}
    splits = {q.split for q in queries}
    for q in sorted(queries, key=lambda q: (q.split, q.scene, walk_order(q))):
        key = str(Path(q.scene).parent) if scene_unknown else q.scene
        groups.setdefault(key if len(splits) == 1 else f"{q.split}/{key}", []).append(q)
    return {k: sorted(v, key=walk_order) for k, v in sorted(groups.items())}


def run_walk_queries(queries: list, maps_dir: str | Path, output: str | Path, params: LocalizeParams, walk: WalkParams,
                     device: str = "cpu", resume: bool = False, meta: dict | None = None, scene_unknown: bool = False,
                     progress: Callable[[QueryResult], None] | None = None, any_options: bool = False,
                     say: Callable[[str], None] | None = None, lag: int = LAG) -> list[QueryResult]:
    """Dataset queries (with ground truth) localized walk by walk (:func:`walk_groups`): against
    their scene's map, or (``scene_unknown``) the maps of its folder, each frame written once
    decided. A walk whose maps cannot be loaded fails each of its frames; a walk of one query is
    localized as one image (the walk adds nothing).
    :func:`ldlloc.batch.ray_run.run_walks_ray` does the same on a Ray cluster."""
    meta = {**(meta or {}), "walk": walk_meta("name", walk, lag)}
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        groups = walk_groups(queries, scene_unknown)
        written = walk_records(writer, [[q.name for q in g] for g in groups.values()]) if resume else [[]] * len(groups)
        for (key, group), records in zip(groups.items(), written):
            job = DatasetWalk(key, group, str(walk_maps(maps_dir, key, scene_unknown)), params, walk, lag, device)
            job.run(lambda rs: write_records(writer, rs, progress), records)
        writer.finish()
        return writer.results


def write_records(writer: ResultsWriter, records: list[QueryResult],
                  progress: Callable[[QueryResult], None] | None = None) -> None:
    """Write ``records`` (in one journal write), then tell ``progress`` of each."""
    writer.extend(records)
    for r in records if progress else []:
        progress(r)


def walk_maps(maps_dir: str | Path, key: str, scene_unknown: bool) -> Path:
    """The maps of a dataset walk: its scene's map, or (``scene_unknown``) its folder of maps."""
    return Path(maps_dir) / (key if scene_unknown else f"{key}.h5")


class DatasetWalk:
    """One walk of a dataset run (a scene's queries in walk order), run in this process or in a Ray
    actor (:mod:`ldlloc.batch.ray_run`): :meth:`run` hands its records on as they are decided."""

    def __init__(self, key: str, queries: list, maps: str, params: LocalizeParams, walk: WalkParams, lag: int,
                 device: str = "cpu"):
        self.key, self.queries, self.maps, self.params, self.walk, self.lag = key, queries, maps, params, walk, lag
        self.device = device

    def failed(self, why: str, written: set[str]) -> list[QueryResult]:
        """The records of the walk's frames not in ``written`` when it cannot go on: failed, with ``why``."""
        return [failed_result(q, self.params, why) for q in self.queries if q.name not in written]

    def run(self, write: Callable[[list[QueryResult]], None], records: list | None = None) -> None:
        """Localize the walk, ``write``-ing each decided block's records: :meth:`batches`."""
        for batch in self.batches(records):
            write(batch)

    def batches(self, records: list | None = None) -> Iterator[list[QueryResult]]:
        """The records of the walk's frames as they are decided (a list per block); ``records``: the
        frames' records already written (a resumed run: it goes on after them, or skips a walk
        written whole). A walk whose maps cannot be loaded fails its frames not yet written."""
        done = 0
        try:
            maps = MapSet.load(self.maps, self.params, self.device, recursive=False)
            whole, state = walk_resume(records, maps, self.lag) if records else (False, None)
            if whole:
                return
            done = state.written if state else 0
            frames = [WalkFrame(q.name, (lambda p=q.image: load_image(p)), None, tilt_bound_for(q, self.params))
                      for q in self.queries[state.start if state else 0:]]
            for block in stream_walk(frames, maps, self.walk, self.lag, state):
                yield [_dataset_record(self.queries[slot.index], slot, self.params, self.key) for slot in block]
                done = block[-1].index + 1
        except LdlError as exc:
            yield [failed_result(q, self.params, str(exc)) for q in self.queries[done:]]


def _dataset_record(q, slot: Slot, params: LocalizeParams, walk: str) -> QueryResult:
    out = slot.out
    if out.loc is None:
        r = failed_result(q, params, out.error or "not localized")
    else:
        r = replace(result_from_localization(q, out.loc), **choice_fields(out))
    r.walk = walk_fields(slot, walk)
    return r


class VideoWalk:
    """One video's walk (:mod:`ldlloc.walk.video`), run in this process or in a Ray actor
    (:mod:`ldlloc.batch.ray_run`): :meth:`batches` hands its records on as they are decided."""

    def __init__(self, video: str | Path, maps: str | Path, params: LocalizeParams, walk: WalkParams,
                 fps: float | None = None, every: int | None = None, lag: int = LAG, device: str = "cpu"):
        self.path, self.key = Path(video), Path(video).stem
        self.maps, self.params, self.walk, self.fps, self.every, self.lag, self.device = \
            maps, params, walk, fps, every, lag, device
        self.queries: list = []  # its frames are known once decoded

    def failed(self, why: str, written: set[str]) -> list[QueryResult]:
        """The records of the frames not written when the walk cannot go on: none (its frames are not
        known without decoding; ``--resume`` goes on from the last written one)."""
        return []

    def batches(self, records: list | None = None, maps: MapSet | None = None,
                progress: Callable[[QueryResult], None] | None = None,
                say: Callable[[str], None] | None = None) -> Iterator[list[QueryResult]]:
        """The records of the kept frames (``fps`` or ``every``) as they are decided, a list per block,
        each named ``<stem>/<frame index>`` with the video as its image and its timestamp in
        ``walk.time``; ``records``: the walk's frames already written, by frame (a resumed run goes on
        after them: the frames before decoded, not localized); ``maps``: loaded already (else read)."""
        info = video_info(self.path)
        check_sampling(info, self.fps, self.every)
        maps = maps if maps is not None else MapSet.load(self.maps, self.params, self.device)
        state = resume_state(records, maps, self.lag) if records else None
        if state is not None and say is not None:
            say(f"resuming: {state.written} frames of {self.key} written, going on from there")
        pairs = islice(decoded_frames(info, self.fps, self.every), state.start if state else 0, None)
        frames = ((WalkFrame(f"{self.key}/{vf.index:06d}", (lambda vf=vf: frame_at(info, vf)), vf.time,
                             self.params.max_tilt_deg), img) for vf, img in pairs)
        record = lambda s: image_frame_record(ImageQuery(info.path, s.out.frame.name), s, self.params,  # noqa: E731
                                              self.key)
        tell = None if progress is None else (lambda i, o: progress(record(Slot(i, o, None, None, False))))

        def at_end(n: int) -> None:
            if n < MIN_FRAMES:
                raise InputError(f"--video {info.path}: {n} frame(s) kept; a walk needs at least {MIN_FRAMES} "
                                 "(lower --every or raise --fps)")

        for block in stream_walk(frames, maps, self.walk, self.lag, state, tell, at_end):
            yield [record(slot) for slot in block]


def run_walk_video(video: str | Path, maps: MapSet, output: str | Path, params: LocalizeParams, walk: WalkParams,
                   fps: float | None = None, every: int | None = None, device: str = "cpu", meta: dict | None = None,
                   say: Callable[[str], None] | None = None, progress: Callable[[QueryResult], None] | None = None,
                   resume: bool = False, any_options: bool = False, lag: int = LAG) -> list[QueryResult]:
    """An equirectangular video localized as one walk (:class:`VideoWalk`), each frame's record written
    once decided (``lag``); ``resume`` goes on from the last written frame. :func:`run_walk_videos` of one."""
    return run_walk_videos([video], maps, output, params, walk, fps, every, device, meta, say, progress, resume,
                           any_options, lag)


def run_walk_videos(videos: list, maps: MapSet, output: str | Path, params: LocalizeParams, walk: WalkParams,
                    fps: float | None = None, every: int | None = None, device: str = "cpu", meta: dict | None = None,
                    say: Callable[[str], None] | None = None, progress: Callable[[QueryResult], None] | None = None,
                    resume: bool = False, any_options: bool = False, lag: int = LAG) -> list[QueryResult]:
    """Equirectangular videos localized in this process, one walk each (:class:`VideoWalk`), in turn,
    into one results file; ``resume`` goes on in each from its last written frame."""
    jobs = [VideoWalk(v, "", params, walk, fps, every, lag, device) for v in videos]
    for job in jobs:
        check_sampling(video_info(job.path), fps, every)  # every video's errors before the first is run
    meta = {**(meta or {}), **video_meta(videos, fps, every), "walk": walk_meta("time", walk, lag)}
    with open_results(output, params, device, meta, resume, any_options, [], say) as writer:
        for job in jobs:
            records = video_records(writer, job.key) if resume else None
            for batch in job.batches(records, maps, progress, say):
                writer.extend(batch)  # one journal write a block: a kill leaves whole blocks
        video_order(writer, [job.key for job in jobs])
        writer.finish()
        return writer.results


def video_order(writer: ResultsWriter, keys: list[str]) -> None:
    """Put a video run's records in the order of its videos (``keys``: their stems), each by frame
    (a resumed or a Ray run writes them as they come)."""
    rank = {k: i for i, k in enumerate(keys)}
    writer.reorder(key=lambda r: (rank.get(r.walk["name"], -1), r.walk["frame"]) if r.walk else (-1, 0))


def video_meta(videos: list, fps: float | None, every: int | None) -> dict:
    """A video run's ``meta``: its video (several: their list), ``fps`` and ``every``."""
    paths = [str(Path(v)) for v in videos]
    return {"video": paths[0] if len(paths) == 1 else paths, "fps": fps, "every": every}


def video_records(writer: ResultsWriter, stem: str) -> list[QueryResult | None]:
    """The records ``writer`` holds of the frames of walk ``stem`` (a video), by frame (None: not written)."""
    mine = {r.walk["frame"]: r for r in writer.light_results if r.walk and r.walk.get("name") == stem}
    return [mine.get(i) for i in range(max(mine, default=-1) + 1)]
