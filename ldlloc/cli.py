"""``ldlloc``: the online side of the LDL toolkit (localize panoramas against LDL maps)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ldlmap.core.cli_common import DATASET_HELP, console, make_app, ray_option, threads_option
from ldlmap.core.lazy import lazy_module

localize_command = lazy_module("ldlloc.commands.localize")  # what each command does, loaded when it runs
run_command = lazy_module("ldlloc.commands.run")
report_command = lazy_module("ldlloc.commands.report")
export_module = lazy_module("ldlloc.export")

app = make_app("ldlloc", "Localize panoramas against LDL maps with line distance functions.")

# Commands are added below, one function each: parse, then call the module that does it (ldlloc/commands/).

# Options shared by `localize` and `run` (method parameters, device, threads).
DEVICE = typer.Option("cpu", "--device", help="cpu | cuda.")
WALK = typer.Option(False, "--walk", help="The panoramas are one walk (a capture tour): localize them together, "
                    "choosing the most likely path (ldlloc/walk/); with --root, one walk per scene (--scene-unknown: "
                    "per folder of maps), in capture order (ZInD: the panorama number).")
ORDER = typer.Option(None, "--order", help="--images --walk: name (natural file-name order, the default) | time "
                     "(EXIF capture time).")
VIDEO = typer.Option(None, "--video", metavar="FILE|DIR|GLOB", help="An equirectangular video (mp4, mov, ...) "
                     "localized as one walk, tracked frame to frame (needs --maps; ldlloc/walk/video.py); a folder "
                     "of videos or a quoted glob, or --video repeated: one walk per video (with --ray, one actor "
                     "each), into one results file.")
FPS = typer.Option(None, "--fps", help="--video: frames a second to localize (at most the video's rate; default: "
                   "every frame).")
EVERY = typer.Option(None, "--every", metavar="N", help="--video: every N-th frame.")
LAG = typer.Option(None, "--lag", metavar="FRAMES", help="--walk, --video: a frame is decided (and written) once this "
                   "many frames after it are localized (default 100; a walk of lag + 1 frames or fewer is decided as a "
                   "whole; ldlloc/walk/stream.py).")
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


def _method(top_k: int, loss: str, no_decompose: bool, no_refine: bool, privacy: bool, features: Optional[str],
            weights: Optional[Path], max_tilt: Optional[float], refine: str, query_frame: str) -> dict:
    """The method options of `localize` and `run`, by the names ``ldlloc.commands.options.localize_params`` takes."""
    return {"top_k": top_k, "loss": loss, "no_decompose": no_decompose, "no_refine": no_refine, "privacy": privacy,
            "features": features, "weights": weights, "max_tilt": max_tilt, "refine": refine,
            "query_frame": query_frame}


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
    method = _method(top_k, loss, no_decompose, no_refine, privacy, features, weights, max_tilt, refine, query_frame)
    localize_command.localize(map_path, pano, as_json, gt, device, method, vis, overwrite, threads)


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
    video: Optional[list[str]] = VIDEO,
    fps: Optional[float] = FPS,
    every: Optional[int] = EVERY,
    lag: Optional[int] = LAG,
) -> None:
    """Localize every query of a dataset split (or all splits) and print accuracy tables; or, with
    --images, your own panoramas against a map or a folder of maps (which map: --top-maps).

    With --ray, one Ray actor per scene map serves its queries (one GPU each with --device cuda);
    with --images, one actor per Ray CPU slot holds all the maps; with --walk or --video, one actor per walk."""
    method = _method(top_k, loss, no_decompose, no_refine, privacy, features, weights, max_tilt, refine, query_frame)
    run_command.run(images, root, dataset, map_level, split, scene, scene_unknown, maps, output, method, top_maps,
                    device, resume, resume_any_options, save_vis, overwrite, threads, ray, walk, order, video, fps,
                    every, lag)


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
    report_command.report(results, html, max_thumbnails)


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
    done = export_module.export_results(results, fmt, output, include_all=include_all, frame=frame, text=text,
                                        image_root=image_root, map_path=map_path, scene=scene, overwrite=overwrite)
    for note in done.notes:
        console.print(note, soft_wrap=True, highlight=False)
    console.print(f"wrote {done.out} ({done.count} poses, {frame} frame)", soft_wrap=True, highlight=False)


if __name__ == "__main__":  # python3 -m ldlloc.cli
    app()
