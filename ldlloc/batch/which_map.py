"""Which map holds a panorama: the maps of ``ldlloc run --images --maps FILE|DIR`` and the choice.

:class:`MapSet` loads every map once (a file, or a folder searched recursively for ``*.h5``;
an ``.h5`` that is not a map is a warning and is left out). :func:`localize_on_maps` localizes one
panorama against them:

1. its 2D lines (the costliest stage) are detected once and shared by every map, and so are its
   vanishing points (:class:`ldlloc.pipeline.QueryLines`); only the candidate rotations (they
   align the vanishing points with each map's principal directions) and the pose search run per
   map (:meth:`ldlloc.pipeline.Localizer.search`);
2. the maps are ranked by the search's best loss (the negative inlier count of the line distance
   functions: the same query points and 2D lines for every map, so the losses compare). This is
   the paper's multi-room mode (one search over the poses of every room, sec. 4.2 and the
   supplement's 20 offices) split per map;
3. the ``top_maps`` best are refined (:meth:`~ldlloc.pipeline.Localizer.localize` from their search)
   and :func:`choose_map` keeps the most confident (:mod:`ldlloc.confidence`); copies of its
   room on the other maps (:func:`ldlloc.confidence.add_copies`: an identical room on another
   floor) make it at most ``ambiguous``.

A single map skips the ranking and the choice: it is plain ``localize``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ldlmap.core.errors import InputError, LdlError
from ldlmap.map.mapfile import read_map
from ldlloc.confidence import add_copies, assess_across, verified
from ldlloc.pipeline import Localization, LocalizeParams, Localizer, Searched
from ldlloc.refine.geometric import GeometricParams
from ldlloc.search.pose_search import score_on_map

TOP_MAPS = 5  # --top-maps default: maps refined after the ranking (docs/measurements.md#which-map)


@dataclass
class MapEntry:
    """One loaded map: its file, its name in results (``scene``) and its localizer."""

    path: Path
    scene: str  # the map's path below the --maps folder without .h5 (its stem for a single file)
    localizer: Localizer


class MapSet:
    """The maps of an image run, loaded once and shared by all its panoramas."""

    def __init__(self, entries: list[MapEntry], skipped: list[tuple[Path, str]]):
        self.entries, self.skipped = entries, skipped  # skipped: (path, why) of .h5 files that are no maps

    @classmethod
    def load(cls, maps: str | Path, params: LocalizeParams, device: str = "cpu",
             progress: Callable[[Path], None] | None = None, recursive: bool = True) -> "MapSet":
        """The maps of ``maps`` (:func:`map_files`); one-line error when none of them loads."""
        files, root = map_files(maps, recursive)
        entries, skipped = [], []
        for f in files:
            if progress:
                progress(f)
            try:
                loc = Localizer(read_map(f, load_cloud=False), params, device)
            except LdlError as exc:
                skipped.append((f, str(exc)))
                continue
            scene = f.stem if root is None else f.relative_to(root).with_suffix("").as_posix()
            entries.append(MapEntry(f, scene, loc))
        if not entries:
            raise InputError(f"--maps {maps}: no usable map among {len(files)} .h5 file(s) (first: {skipped[0][1]})")
        return cls(entries, skipped)


def map_files(maps: str | Path, recursive: bool = True) -> tuple[list[Path], Path | None]:
    """The map files of ``--maps`` (a file, or a folder searched for ``*.h5``, recursively unless
    ``recursive`` is False, hidden folders left out, sorted) and the folder their names are relative
    to (None for a file)."""
    p = Path(maps)
    if p.is_file():
        return [p], None
    if not p.exists():
        raise InputError(f"--maps not found: {p} (a map .h5 file or a folder of maps)")
    if not p.is_dir():
        raise InputError(f"--maps is neither a file nor a folder: {p}")
    files = sorted(f for f in (p.rglob("*.h5") if recursive else p.glob("*.h5")) if f.is_file()
                   and not any(part.startswith(".") for part in f.relative_to(p).parts))
    if not files:
        raise InputError(f"--maps {p}: no .h5 map in this folder or below (build maps with `ldlmap build` "
                         "or `ldlmap prepare`)")
    return files, p


@dataclass
class MapOption:
    """One map's localization of a panorama, as :func:`choose_map` sees it."""

    entry: MapEntry
    search_loss: float  # the search's best loss (the ranking)
    loc: Localization | None = None  # refined localization (top maps only)
    loss: float | None = None  # exact loss of the final pose (lower is better; score_poses)
    searched: Localization | None = None  # the search's coarse localization: its top-K poses (ldlloc.walk)


