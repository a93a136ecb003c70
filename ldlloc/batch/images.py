"""``ldlloc run --images PATH|GLOB --maps FILE|DIR``: your own panoramas, no ground truth.

The panoramas (:func:`find_images`): one image file; a folder, searched recursively for image
files (:data:`IMAGE_SUFFIXES`, any case; hidden files and folders, and the run's own ``--save-vis``
folder, are left out); or a glob (quote it: ``'shots/*.jpg'``, ``**`` goes into subfolders).
Each query's ``name`` is its path relative to the folder (the glob's folder part) without the
suffix, ``sub/pano_01``: unique even when two folders hold the same file name (the suffix is kept
when two files differ by it alone).

Each panorama is localized against the maps of ``--maps`` (:mod:`ldlloc.batch.which_map`: one map,
or the best of several) and recorded as ``split="images"``, ``scene`` = the chosen map's name,
``map`` = its path, ``map_runner_up`` = the next best map and its score, errors None. The run has
the dataset runs' guarantees (:mod:`ldlloc.batch.run`): results written after every query,
``resume``, the lock, a ``failed`` record with its reason for a bad image (and the run goes on),
pictures (``save_vis``: ``<save_vis>/<name>.jpg``).
"""

from __future__ import annotations

import glob
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ldlmap.core.errors import InputError, LdlError
from ldlmap.core.pictures import picture_file
from ldlloc.batch.accuracy import QueryResult
from ldlloc.batch.run import open_results, write_query_picture
from ldlloc.batch.which_map import TOP_MAPS, MapChoice, MapSet, localize_on_maps
from ldlloc.pipeline import Localization, LocalizeParams, load_image, rotation_prior_name
from ldlmap.io.panorama_meta import recorded_up

IMAGES_SPLIT = "images"  # the split of every record of an image run
NO_MAP = "(none)"  # the scene of a query that failed before a map was chosen
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")  # what a folder's search takes


@dataclass(frozen=True)
class ImageQuery:
    """One panorama of an image run."""

    image: Path
    name: str  # its path below the folder (or the glob's folder part) without suffix
    split: str = IMAGES_SPLIT
    scene: str = NO_MAP  # unknown until a map is chosen


def find_images(spec: str | Path, exclude: list[Path] = ()) -> list[ImageQuery]:
    """The panoramas of ``--images`` (module docstring), sorted by name; one-line error when there
    are none. ``exclude``: folders whose files are left out (the run's --save-vis)."""
    text = str(spec)
    p = Path(text)
    if p.is_file():
        return [ImageQuery(p, p.stem)]
    if p.is_dir():
        base = p
        files = [f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES
                 and not any(part.startswith(".") for part in f.relative_to(p).parts)]
        what = f"no image files ({', '.join(s[1:] for s in IMAGE_SUFFIXES)}) in {p} or below"
    elif glob.has_magic(text):
        base = _glob_base(text)
        files = [Path(f) for f in glob.glob(text, recursive=True) if Path(f).is_file()]
        what = f"no file matches --images {text}"
    else:
        raise InputError(f"--images not found: {text} (an image, a folder of images or a quoted glob)")
    skip = [Path(e).resolve() for e in exclude]
    files = sorted(f for f in files if not any(s in f.resolve().parents for s in skip))
    if not files:
        raise InputError(what)
    rel = [f.relative_to(base) if f.is_relative_to(base) else Path(f.name) for f in files]
    stems = [r.with_suffix("").as_posix() for r in rel]
    twice = {s for s in stems if stems.count(s) > 1}
    return [ImageQuery(f, r.as_posix() if s in twice else s) for f, r, s in zip(files, rel, stems)]


def _glob_base(pattern: str) -> Path:
    """The folder part of a glob before its first magic component (``shots/*/a.jpg`` -> ``shots``)."""
    parts = Path(pattern).parts
    fixed = []
    for part in parts[:-1]:
        if glob.has_magic(part):
            break
        fixed.append(part)
    return Path(*fixed) if fixed else Path(".")


def default_images_output(spec: str | Path) -> Path:
    """``results/images_<folder>.json``: the folder (or glob's folder, or image) named by ``--images``."""
    p = Path(str(spec))
    base = _glob_base(str(spec)) if glob.has_magic(str(spec)) and not p.exists() else p
    return Path("results") / f"images_{base.resolve().stem or 'root'}.json"


