"""Walk runs: ``ldlloc run --images ... --walk`` and ``ldlloc run --root ... --walk``.

A walk's frames are localized together (:func:`ldlloc.walk.localize.localize_walk`) and its
records written once the walk is decided, all at once (one write per walk, not per frame);
``--resume`` skips the walks whose frames are all in the results file and runs the others again
whole. Each record is the single-image run's record (the same fields, the final pose) with
``walk``: its place in the walk and the image's own judgement (:func:`walk_fields`).

Dataset runs: one walk per scene (``--scene-unknown``: per folder of maps, a ZInD floor), its
queries in capture order (:func:`walk_order`: ZInD's panorama number).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Callable

from ldlmap.core.errors import InputError, LdlError
from ldlmap.io.imagefile import image_header_size
from ldlloc.record import QueryResult
from ldlloc.batch.images import ImageQuery, failed_image_result, image_result
from ldlloc.batch.run import failed_result, open_results, result_from_localization, tilt_bound_for
from ldlloc.batch.which_map import MapSet
from ldlloc.pipeline import LocalizeParams, load_image
from ldlloc.walk.localize import MIN_FRAMES, FrameOutcome, WalkFrame, WalkParams, localize_walk
from ldlloc.walk.order import natural_key, ordered
from ldlloc.walk.video import check_sampling, decoded_frames, frame_at, video_info


def walk_fields(out: FrameOutcome, walk: str, index: int) -> dict:
    """A frame's ``walk`` record: the walk's name, the frame's index and time, whether the walk
    decided it, the image's own verdict and confidence, the path margin (nats) and tracking."""
    m = out.walk_margin
    return {"name": walk, "frame": index, "time": out.frame.time, "walk_decided": bool(out.walk_decided),
            "single_verdict": out.single_verdict, "single_confidence": out.single_confidence,
            "margin": None if m is None else (round(m, 4) if m != float("inf") else "inf"), "tracked": out.tracked,
            "single_pose": None if out.single_pose is None else {"R": out.single_pose[0].tolist(),
                                                                  "t": out.single_pose[1].tolist()}}


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
                    say: Callable[[str], None] | None = None, name: str = "walk") -> list[QueryResult]:
    """Localize ``queries`` (:class:`ldlloc.batch.images.ImageQuery`) as one walk in ``order``
    (name | time) against ``maps`` and write their records. ``progress``: after each frame's own
    localization (its single-image record)."""
    queries, times = walk_photos(queries, order)
    meta = {**(meta or {}), "walk": {"order": order, "motion": vars(walk.motion), "track": walk.track}}
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        if resume and {q.name for q in queries} <= writer.done():
            writer.finish()
            return writer.results
        frames = [WalkFrame(q.name, (lambda p=q.image: load_image(p)), t, params.max_tilt_deg)
                  for q, t in zip(queries, times)]
        tell = None if progress is None else (lambda i, o: progress(_image_record(queries[i], o, params, name, i)))
        outs = localize_walk(frames, maps, walk, tell)
        writer.extend([_image_record(q, o, params, name, i) for i, (q, o) in enumerate(zip(queries, outs))])
        writer.finish()
        return writer.results


def _image_record(q, out: FrameOutcome, params: LocalizeParams, walk: str, index: int) -> QueryResult:
    """An image frame's record (before the walk is decided: its single-image record, for progress)."""
    if out.loc is None:
        r = failed_image_result(q, params, out.error or "not localized", 0.0)
    else:
        r = replace(image_result(q, out.loc, out.choice), **choice_fields(out), scene=out.entry.scene)
    r.walk = walk_fields(out, walk, index)
    return r


def walk_order(q) -> tuple:
    """A dataset query's place in its walk: the natural order of its file name's stem (ZInD's
    ``pano_<number>``: capture order), then its name."""
    return natural_key(Path(q.name).name), q.name


def walk_groups(queries: list, scene_unknown: bool) -> dict[str, list]:
    """A dataset run's walks: one per scene (``scene_unknown``: per folder of scenes), in walk order."""
    groups: dict[str, list] = {}
    for q in sorted(queries, key=lambda q: (q.scene, walk_order(q))):
        key = str(Path(q.scene).parent) if scene_unknown else q.scene
        groups.setdefault(key, []).append(q)
    return {k: sorted(v, key=walk_order) for k, v in sorted(groups.items())}


