"""Batch localization over dataset splits: ``run_split(...) -> list[QueryResult]``.

Each query is localized against the map of its scene (``<maps>/<scene>.h5``, as written by
``ldlmap prepare``). A query that cannot be localized (missing map or image, corrupt image, no
lines, wrong feature backend, or any other error) becomes a ``failed`` record with its message,
and the run goes on; a ``--save-vis`` picture that cannot be written is a warning recorded beside
the result (``picture_error``), never a failed query. Results are written after every query
(:class:`ldlloc.batch.results.ResultsWriter`, under its lock), so an interrupted run loses nothing and
``resume`` skips the queries already done and retries the failed ones (a map built since, a
panorama fixed).

Upright prior per query (:func:`max_tilt_for`): ``params.max_tilt_deg`` (``--max-tilt``) when
given, always (180: free rotation); otherwise :data:`ldlloc.pipeline.UPRIGHT_MAX_TILT_DEG` for
queries that their dataset marks upright (``Query.upright``, e.g. ZInD) and free rotation for
the others. Each result records the prior that ran (``rotation_prior``), and the run's meta the
option (``max_tilt_deg``, None when not given) and the upright default.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ldlmap.core.errors import InputError, LdlError
from ldlmap.core.pictures import picture_file
from ldlmap.datasets import DEFAULT_ROOTS
from ldlmap.io.panorama_meta import recorded_up
from ldlmap.map.mapfile import read_map
from ldlloc.batch.results import ResultsWriter
from ldlloc.batch.which_map import MapSet, localize_on_maps
from ldlloc.pipeline import (UPRIGHT_MAX_TILT_DEG, Localization, LocalizeParams, Localizer, load_image,
                             rotation_prior_name)
from ldlloc.record import QueryResult, failed_record, record_of
from ldlloc.rotation import FREE_TILT_DEG
from ldlloc.visualize import localization_caption, save_localization_picture


def max_tilt_for(q, params: LocalizeParams) -> float | None:
    """The upright prior for query ``q``: ``params.max_tilt_deg`` when set (the user's
    ``--max-tilt`` wins), else :data:`UPRIGHT_MAX_TILT_DEG` for an upright query, else None (free)."""
    if params.max_tilt_deg is not None:
        return float(params.max_tilt_deg)
    return UPRIGHT_MAX_TILT_DEG if getattr(q, "upright", False) else None


def tilt_bound_for(q, params: LocalizeParams) -> float:
    """:func:`max_tilt_for` as the bound a localization takes: :data:`~ldlloc.rotation.FREE_TILT_DEG` when free."""
    tilt = max_tilt_for(q, params)
    return FREE_TILT_DEG if tilt is None else tilt


def result_from_localization(q, loc: Localization) -> QueryResult:
    """The record of dataset query ``q`` (with ground truth) localized as ``loc``
    (:func:`ldlloc.record.record_of`: errors in the map frame)."""
    return record_of(loc, str(q.image), q.scene, q.split, q.name, truth=(q.rot_cam_from_world, q.center))


class MapCache:
    """Loads each scene's map (and its Localizer) once, one scene in memory at a time (queries are
    sorted by scene); remembers maps that failed to load."""

    def __init__(self, maps_dir: Path, params: LocalizeParams, device: str):
        self.maps_dir, self.params, self.device = Path(maps_dir), params, device
        self._loaded: dict = {}

    def key(self, scene: str):
        """What a query of ``scene`` is localized against (loaded once per key)."""
        return scene

    def load(self, key):
        """The :class:`Localizer` of scene ``key``'s map."""
        path = self.maps_dir / f"{key}.h5"
        if not path.exists():
            raise InputError(f"map not found: {path} (build it with `ldlmap prepare ROOT --maps {self.maps_dir}`)")
        return Localizer(read_map(path, load_cloud=False), self.params, self.device)

    def localize(self, scene: str, img: np.ndarray, max_tilt_deg: float,
                 camera_up: np.ndarray | None = None) -> tuple[Localization, Localizer, dict]:
        """``img`` localized against ``scene``'s map: the localization, the localizer whose map holds
        the pose, and the results record's extra fields (none here). ``camera_up``: the camera's gravity."""
        loc = self.get(scene)
        return loc.localize(img, max_tilt_deg=max_tilt_deg, camera_up=camera_up), loc, {}

    def get(self, scene: str):
        """:meth:`load` of ``scene``'s key, loaded once (raises its load error each time)."""
        key = self.key(scene)
        if key not in self._loaded:
            self._loaded = {k: v for k, v in self._loaded.items() if isinstance(v, LdlError)}
            try:
                self._loaded[key] = self.load(key)
            except LdlError as exc:
                self._loaded[key] = exc
        got = self._loaded[key]
        if isinstance(got, LdlError):
            raise got
        return got


