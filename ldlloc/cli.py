"""``ldlloc``: the online side of the LDL toolkit (localize panoramas against LDL maps)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ldlmap.core.cli_common import (DATASET_HELP, check_device, check_range, check_threads, console, dataset_label,
                                    import_heavy, make_app, open_dataset_root, ray_option, refuse_map_level,
                                    set_threads, threads_option)

app = make_app("ldlloc", "Localize panoramas against LDL maps with line distance functions.")


# Commands are added below, one function each. Keep each one short: parse, call, print.

# Options shared by `localize` and `run` (method parameters, device, threads).
DEVICE = typer.Option("cpu", "--device", help="cpu | cuda.")
WALK = typer.Option(False, "--walk", help="The panoramas are one walk (a capture tour): localize them together, "
                    "choosing the most likely path (ldlloc/walk/); with --root, one walk per scene (--scene-unknown: "
                    "per folder of maps), in capture order (ZInD: the panorama number).")
ORDER = typer.Option(None, "--order", help="--images --walk: name (natural file-name order, the default) | time "
                     "(EXIF capture time).")
VIDEO = typer.Option(None, "--video", help="An equirectangular video (mp4, mov, ...) localized as one walk, tracked "
                     "frame to frame (needs --maps; ldlloc/walk/video.py).")
FPS = typer.Option(None, "--fps", help="--video: frames a second to localize (at most the video's rate; default: "
                   "every frame).")
EVERY = typer.Option(None, "--every", metavar="N", help="--video: every N-th frame.")
TOP_K = typer.Option(20, "--top-k", help="K poses kept by the search for refinement.")
LOSS = typer.Option("inlier", "--loss", help="inlier (paper) | l1 | l2 | huber | median.")
NO_DECOMPOSE = typer.Option(False, "--no-decompose", help="Do not decompose the distance functions.")
NO_REFINE = typer.Option(False, "--no-refine", help="Stop after pose search (= --refine none).")
REFINE = typer.Option("auto", "--refine", help="auto (features when the map has them, else geometric) | features | "
                      "geometric (lines alone) | both (features, then a geometric polish) | none.")
PRIVACY = typer.Option(False, "--privacy", help="Privacy mode: refine only with features near principal lines.")
FEATURES = typer.Option(None, "--features", help="Feature backend (must match the map's).")
WEIGHTS = typer.Option(None, "--weights", help="SuperPoint checkpoint.")
QUERY_FRAME = typer.Option("map", "--query-frame", help="Where query features are extracted: map (the panorama "
                           "rotated into the map's frame by the best candidate rotation, upright like the map's views) "
                           "| image (as taken).")
MAX_TILT = typer.Option(None, "--max-tilt", metavar="DEG",
                        help="Upright prior: keep candidate rotations whose camera up axis is within DEG degrees "
                             "of the world's up (0 < DEG <= 180; 180: free rotation, the paper's). `run` uses "
                             "10 by default for datasets whose panoramas are upright (zind).")


SPLIT_HELP = ("Split(s) to run (repeatable; default all those the dataset holds): OmniScenes robot | handheld | "
              "extreme | change_robot | change_handheld; synthetic (`ldlmap synth`) the same and extreme_gamma | "
              "extreme_intensity | extreme_white_balance; Stanford 2D-3D-S area_1 | area_2 | area_3 | area_4 | area_5a | "
              "area_5b | area_6; ZInD its home folders (000, 001, ...).")
MAX_TOP_K = 1000  # --top-k: each kept pose is refined; more than this is a typo, not a method


def _params(top_k: int, loss: str, no_decompose: bool, no_refine: bool, privacy: bool,
            features: Optional[str], weights: Optional[Path], max_tilt: Optional[float] = None,
            refine: str = "auto", query_frame: str = "map"):
    from ldlloc.search.ldf import LOSS_KINDS
    from ldlloc.pipeline import LocalizeParams
    from ldlloc.search.pose_search import SearchParams
    from ldlmap.core.errors import InputError

    if loss not in LOSS_KINDS:
        raise InputError(f"unknown loss {loss!r}; valid: {', '.join(LOSS_KINDS)}")
    check_range(top_k, "--top-k", 1, MAX_TOP_K, integer=True)
    from ldlloc.pipeline import QUERY_FRAMES, REFINE_MODES

    if refine not in REFINE_MODES:
        raise InputError(f"unknown --refine {refine!r}; valid: {', '.join(REFINE_MODES)}")
    if no_refine and refine not in ("auto", "none"):  # auto: the default, i.e. --refine not given
        raise InputError(f"--no-refine (= --refine none) contradicts --refine {refine}: give one of them")
    if query_frame not in QUERY_FRAMES:
        raise InputError(f"unknown --query-frame {query_frame!r}; valid: {', '.join(QUERY_FRAMES)}")
    if max_tilt is not None and not (0.0 < max_tilt <= 180.0):
        raise InputError(f"--max-tilt must be in (0, 180] degrees, got {max_tilt:g}")
    return LocalizeParams(search=SearchParams(top_k=top_k, loss=loss, decompose=not no_decompose),
                          features=features, weights=str(weights) if weights else None,
                          do_refine=not no_refine, privacy=privacy, max_tilt_deg=max_tilt, refine_mode=refine,
                          query_frame=query_frame)


@app.command()
def localize(
    map_path: Path = typer.Argument(..., metavar="MAP", help="LDL map (.h5) of the scene."),
    pano: Path = typer.Argument(..., metavar="PANO", help="Equirectangular panorama (W = 2H)."),
    as_json: bool = typer.Option(False, "--json", help="Print the result (or the error) as JSON."),
    gt: Optional[Path] = typer.Option(None, "--gt", metavar="POSE", help="Known pose of the panorama, as the datasets "
                                      "store it: a 3x4 [R | t] .txt (OmniScenes, synthetic) or a *_pose.json "
                                      "(Stanford 2D-3D-S). Prints the translation (m) and rotation (deg) errors "
                                      "and whether they are within 0.1 m / 5 deg."),
    device: str = DEVICE,
    top_k: int = TOP_K,
    loss: str = LOSS,
    no_decompose: bool = NO_DECOMPOSE,
    no_refine: bool = NO_REFINE,
    refine: str = REFINE,
    privacy: bool = PRIVACY,
    features: Optional[str] = FEATURES,
    weights: Optional[Path] = WEIGHTS,
    max_tilt: Optional[float] = MAX_TILT,
    query_frame: str = QUERY_FRAME,
    vis: Optional[Path] = typer.Option(None, "--vis", help="Write a picture of the lines and the estimated pose "
                                       "(.jpg, .jpeg, .png, .bmp, .tif, .tiff, .webp); an existing file is replaced "
                                       "only when it is a picture of ldlloc, or with --overwrite."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Let --vis replace a file that is not a picture of "
                                   "ldlloc."),
    threads: int = threads_option(),
) -> None:
    """Localize one panorama: prints R (world to camera) and t (camera centre, metres).

    With --json, also the search's top-K candidates (best first, with their losses). Both say how
    far to trust the pose: confidence in [0, 1], verdict confident | ambiguous | failed, and the
    competing poses of an ambiguous one.
    """
    import json
    import time

    import numpy as np

    from ldlloc.batch.accuracy import pose_errors
    from ldlloc.pipeline import Localizer, load_image
    from ldlmap.datasets import read_pose_file
    from ldlmap.core.pictures import check_picture_path, refuse_replacing_pictures

    from ldlmap.core.errors import LdlError, refuse_overwriting_inputs

    params = _params(top_k, loss, no_decompose, no_refine, privacy, features, weights, max_tilt, refine, query_frame)
    check_threads(threads)
    if vis is not None:
        check_picture_path(vis, "--vis")
        refuse_overwriting_inputs([map_path, pano, gt, weights], [vis])
        refuse_replacing_pictures([vis], overwrite, "--vis")
    truth = read_pose_file(gt) if gt is not None else None
    img = load_image(pano)
    check_device(device)
    m, loading = _read_map_while_importing(map_path, threads)
    tick = time.perf_counter()
    localizer = Localizer(m, params, device)
    loading["setup"] = time.perf_counter() - tick
    up = None
    if params.max_tilt_deg is not None:  # the upright prior around the camera's own gravity (XMP GPano) when recorded
        from ldlmap.io.panorama_meta import recorded_up

        up = recorded_up(pano)
    try:
        loc = localizer.localize(img, camera_up=up)
    except LdlError as exc:  # the panorama could not be localized (too few lines, ...): a failed result
        if not as_json:
            raise
        typer.echo(json.dumps({"error": str(exc), "image": str(pano), "map": str(map_path), "status": "failed",
                               "confidence": 0.0, "verdict": "failed"}, indent=1))
        raise typer.Exit(1) from None
    out = {"image": str(pano), "map": str(map_path), "R": np.round(loc.rot_cam_from_world, 8).tolist(),
           "t": np.round(loc.center, 6).tolist(), "status": loc.status, "refined": loc.refined,
           "message": loc.message, "num_rotations": loc.num_rotations, "num_lines": loc.num_lines,
           "num_matches": loc.num_matches, "num_inliers": loc.num_inliers, "rotation_prior": loc.rotation_prior,
           "refine_method": loc.refine_method, "refine_residual_deg": loc.refine_residual_deg,
           "confidence": loc.confidence, "verdict": loc.verdict, "competitors": loc.competitors,
           "confidence_signals": loc.confidence_signals,
           "seconds": {k: round(v, 4) for k, v in loc.seconds.items()},
           "load_seconds": {k: round(v, 4) for k, v in loading.items()}}
    if truth is not None:  # the dataset's frame is the map's input frame: compared in the map's, as `run` does
        out.update(pose_errors(loc.rot_cam_from_world, loc.center, *loc.truth_in_map_frame(*truth)), gt=str(gt))
    out["candidates"] = loc.candidate_dicts(6)
    in_pose = loc.input_frame_pose()  # maps built from another frame (SfM): the pose there too
    if in_pose is not None:
        out["input_frame"] = {"R": np.round(in_pose[0], 8).tolist(), "t": np.round(in_pose[1], 6).tolist()}
    if vis is not None:  # a picture that cannot be written is a warning: the result stands
        from ldlloc.batch.run import write_query_picture
        from ldlloc.visualize import localization_caption

        errors = (out["t_error_m"], out["r_error_deg"]) if truth is not None else None
        out["picture_error"] = write_query_picture(img, loc, m, vis, localization_caption(pano.name, loc, errors))
    if as_json:
        typer.echo(json.dumps(out, indent=1))
        return
    _print_localization(pano, loc, loading, out if truth is not None else None, gt)
    if vis is not None and out["picture_error"] is None:
        console.print(f"wrote {vis}", soft_wrap=True)
    elif vis is not None:
        console.print(f"[yellow]warning:[/] picture {vis} not written ({out['picture_error']})", soft_wrap=True)


def _read_map_while_importing(map_path: Path, threads: int):
    """The map (without its cloud), read in a thread while torch is imported: h5py decompresses
    with the GIL released for most of the read, so on an idle machine it costs no extra time.
    Returns the map and ``{"read_map": seconds the read took, "wait_map": seconds waited for it
    after the imports}``."""
    import time
    from concurrent.futures import ThreadPoolExecutor

    import h5py  # noqa: F401 - imported here, not in the thread, to keep the two imports apart

    from ldlmap.core.errors import require_file
    from ldlmap.map.mapfile import read_map

    require_file(map_path, "map")  # a missing map is said at once, not after the imports

    def read():
        tick = time.perf_counter()
        return read_map(map_path, load_cloud=False), time.perf_counter() - tick

    with ThreadPoolExecutor(1) as pool:
        reading = pool.submit(read)
        import_heavy("torch", "cv2")
        set_threads(threads)
        tick = time.perf_counter()
        m, seconds = reading.result()
    return m, {"read_map": seconds, "wait_map": time.perf_counter() - tick}


def _print_localization(pano: Path, loc, loading: dict, errors: Optional[dict], gt: Optional[Path]) -> None:
    """The readable result of `localize`: status, pose, counts and seconds, errors against ``--gt``."""
    from ldlloc.batch.accuracy import THRESHOLDS

    R, t = loc.rot_cam_from_world, loc.center
    console.print(f"[bold]{pano.name}[/]: {loc.status}" + (f" ({loc.message})" if loc.message else ""), soft_wrap=True)
    console.print(f"t = [{t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}] m (camera centre, world)", soft_wrap=True)
    console.print("R (world to camera) =\n" + "\n".join("  [" + ", ".join(f"{x: .6f}" for x in row) + "]" for row in R))
    in_pose = loc.input_frame_pose()  # maps built from another frame (SfM): the pose there too
    if in_pose is not None:
        ti = in_pose[1]
        console.print(f"in the map's input frame: t = [{ti[0]:.4f}, {ti[1]:.4f}, {ti[2]:.4f}] (input units), "
                      "R: see --json (input_frame)", soft_wrap=True)
    console.print(f"{loc.num_lines} lines, {loc.num_rotations} candidate rotations ({loc.rotation_prior}), "
                  f"{loc.num_matches} matches, "
                  f"{loc.num_inliers} inliers; " + ", ".join(f"{k} {v:.3f} s" for k, v in loc.seconds.items())
                  + f" (map read {loading['read_map']:.3f} s beside the imports, setup {loading['setup']:.3f} s)",
                  soft_wrap=True)
    _print_verdict(loc)
    if errors is not None:
        _, t_max, r_max = THRESHOLDS[1]
        ok = "[green]localized[/] (within" if errors["localized"] else "[yellow]not localized[/] (not within"
        console.print(f"error against {gt.name}: {errors['t_error_m']:.4f} m, {errors['r_error_deg']:.3f} deg: "
                      f"{ok} {t_max:g} m / {r_max:g} deg)", soft_wrap=True)


def _print_verdict(loc) -> None:
    """The confidence line of `localize` and, for each competing pose, where it is and why."""
    color = {"confident": "green", "ambiguous": "yellow", "failed": "red"}.get(loc.verdict or "", "white")
    console.print(f"confidence {loc.confidence:.2f}: [{color}]{loc.verdict}[/]"
                  + (f", {len(loc.competitors)} competing pose(s):" if loc.competitors else ""), soft_wrap=True)
    for c in loc.competitors:
        t = c["t"]
        loss = "" if c.get("loss") is None else f", search loss {c['loss']:.1f}"
        console.print(f"  {c['why']}: t = [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}]{loss}", soft_wrap=True)


@app.command()
def run(
    images: Optional[str] = typer.Option(None, "--images", metavar="PATH|GLOB", help="Your own panoramas instead of "
                                         "a dataset (no ground truth): an image, a folder (searched recursively for "
                                         ".jpg .jpeg .png .bmp .tif .tiff .webp) or a quoted glob ('shots/*.jpg'); "
                                         "needs --maps FILE|DIR."),
    top_maps: Optional[int] = typer.Option(None, "--top-maps", metavar="N", help="--images with several maps, or "
                                           "--scene-unknown: refine the panorama on the N maps whose pose search "
                                           "scores best and keep the most confident of them (default 5)."),
    scene_unknown: bool = typer.Option(False, "--scene-unknown", help="Do not tell a query its scene: localize it "
                                       "against every map in its scene map's folder, judged together as --images "
                                       "judges a folder (ZInD room maps: the rooms of its floor). The maps of a "
                                       "folder must share a frame (a ZInD floor's rooms do)."),
    root: Optional[str] = typer.Option(None, "--root", help="Dataset root (default ./data/<dataset>)."),
    dataset: Optional[str] = typer.Option(None, "--dataset", help=DATASET_HELP),
    map_level: Optional[str] = typer.Option(None, "--map-level",
                                            help="room | floor: which maps of `ldlmap prepare` to use (zind)."),
    split: Optional[list[str]] = typer.Option(None, "--split", help=SPLIT_HELP),
    scene: Optional[str] = typer.Option(None, "--scene", help="Only queries of this scene."),
    maps: Optional[str] = typer.Option(None, "--maps", help="Folder of the maps (default ROOT/maps); with --images "
                                        "a map file or a folder searched recursively for .h5 maps."),
    output: Optional[Path] = typer.Option(None, "--output", "-o", help="Results JSON, a .json name (a CSV of the "
                                          "same name is written beside it; a run holds NAME.json.lock while it writes); "
                                          "default results/DATASET[_ROOT][_LEVEL]_SPLITS[_SCENE].json, a name per "
                                          "dataset, root folder, ZInD map level, splits and scene."),
    device: str = DEVICE,
    top_k: int = TOP_K,
    loss: str = LOSS,
    no_decompose: bool = NO_DECOMPOSE,
    no_refine: bool = NO_REFINE,
    refine: str = REFINE,
    privacy: bool = PRIVACY,
    features: Optional[str] = FEATURES,
    weights: Optional[Path] = WEIGHTS,
    max_tilt: Optional[float] = MAX_TILT,
    query_frame: str = QUERY_FRAME,
    resume: bool = typer.Option(False, "--resume", help="Skip queries already in the results file, retry its failed "
                                "ones; refuses options other than the file's (see --resume-any-options)."),
    resume_any_options: bool = typer.Option(False, "--resume-any-options", help="With --resume: allow options other "
                                            "than the file's (the file's meta records the earlier ones)."),
    save_vis: Optional[str] = typer.Option(None, "--save-vis", help="Write a picture per query into this folder."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an --output that is not a results file, or "
                                   "the results of a run that did not finish (a finished run's are replaced "
                                   "without it); let --save-vis replace files that are not pictures of ldlloc."),
    threads: int = threads_option(),
    ray: Optional[str] = ray_option(),
    walk: bool = WALK,
    order: Optional[str] = ORDER,
    video: Optional[Path] = VIDEO,
    fps: Optional[float] = FPS,
    every: Optional[int] = EVERY,
) -> None:
    """Localize every query of a dataset split (or all splits) and print accuracy tables; or, with
    --images, your own panoramas against a map or a folder of maps (which map: --top-maps).

    With --ray, one Ray actor per scene map serves its queries (one GPU each with --device cuda);
    with --images, one actor per Ray CPU slot holds all the maps."""
    from ldlloc.batch.results import check_results_path, refuse_replacing_results
    from ldlloc.batch.run import default_results_path, missing_maps_message, run_queries, scenes_without_maps
    from ldlmap.core.errors import InputError

    params = _params(top_k, loss, no_decompose, no_refine, privacy, features, weights, max_tilt, refine, query_frame)
    check_threads(threads)
    root, maps, save_vis = _path(root, "--root"), _path(maps, "--maps"), _path(save_vis, "--save-vis")
    if output is not None:
        check_results_path(output)
    if resume_any_options and not resume:
        raise InputError("--resume-any-options goes with --resume")
    dataset_options = {"--root": root, "--dataset": dataset, "--split": split, "--scene": scene,
                       "--map-level": map_level, "--scene-unknown": scene_unknown}
    if walk or video is not None or any(v is not None for v in (order, fps, every)):
        from ldlloc.walk.options import check_walk_options

        check_walk_options(walk, order, images, ray, save_vis, video, fps, every, resume, maps, dataset_options)
    if video is not None:
        return _run_video(video, maps, output, params, top_maps, device, fps, every, threads, overwrite)
    if images is not None:
        given = [o for o, v in dataset_options.items() if v]
        if given:
            raise InputError(f"--images runs without a dataset: drop {', '.join(given)}")
        return _run_images(images, maps, output, params, top_maps, device, resume, resume_any_options, save_vis,
                           weights, threads, ray, overwrite, (order or "name") if walk else None)
    top_maps = _dataset_top_maps(top_maps, scene_unknown, map_level)
    level = {"map_level": map_level} if map_level is not None else {}  # only when given
    ds = open_dataset_root(root, dataset, "ldlloc run --root ROOT", **level)
    root, kind, label = Path(ds.root), ds.kind, dataset_label(ds)
    refuse_map_level(map_level, kind, label, root)
    queries = ds.queries(split or None, scene)
    if not queries:
        raise InputError(f"no queries in {root} for split(s) {', '.join(split or ['all'])}")
    output = output or default_results_path(label, kind, root, split, scene, getattr(ds, "map_level", None))
    maps_given, maps = maps is not None, maps or Path(root) / "maps"
    _refuse_replacing_run_inputs(queries, maps, output, save_vis, weights, root, overwrite)
    refuse_replacing_results(output, overwrite, resume)
    missing = scenes_without_maps(queries, maps, scene_unknown)
    if len(missing) == len({q.scene for q in queries}):  # nothing could run: say how to build the maps
        extra = (f" --dataset {dataset}" if dataset else "") + (f" --map-level {map_level}" if map_level else "")
        raise InputError(missing_maps_message(missing, maps, root, maps_given, extra))
    check_device(device, local=ray is None)
    set_threads(threads)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    args = (queries, maps, output, params, device, resume, save_vis)
    meta = {"dataset": label, "root": str(root), "splits": split or "all", "maps": str(maps), **level,
            "scene_unknown": scene_unknown, **({"top_maps": top_maps} if scene_unknown else {})}
    say = lambda message: console.print(message, soft_wrap=True, highlight=False)  # noqa: E731
    opts = {"meta": meta, "any_options": resume_any_options, "say": say, "top_maps": top_maps}
    if missing:
        console.print(f"[yellow]warning:[/] no map for {len(missing)} scene(s) in {maps} ({', '.join(missing[:5])}"
                      f"{', ...' if len(missing) > 5 else ''}): their queries fail; `ldlmap prepare` builds them",
                      soft_wrap=True)
    if walk:  # one walk per scene (ldlloc/walk/run.py)
        results = _run_dataset_walks(queries, maps, output, params, top_maps, device, resume, meta, scene_unknown,
                                     resume_any_options, say)
    elif ray is not None:  # one Ray actor per scene map (ldlloc/batch/ray_run.py)
        from ldlloc.batch.ray_run import run_queries_ray
        from ldlmap.batch.ray_cluster import ThroughputBar

        with ThroughputBar(console, "localizing") as bar:
            results = run_queries_ray(*args, **opts, progress=bar, address=ray, threads=threads)
    else:
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                      console=console, transient=True) as bar:
            task = bar.add_task("localizing", total=len(queries))

            def progress(r) -> None:
                err = "failed" if r.status == "failed" else f"{r.t_error_m:.3f} m {r.r_error_deg:.2f} deg"
                bar.update(task, advance=1, description=f"{r.split} {r.scene}: {err}")

            results = run_queries(*args, **opts, progress=progress)
    _print_run(results, label, output, max_tilt)


def _path(value: Optional[str], option: str) -> Optional[Path]:
    """A path option as a Path; an empty one is refused (it would mean the working folder)."""
    from ldlmap.core.errors import InputError

    if value is not None and not value.strip():
        raise InputError(f"{option} is empty: give a path")
    return None if value is None else Path(value)


def _shown(text: str) -> str:
    """``text`` as the terminal can print it: a file name's bytes that are not UTF-8 as escapes."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _dataset_top_maps(top_maps: Optional[int], scene_unknown: bool, map_level: Optional[str]) -> Optional[int]:
    """A dataset run's --top-maps (only with --scene-unknown: its default and range) after its
    --map-level is checked."""
    from ldlloc.batch.which_map import TOP_MAPS
    from ldlmap.core.errors import InputError
    from ldlmap.datasets import MAP_LEVELS

    if top_maps is not None and not scene_unknown:
        raise InputError("--top-maps goes with --images or --scene-unknown")
    if scene_unknown:
        top_maps = TOP_MAPS if top_maps is None else top_maps
        check_range(top_maps, "--top-maps", 1, 1000, integer=True)
    if map_level is not None and map_level not in MAP_LEVELS:
        raise InputError(f"--map-level must be {' or '.join(MAP_LEVELS)}, got {map_level!r}")
    return top_maps


