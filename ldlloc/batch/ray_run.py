"""``ldlloc run --ray``: one Ray actor per scene map serves its queries (:func:`run_queries_ray`);
``--images``: actors that hold every map (:func:`run_images_ray`); ``--walk``: one actor per walk
(:func:`run_walks_ray`); ``--video`` (several): one actor per video (:func:`run_video_walks_ray`).

Each :class:`SceneLocalizer` actor reads its scene's map once (the scene not given,
``--scene-unknown``: one actor per scene folder, holding that folder's maps), where it runs (a shared
filesystem on a multi-node cluster), keeps a :class:`~ldlloc.pipeline.Localizer` (on its own GPU
with ``--device cuda``) and localizes the queries sent to it with the plain path's
:func:`ldlloc.batch.run.localize_query`; the driver sends only the query (paths and ground truth).
Actors start as the cluster has room (one CPU each, or ``threads``) and are killed when their
scene is done, which frees their slot for the next scene.

The driver alone writes the results, through the plain path's
:class:`~ldlloc.batch.results.ResultsWriter`, as results arrive: the file never holds a query twice
or loses a finished one, ``resume`` skips the queries it holds, and at the end the records are
put in the plain path's order, so a complete run's file equals the plain run's but for the
timings. Faults: an actor whose process dies is restarted and its unfinished queries re-run
(:data:`ldlmap.batch.ray_cluster.RETRIES` times); a missing or bad map makes each of its queries a
``failed`` record with the reason, as in the plain path; a query whose actor died past its
retries, or that raised anything but a toolkit error, is recorded ``failed`` with the reason.
Ctrl-C cancels the outstanding queries, kills the actors and re-raises, leaving a results file
that ``resume`` completes.
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from typing import Callable

from ldlloc.batch.images import failed_image_result, localize_image_query
from ldlloc.batch.results import ResultsWriter
from ldlloc.batch.run import failed_result, localize_query, open_results, query_key, scene_maps
from ldlloc.batch.which_map import MapSet
from ldlloc.pipeline import LocalizeParams
from ldlloc.record import QueryResult
from ldlloc.walk.localize import WalkParams
from ldlloc.walk.run import (DatasetWalk, VideoWalk, video_meta, video_order, video_records, walk_groups, walk_maps,
                             walk_meta, walk_records, written_whole)
from ldlloc.walk.stream import LAG
from ldlmap.core.cli_common import set_threads
from ldlmap.core.errors import LdlError
from ldlmap.batch.ray_cluster import RETRIES, TaskDone, WorkerInfo, as_completed, check_resources, current_worker, \
    enter_folder, failure_reason, ray_session, stop


class SceneLocalizer:
    """Ray actor: one scene's map, loaded once, and the queries of that scene (``top_maps`` given:
    the maps of the scene's folder and the queries of its scenes, :class:`ldlloc.batch.run.FolderMaps`)."""

    def __init__(self, cwd: str, maps_dir: str, scene: str, params: LocalizeParams, device: str,
                 save_vis: str | None = None, threads: int = 1, top_maps: int | None = None):
        enter_folder(cwd)  # relative paths (maps, images, pictures) as on the driver
        set_threads(threads)
        self.params, self.save_vis = params, save_vis
        self.cache = scene_maps(Path(maps_dir), params, device, top_maps)
        try:
            self.cache.get(scene)  # load now; a map that fails is remembered and fails each query
        except LdlError:
            pass

    def localize(self, q) -> tuple[QueryResult, WorkerInfo]:
        return localize_query(self.cache, q, self.params, self.save_vis), current_worker()


def _label(r: QueryResult) -> str:
    err = "failed" if r.status == "failed" else f"{r.t_error_m:.3f} m {r.r_error_deg:.2f} deg"
    return f"{r.split} {r.scene}: {err}"


