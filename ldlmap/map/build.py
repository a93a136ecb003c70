"""Build one LDL map from a scan: ``build_map(input, output, params) -> Path``.

Stages (paper section 3.1, DESIGN.md 5.1-5.4), each timed:

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

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.map.inputs import SceneInput, load_input


@dataclass(frozen=True)
class BuildParams:
    """Map-building parameters (paper defaults where the paper gives one)."""

    lam: float = 0.1  # lambda: 3D length filter ratio
    min_line_length: float | None = None  # absolute length threshold (m) instead of lambda's; for maps
    # of several rooms, whose extent makes lambda's threshold longer than most of a room's lines
    num_translations: int = 800  # N_t (800 OmniScenes, 1700 Stanford 2D-3D-S)
    translation_method: str = "octree"  # octree (OmniScenes) | grid (Stanford)
    clearance: float = 0.25  # candidate translations keep this distance (m) from the scan
    features: str = "sift"  # sift | aliked | disk | xfeat | superpoint | none (ldlmap.features)
    weights: str | None = None  # SuperPoint checkpoint path (else env var / cache / download)
    num_views: int = 40  # views rendered for features; each translation uses its nearest view
    width: int = 1024  # rendered view size (the queries' size)
    height: int = 512
    max_keypoints: int | None = None  # per rendered view (None: the backend's max_keypoints)
    feature_extraction: str | None = None  # equirect (the panorama) | cube (its six 90-degree faces;
    # ldlmap.features.sphere), for the map's views and, as the map records it, the queries; None: the
    # backend's default (cube for aliked, equirect for the others: ldlmap.features.sphere.default_extraction)
    stored_cloud_points: int = 200_000  # subsampled colored cloud kept in the map for pictures
    mesh_samples: int = 1_000_000  # points sampled from a mesh input
    device: str = "cpu"  # torch device for rendering and SuperPoint
    seed: int = 0
    distance_fields: bool = True  # precompute 3D distance fields (fast pose search, ldlmap.map.fields3d)
    trans_spacing: float = 0.3  # maps without a scan (layouts, line files): candidate translations on a
    # lattice this many metres apart (a true camera is then within spacing / sqrt(2) in xy)
    camera_height: tuple[float, float] | None = None  # camera-height band (metres above the floor) for candidate
    # translations: a scan's N_t go to its free space in the band (its floor: the robust lowest z); maps without a
    # scan: world z. None: a scan's free space from floor to ceiling; the layout's band when known
    up: str = "auto"  # the input's up axis: auto (cameras, else the lines; ldlmap.sfm.gravity) | x | y | z | -x | -y | -z
    scale: float = 1.0  # input coordinates are multiplied by this first (SfM frames: metres per unit)
    min_kept_lines: int = 100  # length filter floor: keep at least min(this, half the lines), the longest ...
    min_kept_length_share: float = 0.6  # ... and the longest holding this share of the total line length
    # (below what the paper's threshold keeps of a scan, far above an SfM map's: docs/measurements.md#length-share)
    max_kept_lines: int = 3000  # length filter cap: keep at most this many, the longest
    orthonormal_directions: bool = True  # principal directions: the nearest Manhattan frame (paper's assumption)
    atlanta_frame: bool = True  # ... or, when the main horizontals are far from perpendicular, an Atlanta frame
    # (the vertical and those two; ldlmap.lines3d.principal.principal_frame). False: always Manhattan
    max_horizontals: int = 4  # Atlanta frames: at most this many horizontal directions, where the walls run
    # in more than two (FrameParams.max_horizontals; 2: the vertical and the main two only)
    max_inclined: int = 2  # sloped ceilings: at most this many inclined directions added to the frame
    # (FrameParams.max_inclined; 0: none)
    stations: tuple[str, ...] = ()  # E57 input: the scan stations to use, names or 0-based indices (all when empty)


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
    from ldlmap.features import backend_for
    from ldlmap.map.keypoints3d import view_features
    from ldlmap.map.contents import MapFeatures
    from ldlmap.map.render import PointRenderer, RenderParams

    from ldlmap.features.sphere import default_extraction

    extraction = params.feature_extraction or default_extraction(params.features)
    backend = backend_for(params.features, params.weights, params.device, extraction)
    renderer = PointRenderer(points, colors, RenderParams(width=params.width, height=params.height),
                             device=params.device)
    vidx = _farthest_point_indices(translations, max(1, params.num_views), params.seed)
    centers = translations[vidx]
    views = []
    for i, c in enumerate(centers):
        views.append(view_features(None, None, c, backend, params.width, params.height, renderer=renderer,
                                   max_keypoints=params.max_keypoints))
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
        width=params.width,
        height=params.height,
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
    _check_params(params)
    if progress:
        progress("load", 0, 1)
    tick = time.perf_counter()
    src = load_input(input_path, lines_path, params.mesh_samples, images_path, params.stations)
    load_seconds = time.perf_counter() - tick
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
    from ldlmap.io.linefiles import _check_segments

    _check_params(params)
    output = Path(output)
    segs = _check_segments(lines, name or "lines")
    src = SceneInput(None, None, segs, None, source, walkable)
    return build_from_input(src, output, params, name or output.stem, progress, {"input": source, "lines_file": None})


def _check_params(params: BuildParams) -> None:
    from ldlmap.features import available_backends

    if params.features not in (*available_backends(), "none"):
        raise InputError(f"unknown feature backend {params.features!r}; valid: {', '.join(available_backends())}, none")
    from ldlmap.features.sphere import check_extraction

    if params.feature_extraction is not None:
        check_extraction(params.feature_extraction)
    if params.min_line_length is not None and not params.min_line_length > 0:
        raise InputError(f"minimum line length must be > 0 m, got {params.min_line_length}")
    from ldlmap.core.frame import parse_up

    parse_up(params.up)
    if not (np.isfinite(params.scale) and params.scale > 0):
        raise InputError(f"--scale must be > 0, got {params.scale}")
    if params.min_kept_lines < 0 or params.max_kept_lines < 1 or not 0 <= params.min_kept_length_share <= 1:
        raise InputError(f"kept-line bounds must be >= 0, >= 1 and a share in [0, 1], got {params.min_kept_lines}, "
                         f"{params.max_kept_lines}, {params.min_kept_length_share}")
    if not (np.isfinite(params.trans_spacing) and params.trans_spacing > 0):
        raise InputError(f"translation spacing must be > 0 m, got {params.trans_spacing}")
    ch = params.camera_height
    if ch is not None and not (len(ch) == 2 and np.all(np.isfinite(ch)) and ch[0] <= ch[1]):
        raise InputError(f"camera-height band must be MIN:MAX with MIN <= MAX, got {ch}")


def scene_translations(src: SceneInput, lines: np.ndarray, lines_raw: np.ndarray,
                       params: BuildParams) -> tuple[np.ndarray, dict]:
    """Candidate translations of a scene and how they were chosen (stored in the map's config).

    With a scan: N_t in its free space (octree or grid, the paper's), within ``camera_height`` above
    its floor when given. Without one: a lattice of ``trans_spacing`` over where cameras stand
    (:func:`ldlmap.map.translations.spaced_translations`).
    """
    from ldlmap.map.translations import (TranslationParams, candidate_spacing, candidate_translations,
                                         spaced_translations)

    if src.points is not None:
        band = params.camera_height
        T = candidate_translations(src.points, params.num_translations, params.translation_method,
                                   params.clearance, prior_centers=src.prior_centers,
                                   params=TranslationParams(band_above_floor=band))
        return T, {"method": params.translation_method, "num": int(params.num_translations),
                   "camera_height_above_floor": [float(z) for z in band] if band is not None else None,
                   "median_spacing_m": candidate_spacing(T)}
    _check_band_meets_scene(params.camera_height, lines_raw)
    T = spaced_translations(lines_raw, params.trans_spacing, src.walkable, params.camera_height)
    if src.prior_centers is not None:
        T = np.concatenate([T, np.asarray(src.prior_centers, float).reshape(-1, 3)])
    zr = params.camera_height or (src.walkable.z_range if src.walkable is not None else None)
    info = {"method": "spacing", "spacing": float(params.trans_spacing),
            "region": "layout polygons" if src.walkable is not None and src.walkable.polygons else "free space of the lines",
            "camera_height": [float(z) for z in zr] if zr is not None else None}
    return T, info


def _check_band_meets_scene(band: tuple[float, float] | None, lines: np.ndarray) -> None:
    """Refuse (one line) a camera-height band that lies wholly below the scene's floor or above its
    ceiling (the lowest and highest line ends): no candidate translation could stand there."""
    if band is None:
        return
    z = np.asarray(lines, dtype=np.float64)[..., 2]
    floor, ceiling = float(z.min()), float(z.max())
    if band[1] <= floor or band[0] >= ceiling:
        where = "below the floor" if band[1] <= floor else "above the ceiling"
        raise InputError(f"--camera-height {band[0]:g}:{band[1]:g} m lies {where}: the scene spans z = {floor:.2f} "
                         f"to {ceiling:.2f} m, so no candidate translation is left")


def _transformed(src: SceneInput, lines: np.ndarray | None, A: np.ndarray) -> tuple[SceneInput, np.ndarray | None]:
    """``src`` and ``lines`` mapped by the similarity ``A`` (camera down axes rotated only)."""
    from ldlmap.core.frame import apply, decompose, is_identity

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
    from ldlmap.core.frame import parse_up
    from ldlmap.sfm.gravity import estimate_up, map_rotation

    up = parse_up(params.up)
    if src.walkable is not None:  # room layouts are built metric and z-up
        if up is not None and not np.allclose(up, [0, 0, 1]):
            raise InputError(f"--up {params.up} does not apply to room layouts (already z-up)")
        return np.eye(3), {"up_source": "layout", "rotation_deg": 0.0}, "", False
    est, principal = estimate_up(lines_raw, up, src.camera_down)
    R = map_rotation(est, principal)
    deg = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
    info = {"up_source": est.source, "up_input": [round(float(x), 6) for x in est.up], "rotation_deg": deg,
            "snapped_deg": est.snapped_deg, "camera_agreement": est.camera_agreement, "sign_share": est.sign_share,
            "kept_z": est.kept_z}
    if deg == 0.0:  # input frame kept: say so only when the lines had doubts
        return R, info, (f"frame: {est.note}" if est.note and est.source == "lines" else ""), est.weak
    how = {"user": f"--up {params.up}", "cameras": "the cameras", "lines": "the lines"}[est.source]
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
    horizontal = principal[np.abs(principal[:, 2]) < np.sin(np.radians(10.0))]
    return ", ".join(f"{a:.0f}" for a in sorted(round(float(np.degrees(np.arctan2(h[1], h[0]))) % 180.0)
                                               for h in horizontal))


def _frame_notes(report: BuildReport, principal: np.ndarray, deviation: np.ndarray, frame_kind: str) -> None:
    """The build's note on a frame that is not the plain Manhattan one (Atlanta, sloped), and its
    warning when the voted directions were far from the frame the map uses."""
    if frame_kind == "atlanta" and len(principal) == 3:
        pair = np.degrees(np.arccos(np.abs(principal @ principal.T)[np.triu_indices(3, 1)].max()))
        report.notes.append(f"principal directions: an Atlanta frame (the vertical and the two main horizontal "
                            f"directions, {pair:.0f} deg apart: walls not at right angles)")
    elif frame_kind == "atlanta":
        report.notes.append(f"principal directions: an Atlanta frame of {len(principal)} (the vertical and "
                            f"{len(principal) - 1} horizontal directions, at azimuths "
                            f"{_azimuths(principal)} deg: walls in more than two directions)")
    elif frame_kind == "sloped":
        rise = np.degrees(np.arcsin(np.minimum(np.abs(principal[:, 2]), 1.0)))  # each row's elevation
        tilted = [f"{a:.0f}" for a in rise if 10.0 < a < 80.0]
        level = f"the vertical, {int((rise <= 10.0).sum())} horizontal at azimuths {_azimuths(principal)} deg"
        report.notes.append(f"principal directions: {len(principal)} ({level} and {len(tilted)} inclined at "
                            f"{', '.join(tilted)} deg: a sloped ceiling)" if tilted else
                            f"principal directions: {len(principal)} ({level}); the inclined lines form no direction "
                            "of their own (too short or too few for a sloped ceiling's edges)")
    if deviation.max() > 5.0:
        frame_words = {"manhattan": "the nearest orthogonal (Manhattan) frame",
                       "sloped": "the frame of the vertical and the main horizontal directions",
                       "atlanta": "the frame of the vertical and the two main horizontal directions (Atlanta)"}
        report.warnings.append(
            f"the lines' principal directions are up to {deviation.max():.0f} deg off {frame_words[frame_kind]}, "
            "which the map uses: noisy lines or a building of other shapes")


def build_from_input(src: SceneInput, output: Path, params: BuildParams, name: str,
                     progress: Callable[[str, int, int], None] | None = None, config: dict | None = None,
                     load_seconds: float = 0.0) -> BuildReport:
    """Build and write the map of a loaded :class:`SceneInput` (the stages after ``load``)."""
    from ldlmap.core.frame import check_extent, recentring_offset, scale_warning, similarity
    from ldlmap.lines3d import Lines3DParams, extract_lines, filter_by_length, length_threshold, robust_bounds
    from ldlmap.map.contents import LdlMap
    from ldlmap.map.mapfile import write_map
    from ldlmap.lines3d.principal import (FrameParams, assign_line_groups, line_directions, manhattan_frame,
                                          principal_directions_3d, principal_frame)

    report = BuildReport(output)
    report.seconds["load"] = load_seconds
    if progress:
        progress("load", 1, 1)
    tick = time.perf_counter()

    def start(name_: str, total: int = 1) -> None:
        """Say that stage ``name_`` (of ``total`` steps) begins: the screen shows it running."""
        if progress:
            progress(name_, 0, total)

    def stage(name_: str, total: int = 1) -> None:
        """Stage ``name_`` ended: its seconds, and the screen's next step."""
        nonlocal tick
        now = time.perf_counter()
        report.seconds[name_] = now - tick
        tick = now
        if progress:
            progress(name_, total, total)

    start("lines")

    if src.points is not None and len(src.points) < 100:
        raise InputError(f"point cloud has only {len(src.points)} points: too few to build a map")
    if params.features != "none" and src.points is not None and src.colors is None:  # before the long stages
        raise InputError("the point cloud has no colors: features need a colored cloud (or use --features none)")
    if params.scale != 1.0:
        if src.walkable is not None:
            raise InputError("--scale does not apply to room layouts (already metric)")
        src, _ = _transformed(src, None, similarity(params.scale))
    where = _input_points(src)
    check_extent(np.subtract(*robust_bounds(where)[::-1]))  # before any grid is sized
    offset = recentring_offset(where) if src.walkable is None else None
    if offset is not None:  # far from the origin (UTM): work and store relative to the scan's centre
        src, _ = _transformed(src, None, similarity(1.0, None, -offset))
        report.notes.append(f"frame: the input lies far from the origin; the map is centred on "
                            f"({offset[0]:.0f}, {offset[1]:.0f}, {offset[2]:.0f}) (poses in the input frame "
                            f"are given too)")
    if src.lines is not None:
        lines_raw = src.lines
    else:
        lines_raw = extract_lines(src.points, src.colors, Lines3DParams(lam=params.lam))
    if len(lines_raw) == 0:
        raise InputError("no 3D lines found in the input")
    rot, frame_info, note, weak = map_frame(src, lines_raw, params)
    shift = np.zeros(3) if offset is None else offset
    input_to_map = similarity(params.scale, rot, -(rot @ shift))  # X_map = R (s X_input - offset)
    src, lines_raw = _transformed(src, lines_raw, similarity(1.0, rot))
    if note:
        (report.warnings if weak else report.notes).append(note)
    pts_for_bounds = src.points if src.points is not None else lines_raw.reshape(-1, 3)
    bmin, bmax = robust_bounds(pts_for_bounds)  # far outliers do not stretch thresholds
    extent = float(np.mean(bmax - bmin))
    if scale_warning(extent):
        report.warnings.append(scale_warning(extent))
    lam, floor, share = params.lam, min(params.min_kept_lines, (len(lines_raw) + 1) // 2), params.min_kept_length_share
    if params.min_line_length is not None:
        lam, floor, share = float(params.min_line_length / max(extent, 1e-12)), 0, 0.0  # the user's threshold, exactly
    lines, kept, threshold = filter_by_length(lines_raw, bmin, bmax, lam, min_keep=floor,
                                              max_keep=params.max_kept_lines, min_length_share=share)
    if len(lines) == 0:
        raise InputError(f"no 3D line is longer than the length threshold {threshold:.3f} m")
    paper_threshold = length_threshold(bmin, bmax, lam)
    rule = "threshold" if threshold == paper_threshold else ("floor" if threshold < paper_threshold else "cap")
    stage("lines")
    start("principal")
    principal = principal_directions_3d(lines)
    deviation, frame_kind = np.zeros(3), "voted"
    up = known_up(frame_info, rot)
    gravity = {"up": (0.0, 0.0, 1.0) if up is None else up, "up_known": up is not None}
    if params.orthonormal_directions and params.atlanta_frame:
        principal, deviation, frame_kind = principal_frame(lines, principal,
                                                           params=FrameParams(max_horizontals=params.max_horizontals,
                                                                              max_inclined=params.max_inclined),
                                                           **gravity)
    elif params.orthonormal_directions:
        (principal, deviation), frame_kind = manhattan_frame(lines, principal, **gravity), "manhattan"
    _frame_notes(report, principal, deviation, frame_kind)
    # under a sloped ceiling, lines join only directions of about their own elevation (the map frame's up is z)
    groups = assign_line_groups(line_directions(lines)[0], principal,
                                up=(0.0, 0.0, 1.0) if frame_kind == "sloped" else None)
    stage("principal")
    start("translations")
    translations, trans_info = scene_translations(src, lines, lines_raw, params)
    if len(translations) == 0:
        raise InputError("no candidate translation found in the free space of the scan")
    from ldlmap.map.translations import SPARSE_SPACING_M

    spacing = trans_info.get("median_spacing_m", 0.0)  # a scan's candidates only (a lattice has its own spacing)
    if spacing > SPARSE_SPACING_M:
        report.warnings.append(
            f"the {len(translations)} candidate translations stand a median {spacing:.2f} m apart, so cameras "
            "between them may be missed (a scan of a whole floor?): more with --num-trans, nearer the cameras "
            "with --camera-height MIN:MAX (e.g. 0.9:1.7)")
    stage("translations")
    visibility = coverage = None
    walls = getattr(src.walkable, "walls", None)
    if walls is not None and len(walls):
        from ldlmap.map.visibility import line_visibility

        start("visibility")
        visibility = line_visibility(lines, translations, walls)
        if len(src.walkable.ceiling_heights) == len(src.walkable.polygons):
            from ldlmap.map.visibility import coverage_fields, room_surfaces

            coverage = coverage_fields(translations, *room_surfaces(walls, src.walkable.polygons,
                                                                    src.walkable.ceiling_heights))
        stage("visibility")
    fields, fields_attrs = {}, {}
    n_t = len(translations) if params.distance_fields else 1
    start("fields", n_t)
    if params.distance_fields:
        from ldlmap.map.fields3d import FieldParams, compute_fields

        cb = (lambda d, t: progress("fields", d, t)) if progress else None  # per chunk of translations
        dist, fields_attrs = compute_fields(lines, groups, translations, FieldParams(num_groups=len(principal)),
                                            device=params.device, visibility=visibility,
                                            progress=cb)
        fields = {"distances": dist}
    stage("fields", n_t)
    features = None
    with_features = params.features != "none" and src.points is not None
    n_views = min(max(1, params.num_views), len(translations)) if with_features else 1
    start("features", n_views)
    if with_features:
        cb = (lambda d, t: progress("features", d, t)) if progress else None
        features = compute_features(src.points, src.colors, translations, params, cb)
    stage("features", n_views)
    cloud_pts = cloud_cols = None
    if src.points is not None:
        rng = np.random.default_rng(params.seed)
        keep = rng.permutation(len(src.points))[: params.stored_cloud_points]
        keep.sort()
        cloud_pts = src.points[keep]
        cloud_cols = src.colors[keep] if src.colors is not None else None
    config = {**asdict(params), **(config or {}), "source": src.source, "translations": trans_info,
              "frame": frame_info,
              "length_filter": {"rule": rule, "threshold": float(threshold), "lambda_threshold": paper_threshold,
                                "robust_extent": extent},
              "principal_deviation_deg": [round(float(x), 3) for x in deviation], "principal_frame": frame_kind}
    if params.features == "none" or src.points is None:
        config["features"] = "none"
    m = LdlMap(
        name=name,
        bounds_min=bmin, bounds_max=bmax,
        lines_raw=lines_raw, lines=lines, line_groups=groups,
        length_threshold=threshold, kept_ratio=float(kept.mean()), line_lambda=lam,
        principal_directions=principal, translations=translations,
        cloud_points=cloud_pts, cloud_colors=cloud_cols, features=features, config=config,
        fields=fields, fields_attrs=fields_attrs, visibility=visibility, coverage=coverage,
        input_to_map=input_to_map,
    )
    start("write")
    write_map(output, m)
    stage("write")
    report.seconds["total"] = sum(report.seconds.values())
    report.counts = {
        "lines_raw": int(len(lines_raw)), "lines": int(len(lines)), "kept_ratio": float(kept.mean()),
        "translations": int(len(translations)),
        "visible_lines": float(visibility.sum(1).mean()) if visibility is not None else float(len(lines)),
        "views": features.num_views if features else 0,
        "keypoints": int(len(features.xyz)) if features else 0,
        "size_mb": output.stat().st_size / 1e6,
        "note": src.note,
        "frame_rotation_deg": frame_info["rotation_deg"], "scale": float(params.scale),
    }
    return report


def params_with(params: BuildParams, **changes: Any) -> BuildParams:
    """A copy of ``params`` with the non-None ``changes`` applied (for CLI options)."""
    return replace(params, **{k: v for k, v in changes.items() if v is not None})