def _run_images(images: str, maps: Optional[Path], output: Optional[Path], params, top_maps: Optional[int], device: str,
                resume: bool, any_options: bool, save_vis: Optional[Path], weights: Optional[Path], threads: int,
                ray: Optional[str], overwrite: bool, walk_order: Optional[str] = None) -> None:
    """`run --images`: find the panoramas and the maps, localize, print the counts (ldlloc/batch/images.py)."""
    from ldlloc.batch.images import (default_images_output, find_images, image_run_meta, picture_path,
                                     refuse_other_folders_results, run_images)
    from ldlloc.batch.which_map import TOP_MAPS, MapSet, map_files
    from ldlmap.core.errors import InputError, refuse_overwriting_inputs
    from ldlmap.core.pictures import refuse_replacing_pictures
    from ldlloc.batch.results import refuse_replacing_results, results_outputs

    if maps is None:
        raise InputError("--images needs --maps: a map (.h5) or a folder of maps")
    top_maps = TOP_MAPS if top_maps is None else top_maps
    check_range(top_maps, "--top-maps", 1, 1000, integer=True)
    say = lambda message: console.print(_shown(message), soft_wrap=True, highlight=False)  # noqa: E731
    queries = find_images(images, exclude=[save_vis] if save_vis is not None else [], warn=say)
    files, _ = map_files(maps)
    if output is None:
        output = default_images_output(images)
        if not resume:  # --resume compares the folders itself
            refuse_other_folders_results(output, images)
    pictures = [picture_path(save_vis, q) for q in queries] if save_vis is not None else []
    refuse_overwriting_inputs([weights, *files, *(q.image for q in queries)], [*results_outputs(output), *pictures])
    refuse_replacing_pictures(pictures, overwrite, "--save-vis")
    refuse_replacing_results(output, overwrite, resume)
    check_device(device, local=ray is None)
    set_threads(threads)
    meta = image_run_meta(images, maps, top_maps)
    opts = {"meta": meta, "top_maps": top_maps, "any_options": any_options, "say": say}
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    if ray is not None:  # one Ray actor per CPU slot, each holding every map (ldlloc/batch/ray_run.py)
        from ldlloc.batch.ray_run import run_images_ray
        from ldlmap.batch.ray_cluster import ThroughputBar

        with console.status(f"checking {len(files)} map(s)"):  # the actors load them; bad maps are said here
            for f, why in MapSet.load(maps, params, "cpu").skipped:
                say(f"[yellow]warning:[/] {f} left out: {why}")
        with ThroughputBar(console, "localizing") as bar:
            results = run_images_ray(queries, maps, output, params, device, resume, save_vis, **opts, progress=bar,
                                     address=ray, threads=threads)
        _print_run(results, "images", output, params.max_tilt_deg)
        return

    if walk_order is not None:  # --walk: the panoramas as one walk (ldlloc/walk/run.py)
        from ldlloc.walk.localize import WalkParams
        from ldlloc.walk.run import run_walk_images, walk_photos

        walk_photos(queries, walk_order)  # its errors before the maps are read
        mapset = MapSet.load(maps, params, device)
        for f, why in mapset.skipped:
            say(f"[yellow]warning:[/] {f} left out: {why}")
        with console.status(f"localizing {len(queries)} panoramas as one walk"):
            results = run_walk_images(queries, mapset, output, params, WalkParams(top_maps=top_maps), walk_order,
                                      device, resume, meta, any_options=any_options, say=say)
        _print_run(results, "images", output, params.max_tilt_deg)
        return
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task(f"loading {len(files)} map(s)", total=len(files))
        mapset = MapSet.load(maps, params, device, progress=lambda f: bar.update(task, advance=1,
                                                                                   description=f"loading {f.name}"))
        for f, why in mapset.skipped:
            say(f"[yellow]warning:[/] {f} left out: {why}")
        bar.update(task, total=len(queries), completed=0, description="localizing")

        def progress(r) -> None:
            bar.update(task, advance=1, description=f"{_shown(r.name)}: {r.status}" + ("" if r.status == "failed"
                                                                                       else f" in {r.scene}"))

        results = run_images(queries, mapset, output, params, device, resume, save_vis, **opts, progress=progress)
    _print_run(results, "images", output, params.max_tilt_deg)


