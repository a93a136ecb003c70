"""``ldlloc run``: a dataset's queries (:func:`run_dataset`), your own panoramas (:func:`run_images`,
``--images``), a walk (``--walk``) or a video (:func:`run_video`, ``--video``) against maps, with a
results file and the tables of :mod:`.show`."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from ldlloc.batch.images import (default_images_output, find_images, image_run_meta, picture_path as image_picture,
                                 refuse_other_folders_results, run_images as localize_images)
from ldlloc.batch.results import check_results_path, refuse_replacing_results, results_outputs
from ldlloc.batch.run import (default_results_path, missing_maps_message, picture_path, run_queries,
                              scenes_without_maps)
from ldlloc.batch.which_map import TOP_MAPS, MapSet, map_files
from ldlloc.commands.options import localize_params, path_option, top_maps_or_default
from ldlloc.commands.show import print_run, say, shown
from ldlloc.pipeline import LocalizeParams
from ldlloc.walk.localize import VIDEO, WalkParams
from ldlloc.walk.options import check_walk_options
from ldlloc.walk.run import run_walk_images, run_walk_queries, run_walk_videos, walk_photos
from ldlloc.walk.video import find_videos, video_info
from ldlloc.walk.stream import LAG
from ldlmap.core.cli_common import (check_device, check_threads, console, dataset_label, open_dataset_root,
                                    refuse_map_level, set_threads)
from ldlmap.core.errors import InputError, refuse_overwriting_inputs
from ldlmap.core.pictures import refuse_replacing_pictures
from ldlmap.core.lazy import lazy_module
from ldlmap.datasets.base import check_map_level

ray_run = lazy_module("ldlloc.batch.ray_run")  # the Ray plumbing loads only for --ray (tests/test_ray.py checks it)
ray_cluster = lazy_module("ldlmap.batch.ray_cluster")


@dataclass
class RunOptions:
    """The options of a run that every kind of run reads (the command's own: :func:`ldlloc.cli.run`)."""

    maps: Path | None
    output: Path | None
    params: LocalizeParams
    top_maps: int | None
    device: str
    resume: bool
    any_options: bool
    save_vis: Path | None
    weights: Path | None
    threads: int
    ray: str | None
    overwrite: bool
    lag: int = LAG  # --walk, --video: frames a frame is decided after (ldlloc/walk/stream.py)


def run(images: str | None, root: str | None, dataset: str | None, map_level: str | None, split: list[str] | None,
        scene: str | None, scene_unknown: bool, maps: str | None, output: Path | None, method: dict,
        top_maps: int | None, device: str, resume: bool, resume_any_options: bool, save_vis: str | None,
        overwrite: bool, threads: int, ray: str | None, walk: bool, order: str | None, video: list[str] | None,
        fps: float | None, every: int | None, lag: int | None = None) -> None:
    """The command (its options: :func:`ldlloc.cli.run`): checks the options that go together, then
    runs the video, the images or the dataset. ``method``: :func:`localize_params`' arguments."""
    params = localize_params(**method)
    check_threads(threads)
    root_path, maps_path = path_option(root, "--root"), path_option(maps, "--maps")
    save_vis_path = path_option(save_vis, "--save-vis")
    opts = RunOptions(maps_path, output, params, top_maps, device, resume, resume_any_options, save_vis_path,
                      method["weights"], threads, ray, overwrite, LAG if lag is None else lag)
    if output is not None:
        check_results_path(output)
    if resume_any_options and not resume:
        raise InputError("--resume-any-options goes with --resume")
    dataset_options = {"--root": root_path, "--dataset": dataset, "--split": split, "--scene": scene,
                       "--map-level": map_level, "--scene-unknown": scene_unknown}
    video = video or None  # typer gives an empty list for a repeatable option not given
    if walk or video is not None or any(v is not None for v in (order, fps, every, lag)):
        check_walk_options(walk, order, images, ray, save_vis_path, video, fps, every, resume, opts.maps,
                           dataset_options, lag)
    if video is not None:
        return run_video(video, opts, fps, every)
    if images is not None:
        given = [o for o, v in dataset_options.items() if v]
        if given:
            raise InputError(f"--images runs without a dataset: drop {', '.join(given)}")
        return run_images(images, opts, (order or "name") if walk else None)
    run_dataset(root_path, dataset, map_level, split, scene, scene_unknown, opts, walk)


def run_dataset(root: Path | None, dataset: str | None, map_level: str | None, split: list[str] | None,
                scene: str | None, scene_unknown: bool, o: RunOptions, walk: bool) -> None:
    """`run --root`: a dataset's queries, each against its scene's map (or its folder's maps)."""
    top_maps = dataset_top_maps(o.top_maps, scene_unknown, map_level)
    level = {"map_level": map_level} if map_level is not None else {}  # only when given
    ds = open_dataset_root(root, dataset, "ldlloc run --root ROOT", **level)
    root, kind, label = Path(ds.root), ds.kind, dataset_label(ds)
    refuse_map_level(map_level, kind, label, root)
    queries = ds.queries(split or None, scene)
    if not queries:
        raise InputError(f"no queries in {root} for split(s) {', '.join(split or ['all'])}")
    output = o.output or default_results_path(label, kind, root, split, scene, getattr(ds, "map_level", None))
    maps_given, maps = o.maps is not None, o.maps or Path(root) / "maps"
    refuse_replacing_run_inputs(queries, maps, output, o.save_vis, o.weights, root, o.overwrite)
    refuse_replacing_results(output, o.overwrite, o.resume)
    missing = scenes_without_maps(queries, maps, scene_unknown)
    if len(missing) == len({q.scene for q in queries}):  # nothing could run: say how to build the maps
        extra = (f" --dataset {dataset}" if dataset else "") + (f" --map-level {map_level}" if map_level else "")
        raise InputError(missing_maps_message(missing, maps, root, maps_given, extra))
    check_device(o.device, local=o.ray is None)
    set_threads(o.threads)
    meta = {"dataset": label, "root": str(root), "splits": split or "all", "maps": str(maps), **level,
            "scene_unknown": scene_unknown, **({"top_maps": top_maps} if scene_unknown else {})}
    if missing:
        console.print(f"[yellow]warning:[/] no map for {len(missing)} scene(s) in {maps} ({', '.join(missing[:5])}"
                      f"{', ...' if len(missing) > 5 else ''}): their queries fail; `ldlmap prepare` builds them",
                      soft_wrap=True)
    args = (queries, maps, output, o.params, o.device, o.resume)
    opts = {"meta": meta, "any_options": o.any_options, "say": say, "top_maps": top_maps}
    walk_params = WalkParams(top_maps=top_maps or TOP_MAPS)
    if walk and o.ray is not None:  # one Ray actor per walk (ldlloc/batch/ray_run.py)
        with ray_cluster.ThroughputBar(console, "localizing") as bar:
            results = ray_run.run_walks_ray(queries, maps, output, o.params, walk_params, o.device, o.resume, meta,
                                            scene_unknown, progress=bar, address=o.ray, threads=o.threads,
                                            any_options=o.any_options, say=say, lag=o.lag)
    elif walk:  # one walk per scene (ldlloc/walk/run.py)
        with console.status(f"localizing {len(queries)} queries as walks"):
            results = run_walk_queries(queries, maps, output, o.params, walk_params, o.device, o.resume, meta,
                                       scene_unknown, any_options=o.any_options, say=say, lag=o.lag)
    elif o.ray is not None:  # one Ray actor per scene map (ldlloc/batch/ray_run.py)
        with ray_cluster.ThroughputBar(console, "localizing") as bar:
            results = ray_run.run_queries_ray(*args, o.save_vis, **opts, progress=bar, address=o.ray, threads=o.threads)
    else:
        with _progress_bar() as bar:
            task = bar.add_task("localizing", total=len(queries))

            def progress(r) -> None:
                err = "failed" if r.status == "failed" else f"{r.t_error_m:.3f} m {r.r_error_deg:.2f} deg"
                bar.update(task, advance=1, description=f"{r.split} {r.scene}: {err}")

            results = run_queries(*args, o.save_vis, **opts, progress=progress)
    print_run(results, label, output, o.params.max_tilt_deg)


def _progress_bar() -> Progress:
    """The bar of a run: what it does, a bar, done / total, the time left (gone when done)."""
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                    console=console, transient=True)