@dataclass
class MapChoice:
    """The outcome of :func:`localize_on_maps`."""

    chosen: MapOption
    ranked: list[MapOption]  # every map that could be searched, best search loss first
    failures: list[tuple[MapEntry, str]] = field(default_factory=list)  # maps whose search failed, why
    seconds: dict[str, float] = field(default_factory=dict)

    def runner_up(self) -> dict | None:
        """``{"map", "score"}`` of the best map not chosen (None with a single map)."""
        others = [o for o in self.ranked if o is not self.chosen]
        if not others:
            return None
        best = min(others, key=choice_key)
        out = {"map": str(best.entry.path), "score": option_score(best)}
        if best.loc is not None and best.loc.confidence is not None:
            out["confidence"] = float(best.loc.confidence)
        return out

    def record(self) -> dict:
        """The results record's fields of the choice: ``map`` (the chosen map's path),
        ``map_runner_up`` and, with several maps, ``map_scores``."""
        return {"map": str(self.chosen.entry.path), "map_runner_up": self.runner_up(),
                "map_scores": self.scores() if len(self.ranked) > 1 else None}

    def scores(self) -> list[dict]:
        """Per map that was refined: ``{"map", "search_loss", "loss"}``; then the next ranked maps'
        search losses (at most 10 maps in all)."""
        return [{"map": str(o.entry.path), "search_loss": o.search_loss, "loss": o.loss}
                for o in self.ranked[:max(10, sum(o.loc is not None for o in self.ranked))]]


def option_score(o: MapOption) -> float:
    """The score :func:`choose_map` compares (lower is better): the final pose's loss when the map
    was refined, else its search loss."""
    return float(o.loss) if o.loss is not None else float(o.search_loss)


def choice_key(o: MapOption) -> tuple[float, float, float, float]:
    """How :func:`choose_map` orders options (smallest first): first the verified PnP poses
    (:func:`ldlloc.confidence.verified`: features and lines back them), most inliers first, as the
    feature refinement keeps the PnP pose of most inliers (two of them within 10 % on the lines are
    twins, neither confident: docs/measurements.md#verified-across-maps); then the refined ones by
    confidence (:mod:`ldlloc.confidence`, highest first), then by :func:`option_score`, then by
    search loss."""
    conf = o.loc.confidence if o.loc is not None and o.loc.confidence is not None else -1.0
    if o.loc is not None and verified(o.loc, option_score(o)):
        return (0.0, -float(o.loc.num_inliers), -conf, option_score(o))
    return (1.0, -conf, option_score(o), o.search_loss)


def choose_map(options: list[MapOption], params: GeometricParams | None = None) -> MapOption:
    """The map kept among the refined ``options`` (the top of the ranking). With several, their
    poses are first judged together (:func:`ldlloc.confidence.assess_across`: a pose that another
    map's distinct pose matches on loss and map-line support is not confident, and that pose is
    named as its competitor); then the verified PnP pose of most inliers is kept, else the most
    confident, ties to the lowest loss of the final pose (:func:`final_pose_loss`) (:func:`choice_key`). Nothing comes from ground truth (docs/measurements.md#which-map)."""
    if len(options) > 1:
        assess_across([o.loc for o in options], [option_score(o) for o in options],
                      [o.entry.scene for o in options], params)
    return min(options, key=choice_key)