def _run_dataset_walks(queries: list, maps: Path, output: Path, params, top_maps: Optional[int], device: str,
                       resume: bool, meta: dict, scene_unknown: bool, any_options: bool, say) -> list:
    """`run --root ... --walk`: one walk per scene (ldlloc/walk/run.py)."""
    from ldlloc.batch.which_map import TOP_MAPS
    from ldlloc.walk.localize import WalkParams
    from ldlloc.walk.run import run_walk_queries

    with console.status(f"localizing {len(queries)} queries as walks"):
        return run_walk_queries(queries, maps, output, params, WalkParams(top_maps=top_maps or TOP_MAPS), device,
                                resume, meta, scene_unknown, any_options=any_options, say=say)


def _run_video(video: Path, maps: Path, output: Optional[Path], params, top_maps: Optional[int], device: str,
               fps: Optional[float], every: Optional[int], threads: int, overwrite: bool) -> None:
    """`run --video`: the video as one tracked walk against the maps (ldlloc/walk/run.py)."""
    from ldlloc.batch.results import refuse_replacing_results, results_outputs
    from ldlloc.batch.which_map import TOP_MAPS, MapSet, map_files
    from ldlloc.walk.localize import VIDEO
    from ldlloc.walk.run import run_walk_video
    from ldlmap.core.errors import refuse_overwriting_inputs
    from dataclasses import replace

    top_maps = TOP_MAPS if top_maps is None else top_maps
    check_range(top_maps, "--top-maps", 1, 1000, integer=True)
    files, _ = map_files(maps)
    output = output or Path("results") / f"video_{video.stem}.json"
    refuse_overwriting_inputs([video, *files], results_outputs(output))
    refuse_replacing_results(output, overwrite, False)
    check_device(device, local=True)
    set_threads(threads)
    say = lambda message: console.print(message, soft_wrap=True, highlight=False)  # noqa: E731
    mapset = MapSet.load(maps, params, device)
    for f, why in mapset.skipped:
        say(f"[yellow]warning:[/] {f} left out: {why}")
    with console.status(f"localizing {video.name} as one walk"):
        results = run_walk_video(video, mapset, output, params, replace(VIDEO, top_maps=top_maps), fps, every, device,
                                 meta={"dataset": "video", "maps": str(maps), "top_maps": top_maps}, say=say)
    _print_run(results, "video", output, params.max_tilt_deg)