def picture_path(save_vis: str | Path, q: ImageQuery) -> Path:
    """Where ``--save-vis`` writes the picture of image query ``q``: ``<save_vis>/<name>.jpg``, inside
    ``save_vis`` whatever the name holds (``..`` parts stay names: :func:`ldlmap.core.pictures.picture_file`)."""
    return picture_file(save_vis, q.name)


def image_result(q: ImageQuery, loc: Localization, choice: MapChoice) -> QueryResult:
    """The results record of image query ``q`` localized on the chosen map (no ground truth)."""
    input_frame = None
    in_pose = loc.input_frame_pose()
    if in_pose is not None:
        input_frame = {"R": in_pose[0].tolist(), "t": in_pose[1].tolist()}
    entry = choice.chosen.entry
    return QueryResult(
        image=str(q.image), scene=entry.scene, split=q.split, name=q.name,
        R=np.asarray(loc.rot_cam_from_world).tolist(), t=np.asarray(loc.center).tolist(),
        seconds={k: float(v) for k, v in loc.seconds.items()},
        num_rotations=int(loc.num_rotations), num_matches=int(loc.num_matches), num_inliers=int(loc.num_inliers),
        refined=bool(loc.refined), status=loc.status, message=loc.message, rotation_prior=loc.rotation_prior,
        candidates=loc.candidate_dicts(), refine_method=loc.refine_method,
        refine_residual_deg=loc.refine_residual_deg, input_frame=input_frame,
        **choice.record(), confidence=loc.confidence, verdict=loc.verdict, competitors=list(loc.competitors),
        confidence_signals=dict(loc.confidence_signals) or None,
    )


def failed_image_result(q: ImageQuery, params: LocalizeParams, message: str, seconds: float) -> QueryResult:
    """The ``failed`` record of image query ``q``, with its reason."""
    return QueryResult(image=str(q.image), scene=q.scene, split=q.split, name=q.name, status="failed",
                       message=message, seconds={"total": seconds},
                       rotation_prior=rotation_prior_name(params.max_tilt_deg), confidence=0.0, verdict="failed")


def localize_image_query(maps: MapSet, q: ImageQuery, params: LocalizeParams, top_maps: int = TOP_MAPS,
                         save_vis: str | Path | None = None) -> QueryResult:
    """Localize one panorama against ``maps``; any error becomes its ``failed`` record (the run goes
    on), a picture that cannot be written its ``picture_error``."""
    t0 = time.perf_counter()
    try:
        img = load_image(q.image)
        up = recorded_up(q.image) if params.max_tilt_deg is not None else None  # the camera's own gravity
        loc, choice = localize_on_maps(img, maps, params.max_tilt_deg, top_maps, up)
        r = image_result(q, loc, choice)
    except LdlError as exc:
        return failed_image_result(q, params, str(exc), time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - e.g. cv2.error, MemoryError: one query's failure, not the run's
        return failed_image_result(q, params, f"internal error ({type(exc).__name__}: {exc})",
                                   time.perf_counter() - t0)
    if save_vis is not None:
        from ldlloc.visualize import localization_caption

        caption = f"{localization_caption(Path(q.image).name, loc)} | map {choice.chosen.entry.scene}"
        r.picture_error = write_query_picture(img, loc, choice.chosen.entry.localizer.map, picture_path(save_vis, q),
                                              caption)
    return r


def image_run_meta(images: str, maps: str | Path, top_maps: int, meta: dict | None = None) -> dict:
    """The results ``meta`` of an image run (``maps`` and ``top_maps`` are compared by --resume)."""
    return {**(meta or {}), "dataset": IMAGES_SPLIT, "images": str(images), "maps": str(maps), "top_maps": top_maps}


def run_images(queries: list[ImageQuery], maps: MapSet, output: str | Path, params: LocalizeParams,
               device: str = "cpu", resume: bool = False, save_vis: str | Path | None = None,
               meta: dict | None = None, top_maps: int = TOP_MAPS,
               progress: Callable[[QueryResult], None] | None = None, any_options: bool = False,
               say: Callable[[str], None] | None = None) -> list[QueryResult]:
    """Localize ``queries`` against ``maps``, writing results as they finish (as
    :func:`ldlloc.batch.run.run_queries`: lock, ``resume`` skips done queries and retries failed
    ones). ``meta``: :func:`image_run_meta`'s."""
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        done = writer.done()
        for q in sorted(queries, key=lambda q: q.name):
            if q.name in done:
                continue
            r = localize_image_query(maps, q, params, top_maps, save_vis)
            writer.add(r)
            if progress:
                progress(r)
        writer.finish()  # every query done: a later run without --resume may replace the file
        return writer.results