class FolderMaps(MapCache):
    """Scene not given (``run --scene-unknown``): each query is localized against every map of its
    scene map's folder (``<maps>/<scene's parent>/*.h5``: for ZInD room maps, the rooms of its
    floor; for floor maps, the floors of its home), judged together as ``run --images`` judges a
    folder of maps (:func:`ldlloc.batch.which_map.localize_on_maps`, ``top_maps`` refined). The
    maps of one folder must share a frame for the errors against the dataset's ground truth to
    mean anything (a ZInD floor's rooms do). A folder whose maps fail to load fails each of its
    queries; an ``.h5`` in it that is not a map is left out, and ``warn`` (when given) says so once."""

    def __init__(self, maps_dir: Path, params: LocalizeParams, device: str, top_maps: int,
                 warn: Callable[[str], None] | None = None):
        super().__init__(maps_dir, params, device)
        self.top_maps, self.warn = int(top_maps), warn

    def key(self, scene: str) -> Path:
        return self.maps_dir / Path(scene).parent

    def load(self, key: Path):
        """The :class:`ldlloc.batch.which_map.MapSet` of the maps in folder ``key``."""
        maps = MapSet.load(key, self.params, self.device, recursive=False)
        for path, why in maps.skipped if self.warn is not None else []:
            self.warn(f"warning: {path} left out: {why}")
        return maps

    def localize(self, scene: str, img: np.ndarray, max_tilt_deg: float,
                 camera_up: np.ndarray | None = None) -> tuple[Localization, Localizer, dict]:
        """``img`` localized against the maps of ``scene``'s folder; the record's extra fields name
        the chosen map and the runner-up (:meth:`ldlloc.batch.which_map.MapChoice.record`)."""
        res, choice = localize_on_maps(img, self.get(scene), max_tilt_deg, self.top_maps, camera_up)
        return res, choice.chosen.entry.localizer, choice.record()


def default_results_path(label: str, kind: str, root: Path, splits: list[str] | None, scene: str | None = None,
                         map_level: str | None = None) -> Path:
    """``results/<label>[_<root>][_<level>]_<splits>[_<scene>].json``: a name per thing a run
    measures, so that runs of other data never replace each other's results. ``label``: the kind
    users see (``synthetic`` for a dataset of ``ldlmap synth``); the root folder's name when it is
    not the kind's usual one; ZInD's map level (room or floor); the splits (``all``) and scene."""
    usual = {label, kind, DEFAULT_ROOTS[kind].name if kind in DEFAULT_ROOTS else kind}
    parts = [label, *([root.name] if root.name and root.name not in usual else []),
             *([map_level] if kind == "zind" and map_level else []), "-".join(splits) if splits else "all",
             *([scene.replace("/", "-")] if scene else [])]
    return Path("results") / f"{'_'.join(parts)}.json"


def scenes_without_maps(queries: list, maps_dir: Path, scene_unknown: bool = False) -> list[str]:
    """The scenes of ``queries`` whose map ``<maps_dir>/<scene>.h5`` is not there (``scene_unknown``:
    whose folder holds no map, :class:`FolderMaps`), in query order."""
    scenes = dict.fromkeys(q.scene for q in sorted(queries, key=query_key))
    if scene_unknown:
        return [s for s in scenes if not any((Path(maps_dir) / s).parent.glob("*.h5"))]
    return [s for s in scenes if not (Path(maps_dir) / f"{s}.h5").is_file()]


def missing_maps_message(missing: list[str], maps_dir: Path, root: Path, maps_given: bool,
                         extra: str = "") -> str:
    """One line: no map for any scene of the run, and the two commands that build them and run.
    The maps go where ``--maps`` said, else beside the data when that folder is writable, else
    into ``./maps/<root name>`` (datasets are often read-only); ``extra``: options both commands
    need (``--dataset``, ``--map-level``)."""
    target = maps_dir if maps_given or os.access(root, os.W_OK) else Path("maps") / root.name
    where = f"{len(missing)} scene(s), e.g. {Path(maps_dir) / (missing[0] + '.h5')}"
    return (f"no maps for the queries' {where}: build them first with `ldlmap prepare {root}{extra} --maps "
            f"{target}`, then `ldlloc run --root {root}{extra} --maps {target}`")


def query_key(q) -> tuple[str, str, str]:
    """The order in which a run localizes (and records) its queries: by scene, split, name."""
    return q.scene, q.split, q.name


def run_meta(params: LocalizeParams, device: str, meta: dict | None = None) -> dict:
    """The results file's ``meta``: the caller's fields plus device, parameters and tilt prior, and
    ``base_dir``: the absolute working folder the records' relative paths (images, maps) start from."""
    return {**(meta or {}), "base_dir": os.path.abspath(os.curdir), "device": device, "params": asdict(params),
            "max_tilt_deg": params.max_tilt_deg, "upright_max_tilt_deg": UPRIGHT_MAX_TILT_DEG}


def failed_result(q, params: LocalizeParams, message: str, seconds: float | None = None) -> QueryResult:
    """The ``failed`` record of query ``q``, with its reason."""
    return failed_record(str(q.image), q.scene, q.split, q.name, message, {} if seconds is None else {"total": seconds},
                         rotation_prior_name(max_tilt_for(q, params)))


