"""``ldlloc run --images PATH|GLOB --maps FILE|DIR``: your own panoramas, no ground truth.

The panoramas (:func:`find_images`): one image file; a folder, searched recursively for image
files (:data:`IMAGE_SUFFIXES`, any case; hidden files and folders, and the run's own ``--save-vis``
folder, are left out); or a glob (quote it: ``'shots/*.jpg'``, ``**`` goes into subfolders).
Each query's ``name`` is its path relative to the folder (the glob's folder part) without the
suffix, ``sub/pano_01``: unique even when two folders hold the same file name; with the suffix
when that alone tells two files apart (``a.jpg``, ``a.png``, ``a.jpg.png``: :func:`query_names`).
Folders are searched following symbolic links once (never in a loop) and each file is one query
however many links lead to it; what was left out is said (:func:`find_images`).

Each panorama is localized against the maps of ``--maps`` (:mod:`ldlloc.batch.which_map`: one map,
or the best of several) and recorded as ``split="images"``, ``scene`` = the chosen map's name,
``map`` = its path, ``map_runner_up`` = the next best map and its score, errors None. The run has
the dataset runs' guarantees (:mod:`ldlloc.batch.run`): results written after every query,
``resume``, the lock, a ``failed`` record with its reason for a bad image (and the run goes on),
pictures (``save_vis``: ``<save_vis>/<name>.jpg``).
"""

from __future__ import annotations

import fnmatch
import glob
import os
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable


from ldlmap.core.errors import InputError, LdlError
from ldlmap.core.pictures import picture_file
from ldlloc.record import QueryResult, failed_record, record_of
from ldlloc.batch.results import load_results
from ldlloc.batch.run import open_results, write_query_picture
from ldlloc.batch.which_map import TOP_MAPS, MapChoice, MapSet, localize_on_maps
from ldlloc.pipeline import Localization, LocalizeParams, load_image, rotation_prior_name
from ldlloc.visualize import localization_caption
from ldlmap.io.panorama_meta import recorded_up

IMAGES_SPLIT = "images"  # the split of every record of an image run
NO_MAP = "(none)"  # the scene of a query that failed before a map was chosen
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")  # what a folder's search takes


@dataclass(frozen=True)
class ImageQuery:
    """One panorama of an image run."""

    image: Path
    name: str  # its path below the folder (or the glob's folder part), without suffix unless needed (query_names)
    split: str = IMAGES_SPLIT
    scene: str = NO_MAP  # unknown until a map is chosen


def find_images(spec: str | Path, exclude: list[Path] = (),
                warn: Callable[[str], None] | None = None) -> list[ImageQuery]:
    """The panoramas of ``--images`` (module docstring), sorted by name; one-line error when there
    are none. ``exclude``: folders whose files are left out (the run's --save-vis). Folders are
    searched following symbolic links once: a folder reached again (a link loop, a second link to
    it) is not searched again, and a file reached twice (through links) is one query; ``warn``
    says what was left out, once per kind."""
    text = str(spec)
    if not text.strip():
        raise InputError("--images is empty: give an image, a folder of images or a quoted glob")
    p = Path(text)
    walk = _Walk()
    if p.is_file():
        return [ImageQuery(p, p.stem)]
    if p.is_dir():
        base = p
        files = [f for f in walk.files(p) if f.suffix.lower() in IMAGE_SUFFIXES]
        what = f"no image files ({', '.join(s[1:] for s in IMAGE_SUFFIXES)}) in {p} or below"
    elif glob.has_magic(text):
        base = _glob_base(text)
        files = _glob_files(text, base, walk)
        what = f"no file matches --images {text}"
    else:
        raise InputError(f"--images not found: {text} (an image, a folder of images or a quoted glob)")
    skip = [Path(e).resolve() for e in exclude]
    left_out = {f for f in files if any(s in f.resolve().parents for s in skip)}
    files, twins = _one_per_file(sorted(f for f in files if f not in left_out))
    if not files and left_out:
        raise InputError(f"the {len(left_out)} image file(s) of --images {text} are in the --save-vis folder "
                         f"{exclude[0]}, which a run leaves out (pictures are not queries): write the pictures "
                         "to another folder")
    if not files:
        raise InputError(what)
    say = warn or (lambda message: None)
    if left_out:
        say(f"warning: {len(left_out)} image file(s) in the --save-vis folder {exclude[0]} left out (pictures "
            "are not queries)")
    if walk.skipped:
        link, target = walk.skipped[0]
        say(f"warning: {len(walk.skipped)} linked folder(s) not searched again (e.g. {link} -> {target}: "
            "searched already; links are followed once)")
    if twins:
        say(f"warning: {len(twins)} file(s) left out: the same file as another through a link (e.g. {twins[0][0]} "
            f"is {twins[0][1]})")
    rel = [f.relative_to(base) if f.is_relative_to(base) else Path(f.name) for f in files]
    return [ImageQuery(f, name) for f, name in zip(files, query_names(rel))]