def _print_run(results: list, label: str, output: Path, max_tilt: Optional[float]) -> None:
    """The tables of a run, its failures and pictures not written, and where the results went; a
    run in which no query could be localized is an error (exit 1) after its failures."""
    from ldlloc.batch.accuracy import has_ground_truth, summary_table, timing_table
    from ldlmap.core.errors import InputError

    failed = [r for r in results if r.status == "failed"]
    if len(failed) < len(results) and not has_ground_truth(results):  # image runs: counts by map, timings
        console.print(summary_table(results, "scene", f"{label} by map"))
        console.print(timing_table(results))
    elif len(failed) < len(results):
        console.print(summary_table(results, "scene", f"{label} by scene"))
        console.print(summary_table(results, "split", f"{label} by split"))
        console.print(timing_table(results))
        _print_priors_and_search(results, max_tilt)
        _print_own_maps(results)
    _print_verdicts(results)
    for r in failed[:10]:
        console.print(f"[yellow]failed[/] {_shown(r.name)}: {_shown(r.message)}", soft_wrap=True)
    if len(failed) > 10:
        console.print(f"... and {len(failed) - 10} more failures (see {output})", soft_wrap=True)
    no_picture = [r for r in results if r.picture_error]
    if no_picture:
        console.print(f"[yellow]warning:[/] {len(no_picture)} pictures not written (first: {no_picture[0].picture_error}); "
                      f"their results are kept", soft_wrap=True)
    csv_path = output.with_suffix(".csv")
    console.print(f"wrote {output}" + (f" and {csv_path}" if csv_path.exists() else f" ({csv_path} not written)"),
                  soft_wrap=True)
    if results and len(failed) == len(results):
        raise InputError(f"none of the {len(results)} queries could be localized (reasons above, and in {output})")