def run_queries_ray(queries: list, maps_dir: str | Path, output: str | Path, params: LocalizeParams = LocalizeParams(),
                    device: str = "cpu", resume: bool = False, save_vis: str | Path | None = None,
                    meta: dict | None = None, progress: Callable[[TaskDone], None] | None = None,
                    address: str = "local", threads: int = 1, any_options: bool = False,
                    say: Callable[[str], None] | None = None, top_maps: int | None = None) -> list[QueryResult]:
    """:func:`ldlloc.batch.run.run_queries` on a Ray cluster (``address``: see
    :data:`ldlmap.batch.ray_cluster.ADDRESS_HELP`); ``threads``: CPU threads (and Ray CPUs) per actor, as
    ``--threads`` (0: one per core, one Ray CPU); ``top_maps``: the scene not given (as
    :func:`ldlloc.batch.run.run_queries`)."""
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        return _run_on_ray(writer, queries, maps_dir, params, device, save_vis, progress, address, threads, top_maps)


def _run_on_ray(writer: ResultsWriter, queries: list, maps_dir: str | Path, params: LocalizeParams, device: str,
                save_vis: str | Path | None, progress: Callable[[TaskDone], None] | None, address: str,
                threads: int, top_maps: int | None = None) -> list[QueryResult]:
    """The body of :func:`run_queries_ray`, writing through the open (locked) ``writer``."""
    key = scene_maps(maps_dir, params, device, top_maps).key  # one actor per key: a scene, or a scene folder
    group = lambda q: str(key(q.scene))  # noqa: E731
    done = writer.done()
    todo = [q for q in sorted(queries, key=query_key) if q.name not in done]
    if not todo:  # everything is in the results file already: nothing to start
        writer.finish()
        return writer.results
    remaining = Counter(group(q) for q in todo)
    first = {group(q): q.scene for q in reversed(todo)}  # a scene of each actor's group, to load its maps
    with ray_session(address) as ray:
        actor_cls = ray.remote(SceneLocalizer).options(**check_resources(ray, device, max(1, threads)),
                                                       max_restarts=RETRIES, max_task_retries=RETRIES)
        vis = None if save_vis is None else str(save_vis)
        actors: dict = {}
        refs: dict = {}
        finished: set = set()
        arrived: list[QueryResult] = []  # results not yet in the file
        try:
            for s in remaining:
                actors[s] = actor_cls.remote(os.getcwd(), str(maps_dir), first[s], params, device, vis, threads,
                                             top_maps)
            for q in todo:
                refs[actors[group(q)].localize.remote(q)] = q
            for batch in as_completed(list(refs)):
                for ref, value, exc in batch:
                    q = refs[ref]
                    r, worker = value if exc is None else (failed_result(q, params, failure_reason(exc)), None)
                    finished.add(ref)
                    arrived.append(r)
                    remaining[group(q)] -= 1
                    if remaining[group(q)] == 0:  # scene done: free its slot for the next scene's actor
                        ray.kill(actors.pop(group(q)))
                    if progress:
                        progress(TaskDone(_label(r), worker, len(finished), len(todo)))
                writer.extend(arrived)
                arrived = []
        except BaseException:  # Ctrl-C (KeyboardInterrupt) included: keep what arrived, stop the rest
            if arrived:
                writer.extend(arrived)
            stop([r for r in refs if r not in finished], list(actors.values()))
            raise
    rank = {q.name: i for i, q in enumerate(todo)}  # resumed records first, as they were; then the plain order
    writer.reorder(key=lambda r: rank.get(r.name, -1))
    writer.finish()  # every query done; flushes the sorted results
    return writer.results


# ------------------------------------------------------------------ --images: actors holding all maps


class ImagesLocalizer:
    """Ray actor of ``run --images``: every map of the run (a panorama may be in any of them, and
    the which-map ranking searches them all), loaded once, and the panoramas sent to it."""

    def __init__(self, cwd: str, maps: str, params: LocalizeParams, device: str, top_maps: int,
                 save_vis: str | None = None, threads: int = 1):
        enter_folder(cwd)
        set_threads(threads)
        self.params, self.top_maps, self.save_vis = params, top_maps, save_vis
        self.maps = MapSet.load(maps, params, device)

    def localize(self, q) -> tuple[QueryResult, WorkerInfo]:
        return localize_image_query(self.maps, q, self.params, self.top_maps, self.save_vis), current_worker()