def query_names(rel: list[Path]) -> list[str]:
    """The query name of each image path ``rel`` (distinct paths, relative to the folder searched):
    its path without the suffix, unless another image has the same one or that is another's path
    with suffix (``a.jpg``, ``a.png``, ``a.jpg.png``): then its path with the suffix. Names are
    unique and depend only on the set of files."""
    full = [r.as_posix() for r in rel]
    stems = [r.with_suffix("").as_posix() for r in rel]
    counts = Counter(stems)
    taken = set(full)
    return [s if counts[s] == 1 and s not in taken else f for s, f in zip(stems, full)]


class _Walk:
    """Searches folders following symbolic links once: each real folder (device, inode) is searched
    once; ``skipped`` lists the (link, target) of folders reached again. Hidden files and folders
    (``.name``) are left out unless ``hidden``."""

    def __init__(self, hidden: bool = False):
        self.hidden = hidden
        self.seen: set[tuple[int, int]] = set()
        self.skipped: list[tuple[Path, Path]] = []

    def files(self, folder: Path) -> list[Path]:
        """Every file below ``folder``, in sorted order of the walk."""
        try:
            st = folder.stat()
        except OSError:
            return []
        self.seen.add((st.st_dev, st.st_ino))
        out: list[Path] = []
        stack = [folder]
        while stack:
            current = stack.pop()
            try:
                entries = sorted(os.scandir(current), key=lambda e: e.name)
            except OSError:
                continue  # unreadable folder: nothing from it
            subfolders = []
            for e in entries:
                if e.name.startswith(".") and not self.hidden:
                    continue
                try:
                    is_dir, is_file = e.is_dir(), e.is_file()  # both follow links
                except OSError:
                    continue
                path = current / e.name
                if is_dir:
                    try:
                        st = e.stat()
                    except OSError:
                        continue
                    key = (st.st_dev, st.st_ino)
                    if key in self.seen:
                        self.skipped.append((path, Path(os.path.realpath(path))))
                        continue
                    self.seen.add(key)
                    subfolders.append(path)
                elif is_file:
                    out.append(path)
            stack.extend(reversed(subfolders))
        return out


def _glob_files(pattern: str, base: Path, walk: _Walk) -> list[Path]:
    """The files that glob ``pattern`` (its folder part ``base``) matches. A pattern with ``**``
    walks ``base`` through :class:`_Walk` (links once, never a loop) and matches the paths below it
    as :func:`glob.glob` does (``**``: any folders; a hidden name only by a pattern part starting
    with a dot); others are :func:`glob.glob` (bounded by the pattern's depth)."""
    parts = Path(pattern).parts[len(base.parts) if base != Path(".") else 0:]
    if "**" not in parts:
        return [Path(f) for f in glob.glob(pattern) if Path(f).is_file()]
    if any(part in (".", "..") for part in parts):
        raise InputError(f"--images {pattern}: a '**' glob cannot go up or stay ('..', '.') after its folder part")
    walk.hidden = any(part.startswith(".") for part in parts)
    files = walk.files(base)
    return [f for f in files if _matches(parts, f.relative_to(base).parts)]


def _matches(pattern: tuple[str, ...], parts: tuple[str, ...]) -> bool:
    """Whether path ``parts`` match glob ``pattern`` parts (``**``: zero or more folders)."""
    if not pattern:
        return not parts
    if pattern[0] == "**":
        return _matches(pattern[1:], parts) or (bool(parts) and not parts[0].startswith(".")
                                                 and _matches(pattern, parts[1:]))
    if not parts or (parts[0].startswith(".") and not pattern[0].startswith(".")):
        return False
    return fnmatch.fnmatchcase(parts[0], pattern[0]) and _matches(pattern[1:], parts[1:])