def _print_own_maps(results: list) -> None:
    """--scene-unknown: how often the chosen map is the query's own scene's."""
    chosen = [r for r in results if r.status != "failed" and r.map is not None]
    if chosen:
        own = sum(Path(r.map).stem == Path(r.scene).name for r in chosen)
        console.print(f"scene unknown: the chosen map is the query's own for {own} / {len(chosen)} "
                      "(maps of one folder share a frame: another map's pose can be right)", soft_wrap=True)


def _print_priors_and_search(results: list, max_tilt: Optional[float]) -> None:
    """The rotation priors that ran and the pose search's own accuracy."""
    priors = sorted({r.rotation_prior for r in results})
    console.print(f"rotation prior: {', '.join(priors)}" + ("" if max_tilt is None else f" (--max-tilt {max_tilt:g})"),
                  soft_wrap=True)
    _print_search_summary(results)


def _refuse_replacing_run_inputs(queries: list, maps: Path, output: Path, save_vis: Optional[Path],
                                 weights: Optional[Path], root: Path, overwrite: bool) -> None:
    """One line, before any work, when the results or a picture would replace a panorama, a pose file,
    a map or a dataset manifest (``dataset.json`` of `ldlmap synth`, ZInD's ``zind_data.json``) of the run,
    or a picture a file that is not one of ldlloc's (unless ``overwrite``)."""
    from ldlloc.batch.results import results_outputs
    from ldlloc.batch.run import picture_path
    from ldlmap.core.errors import refuse_overwriting_inputs
    from ldlmap.core.pictures import refuse_replacing_pictures

    manifests = [root / "dataset.json", *root.glob("*/zind_data.json"), *root.glob("zind_data.json")]
    inputs = [p for p in (weights, *{maps / f"{q.scene}.h5" for q in queries}, *{q.pose_file for q in queries},
                          *(q.image for q in queries), *manifests) if p is not None]
    pictures = [picture_path(save_vis, q) for q in queries] if save_vis is not None else []
    refuse_overwriting_inputs(inputs, [*results_outputs(output), *pictures])
    refuse_replacing_pictures(pictures, overwrite, "--save-vis")