def poses_loss(localizer: Localizer, arcs: np.ndarray, rotations: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """(N,) the exact losses (:func:`ldlloc.search.pose_search.score_on_map`) of the query lines ``arcs`` at
    the poses ``rotations`` (N, 3, 3) and ``centers`` (N, 3) on ``localizer``'s map, each seen from the
    candidate translation nearest to it."""
    p = localizer.params
    return score_on_map(arcs, rotations, centers, localizer.map, p.search, localizer.device, p.principal.group_tol)


def final_pose_loss(localizer: Localizer, loc: Localization) -> float:
    """The exact loss of ``loc``'s final pose on ``localizer``'s map (:func:`poses_loss`)."""
    return float(poses_loss(localizer, loc.arcs, np.asarray(loc.rot_cam_from_world)[None],
                            np.asarray(loc.center)[None])[0])


def localize_on_maps(img: np.ndarray, maps: MapSet, max_tilt_deg: float | None, top_maps: int = TOP_MAPS,
                     camera_up: np.ndarray | None = None) -> tuple[Localization, MapChoice]:
    """Localize ``img`` against the maps of ``maps`` (module docstring); returns the chosen map's
    localization and the choice. Its ``seconds``: ``lines2d`` once, ``rotation`` and ``search``
    summed over every map, ``refine`` over the refined ones, ``choose`` (final losses), ``total``.
    Raises the first map's error when no map can be searched."""
    first = maps.entries[0].localizer
    lines = first.detect_lines(img)
    if len(maps.entries) == 1:
        loc = first.localize(img, max_tilt_deg, lines=lines, camera_up=camera_up)
        opt = MapOption(maps.entries[0], float(loc.candidates_loss[0]), loc, searched=loc)
        return loc, MapChoice(opt, [opt], seconds=dict(loc.seconds))
    secs = {"lines2d": lines.seconds, "rotation": 0.0, "search": 0.0, "refine": 0.0, "choose": 0.0}
    searched: list[tuple[MapOption, Searched]] = []
    failures: list[tuple[MapEntry, str]] = []
    for e in maps.entries:
        try:
            s = e.localizer.search(img, max_tilt_deg, lines, camera_up)
        except InputError as exc:
            failures.append((e, str(exc)))
            continue
        secs["rotation"] += s.out.seconds["rotation"]
        secs["search"] += s.out.seconds["search"]
        searched.append((MapOption(e, s.best_loss, searched=s.out), s))
    if not searched:
        raise InputError(f"no map could be searched ({failures[0][0].scene}: {failures[0][1]})")
    searched.sort(key=lambda x: x[0].search_loss)
    for o, s in searched[:max(1, top_maps)]:
        o.loc = o.entry.localizer.localize(img, max_tilt_deg, searched=s)
        secs["refine"] += o.loc.seconds["refine"]
        tick = time.perf_counter()
        o.loss = final_pose_loss(o.entry.localizer, o.loc)
        secs["choose"] += time.perf_counter() - tick
    ranked = [o for o, _ in searched]
    tick = time.perf_counter()
    chosen = choose_map([o for o in ranked if o.loc is not None], first.params.geometric)
    others = [(e.scene, e.localizer.map) for e in maps.entries if e is not chosen.entry]
    loz = {e.scene: e.localizer for e in maps.entries}
    add_copies(chosen.loc, chosen.entry.localizer.map, others, first.params.geometric.support_deg,  # other floors
               inliers_at=lambda name, R, t, beyond=0.0: (loz[name] if name else chosen.entry.localizer).inliers_at(
                   chosen.loc, R, t, beyond))
    for o in ranked:  # the query's features served the copies' check only
        if o.loc is not None:
            o.loc.query_features = None
    secs["choose"] += time.perf_counter() - tick
    secs["total"] = sum(secs.values())
    loc = chosen.loc
    loc.seconds = dict(secs)
    return loc, MapChoice(chosen, ranked, failures, secs)