def run_walk_queries(queries: list, maps_dir: str | Path, output: str | Path, params: LocalizeParams, walk: WalkParams,
                     device: str = "cpu", resume: bool = False, meta: dict | None = None, scene_unknown: bool = False,
                     progress: Callable[[QueryResult], None] | None = None, any_options: bool = False,
                     say: Callable[[str], None] | None = None) -> list[QueryResult]:
    """Dataset queries (with ground truth) localized walk by walk (:func:`walk_groups`): against
    their scene's map, or (``scene_unknown``) the maps of its folder. A walk whose maps cannot be
    loaded fails each of its frames; a walk of one query is localized as one image (the walk adds nothing)."""
    meta = {**(meta or {}), "walk": {"order": "name", "motion": vars(walk.motion), "track": walk.track}}
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        done = writer.done()
        for key, group in walk_groups(queries, scene_unknown).items():
            if resume and {q.name for q in group} <= done:
                continue
            where = Path(maps_dir) / (key if scene_unknown else f"{key}.h5")
            try:
                maps = MapSet.load(where, params, device, recursive=False)
                frames = [WalkFrame(q.name, (lambda p=q.image: load_image(p)), None, tilt_bound_for(q, params))
                          for q in group]
                outs = localize_walk(frames, maps, walk)
            except LdlError as exc:
                writer.extend([failed_result(q, params, str(exc)) for q in group])
                continue
            recs = [_dataset_record(q, o, params, key, i) for i, (q, o) in enumerate(zip(group, outs))]
            writer.extend(recs)
            for r in recs if progress else []:
                progress(r)
        writer.finish()
        return writer.results


def _dataset_record(q, out: FrameOutcome, params: LocalizeParams, walk: str, index: int) -> QueryResult:
    if out.loc is None:
        r = failed_result(q, params, out.error or "not localized")
    else:
        r = replace(result_from_localization(q, out.loc), **choice_fields(out))
    r.walk = walk_fields(out, walk, index)
    return r


def run_walk_video(video: str | Path, maps: MapSet, output: str | Path, params: LocalizeParams, walk: WalkParams,
                   fps: float | None = None, every: int | None = None, device: str = "cpu", meta: dict | None = None,
                   say: Callable[[str], None] | None = None,
                   progress: Callable[[QueryResult], None] | None = None) -> list[QueryResult]:
    """An equirectangular video localized as one walk (:mod:`ldlloc.walk.video`), its kept frames
    decoded in order (``fps`` or ``every``), each record named ``<stem>/<frame index>`` with the
    video as its image and its timestamp in ``walk.time``. The records are written once the walk
    is decided (a rerun localizes the video again)."""
    info = video_info(video)
    check_sampling(info, fps, every)
    stem = info.path.stem
    meta = {**(meta or {}), "video": str(info.path), "fps": fps, "every": every,
            "walk": {"order": "time", "motion": vars(walk.motion), "track": walk.track}}
    pairs = ((WalkFrame(f"{stem}/{vf.index:06d}", (lambda vf=vf: frame_at(info, vf)), vf.time, params.max_tilt_deg),
              img) for vf, img in decoded_frames(info, fps, every))
    queries: list = []
    tell = None if progress is None else (lambda i, o: progress(_image_record(queries[i], o, params, stem, i)))

    def frames():
        for fr, img in pairs:
            queries.append(ImageQuery(info.path, fr.name))
            yield fr, img

    outs = localize_walk(frames(), maps, walk, tell)
    if len(outs) < MIN_FRAMES:
        raise InputError(f"--video {info.path}: {len(outs)} frame(s) kept; a walk needs at least {MIN_FRAMES} "
                         "(lower --every or raise --fps)")
    with open_results(output, params, device, meta, False, False, queries, say) as writer:
        writer.extend([_image_record(q, o, params, stem, i) for i, (q, o) in enumerate(zip(queries, outs))])
        writer.finish()
        return writer.results