def dataset_top_maps(top_maps: int | None, scene_unknown: bool, map_level: str | None) -> int | None:
    """A dataset run's --top-maps (only with --scene-unknown: its default and range) after its
    --map-level is checked."""
    if top_maps is not None and not scene_unknown:
        raise InputError("--top-maps goes with --images or --scene-unknown")
    if scene_unknown:
        top_maps = top_maps_or_default(top_maps)
    if map_level is not None:
        check_map_level(map_level, "--map-level")
    return top_maps


def run_images(images: str, o: RunOptions, walk_order: str | None = None) -> None:
    """`run --images`: find the panoramas and the maps, localize, print the counts (ldlloc/batch/images.py)."""
    if o.maps is None:
        raise InputError("--images needs --maps: a map (.h5) or a folder of maps")
    top_maps = top_maps_or_default(o.top_maps)
    queries = find_images(images, exclude=[o.save_vis] if o.save_vis is not None else [], warn=say)
    files, _ = map_files(o.maps)
    output = o.output
    if output is None:
        output = default_images_output(images)
        if not o.resume:  # --resume compares the folders itself
            refuse_other_folders_results(output, images)
    pictures = [image_picture(o.save_vis, q) for q in queries] if o.save_vis is not None else []
    refuse_overwriting_inputs([o.weights, *files, *(q.image for q in queries)], [*results_outputs(output), *pictures])
    refuse_replacing_pictures(pictures, o.overwrite, "--save-vis")
    refuse_replacing_results(output, o.overwrite, o.resume)
    check_device(o.device, local=o.ray is None)
    set_threads(o.threads)
    meta = image_run_meta(images, o.maps, top_maps)
    opts = {"meta": meta, "top_maps": top_maps, "any_options": o.any_options, "say": say}
    if o.ray is not None:  # one Ray actor per CPU slot, each holding every map (ldlloc/batch/ray_run.py)
        with console.status(f"checking {len(files)} map(s)"):  # the actors load them; bad maps are said here
            _warn_left_out(MapSet.load(o.maps, o.params, "cpu"))
        with ray_cluster.ThroughputBar(console, "localizing") as bar:
            results = ray_run.run_images_ray(queries, o.maps, output, o.params, o.device, o.resume, o.save_vis, **opts,
                                     progress=bar, address=o.ray, threads=o.threads)
    elif walk_order is not None:  # --walk: the panoramas as one walk (ldlloc/walk/run.py)
        walk_photos(queries, walk_order)  # its errors before the maps are read
        mapset = _warn_left_out(MapSet.load(o.maps, o.params, o.device))
        with console.status(f"localizing {len(queries)} panoramas as one walk"):
            results = run_walk_images(queries, mapset, output, o.params, WalkParams(top_maps=top_maps), walk_order,
                                      o.device, o.resume, meta, any_options=o.any_options, say=say, lag=o.lag)
    else:
        results = _localize_images_with_bar(queries, files, output, o, opts)
    print_run(results, "images", output, o.params.max_tilt_deg)