def _print_verdicts(results) -> None:
    """How many poses are confident, ambiguous, failed (and how right the confident ones are)."""
    from ldlloc.batch.accuracy import verdict_line

    line = verdict_line(results)
    if line:
        console.print(line, soft_wrap=True, highlight=False)


def _print_search_summary(results) -> None:
    """The pose search alone: its best pose, and the best of its top K, within 0.5 m / 10 deg."""
    from ldlloc.batch.accuracy import summarize

    search, n = summarize(results).get("search"), len(results)
    if search:
        top1, topk = search["top1_0.5m_10deg"], search["topk_0.5m_10deg"]
        console.print(f"pose search: top-1 within 0.5 m / 10 deg {top1:.3f} ({round(top1 * n)} / {n}), "
                      f"best of the top K {topk:.3f} ({round(topk * n)} / {n})", soft_wrap=True)


@app.command()
def report(
    results: Path = typer.Argument(..., help="Results JSON written by `ldlloc run`."),
    html: Optional[Path] = typer.Option(None, "--html", help="Also write one self-contained page (.html): summary, "
                                        "confidence histogram, error CDFs per split, seconds per stage, a thumbnail "
                                        "per query with the map's lines at its pose, worst first."),
    max_thumbnails: int = typer.Option(200, "--max-thumbnails", metavar="N", help="With --html: thumbnails for the "
                                       "N worst queries (0-100000)."),
) -> None:
    """Print the accuracy and timing tables of a results file again (and write an HTML report)."""
    from ldlloc.batch.results import load_results
    from ldlloc.batch.accuracy import has_ground_truth, summary_table, timing_table

    check_range(max_thumbnails, "--max-thumbnails", 0, 100000, integer=True)
    if html is not None:
        from ldlloc.report import check_html_path

        check_html_path(html)
    rs, meta = load_results(results)
    from ldlloc.report.page import unfinished_note

    unfinished = unfinished_note(rs, meta)
    if unfinished:
        console.print(f"[yellow]warning:[/] {results}: {unfinished}", soft_wrap=True, highlight=False)
    console.print(summary_table(rs, "scene", f"{results} by scene"))
    console.print(summary_table(rs, "split", f"{results} by split"))
    console.print(timing_table(rs))
    _print_search_summary(rs)
    if has_ground_truth(rs):
        _print_own_maps(rs)
    _print_verdicts(rs)
    if html is not None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

        from ldlloc.report import write_html_report

        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), console=console,
                      transient=True) as bar:
            task = bar.add_task("thumbnails", total=None)
            write_html_report(results, html, max_thumbnails,
                              progress=lambda done, total: bar.update(task, completed=done, total=total))
        console.print(f"wrote {html}", soft_wrap=True, highlight=False)