def run_images_ray(queries: list, maps: str | Path, output: str | Path, params: LocalizeParams, device: str = "cpu",
                   resume: bool = False, save_vis: str | Path | None = None, meta: dict | None = None,
                   top_maps: int = 3, progress: Callable[[TaskDone], None] | None = None, address: str = "local",
                   threads: int = 1, any_options: bool = False,
                   say: Callable[[str], None] | None = None) -> list[QueryResult]:
    """:func:`ldlloc.batch.images.run_images` on a Ray cluster: as many :class:`ImagesLocalizer`
    actors as the cluster has slots of ``threads`` CPUs (one GPU each with cuda), at most one per
    panorama, each holding all the maps (so any actor can take any panorama: the panoramas are
    dealt out in turn). Results are written by the driver as they arrive; faults and Ctrl-C as
    :func:`run_queries_ray`."""
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        done = writer.done()
        todo = [q for q in sorted(queries, key=lambda q: q.name) if q.name not in done]
        if not todo:
            writer.finish()
            return writer.results
        with ray_session(address) as ray:
            need = check_resources(ray, device, max(1, threads))
            have = ray.cluster_resources()
            slots = int(have.get("CPU", 1) // need["num_cpus"])
            if "num_gpus" in need:
                slots = min(slots, int(have.get("GPU", 1)))
            actor_cls = ray.remote(ImagesLocalizer).options(**need, max_restarts=RETRIES, max_task_retries=RETRIES)
            vis = None if save_vis is None else str(save_vis)
            actors = [actor_cls.remote(os.getcwd(), str(maps), params, device, top_maps, vis, threads)
                      for _ in range(max(1, min(slots, len(todo))))]
            refs = {actors[i % len(actors)].localize.remote(q): q for i, q in enumerate(todo)}
            finished: set = set()
            try:
                for batch in as_completed(list(refs)):
                    arrived = []
                    for ref, value, exc in batch:
                        q = refs[ref]
                        r, worker = (value if exc is None
                                     else (failed_image_result(q, params, failure_reason(exc), 0.0), None))
                        finished.add(ref)
                        arrived.append(r)
                        if progress:
                            progress(TaskDone(f"{r.name}: {r.status}", worker, len(finished), len(todo)))
                    writer.extend(arrived)
            except BaseException:
                stop([r for r in refs if r not in finished], actors)
                raise
            for a in actors:
                ray.kill(a)
        rank = {q.name: i for i, q in enumerate(todo)}
        writer.reorder(key=lambda r: rank.get(r.name, -1))
        writer.finish()  # every query done (as run_images); flushes the sorted results
        return writer.results


# ------------------------------------------------------------------ --walk: one actor per walk


WALK_STEP = 8  # frames' records an actor hands back per call (the driver writes them, then asks for more)


class WalkLocalizer:
    """Ray actor of ``run --root ... --walk``: one walk (:class:`ldlloc.walk.run.DatasetWalk`), never
    split, localized as a stream; :meth:`step` hands back the records decided since the last call.
    Restarted after its process died, it starts again from the records given at its start (those
    it hands back again are the same records: the driver drops them)."""

    def __init__(self, cwd: str, job: DatasetWalk, records: list, threads: int = 1):
        enter_folder(cwd)
        set_threads(threads)
        self.batches = job.batches(records)

    def step(self, n: int = WALK_STEP) -> tuple[list[QueryResult], bool, WorkerInfo]:
        """At least ``n`` records (fewer at the walk's end), and whether the walk is done."""
        got: list[QueryResult] = []
        for batch in self.batches:
            got += batch
            if len(got) >= n:
                return got, False, current_worker()
        return got, True, current_worker()


def run_walks_ray(queries: list, maps_dir: str | Path, output: str | Path, params: LocalizeParams, walk: WalkParams,
                  device: str = "cpu", resume: bool = False, meta: dict | None = None, scene_unknown: bool = False,
                  progress: Callable[[TaskDone], None] | None = None, address: str = "local", threads: int = 1,
                  any_options: bool = False, say: Callable[[str], None] | None = None,
                  lag: int = LAG) -> list[QueryResult]:
    """:func:`ldlloc.walk.run.run_walk_queries` on a Ray cluster: one :class:`WalkLocalizer` actor per
    walk (as many at once as the cluster has slots of ``threads`` CPUs), whose records the driver
    writes as they come; at the end the records are put in the plain run's order, so the file
    equals the plain run's but for the timings. A walk whose actor died past its retries (or
    raised) fails its frames not yet written; Ctrl-C as :func:`run_queries_ray`."""
    meta = {**(meta or {}), "walk": walk_meta("name", walk, lag)}
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        jobs = []
        groups = walk_groups(queries, scene_unknown)
        written = walk_records(writer, [[q.name for q in g] for g in groups.values()]) if resume else [[]] * len(groups)
        for (key, group), records in zip(groups.items(), written):  # light records: what resuming reads
            if not written_whole(records):
                jobs.append((DatasetWalk(key, group, str(walk_maps(maps_dir, key, scene_unknown)), params, walk, lag,
                                         device), records))
        if jobs:
            with ray_session(address) as ray:
                _walks_on_ray(ray, writer, jobs, params, device, progress, threads)
        order = {q.name: i for i, q in enumerate(q for g in groups.values() for q in g)}
        writer.reorder(key=lambda r: order.get(r.name, -1))
        writer.finish()
        return writer.results


def _walks_on_ray(ray, writer: ResultsWriter, jobs: list, params: LocalizeParams, device: str,
                  progress: Callable[[TaskDone], None] | None, threads: int) -> list[str]:
    """The body of :func:`run_walks_ray`: start the actors, write their records as they come. Returns
    what stopped the walks whose actor died past its retries and that left no record of it (a video's)."""
    stopped: list[str] = []
    actor_cls = ray.remote(WalkLocalizer).options(**check_resources(ray, device, max(1, threads)),
                                                  max_restarts=RETRIES, max_task_retries=RETRIES)
    total = sum(len(job.queries) for job, _ in jobs)
    written: set[str] = set()  # names written by this run (an actor restarted hands some back again)
    actors = {job.key: actor_cls.remote(os.getcwd(), job, records, threads) for job, records in jobs}
    refs = {actors[job.key].step.remote(): job for job, _ in jobs}
    try:
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=0.5)
            for ref in ready:
                job = refs.pop(ref)
                try:
                    got, done, worker = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    why = failure_reason(exc)
                    got, done, worker = job.failed(why, written), True, None
                    if not got:  # nothing to record it by (a video's frames not decoded): said at the end
                        stopped.append(f"the walk of {job.key} stopped ({why})")
                new = [r for r in got if r.name not in written]
                writer.extend(new)
                written.update(r.name for r in new)
                if done:
                    ray.kill(actors.pop(job.key))
                else:
                    refs[actors[job.key].step.remote()] = job
                if progress and new:
                    progress(TaskDone(f"{job.key}: frame {new[-1].walk['frame'] if new[-1].walk else '?'}",
                                      worker, len(written), total))
    except BaseException:  # Ctrl-C included: what arrived is written; stop the rest
        stop(list(refs), list(actors.values()))
        raise
    return stopped