def localize_query(cache: MapCache, q, params: LocalizeParams,
                   save_vis: str | Path | None = None) -> QueryResult:
    """Localize one dataset query against its scene's map (``cache`` a :class:`MapCache`), or, the
    scene not given, against the maps of its scene's folder (a :class:`FolderMaps`: the record
    names the chosen map, ``map``, and the runner-up). Any error (a toolkit error, or anything
    else a bad panorama or map provokes) becomes this query's ``failed`` record, never the run's
    end; a picture that cannot be written is recorded (``picture_error``) beside the result."""
    t0 = time.perf_counter()
    tilt = tilt_bound_for(q, params)
    try:
        cache.get(q.scene)  # a map that cannot be read fails the query before its image is read
        img = load_image(q.image)
        res, loc, extra = cache.localize(q.scene, img, tilt, recorded_up(q.image) if tilt < FREE_TILT_DEG else None)
        r = replace(result_from_localization(q, res), **extra)
    except LdlError as exc:
        return failed_result(q, params, str(exc), time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - e.g. cv2.error, MemoryError: one query's failure, not the run's
        return failed_result(q, params, f"internal error ({type(exc).__name__}: {exc})", time.perf_counter() - t0)
    if save_vis is not None:
        caption = localization_caption(f"{q.name}{Path(q.image).suffix}", res, (r.t_error_m, r.r_error_deg))
        if r.map is not None:
            caption += f" | map {Path(r.map).stem}"
        r.picture_error = write_query_picture(img, res, loc.map, picture_path(save_vis, q), caption)
    return r


def scene_maps(maps_dir: str | Path, params: LocalizeParams, device: str, top_maps: int | None,
               warn: Callable[[str], None] | None = None) -> MapCache:
    """Where a run's queries find their maps: their scene's (``top_maps`` None) or their scene
    folder's, judged together with ``top_maps`` refined (:class:`FolderMaps`, which ``warn``s of
    files left out)."""
    if top_maps is None:
        return MapCache(Path(maps_dir), params, device)
    return FolderMaps(Path(maps_dir), params, device, top_maps, warn)


def picture_path(save_vis: str | Path, q) -> Path:
    """Where ``--save-vis`` writes the picture of query ``q``: ``<save_vis>/<name>.jpg``, one per
    query (names are unique in a run) and always inside ``save_vis``."""
    return picture_file(save_vis, q.name)


def write_query_picture(img: np.ndarray, res: Localization, ldl_map, path: Path, caption: str = "") -> str | None:
    """Write a query's picture (``caption``: under it); returns why it could not be written (None when written)."""
    try:
        save_localization_picture(img, res, ldl_map, path, caption)
    except (LdlError, OSError) as exc:
        return getattr(exc, "strerror", None) or str(exc)
    return None


def run_queries(queries: list, maps_dir: str | Path, output: str | Path, params: LocalizeParams = LocalizeParams(),
                device: str = "cpu", resume: bool = False, save_vis: str | Path | None = None,
                meta: dict | None = None, progress: Callable[[QueryResult], None] | None = None,
                any_options: bool = False, say: Callable[[str], None] | None = None,
                top_maps: int | None = None) -> list[QueryResult]:
    """Localize ``queries`` (from :mod:`ldlmap.datasets`) and write results as they finish.

    ``resume``: skip the queries the results file holds, except failed ones (retried); refuses
    other options than the file's unless ``any_options``. ``say``: where warnings and the resume
    summary go (one line each). ``top_maps``: the scene not given, each query against the maps of
    its scene's folder, this many refined (:class:`FolderMaps`); None: against its scene's map.
    :func:`ldlloc.batch.ray_run.run_queries_ray` does the same on a Ray cluster."""
    with open_results(output, params, device, meta, resume, any_options, queries, say) as writer:
        done = writer.done()
        cache = scene_maps(maps_dir, params, device, top_maps, say)
        for q in sorted(queries, key=query_key):
            if q.name in done:
                continue
            r = localize_query(cache, q, params, save_vis)
            writer.add(r)
            if progress:
                progress(r)
        writer.finish()
        return writer.results


def open_results(output: str | Path, params: LocalizeParams, device: str, meta: dict | None, resume: bool,
                 any_options: bool, queries: list, say: Callable[[str], None] | None) -> ResultsWriter:
    """The locked :class:`ResultsWriter` of a run; on ``resume`` says how many of ``queries`` are
    done and how many failed ones are retried (none given, a video's frames: its run says it)."""
    writer = ResultsWriter(output, meta=run_meta(params, device, meta), resume=resume, any_options=any_options,
                           warn=say)
    if resume and say is not None and queries:
        names = {q.name for q in queries}
        done, retry = len(writer.done() & names), len(writer.failed() & names)
        say(f"resuming {writer.path}: {done} of {len(names)} queries done, {len(names) - done - retry} to run, "
            f"{retry} failed ones retried" + (" (options mixed: --resume-any-options)" if any_options
                                                and "mixed_options" in writer.meta else ""))
    return writer