@app.command()
def export(
    results: Path = typer.Argument(..., help="Results JSON written by `ldlloc run`."),
    fmt: str = typer.Option(..., "--format", help="colmap (a model folder: cameras, images, points3D) | nerfstudio "
                            "(a transforms.json) | ply (cameras and map lines for a viewer) | tum (a walk's trajectory: "
                            "timestamp tx ty tz qx qy qz qw)."),
    output: Path = typer.Option(..., "--output", "-o", help="colmap: a folder; nerfstudio: a .json file; ply: a "
                                ".ply file; tum: a .txt file."),
    include_all: bool = typer.Option(False, "--all", help="Also queries whose verdict is not `confident` (failed "
                                     "queries never)."),
    frame: str = typer.Option("map", "--frame", help="map (the map's frame: metres, z up) | input (the frame the "
                              "map was built from: SfM, --up, --scale)."),
    text: bool = typer.Option(False, "--text", help="colmap: text files (.txt) instead of binary (.bin)."),
    image_root: Optional[Path] = typer.Option(None, "--image-root", help="colmap: the folder image names are "
                                              "relative to (COLMAP's image path; default: the deepest folder "
                                              "holding every image)."),
    map_path: Optional[Path] = typer.Option(None, "--map", help="The map, for queries whose record names none that "
                                            "exists (default: the run's maps folder + scene)."),
    scene: Optional[str] = typer.Option(None, "--scene", help="Only this scene's (map's) queries."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output."),
) -> None:
    """Write the poses of a results file for COLMAP, nerfstudio or a 3D viewer.

    Only `confident` queries unless --all; a file without verdicts exports every localized query."""
    from ldlloc.export import export_results

    done = export_results(results, fmt, output, include_all=include_all, frame=frame, text=text,
                          image_root=image_root, map_path=map_path, scene=scene, overwrite=overwrite)
    for note in done.notes:
        console.print(note, soft_wrap=True, highlight=False)
    console.print(f"wrote {done.out} ({done.count} poses, {frame} frame)", soft_wrap=True, highlight=False)


if __name__ == "__main__":  # python3 -m ldlloc.cli
    app()