def run_video_walks_ray(videos: list, maps: str | Path, output: str | Path, params: LocalizeParams, walk: WalkParams,
                        fps: float | None = None, every: int | None = None, device: str = "cpu", resume: bool = False,
                        meta: dict | None = None, progress: Callable[[TaskDone], None] | None = None,
                        address: str = "local", threads: int = 1, any_options: bool = False,
                        say: Callable[[str], None] | None = None, lag: int = LAG) -> list[QueryResult]:
    """:func:`ldlloc.walk.run.run_walk_videos` on a Ray cluster: one :class:`WalkLocalizer` actor per video
    (:class:`ldlloc.walk.run.VideoWalk`, never split), its records written by the driver as they come and
    put in the plain run's order at the end. A walk whose actor died past its retries leaves its frames
    not yet written out, and the run is not finished: a one-line error after the other walks end
    (``--resume`` goes on from the last written frame)."""
    meta = {**(meta or {}), **video_meta(videos, fps, every), "walk": walk_meta("time", walk, lag)}
    with open_results(output, params, device, meta, resume, any_options, [], say) as writer:
        jobs = [(VideoWalk(v, str(maps), params, walk, fps, every, lag, device),
                 video_records(writer, Path(v).stem) if resume else None) for v in videos]
        with ray_session(address) as ray:
            stopped = _walks_on_ray(ray, writer, jobs, params, device, progress, threads)
        if stopped:
            raise LdlError(f"{'; '.join(stopped)}: the records written are kept (continue with --resume)")
        video_order(writer, [job.key for job, _ in jobs])
        writer.finish()
        return writer.results