def _one_per_file(files: list[Path]) -> tuple[list[Path], list[tuple[Path, Path]]]:
    """``files`` with each real file once (the first path to it kept), and the (left out, kept) pairs."""
    kept: dict[str, Path] = {}
    twins = []
    for f in files:
        real = os.path.realpath(f)
        if real in kept:
            twins.append((f, kept[real]))
        else:
            kept[real] = f
    return list(kept.values()), twins


def _glob_base(pattern: str) -> Path:
    """The folder part of a glob before its first magic component (``shots/*/a.jpg`` -> ``shots``)."""
    parts = Path(pattern).parts
    fixed = []
    for part in parts[:-1]:
        if glob.has_magic(part):
            break
        fixed.append(part)
    return Path(*fixed) if fixed else Path(".")


def images_path(spec: str | Path) -> str:
    """``--images`` as an absolute path (a glob: its folder part resolved, the rest as given): what
    ``--resume`` compares, and what tells two folders of the same name apart."""
    text, p = str(spec), Path(str(spec))
    if glob.has_magic(text) and not p.exists():
        base = _glob_base(text)
        return str(base.resolve().joinpath(*p.parts[len(base.parts) if base != Path(".") else 0:]))
    return str(p.resolve())


def default_images_output(spec: str | Path) -> Path:
    """``results/images_<folder>.json``: the folder (or glob's folder, or image) named by ``--images``."""
    p = Path(str(spec))
    base = _glob_base(str(spec)) if glob.has_magic(str(spec)) and not p.exists() else p
    return Path("results") / f"images_{base.resolve().stem or 'root'}.json"


def refuse_other_folders_results(output: Path, spec: str | Path) -> None:
    """The default output (:func:`default_images_output`) of ``--images spec`` when it holds the
    results of another folder of the same name (``day1/pano``, then ``day2/pano``): refuse in one
    line naming that folder (a run never replaces another folder's results; ``-o`` names its own)."""
    if not output.is_file():
        return
    try:
        _, meta = load_results(output)
    except LdlError:
        return  # not a results file: refuse_replacing_results says so
    if meta.get("dataset") != IMAGES_SPLIT:
        return
    earlier = meta.get("images_path") or (images_path(meta["images"]) if isinstance(meta.get("images"), str) else None)
    if earlier is not None and earlier != images_path(spec):
        raise InputError(f"{output} holds the results of another --images ({earlier}); name this run's results "
                         "with -o (or move that file)")


def picture_path(save_vis: str | Path, q: ImageQuery) -> Path:
    """Where ``--save-vis`` writes the picture of image query ``q``: ``<save_vis>/<name>.jpg``, inside
    ``save_vis`` whatever the name holds (``..`` parts stay names: :func:`ldlmap.core.pictures.picture_file`)."""
    return picture_file(save_vis, q.name)


def image_result(q: ImageQuery, loc: Localization, choice: MapChoice) -> QueryResult:
    """The results record of image query ``q`` localized on the chosen map (no ground truth)."""
    return record_of(loc, str(q.image), choice.chosen.entry.scene, q.split, q.name, **choice.record())


def failed_image_result(q: ImageQuery, params: LocalizeParams, message: str, seconds: float) -> QueryResult:
    """The ``failed`` record of image query ``q``, with its reason."""
    return failed_record(str(q.image), q.scene, q.split, q.name, message, {"total": seconds},
                         rotation_prior_name(params.max_tilt_deg))


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
        caption = f"{localization_caption(Path(q.image).name, loc)} | map {choice.chosen.entry.scene}"
        r.picture_error = write_query_picture(img, loc, choice.chosen.entry.localizer.map, picture_path(save_vis, q),
                                              caption)
    return r


def image_run_meta(images: str, maps: str | Path, top_maps: int, meta: dict | None = None) -> dict:
    """The results ``meta`` of an image run (``images_path``, ``maps`` and ``top_maps`` are compared
    by --resume)."""
    return {**(meta or {}), "dataset": IMAGES_SPLIT, "images": str(images), "images_path": images_path(images),
            "maps": str(maps), "top_maps": top_maps}


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