def _localize_images_with_bar(queries: list, files: list, output: Path, o: RunOptions, opts: dict) -> list:
    """`run --images` in this process: the maps loaded, then the panoramas localized, under one bar."""
    with _progress_bar() as bar:
        task = bar.add_task(f"loading {len(files)} map(s)", total=len(files))
        mapset = MapSet.load(o.maps, o.params, o.device,
                             progress=lambda f: bar.update(task, advance=1, description=f"loading {f.name}"))
        _warn_left_out(mapset)
        bar.update(task, total=len(queries), completed=0, description="localizing")

        def progress(r) -> None:
            bar.update(task, advance=1, description=f"{shown(r.name)}: {r.status}" + ("" if r.status == "failed"
                                                                                      else f" in {r.scene}"))

        return localize_images(queries, mapset, output, o.params, o.device, o.resume, o.save_vis, **opts,
                               progress=progress)


def _warn_left_out(mapset: MapSet) -> MapSet:
    """``mapset`` after a warning for each map file it left out (not a map, unreadable)."""
    for f, why in mapset.skipped:
        say(f"[yellow]warning:[/] {f} left out: {why}")
    return mapset


def run_video(video: list[str], o: RunOptions, fps: float | None, every: int | None) -> None:
    """`run --video`: each video as one tracked walk against the maps (ldlloc/walk/run.py), in this
    process one after the other, or with --ray one actor each (ldlloc/batch/ray_run.py)."""
    videos = find_videos(video, warn=say)
    top_maps = top_maps_or_default(o.top_maps)
    files, _ = map_files(o.maps)
    output = o.output or Path("results") / (f"video_{videos[0].stem}.json" if len(videos) == 1 else "videos.json")
    refuse_overwriting_inputs([*videos, *files], results_outputs(output))
    refuse_replacing_results(output, o.overwrite, o.resume)
    for v in videos:  # every video's one-line error before any work
        video_info(v)
    check_device(o.device, local=o.ray is None)
    set_threads(o.threads)
    meta = {"dataset": "video", "maps": str(o.maps), "top_maps": top_maps}
    walk = replace(VIDEO, top_maps=top_maps)
    if o.ray is not None:
        with console.status(f"checking {len(files)} map(s)"):  # the actors load them; bad maps are said here
            _warn_left_out(MapSet.load(o.maps, o.params, "cpu"))
        with console.status(f"localizing {len(videos)} videos, one walk each, on Ray"):
            results = ray_run.run_video_walks_ray(videos, o.maps, output, o.params, walk, fps, every, o.device,
                                                  o.resume, meta, address=o.ray, threads=o.threads,
                                                  any_options=o.any_options, say=say, lag=o.lag)
    else:
        mapset = _warn_left_out(MapSet.load(o.maps, o.params, o.device))
        what = videos[0].name if len(videos) == 1 else f"{len(videos)} videos"
        with console.status(f"localizing {what}, one walk each"):
            results = run_walk_videos(videos, mapset, output, o.params, walk, fps, every, o.device, meta=meta, say=say,
                                      resume=o.resume, any_options=o.any_options, lag=o.lag)
    print_run(results, "video", output, o.params.max_tilt_deg)


def refuse_replacing_run_inputs(queries: list, maps: Path, output: Path, save_vis: Path | None,
                                weights: Path | None, root: Path, overwrite: bool) -> None:
    """One line, before any work, when the results or a picture would replace a panorama, a pose file,
    a map or a dataset manifest (``dataset.json`` of `ldlmap synth`, ZInD's ``zind_data.json``) of the run,
    or a picture a file that is not one of ldlloc's (unless ``overwrite``)."""
    manifests = [root / "dataset.json", *root.glob("*/zind_data.json"), *root.glob("zind_data.json")]
    inputs = [p for p in (weights, *{maps / f"{q.scene}.h5" for q in queries}, *{q.pose_file for q in queries},
                          *(q.image for q in queries), *manifests) if p is not None]
    pictures = [picture_path(save_vis, q) for q in queries] if save_vis is not None else []
    refuse_overwriting_inputs(inputs, [*results_outputs(output), *pictures])
    refuse_replacing_pictures(pictures, overwrite, "--save-vis")
