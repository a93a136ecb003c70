"""Build one LDL map from a scan: ``build_map(input, output, params) -> Path``.

Stages (paper section 3.1), each timed, in the order :func:`build_from_input` calls them:

1. ``load``: a colored point cloud (.ply/.pcd/.txt), a mesh (sampled with its texture colors),
   a COLMAP model folder (dense ``fused.ply`` when present, else 3D lines from its photos for a
   lines-only map, :mod:`ldlmap.map.inputs`; camera centres as translation priors, their down
   axes for gravity), or only a 3D line file (a lines-only map).
2. ``lines``: 3D lines from the cloud (or the ``--lines`` file); the input is scaled by
   ``--scale`` first and, once the lines are known, rotated into z-up (:mod:`ldlmap.sfm.gravity`;
   the similarity is stored as ``input_to_map``, :mod:`ldlmap.core.frame`); then the length filter
   ``lambda (b_x + b_y + b_z) / 3`` of the robust box, with a floor and a cap on the kept count.
3. ``principal``: the 3 principal directions by voting, then the map's frame
   (:func:`ldlmap.lines3d.principal.principal_frame`): the nearest orthonormal (Manhattan) frame,
   or where the main horizontal directions are far from perpendicular
   the vertical and those two (Atlanta frame; ``build_config["principal_frame"]``), and the
   further horizontal directions of rooms whose walls run in more than two (up to
   ``max_horizontals``: the map then has K > 3 directions); in rooms with a sloped ceiling, the
   slopes' inclined directions too (up to ``max_inclined``, each only with the evidence of
   ``FrameParams``); and each kept line's group (lines join only directions of about their own
   elevation). When the user, the cameras or a room layout gave the up axis, the vertical is
   that axis (:func:`known_up`), not the lines' most vertical direction.
4. ``translations``: N_t candidate camera centres in the free space of the scan.
   ``fields``: when ``distance_fields``, each translation's K decomposed 3D line distance
   functions sampled on a spherical grid (:mod:`ldlmap.map.fields3d`) for the fast pose search.
5. ``features``: views rendered at ``num_views`` of the candidate translations (farthest-point
   sampled), local features extracted and lifted to 3D; every candidate translation is served
   by its nearest rendered view during refinement.
6. ``write``: the HDF5 map (atomically).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.frame import (apply, check_extent, decompose, is_identity, parse_up, recentring_offset, scale_warning,
                               similarity)
from ldlmap.core.geometry import angle_from_trace_deg
from ldlmap.core.timing import StageClock
from ldlmap.features import backend_for
from ldlmap.features.sphere import default_extraction
from ldlmap.io.linefiles import check_segments
from ldlmap.lines3d import extract_lines, filter_by_length, length_threshold, robust_bounds
from ldlmap.lines3d.principal import (FrameParams, HORIZONTAL_DEG, assign_line_groups, line_directions,
                                      manhattan_frame, principal_directions_3d, principal_frame)
from ldlmap.map.contents import Footprint, LdlMap, MapFeatures
from ldlmap.map.fields3d import FieldParams, compute_fields
from ldlmap.map.inputs import SceneInput, load_input
from ldlmap.map.keypoints3d import view_features
from ldlmap.map.mapfile import write_map
from ldlmap.map.params import BuildParams
from ldlmap.map.render import PointRenderer, RenderParams
from ldlmap.map.floors import BAND_LEVEL_SPACING_M, DEFAULT_CAMERA_HEIGHT, band_ranges, find_floors
from ldlmap.map.translations import (SPARSE_SPACING_M, TranslationParams, candidate_spacing, spaced_translations,
                                     translations_and_footprint)
from ldlmap.map.visibility import coverage_fields, line_visibility, room_surfaces
from ldlmap.sfm.gravity import estimate_up, map_rotation

@dataclass
class BuildReport:
    """What a build did: the output path, per-stage seconds and counts."""

    path: Path
    seconds: dict[str, float] = field(default_factory=dict)
    counts: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # what the build decided (e.g. the frame), one line each
    warnings: list[str] = field(default_factory=list)  # what the user should check, one line each


def _farthest_point_indices(P: np.ndarray, k: int, seed: int) -> np.ndarray:
    """Indices of ``k`` points spread over ``P`` by farthest-point sampling (vectorized per step)."""
    n = len(P)
    if k >= n:
        return np.arange(n)
    idx = np.empty(k, dtype=np.int64)
    idx[0] = int(np.argmin(np.linalg.norm(P - P.mean(0), axis=1)))
    d = np.linalg.norm(P - P[idx[0]], axis=1)
    for i in range(1, k):  # k steps, each vectorized over the N_t candidates
        idx[i] = int(np.argmax(d))
        d = np.minimum(d, np.linalg.norm(P - P[idx[i]], axis=1))
    return idx


def compute_features(points: np.ndarray, colors: np.ndarray, translations: np.ndarray, params: BuildParams,
                     progress: Callable[[int, int], None] | None = None):
    """Render ``num_views`` views, extract and lift features; returns a MapFeatures."""
    fp = params.features
    extraction = fp.extraction or default_extraction(fp.backend)
    backend = backend_for(fp.backend, fp.weights, params.device, extraction)
    renderer = PointRenderer(points, colors, RenderParams(width=fp.width, height=fp.height), device=params.device)
    vidx = _farthest_point_indices(translations, max(1, fp.num_views), params.seed)
    centers = translations[vidx]
    views = []
    for i, c in enumerate(centers):
        views.append(view_features(None, None, c, backend, fp.width, fp.height, renderer=renderer,
                                   max_keypoints=fp.max_keypoints))
        if progress:
            progress(i + 1, len(centers))
    counts = np.array([len(v.xyz) for v in views])
    d = np.linalg.norm(translations[:, None, :] - centers[None, :, :], axis=2)
    return MapFeatures(
        backend=backend.name,
        view_centers=centers,
        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        xyz=np.concatenate([v.xyz for v in views]).astype(np.float32),
        keypoints=np.concatenate([v.keypoints for v in views]).astype(np.float32),
        scores=np.concatenate([v.scores for v in views]).astype(np.float16),
        descriptors=np.concatenate([v.descriptors for v in views]),
        translation_view=d.argmin(1).astype(np.int32),
        width=fp.width,
        height=fp.height,
        extraction=extraction,
    )


def build_map(input_path: str | Path, output: str | Path | None = None, lines_path: str | Path | None = None,
              params: BuildParams = BuildParams(), name: str | None = None,
              progress: Callable[[str, int, int], None] | None = None,
              images_path: str | Path | None = None) -> BuildReport:
    """Build the LDL map of one scene and write it to ``output`` (default: input with ``.h5``).
    ``images_path``: the photos of a COLMAP model without ``fused.ply`` (default: its workspace's).
    ``name``: the scene's name stored in the map (default: the output's stem, which is what `ldlloc
    run --maps` calls the scene; the input is recorded in the map's config).

    ``progress(stage, done, total)`` is called as stages advance (for a progress bar): with
    ``done = 0`` when a stage starts, ``done = total`` when it ends, and in between by the stages
    that count their steps (``fields``: translations, ``features``: rendered views).
    """
    input_path = Path(input_path)
    output = Path(output) if output is not None else input_path.with_suffix(".h5")
    params.check()
    if progress:
        progress("load", 0, 1)
    clock = StageClock({})
    src = load_input(input_path, lines_path, params.input.mesh_samples, images_path, params.input.stations)
    load_seconds = clock.lap("load")
    config = {"input": str(input_path), "lines_file": str(lines_path) if lines_path else None}
    if images_path is not None:
        config["images"] = str(images_path)
    return build_from_input(src, output, params, name or output.stem, progress, config, load_seconds)


def build_lines_map(lines: np.ndarray, output: str | Path, params: BuildParams = BuildParams(), name: str | None = None,
                    walkable=None, source: str = "lines",
                    progress: Callable[[str, int, int], None] | None = None) -> BuildReport:
    """Build a lines-only map from 3D segments (L, 2, 3) held in memory (e.g. a room layout);
    ``name``: the scene's name (default: the output's stem, as :func:`build_map`).

    ``walkable`` (:class:`ldlmap.map.translations.Walkable`) says where cameras can stand; without it
    candidate translations fill the free space of the lines.
    """
    params.check()
    output = Path(output)
    segs = check_segments(lines, name or "lines")
    src = SceneInput(None, None, segs, None, source, walkable)
    return build_from_input(src, output, params, name or output.stem, progress, {"input": source, "lines_file": None})


def scene_translations(src: SceneInput, lines: np.ndarray, lines_raw: np.ndarray,
                       params: BuildParams) -> tuple[np.ndarray, dict, Footprint | None]:
    """Candidate translations of a scene, how they were chosen (stored in the map's config) and, with
    a scan, its free space seen from above (:class:`ldlmap.map.contents.Footprint`: the walls a walk
    does not step through; None without a scan).

    Heights: ``camera_height`` above each floor the lines show (:func:`ldlmap.map.floors.find_floors`),
    by default :data:`ldlmap.map.floors.DEFAULT_CAMERA_HEIGHT`; a layout that knows its cameras'
    heights (``walkable.z_range``) keeps them unless ``camera_height`` is given. With a scan: N_t
    in its free space (octree or grid, the paper's) within the band. Without one: a lattice of
    ``trans_spacing`` over where cameras stand (:func:`ldlmap.map.translations.spaced_translations`).
    """
    floors = find_floors(lines_raw)
    band, source = params.translations.camera_height, "given"
    known = src.walkable.z_range if src.walkable is not None else None
    if band is None:
        band, source = (None, "layout") if known is not None else (DEFAULT_CAMERA_HEIGHT, "default")
    tp = TranslationParams(band_above_floor=band, floors=tuple(float(f) for f in floors),
                           height_spacing=BAND_LEVEL_SPACING_M)
    top = float(np.max(lines_raw[..., 2]))
    world = [tuple(known)] if band is None else band_ranges(floors, band, top)
    info = {"floors": [round(float(f), 4) for f in floors], "camera_height_source": source,
            "camera_height": [float(z) for z in (band if band is not None else known)],
            "camera_z": [[round(float(a), 4), round(float(b), 4)] for a, b in world]}
    if src.points is not None:
        T, footprint = translations_and_footprint(src.points, params.translations.num, params.translations.method,
                                                  params.translations.clearance, prior_centers=src.prior_centers,
                                                  params=tp)
        return T, {"method": params.translations.method, "num": int(params.translations.num), **info,
                   "median_spacing_m": candidate_spacing(T)}, footprint
    T = spaced_translations(lines_raw, params.translations.spacing, src.walkable,
                            known if band is None else None, params=tp)
    if src.prior_centers is not None:
        T = np.concatenate([T, np.asarray(src.prior_centers, float).reshape(-1, 3)])
    return T, {"method": "spacing", "spacing": float(params.translations.spacing),
               "region": "layout polygons" if src.walkable is not None and src.walkable.polygons else "free space of the lines",
               **info}, None


def _transformed(src: SceneInput, lines: np.ndarray | None, A: np.ndarray) -> tuple[SceneInput, np.ndarray | None]:
    """``src`` and ``lines`` mapped by the similarity ``A`` (camera down axes rotated only)."""
    if is_identity(A):
        return src, lines
    _, R, _ = decompose(A)

    def f(X):
        return None if X is None else apply(A, X)

    down = None if src.camera_down is None else np.asarray(src.camera_down, dtype=np.float64) @ R.T
    return replace(src, points=f(src.points), lines=f(src.lines), prior_centers=f(src.prior_centers),
                   camera_down=down), f(lines)


def _input_points(src: SceneInput) -> np.ndarray:
    """The points that say where the input lies: the cloud, else the lines' end points."""
    return src.points if src.points is not None else np.asarray(src.lines, dtype=np.float64).reshape(-1, 3)


def map_frame(src: SceneInput, lines_raw: np.ndarray, params: BuildParams) -> tuple[np.ndarray, dict, str, bool]:
    """The rotation input -> map (z up) of an already scaled input, its record for the map's
    config, a one-line note for the user ("" when the input frame is kept without doubt) and
    whether the note is a warning (the lines barely told the up axis, or leaned elsewhere)."""
    up = parse_up(params.input.up)
    if src.walkable is not None:  # room layouts are built metric and z-up
        if up is not None and not np.allclose(up, [0, 0, 1]):
            raise InputError(f"--up {params.input.up} does not apply to room layouts (already z-up)")
        return np.eye(3), {"up_source": "layout", "rotation_deg": 0.0}, "", False
    est, principal = estimate_up(lines_raw, up, src.camera_down)
    R = map_rotation(est, principal)
    deg = float(angle_from_trace_deg(np.trace(R)))  # the rotation's angle
    info = {"up_source": est.source, "up_input": [round(float(x), 6) for x in est.up], "rotation_deg": deg,
            "snapped_deg": est.snapped_deg, "camera_agreement": est.camera_agreement, "sign_share": est.sign_share,
            "kept_z": est.kept_z}
    if deg == 0.0:  # input frame kept: say so only when the lines had doubts
        return R, info, (f"frame: {est.note}" if est.note and est.source == "lines" else ""), est.weak
    how = {"user": f"--up {params.input.up}", "cameras": "the cameras", "lines": "the lines"}[est.source]
    snap = f", snapped {est.snapped_deg:.1f} deg onto the lines' vertical" if est.snapped_deg else ""
    note = (f"frame: input up = ({est.up[0]:.3f}, {est.up[1]:.3f}, {est.up[2]:.3f}) from {how}{snap}; "
            f"rotated {deg:.1f} deg into z-up" + (f" ({est.note})" if est.note else ""))
    return R, info, note, est.weak


def known_up(frame_info: dict, rot: np.ndarray) -> np.ndarray | None:
    """The up axis in the map frame when the user, the cameras or a room layout gave it (the
    map's vertical is then this, not the lines' most vertical direction); None when the lines told it."""
    if frame_info["up_source"] == "layout":
        return np.array([0.0, 0.0, 1.0])
    if frame_info["up_source"] in ("user", "cameras"):
        up = rot @ np.asarray(frame_info["up_input"], dtype=np.float64)
        return up / np.linalg.norm(up)
    return None


def _azimuths(principal: np.ndarray) -> str:
    """The azimuths (degrees modulo 180, ascending) of the horizontal rows of a z-up frame, for notes."""
    horizontal = principal[np.abs(principal[:, 2]) < np.sin(np.radians(HORIZONTAL_DEG))]
    return ", ".join(f"{a:.0f}" for a in sorted(round(float(np.degrees(np.arctan2(h[1], h[0]))) % 180.0)
                                               for h in horizontal))


FRAME_WORDS = {"manhattan": "the nearest orthogonal (Manhattan) frame",
               "sloped": "the frame of the vertical and the main horizontal directions",
               "atlanta": "the frame of the vertical and the two main horizontal directions (Atlanta)"}


def frame_note(principal: np.ndarray, frame_kind: str) -> str | None:
    """The build's note on a frame that is not the plain Manhattan one (Atlanta, sloped); None for that one."""
    if frame_kind == "atlanta" and len(principal) == 3:
        pair = np.degrees(np.arccos(np.abs(principal @ principal.T)[np.triu_indices(3, 1)].max()))
        return (f"principal directions: an Atlanta frame (the vertical and the two main horizontal "
                f"directions, {pair:.0f} deg apart: walls not at right angles)")
    if frame_kind == "atlanta":
        return (f"principal directions: an Atlanta frame of {len(principal)} (the vertical and "
                f"{len(principal) - 1} horizontal directions, at azimuths "
                f"{_azimuths(principal)} deg: walls in more than two directions)")
    if frame_kind == "sloped":
        rise = np.degrees(np.arcsin(np.minimum(np.abs(principal[:, 2]), 1.0)))  # each row's elevation
        tilted = [f"{a:.0f}" for a in rise if HORIZONTAL_DEG < a < 90.0 - HORIZONTAL_DEG]
        level = f"the vertical, {int((rise <= HORIZONTAL_DEG).sum())} horizontal at azimuths {_azimuths(principal)} deg"
        return (f"principal directions: {len(principal)} ({level} and {len(tilted)} inclined at "
                f"{', '.join(tilted)} deg: a sloped ceiling)" if tilted else
                f"principal directions: {len(principal)} ({level}); the inclined lines form no direction "
                "of their own (too short or too few for a sloped ceiling's edges)")
    return None


def _frame_notes(report: BuildReport, principal: np.ndarray, deviation: np.ndarray, frame_kind: str) -> None:
    """The build's note on a frame that is not the plain Manhattan one, and its warning when the
    voted directions were far from the frame the map uses."""
    note = frame_note(principal, frame_kind)
    if note is not None:
        report.notes.append(note)
    if deviation.max() > 5.0:
        report.warnings.append(
            f"the lines' principal directions are up to {deviation.max():.0f} deg off {FRAME_WORDS[frame_kind]}, "
            "which the map uses: noisy lines or a building of other shapes")


class BuildStages:
    """The build's stage clock and progress: ``start(name)`` shows stage ``name`` running,
    ``end(name)`` stores its seconds in the report and shows it done."""

    def __init__(self, seconds: dict[str, float], progress: Callable[[str, int, int], None] | None):
        self.clock, self.progress = StageClock(seconds), progress

    def start(self, name: str, total: int = 1) -> None:
        """Stage ``name`` (of ``total`` steps) begins: the screen shows it running."""
        if self.progress:
            self.progress(name, 0, total)

    def end(self, name: str, total: int = 1) -> None:
        """Stage ``name`` ended: its seconds, and the screen's next step."""
        self.clock.lap(name)
        if self.progress:
            self.progress(name, total, total)

    def steps(self, name: str) -> Callable[[int, int], None] | None:
        """The progress callback of a stage that counts its steps (None without progress)."""
        return (lambda d, t: self.progress(name, d, t)) if self.progress else None


@dataclass
class MapFrame:
    """The input's placement in the map: the similarity input -> map and the frame's record."""

    src: SceneInput  # the input, scaled, recentred and rotated into z-up
    lines_raw: np.ndarray  # the 3D lines before the length filter, in the map frame
    rotation: np.ndarray  # the rotation input -> map
    info: dict  # the frame's record in the map's config
    input_to_map: np.ndarray  # the similarity X_map = R (s X_input - offset)


@dataclass
class LengthFilter:
    """The paper's length filter applied to the raw lines, and its record."""

    lines: np.ndarray  # the kept lines
    kept: np.ndarray  # (N_raw,) bool: which raw lines were kept
    threshold: float  # the length threshold applied (m)
    lam: float  # its ratio to the robust extent
    lambda_threshold: float  # the paper's threshold lambda * extent
    bmin: np.ndarray  # robust bounds of the scan (or the lines)
    bmax: np.ndarray
    extent: float  # mean robust extent (m)

    def config(self) -> dict:
        """The filter's record in the map's config."""
        rule = "threshold" if self.threshold == self.lambda_threshold else (
            "floor" if self.threshold < self.lambda_threshold else "cap")
        return {"rule": rule, "threshold": float(self.threshold), "lambda_threshold": self.lambda_threshold,
                "robust_extent": self.extent}


@dataclass
class Directions:
    """The map's principal directions and the lines' groups."""

    principal: np.ndarray  # (K, 3)
    deviation: np.ndarray  # the voted directions' angles (deg) from the frame used
    kind: str  # voted | manhattan | atlanta | sloped
    groups: np.ndarray  # (N,) each kept line's direction, -1 for none


def check_scene_input(src: SceneInput, params: BuildParams) -> None:
    """Refuse, before the long stages, a cloud too small to build on or without the colors features need."""
    if src.points is not None and len(src.points) < 100:
        raise InputError(f"point cloud has only {len(src.points)} points: too few to build a map")
    if params.features.backend != "none" and src.points is not None and src.colors is None:
        raise InputError("the point cloud has no colors: features need a colored cloud (or use --features none)")


def scaled_and_centred(src: SceneInput, params: BuildParams, report: BuildReport) -> tuple[SceneInput, np.ndarray | None]:
    """The input multiplied by ``scale`` and, when far from the origin (UTM), moved to its centre
    (the offset is returned, None when kept); its extent is checked before any grid is sized."""
    if params.input.scale != 1.0:
        if src.walkable is not None:
            raise InputError("--scale does not apply to room layouts (already metric)")
        src, _ = _transformed(src, None, similarity(params.input.scale))
    where = _input_points(src)
    check_extent(np.subtract(*robust_bounds(where)[::-1]))
    offset = recentring_offset(where) if src.walkable is None else None
    if offset is not None:  # work and store relative to the scan's centre
        src, _ = _transformed(src, None, similarity(1.0, None, -offset))
        report.notes.append(f"frame: the input lies far from the origin; the map is centred on "
                            f"({offset[0]:.0f}, {offset[1]:.0f}, {offset[2]:.0f}) (poses in the input frame "
                            f"are given too)")
    return src, offset


def raw_lines(src: SceneInput) -> np.ndarray:
    """The input's 3D lines: the line file's, else those extracted from the cloud."""
    lines_raw = src.lines if src.lines is not None else extract_lines(src.points)
    if len(lines_raw) == 0:
        raise InputError("no 3D lines found in the input")
    return lines_raw


def into_map_frame(src: SceneInput, lines_raw: np.ndarray, offset: np.ndarray | None, params: BuildParams,
                   report: BuildReport) -> MapFrame:
    """The input and its lines rotated into z-up (:func:`map_frame`), with the frame's note."""
    rot, frame_info, note, weak = map_frame(src, lines_raw, params)
    shift = np.zeros(3) if offset is None else offset
    input_to_map = similarity(params.input.scale, rot, -(rot @ shift))  # X_map = R (s X_input - offset)
    src, lines_raw = _transformed(src, lines_raw, similarity(1.0, rot))
    if note:
        (report.warnings if weak else report.notes).append(note)
    return MapFrame(src, lines_raw, rot, frame_info, input_to_map)


def length_filter(src: SceneInput, lines_raw: np.ndarray, params: BuildParams, report: BuildReport) -> LengthFilter:
    """The paper's length filter ``lambda`` times the robust extent (or the user's absolute length),
    with a floor and a cap on the kept count; warns when the extent is not in metres."""
    pts_for_bounds = src.points if src.points is not None else lines_raw.reshape(-1, 3)
    bmin, bmax = robust_bounds(pts_for_bounds)  # far outliers do not stretch thresholds
    extent = float(np.mean(bmax - bmin))
    if scale_warning(extent):
        report.warnings.append(scale_warning(extent))
    lp = params.lines
    lam, floor, share = lp.lam, min(lp.min_kept, (len(lines_raw) + 1) // 2), lp.min_kept_share
    if lp.min_length is not None:
        lam, floor, share = float(lp.min_length / max(extent, 1e-12)), 0, 0.0  # the user's threshold, exactly
    lines, kept, threshold = filter_by_length(lines_raw, bmin, bmax, lam, min_keep=floor,
                                              max_keep=lp.max_kept, min_length_share=share)
    if len(lines) == 0:
        raise InputError(f"no 3D line is longer than the length threshold {threshold:.3f} m")
    return LengthFilter(lines, kept, threshold, lam, length_threshold(bmin, bmax, lam), bmin, bmax, extent)


def principal_stage(lines: np.ndarray, frame: MapFrame, params: BuildParams, report: BuildReport) -> Directions:
    """The principal directions by voting, snapped to the map's frame (Manhattan, Atlanta or
    sloped), and each line's group; notes on the frame."""
    principal = principal_directions_3d(lines)
    deviation, frame_kind = np.zeros(3), "voted"
    up = known_up(frame.info, frame.rotation)
    gravity = {"up": (0.0, 0.0, 1.0) if up is None else up, "up_known": up is not None}
    pp = params.principal
    if pp.orthonormal and pp.atlanta:
        principal, deviation, frame_kind = principal_frame(
            lines, principal, params=FrameParams(max_horizontals=pp.max_horizontals, max_inclined=pp.max_inclined),
            **gravity)
    elif pp.orthonormal:
        (principal, deviation), frame_kind = manhattan_frame(lines, principal, **gravity), "manhattan"
    _frame_notes(report, principal, deviation, frame_kind)
    # under a sloped ceiling, lines join only directions of about their own elevation (the map frame's up is z)
    groups = assign_line_groups(line_directions(lines)[0], principal,
                                up=(0.0, 0.0, 1.0) if frame_kind == "sloped" else None)
    return Directions(principal, deviation, frame_kind, groups)


def translations_stage(src: SceneInput, lines: np.ndarray, lines_raw: np.ndarray, params: BuildParams,
                       report: BuildReport) -> tuple[np.ndarray, dict, Footprint | None]:
    """The candidate translations and footprint (:func:`scene_translations`), with a warning when they stand sparse."""
    translations, trans_info, footprint = scene_translations(src, lines, lines_raw, params)
    if len(translations) == 0:
        raise InputError("no candidate translation found in the free space of the scan")
    spacing = trans_info.get("median_spacing_m", 0.0)  # a scan's candidates only (a lattice has its own spacing)
    if spacing > SPARSE_SPACING_M:
        report.warnings.append(
            f"the {len(translations)} candidate translations stand a median {spacing:.2f} m apart, so cameras "
            "between them may be missed (a scan of a whole floor?): more with --num-trans, nearer the cameras "
            "with --camera-height MIN:MAX (e.g. 0.9:1.7)")
    return translations, trans_info, footprint


def visibility_stage(src: SceneInput, lines: np.ndarray, translations: np.ndarray,
                     stages: BuildStages) -> tuple[np.ndarray | None, Any]:
    """Room layouts: which lines each translation sees through the walls, and the rooms' surface
    coverage when every room has a ceiling height; (None, None) without walls."""
    walls = getattr(src.walkable, "walls", None)
    if walls is None or not len(walls):
        return None, None
    coverage = None
    stages.start("visibility")
    visibility = line_visibility(lines, translations, walls)
    if len(src.walkable.ceiling_heights) == len(src.walkable.polygons):
        coverage = coverage_fields(translations, *room_surfaces(walls, src.walkable.polygons,
                                                                src.walkable.ceiling_heights))
    stages.end("visibility")
    return visibility, coverage


def fields_stage(lines: np.ndarray, directions: Directions, translations: np.ndarray,
                 visibility: np.ndarray | None, params: BuildParams, stages: BuildStages) -> tuple[dict, dict]:
    """The 3D distance fields of every translation (empty when ``distance_fields`` is off)."""
    fields, fields_attrs = {}, {}
    n_t = len(translations) if params.output.distance_fields else 1
    stages.start("fields", n_t)
    if params.output.distance_fields:
        dist, fields_attrs = compute_fields(lines, directions.groups, translations,
                                            FieldParams(num_groups=len(directions.principal)),
                                            device=params.device, visibility=visibility,
                                            progress=stages.steps("fields"))  # per chunk of translations
        fields = {"distances": dist}
    stages.end("fields", n_t)
    return fields, fields_attrs


def features_stage(src: SceneInput, translations: np.ndarray, params: BuildParams, stages: BuildStages):
    """The map's local features (a MapFeatures), None without a colored scan or with ``features = none``."""
    features = None
    with_features = params.features.backend != "none" and src.points is not None
    n_views = min(max(1, params.features.num_views), len(translations)) if with_features else 1
    stages.start("features", n_views)
    if with_features:
        features = compute_features(src.points, src.colors, translations, params, stages.steps("features"))
    stages.end("features", n_views)
    return features


def stored_cloud(src: SceneInput, params: BuildParams) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The subsampled colored cloud kept in the map for pictures (None, None without a scan)."""
    if src.points is None:
        return None, None
    rng = np.random.default_rng(params.seed)
    keep = rng.permutation(len(src.points))[: params.output.cloud_points]
    keep.sort()
    return src.points[keep], (src.colors[keep] if src.colors is not None else None)


def map_config(params: BuildParams, config: dict | None, src: SceneInput, trans_info: dict, frame: MapFrame,
               filt: LengthFilter, directions: Directions) -> dict:
    """The build's record stored in the map: the parameters, the input and what each stage decided."""
    out = {**params.config(), **(config or {}), "source": src.source, "translations": trans_info,
           "frame": frame.info, "length_filter": filt.config(),
           "principal_deviation_deg": [round(float(x), 3) for x in directions.deviation],
           "principal_frame": directions.kind}
    if params.features.backend == "none" or src.points is None:
        out["features"] = "none"
    return out


def build_counts(m: LdlMap, filt: LengthFilter, src: SceneInput, output: Path, params: BuildParams) -> dict:
    """The report's counts of a written map."""
    return {
        "lines_raw": int(len(m.lines_raw)), "lines": int(len(m.lines)), "kept_ratio": float(filt.kept.mean()),
        "translations": int(len(m.translations)),
        "visible_lines": float(m.visibility.sum(1).mean()) if m.visibility is not None else float(len(m.lines)),
        "views": m.features.num_views if m.features else 0,
        "keypoints": int(len(m.features.xyz)) if m.features else 0,
        "size_mb": output.stat().st_size / 1e6,
        "note": src.note,
        "frame_rotation_deg": m.config["frame"]["rotation_deg"], "scale": float(params.input.scale),
    }


def build_from_input(src: SceneInput, output: Path, params: BuildParams, name: str,
                     progress: Callable[[str, int, int], None] | None = None, config: dict | None = None,
                     load_seconds: float = 0.0) -> BuildReport:
    """Build and write the map of a loaded :class:`SceneInput` (the stages after ``load``)."""
    report = BuildReport(output)
    report.seconds["load"] = load_seconds
    if progress:
        progress("load", 1, 1)
    stages = BuildStages(report.seconds, progress)
    stages.start("lines")
    check_scene_input(src, params)
    src, offset = scaled_and_centred(src, params, report)
    frame = into_map_frame(src, raw_lines(src), offset, params, report)
    src, lines_raw = frame.src, frame.lines_raw
    filt = length_filter(src, lines_raw, params, report)
    stages.end("lines")
    stages.start("principal")
    directions = principal_stage(filt.lines, frame, params, report)
    stages.end("principal")
    stages.start("translations")
    translations, trans_info, footprint = translations_stage(src, filt.lines, lines_raw, params, report)
    stages.end("translations")
    visibility, coverage = visibility_stage(src, filt.lines, translations, stages)
    fields, fields_attrs = fields_stage(filt.lines, directions, translations, visibility, params, stages)
    features = features_stage(src, translations, params, stages)
    cloud_pts, cloud_cols = stored_cloud(src, params)
    m = LdlMap(
        name=name, bounds_min=filt.bmin, bounds_max=filt.bmax,
        lines_raw=lines_raw, lines=filt.lines, line_groups=directions.groups,
        length_threshold=filt.threshold, kept_ratio=float(filt.kept.mean()), line_lambda=filt.lam,
        principal_directions=directions.principal, translations=translations,
        cloud_points=cloud_pts, cloud_colors=cloud_cols, features=features,
        config=map_config(params, config, src, trans_info, frame, filt, directions),
        fields=fields, fields_attrs=fields_attrs, visibility=visibility, coverage=coverage,
        input_to_map=frame.input_to_map, footprint=footprint,
    )
    stages.start("write")
    write_map(output, m)
    stages.end("write")
    report.seconds["total"] = sum(report.seconds.values())
    report.counts = build_counts(m, filt, src, output, params)
    return report

