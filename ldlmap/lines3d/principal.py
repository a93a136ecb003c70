"""Principal 3D directions of a line map by voting (paper supp. "Principal
Direction Computation").

Every line votes for the bins of a half icosphere (level 5: 5121 directions, ~2.2 degrees apart)
within ``vote_angle_deg`` of its direction, with weight = its length (long lines are the reliable
structure of a room; counting lines instead lets clutter of many short pieces win). The best bin
is refined by the length-weighted mean of the sign-aligned directions within
``refine_angle_deg`` of it (``refine_steps`` times, re-centred); lines with ``|cos| > cos_thresh``
to the refined direction are removed and the vote repeats, ``k`` times (k3D = 3). With ``k = 3``
the triplet is made right-handed by flipping the third direction when ``det < 0``.
:func:`manhattan_frame` then gives the nearest orthonormal frame (the paper's assumption), and
:func:`principal_frame` chooses between it and an Atlanta frame (the vertical and the two main
horizontal directions, at whatever angle they meet, and any further horizontal direction that holds
a stated share of the line length) for rooms whose walls are not at right angles.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import half_icosphere_points, normalize
from ldlmap.core.lazy import lazy_module

hierarchy = lazy_module("scipy.cluster.hierarchy")

HORIZONTAL_DEG = 10.0  # lines and directions this close to horizontal (degrees) count as horizontal


@dataclass(frozen=True)
class Principal3DParams:
    """Parameters of :func:`principal_directions_3d`."""

    sphere_level: int = 5  # icosphere level of the voting grid (halved)
    vote_angle_deg: float = 3.0  # a line votes for every bin this close to its direction
    refine_angle_deg: float = 5.0  # inliers averaged to refine the winning bin ...
    refine_steps: int = 3  # ... this many times, each cone centred on the last mean
    cos_thresh: float = 0.95  # lines with |cos| above this to a found direction are removed


def line_directions(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (N, 3) and lengths (N,) of segments (N, 2, 3)."""
    L = np.asarray(lines, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (2, 3):
        raise InputError(f"lines must have shape (N, 2, 3), got {L.shape}")
    if not np.all(np.isfinite(L)):
        raise InputError("lines contain NaN or infinite coordinates")
    v = L[:, 1] - L[:, 0]
    length = np.linalg.norm(v, axis=1)
    return normalize(v), length


def _any_perpendicular(d: np.ndarray) -> np.ndarray:
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    return normalize(np.cross(d, a))


def principal_directions_3d(lines: np.ndarray, k: int = 3,
                            params: Principal3DParams = Principal3DParams()) -> np.ndarray:
    """Top ``k`` (k_3D, paper default 3) line directions (k, 3), rows unit vectors, right-handed when ``k == 3``.

    When the lines run out before ``k`` directions are found (e.g. all lines in two directions)
    the missing ones are completed orthogonally (cross product / any perpendicular).
    """
    d, w = line_directions(lines)
    keep = w > 1e-9
    d, w = d[keep], w[keep]
    if len(d) == 0:
        raise InputError("no (non-degenerate) lines to estimate principal directions from")
    if k < 1:
        raise InputError(f"k must be >= 1, got {k}")
    bins = half_icosphere_points(params.sphere_level)
    cos_vote = np.cos(np.radians(params.vote_angle_deg))
    cos_ref = np.cos(np.radians(params.refine_angle_deg))
    found: list[np.ndarray] = []
    alive = np.ones(len(d), bool)
    for _ in range(k):
        if not alive.any():
            break
        da, wa = d[alive], w[alive]
        score = np.zeros(len(bins))
        block = max(1, int(2e6 // len(bins)))
        for s in range(0, len(da), block):
            c = np.abs(da[s:s + block] @ bins.T)
            score += (wa[s:s + block, None] * (c >= cos_vote)).sum(axis=0)
        p = bins[int(np.argmax(score))]
        for _ in range(params.refine_steps):  # re-centred: a cone off the true direction biases the mean
            c = da @ p
            inl = np.abs(c) >= cos_ref
            if not inl.any():
                break
            p = normalize((np.sign(c[inl]) * wa[inl])[:, None].T @ da[inl])[0]
        found.append(p)
        alive &= np.abs(d @ p) <= params.cos_thresh
    while len(found) < k:
        if len(found) == 1:
            found.append(_any_perpendicular(found[0]))
        elif len(found) == 2:
            found.append(normalize(np.cross(found[0], found[1])))
        else:  # k > 3 and no lines left: repeat the last direction's perpendicular
            found.append(_any_perpendicular(found[-1]))
    P = np.stack(found[:k])
    if k == 3 and np.linalg.det(P) < 0:
        P[2] = -P[2]
    return P


def assign_line_groups(directions_of_lines: np.ndarray, principal: np.ndarray,
                       cos_thresh: float = 0.95, up: np.ndarray | None = None,
                       elevation_deg: float = 10.0) -> np.ndarray:
    """Group index (N,) of each line: the principal direction with the largest ``|cos|`` when it
    exceeds ``cos_thresh`` (a line joins group j when ``|d . p_j| > 0.95``), else -1.

    With ``up``, a line joins only the directions whose elevation (angle above the horizontal
    plane of ``up``) is within ``elevation_deg`` of its own: a sloped ceiling's edge 15 deg off a
    wall direction stays out of that horizontal's group (in a panorama its arc does not pass
    through the wall direction's vanishing point, so the query would not put it there either).
    """
    D = normalize(np.asarray(directions_of_lines, dtype=np.float64))
    Pd = normalize(np.asarray(principal, dtype=np.float64))
    if D.ndim != 2 or D.shape[1] != 3 or Pd.ndim != 2 or Pd.shape[1] != 3:
        raise InputError("directions must have shapes (N, 3) and (k, 3)")
    if len(D) == 0:
        return np.zeros(0, np.int64)
    c = np.abs(D @ Pd.T)
    if up is not None:
        u = normalize(np.asarray(up, dtype=np.float64)[None])[0]
        elevation = np.degrees(np.arcsin(np.clip(np.abs(np.concatenate([D, Pd]) @ u), 0.0, 1.0)))
        far = np.abs(elevation[:len(D), None] - elevation[None, len(D):]) > elevation_deg
        c = np.where(far, 0.0, c)
    best = np.argmax(c, axis=1)
    return np.where(c[np.arange(len(D)), best] > cos_thresh, best, -1).astype(np.int64)


def manhattan_frame(lines: np.ndarray, estimated: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0),
                    horizontal_deg: float = 15.0, vote_deg: float = 2.0,
                    refine_deg: float = 5.0, up_known: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The orthonormal (Manhattan) frame nearest the lines, and each estimated direction's angle to it.

    The paper assumes three orthogonal principal directions; voting them one by one does not
    enforce it (an SfM map's may be far from perpendicular: docs/measurements.md#manhattan-frame).
    The frame keeps the vertical (``up`` itself when ``up_known``: the user, the cameras or a layout
    gave it; else the ``estimated`` row closest to ``up`` when within 20 degrees, else ``up``) and fits the horizontals to the data rather than to the
    estimated directions: the azimuths of the lines within ``horizontal_deg`` of horizontal, folded
    modulo 90 degrees, vote (length-weighted, +-``vote_deg``) for the pair of perpendicular
    horizontals, refined by the circular mean of the votes within ``refine_deg``. So every
    horizontal line supports the pair, a spurious third direction does not pull it, and when the
    estimate was orthogonal the frame equals it to the voting precision. Rows are ordered like
    ``estimated`` (each to its nearest frame axis) and right-handed. Returns
    ``(frame (3, 3), deviation_deg (3,))``.
    """
    E = np.asarray(estimated, dtype=np.float64)
    if E.shape != (3, 3):
        raise InputError(f"estimated principal directions must have shape (3, 3), got {E.shape}")
    u = normalize(np.asarray(up, dtype=np.float64)[None])[0]
    d, w = line_directions(lines)
    kv, v = _vertical(E, u, up_known)
    e1 = _any_perpendicular(v)
    e2 = np.cross(v, e1)
    hz = (np.abs(d @ v) < np.sin(np.radians(horizontal_deg))) & (w > 1e-12)
    if hz.any():  # azimuths folded modulo 90 degrees
        phi0 = _azimuth_peak(np.degrees(np.arctan2(d[hz] @ e2, d[hz] @ e1)), w[hz], 90.0, vote_deg, refine_deg)
    else:  # no horizontal line: the estimated horizontal closest to the plane
        rest = [E[i] for i in range(3) if i != kv]
        h = rest[int(np.argmin([abs(r @ v) for r in rest]))]
        phi0 = np.degrees(np.arctan2(h @ e2, h @ e1))
    h1 = np.cos(np.radians(phi0)) * e1 + np.sin(np.radians(phi0)) * e2
    F = _order_like(np.stack([v, h1, np.cross(v, h1)]), E, kv, pin_vertical=False)
    return F, _deviation(F, E)


@dataclass(frozen=True)
class FrameParams:
    """Parameters of :func:`principal_frame` (docs/measurements.md#atlanta-frame)."""

    horizontal_deg: float = HORIZONTAL_DEG  # lines this close to horizontal give the horizontal directions
    atlanta_deg: float = 10.0  # Atlanta frame when the two main horizontals are more than this from perpendicular
    sloped_share: float = 0.02  # a room is sloped (its ceiling) when more than this share of the line length
    # is inclined (10-80 deg from horizontal); its frame then gets inclined directions
    separate_deg: float = 26.0  # the second horizontal: among lines at least this far from the first
    # (closer directions could not be told apart: the map's directions must differ by arccos 0.9)
    vote_deg: float = 2.0  # azimuth votes smoothed over +- this
    refine_deg: float = 5.0  # a direction is the circular mean of the azimuths this close to its peak
    max_horizontals: int = 4  # Atlanta frames: at most this many horizontal directions (the map then has
    # 1 + this many principal directions; docs/measurements.md#atlanta-many)
    min_share: float = 0.08  # ... each beyond the first holding at least this share of the horizontal line
    # length (within refine_deg of it), so clutter (a table at an angle) adds no direction
    extra_share: float = 0.1  # a room whose two main horizontals are perpendicular keeps the Manhattan
    # frame unless its other horizontal directions hold at least this share of the horizontal length
    max_inclined: int = 2  # sloped ceilings: at most this many inclined directions added to the frame (a
    # gable's two slopes; docs/measurements.md#inclined-directions)
    inclined_share: float = 0.02  # ... each holding at least this share of all the line length
    inclined_apart_deg: float = 12.0  # ... and at least this far from every other direction (a 15-deg slope
    # is 15 deg from its horizontal; ldlmap.map.validate.MAX_PRINCIPAL_COS)
    inclined_max_deg: float = 60.0  # ... rising at most this much (ceilings slope 15-45 deg; steeper lines are
    # walls' or an SfM model's leaning verticals, 15 deg off when its gravity is known) ...
    inclined_min_lines: int = 2  # ... and held by at least this many lines (a slope meets two walls) ...
    inclined_chain_m: float = 1.0  # ... of which those along one crease (pieces whose axes lie within
    inclined_chain_gap_m: float = 0.15  # this of each other) hold at least this length (metres: maps are metric).
    # A sparse scan's plane outlines zigzag in parallel pieces near the length threshold, side by side, not end
    # to end: in flat rooms their longest crease holds 0.3-0.7 m, a sloped ceiling's 1.2-5.6 m
    # (docs/measurements.md#inclined-evidence)


def _vertical(E: np.ndarray, u: np.ndarray, known: bool = False) -> tuple[int, np.ndarray]:
    """Index of the estimated row closest to ``u`` and the vertical: ``u`` when ``known`` (gravity
    from the user, the cameras or a layout: an SfM model's most vertical line direction may lean 15
    deg), else that row (sign towards ``u``) when within 20 degrees of ``u``, else ``u``."""
    kv = int(np.argmax(np.abs(E @ u)))
    if known:
        return kv, u
    v = E[kv] * np.sign(E[kv] @ u)
    return kv, (v if v @ u >= np.cos(np.radians(20.0)) else u)


def _azimuth_peak(phi: np.ndarray, w: np.ndarray, period: float, vote_deg: float,
                  refine_deg: float) -> float:
    """The length-weighted mode of azimuths ``phi`` (degrees, modulo ``period``): the smoothed
    histogram's peak refined by the circular mean within ``refine_deg``."""
    bins = 0.25
    n = int(round(period / bins))
    hist = np.bincount((np.mod(phi, period) / bins).astype(np.int64) % n, w, n)
    k = int(round(vote_deg / bins))
    smooth = sum(np.roll(hist, s) for s in range(-k, k + 1))
    peak = (np.argmax(smooth) + 0.5) * bins
    near = np.abs((phi - peak + period / 2) % period - period / 2) <= refine_deg
    turn = 360.0 / period  # the azimuths' period mapped onto a full turn for the circular mean
    ang = np.radians(turn * phi[near])
    mean = np.degrees(np.arctan2(w[near] @ np.sin(ang), w[near] @ np.cos(ang))) / turn
    return float(mean % period)


def _order_like(axes: np.ndarray, E: np.ndarray, kv: int, pin_vertical: bool = True) -> np.ndarray:
    """``axes`` (3, 3) reordered and signed like the rows of ``E``: the vertical (``axes[0]``) in
    row ``kv`` as it is (``pin_vertical``), or row ``kv`` first to take its closest axis, signed
    like it; the others greedily by ``|cos|``; the last horizontal row flipped if needed so the
    triplet is right-handed."""
    F = np.zeros((3, 3))
    rows = [i for i in range(3) if i != kv]
    if pin_vertical:
        free = [1, 2]
        F[kv] = axes[0]
    else:
        free, rows = [0, 1, 2], [kv] + rows
    for i in rows:
        j = max(free, key=lambda a: abs(axes[a] @ E[i]))
        free.remove(j)
        F[i] = axes[j] * (1.0 if axes[j] @ E[i] >= 0 else -1.0)
    if np.linalg.det(F) < 0:
        last = [i for i in range(3) if i != kv][-1]
        F[last] = -F[last]
    return F


def _deviation(F: np.ndarray, E: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.abs(np.sum(F * normalize(E), axis=1)), -1.0, 1.0)))


def _horizontal_azimuths(lines: np.ndarray, v: np.ndarray, params: FrameParams
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Azimuths (degrees modulo 180) and lengths of the lines within ``horizontal_deg`` of
    horizontal, and the horizontal basis ``e1``, ``e2`` they are measured in; None without any."""
    d, w = line_directions(lines)
    v = normalize(np.asarray(v, dtype=np.float64)[None])[0]
    e1 = _any_perpendicular(v)
    e2 = np.cross(v, e1)
    hz = (np.abs(d @ v) < np.sin(np.radians(params.horizontal_deg))) & (w > 1e-12)
    if not hz.any():
        return None
    return np.degrees(np.arctan2(d[hz] @ e2, d[hz] @ e1)) % 180.0, w[hz], e1, e2


def _apart(a: np.ndarray | float, b: float) -> np.ndarray | float:
    """Angle between azimuths modulo 180 degrees, in [0, 90]."""
    return np.abs((np.asarray(a) - b + 90.0) % 180.0 - 90.0)


def horizontal_peaks(lines: np.ndarray, v: np.ndarray, params: FrameParams = FrameParams()
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The main horizontal line directions (n, 3) (unit, perpendicular to ``v``; n in 2 ..
    ``max_horizontals``), the share of the horizontal line length within ``refine_deg`` of each
    (n,) and their azimuths (n,) in degrees, strongest first; None when the lines hold no two.

    Azimuths (modulo 180 degrees) of the lines within ``horizontal_deg`` of horizontal vote,
    length-weighted; each next direction is the peak among the lines at least ``separate_deg`` from
    every direction found (so a found direction's noise is not taken for another). The first two
    are found whatever their share (:func:`horizontal_directions`); a third and later one only with
    at least ``min_share`` of the length."""
    hz = _horizontal_azimuths(lines, v, params)
    if hz is None:
        return None
    phi, wh, e1, e2 = hz
    total = max(float(wh.sum()), 1e-12)
    found: list[float] = []
    shares: list[float] = []
    far = np.ones(len(phi), bool)
    while len(found) < max(2, params.max_horizontals) and far.any():
        a = _azimuth_peak(phi[far], wh[far], 180.0, params.vote_deg, params.refine_deg)
        if any(_apart(a, b) < params.separate_deg for b in found):  # the refined mean slid back towards one
            break
        share = float(wh[_apart(phi, a) <= params.refine_deg].sum()) / total
        if len(found) >= 2 and share < params.min_share:
            break
        found.append(a)
        shares.append(share)
        far &= _apart(phi, a) >= params.separate_deg
    if len(found) < 2:
        return None
    H = np.stack([np.cos(np.radians(a)) * e1 + np.sin(np.radians(a)) * e2 for a in found])
    return H, np.asarray(shares), np.asarray(found)


def horizontal_directions(lines: np.ndarray, v: np.ndarray, params: FrameParams = FrameParams()
                          ) -> tuple[np.ndarray, float] | None:
    """The two main horizontal line directions (2, 3) (unit, perpendicular to ``v``) and the angle
    between them in degrees (in [0, 90]), or None when the lines hold no two
    (:func:`horizontal_peaks`' first two)."""
    found = horizontal_peaks(lines, v, replace(params, max_horizontals=2))
    if found is None:
        return None
    H, _, azimuth = found
    return H, float(_apart(azimuth[1], azimuth[0]))


def longest_crease(lines: np.ndarray, direction: np.ndarray, gap_m: float) -> float:
    """The summed length of the largest set of ``lines`` (n, 2, 3), all about along ``direction``,
    that lie on one axis: their midpoints, seen along ``direction``, within ``gap_m`` of each other
    (single hierarchy.linkage). One crease broken into pieces sums up; parallel pieces side by side do not."""
    p = normalize(np.asarray(direction, dtype=np.float64)[None])[0]
    length = np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1)
    if len(lines) < 2:
        return float(length.sum())
    mids = lines.mean(axis=1)
    across = mids - np.outer(mids @ p, p)  # where each line's axis meets the plane perpendicular to the direction
    labels = hierarchy.fcluster(hierarchy.linkage(across, "single"), gap_m, "distance")
    return float(np.bincount(labels, length).max())


def inclined_peaks(lines: np.ndarray, frame: np.ndarray, v: np.ndarray, params: FrameParams = FrameParams()
                   ) -> np.ndarray:
    """Inclined line directions (n, 3), n <= ``max_inclined``, to add to ``frame`` (K, 3): the
    length-weighted 3D vote (:func:`principal_directions_3d`) among the lines 10 (``horizontal_deg``) to
    ``inclined_max_deg`` degrees from horizontal and at least ``inclined_apart_deg`` from every frame direction, each
    peak kept while it holds ``inclined_share`` of all the line length (within ``refine_deg``) and
    only with the evidence of a surface's edge: at least ``inclined_min_lines`` lines, and pieces of
    one crease holding ``inclined_chain_m`` (:func:`longest_crease`; a peak without it is passed over). A sloped ceiling's edges (the gable
    walls' tops, the slope's own creases) then form groups of their own instead of being left out
    of the loss, and a flat room's short scan artefacts add no direction."""
    d, w = line_directions(lines)
    v = normalize(np.asarray(v, dtype=np.float64)[None])[0]
    total = max(float(w.sum()), 1e-12)
    elevation = np.degrees(np.arcsin(np.clip(np.abs(d @ v), 0.0, 1.0)))
    cos_sep = np.cos(np.radians(params.inclined_apart_deg))
    alive = ((elevation > params.horizontal_deg) & (elevation <= params.inclined_max_deg) & (w > 1e-12)
             & np.all(np.abs(d @ np.asarray(frame).T) < cos_sep, axis=1))
    found: list[np.ndarray] = []
    L = np.asarray(lines, dtype=np.float64)
    while len(found) < params.max_inclined and alive.any():
        p = principal_directions_3d(L[alive], k=1)[0]
        held = (np.abs(d @ p) >= np.cos(np.radians(params.refine_deg))) & alive
        if float(w[held].sum()) < params.inclined_share * total:
            break
        if held.sum() >= params.inclined_min_lines and \
                longest_crease(L[held], p, params.inclined_chain_gap_m) >= params.inclined_chain_m:
            found.append(p * (1.0 if p @ v >= 0 else -1.0))
        alive &= np.abs(d @ p) < cos_sep
    return np.asarray(found, dtype=np.float64).reshape(-1, 3)


def principal_frame(lines: np.ndarray, estimated: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0),
                    params: FrameParams = FrameParams(), up_known: bool = False) -> tuple[np.ndarray, np.ndarray, str]:
    """The map's principal directions: the Manhattan frame, or an Atlanta frame where the walls
    are not at right angles, and inclined directions where the ceiling slopes. Returns ``(frame
    (K, 3), deviation_deg (3,), kind)``, kind ``"manhattan"`` (K = 3), ``"atlanta"`` (K = 3 .. 1 +
    ``max_horizontals``) or ``"sloped"`` (either of those and 0 .. ``max_inclined`` inclined rows).

    The vertical is kept as :func:`manhattan_frame` keeps it (``up`` itself when ``up_known``); the horizontals come from the
    horizontal lines only (:func:`horizontal_peaks`: sloped ceiling edges and other inclined lines
    do not compete). When the two main horizontal directions are within ``atlanta_deg`` of
    perpendicular (boxes), the Manhattan frame is used (:func:`manhattan_frame`, unchanged);
    otherwise the frame is (vertical, first, second horizontal): walls at 30-75 degrees keep their
    own directions instead of being folded onto a perpendicular pair. Rooms whose walls run in more
    than two horizontal directions (each further one holding at least ``min_share`` of the
    horizontal line length) keep them all, as rows 3 and on, whether or not the main two are
    perpendicular, once those further ones hold ``extra_share`` of the length together (below that,
    with a perpendicular main pair: the Manhattan frame, as for boxes). Where more than
    ``sloped_share`` of the line length is inclined (a sloped ceiling), the frame is ``"sloped"``:
    the main inclined directions (:func:`inclined_peaks`, none where none has the evidence of a crease)
    follow as the last rows, so the slope's edges form groups of their own in the map and in the
    query instead of joining a horizontal's group in the map only (the map build then groups lines
    by elevation, :func:`assign_line_groups` with ``up``). The first
    three rows are ordered like ``estimated`` and right-handed; ``deviation_deg``: each estimated
    direction's angle to its row.
    """
    E = np.asarray(estimated, dtype=np.float64)
    if E.shape != (3, 3):
        raise InputError(f"estimated principal directions must have shape (3, 3), got {E.shape}")
    u = normalize(np.asarray(up, dtype=np.float64)[None])[0]
    kv, v = _vertical(E, u, up_known)
    found = horizontal_peaks(lines, v, params)
    d, w = line_directions(lines)
    elevation = np.degrees(np.arcsin(np.clip(np.abs(d @ v), 0.0, 1.0)))
    inclined = (elevation > params.horizontal_deg) & (elevation < 90.0 - params.horizontal_deg)
    sloped = w[inclined].sum() > params.sloped_share * max(w.sum(), 1e-12)
    perpendicular = found is not None and 90.0 - float(_apart(found[2][1], found[2][0])) <= params.atlanta_deg
    if found is None or (perpendicular and found[1][2:].sum() < params.extra_share):
        F, dev = manhattan_frame(lines, E, u, up_known=up_known)
        F_all, kind = F, "manhattan"
    else:
        H = found[0]
        F = _order_like(np.concatenate([v[None], H[:2]]), E, kv)
        dev = _deviation(F, E)
        F_all, kind = np.concatenate([F, H[2:]]), "atlanta"
    if not sloped:
        return F_all, dev, kind
    tilted = inclined_peaks(lines, F_all, v, params) if params.max_inclined > 0 else np.zeros((0, 3))
    return np.concatenate([F_all, tilted]), dev, "sloped"
