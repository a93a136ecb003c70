"""The input's up axis, and the rotation that makes a map z-up (docs/inputs.md).

Sources, first that applies:

1. ``--up AXIS`` (the user's word: x, y, z, -x, -y, -z of the input frame);
2. registered cameras (COLMAP): photos are mostly upright, so the mean of the images' +y axes
   (image down) in world coordinates points down; used when they agree (mean resultant length
   >= ``min_camera_agreement``: random orientations give ~1 / sqrt(M));
3. the lines (:func:`up_from_lines`), scored per principal direction as a candidate vertical
   (:func:`axis_scores`): vertical structure (its share of the line length along the three axes
   of its frame beyond its share of their extents: wall corners, jambs and furniture sides add
   vertical edges beyond a box's proportions), the share of all the length it explains as
   vertical or horizontal (walls and furniture at any azimuth), and how lopsided the length is
   along it (furniture, doors and windows stand on the floor; the same share gives the sign, a
   guess the build reports).

Scans, meshes and layouts are z-up by convention (docs/inputs.md): when a principal
direction lies within ``keep_deg`` of the input's z axis, z stays the vertical unless another
direction, nearly perpendicular to z, beats it by ``override_margin`` with at least
``override_structure`` more vertical structure *and* a smaller extent (a bare layout shell's
proportions cannot tell: z then stays) (rooms are wider than tall; sloped ceiling edges and beams run
long and obliquely, so they cannot turn an upright room over); the note says why. When z is kept
although another direction scores higher, or has more structure and a smaller extent, the build
warns. Without such a direction (SfM frames) the best score wins, with a warning when it barely
does or when structure and extent point elsewhere.

An estimate from the user or the cameras is then snapped to the lines' principal direction
within ``snap_deg`` (photos tilted up at a facade bias the camera mean; a frame's axis is only
roughly vertical): the vertical edges of the structure are the precise vertical. A frame whose up
lies within ``keep_deg`` of +z is kept as it is, so z-up inputs give the identity; from the lines
alone, whose sign is a guess, so is one whose up lies within ``keep_deg`` of -z (never turn a scan
upside down: the build warns when the lines put the floor on top).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.frame import rotation_to_z
from ldlmap.lines3d.principal import line_directions, principal_directions_3d

Z = np.array([0.0, 0.0, 1.0])  # the input's z axis: up by the convention of scans, meshes and layouts


@dataclass(frozen=True)
class GravityParams:
    """Parameters of :func:`estimate_up` and :func:`map_rotation`."""

    min_camera_agreement: float = 0.75  # |mean of the cameras' down axes| needed to trust them
    min_cameras: int = 3
    snap_deg: float = 10.0  # user / camera up moved onto a principal direction this close
    keep_deg: float = 5.0  # an up this close to +z keeps the input frame (identity)
    axis_tol_deg: float = 5.0  # a line is vertical / horizontal within this angle
    max_lines: int = 3000  # the longest lines used (voting cost)
    override_margin: float = 0.1  # score lead another axis needs to turn an input whose z is a principal direction
    override_structure: float = 0.2  # ... and its vertical structure lead over z: bare layout shells reach 0.17, a
    # room with doors or furniture turned sideways 0.23-0.32 (docs/measurements.md#up-axis-rule)
    across_deg: float = 15.0  # ... and it must be this close to perpendicular to z (z then a wall direction)
    weak_margin: float = 0.05  # a lead smaller than this barely tells the axis (warning)
    weak_share: float = 0.55  # a floor-side share smaller than this barely tells the sign (warning)
    upside_down_share: float = 0.35  # a kept z with less of the length below its middle: floor on top?


@dataclass(frozen=True)
class UpEstimate:
    """The input frame's up axis and how it was found."""

    up: np.ndarray  # (3,) unit vector, input frame
    source: str  # user | cameras | lines
    snapped_deg: float | None = None  # angle moved onto the lines' vertical (None: not snapped)
    camera_agreement: float | None = None  # resultant length of the cameras' down axes
    sign_share: float | None = None  # lines: share of line length on the chosen floor side
    note: str = ""  # one line for the user ("" when there is nothing to say)
    weak: bool = False  # lines: the axis or its sign is barely told (the user should check, or pass --up)
    kept_z: bool = False  # lines: the input's z axis kept as the vertical (z-up convention)


@dataclass(frozen=True)
class AxisScores:
    """Evidence that each candidate direction is the vertical (arrays over the candidates)."""

    structure: np.ndarray  # its share of the line length along its frame's axes minus its share of their extents
    extent: np.ndarray  # its share of its frame's robust extents
    below: np.ndarray  # share of the line length whose midpoint lies below the middle along it
    explained: np.ndarray  # share of the line length parallel or perpendicular to it

    @property
    def total(self) -> np.ndarray:
        """The lines' score of each candidate (module docstring, source 3)."""
        return self.structure + np.abs(self.below - 0.5) + self.explained


def _longest(lines: np.ndarray, n: int) -> np.ndarray:
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    if len(L) <= n:
        return L
    length = np.linalg.norm(L[:, 1] - L[:, 0], axis=1)
    return L[np.sort(np.argsort(-length, kind="stable")[:n])]


def up_from_cameras(down_axes: np.ndarray) -> tuple[np.ndarray, float]:
    """Up (unit, world) from the cameras' image-down axes (M, 3) in world coordinates, and their
    agreement: the length of the mean down axis (1: all parallel)."""
    D = np.asarray(down_axes, dtype=np.float64).reshape(-1, 3)
    if len(D) == 0 or not np.all(np.isfinite(D)):
        raise InputError("camera down axes must be finite (M, 3) vectors")
    D = D / np.maximum(np.linalg.norm(D, axis=1, keepdims=True), 1e-12)
    m = D.mean(0)
    r = float(np.linalg.norm(m))
    return (-m / r if r > 1e-12 else Z.copy()), r


def _frame(P: np.ndarray, k: int) -> np.ndarray:
    """Orthonormal rows: candidate ``k`` and the other principal direction most nearly perpendicular
    to it (made exactly so), then their cross product."""
    v = P[k] / np.linalg.norm(P[k])
    others = [j for j in range(len(P)) if j != k]
    h = P[min(others, key=lambda j: abs(P[j] @ v))] if others else np.eye(3)[int(np.argmin(np.abs(v)))]
    h = h - (h @ v) * v
    if np.linalg.norm(h) < 1e-6:
        h = np.cross(v, np.eye(3)[int(np.argmin(np.abs(v)))])
    h = h / np.linalg.norm(h)
    return np.stack([v, h, np.cross(v, h)])


def axis_scores(lines: np.ndarray, principal: np.ndarray, tol_deg: float = 5.0) -> AxisScores:
    """The evidence (:class:`AxisScores`) that each principal direction is the vertical."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    P = np.asarray(principal, dtype=np.float64)
    d, w = line_directions(L)
    w = w / max(w.sum(), 1e-12)
    ends, mids = L.reshape(-1, 3), L.mean(1)
    cos_t, sin_t = np.cos(np.radians(tol_deg)), np.sin(np.radians(tol_deg))
    out = np.zeros((4, len(P)))
    for k in range(len(P)):
        F = _frame(P, k)
        c = np.abs(d @ F.T)
        along = w @ (c >= cos_t)
        lo, hi = np.percentile(ends @ F.T, [2.0, 98.0], axis=0)
        extent = np.maximum(hi - lo, 0.0)
        share = extent[0] / max(extent.sum(), 1e-12)
        out[:, k] = (along[0] / max(along.sum(), 1e-12) - share, share,
                     w @ (mids @ F[0] < 0.5 * (lo[0] + hi[0])), w @ ((c[:, 0] >= cos_t) | (c[:, 0] <= sin_t)))
    return AxisScores(*out)


def _vec(v: np.ndarray) -> str:
    return f"({v[0]:.3f}, {v[1]:.3f}, {v[2]:.3f})"


def _signed(P: np.ndarray, s: AxisScores, k: int) -> tuple[np.ndarray, float]:
    """Candidate ``k`` pointing away from the floor side (where most of the line length lies), and
    that side's share of the length."""
    return (P[k] if s.below[k] >= 0.5 else -P[k]), float(max(s.below[k], 1.0 - s.below[k]))


def _z_kept_or_overridden(P: np.ndarray, s: AxisScores, kz: int, params: GravityParams) -> UpEstimate:
    """The z-up convention (module docstring): candidate ``kz`` lies along the input's z axis."""
    total = s.total
    best = int(np.argmax(total))
    lead = float(total[best] - total[kz])
    across = np.abs(P @ P[kz]) <= np.sin(np.radians(params.across_deg))
    rival = across & (s.structure > s.structure[kz]) & (s.extent < s.extent[kz])
    told = s.structure[best] - s.structure[kz] >= params.override_structure  # else the lines cannot tell: z stays
    if best != kz and rival[best] and told and lead >= params.override_margin:
        up, share = _signed(P, s, best)
        weak = share < params.weak_share
        sign = f"; the sign is a guess, {share:.0%} of the length on the floor side" if weak else ""
        note = (f"the lines say the input's z axis is horizontal: this up has {s.structure[best]:+.2f} vertical "
                f"structure and {s.extent[best]:.0%} of the extent, z {s.structure[kz]:+.2f} and {s.extent[kz]:.0%} "
                f"(score lead {lead:.2f}{sign}); pass --up z to keep the input frame")
        return UpEstimate(up, "lines", sign_share=share, note=note, weak=weak)
    up, share = _signed(P, s, kz)
    kept = "kept the input's z axis as up (scans, meshes and layouts are z-up) though "
    below_z = share if up @ Z > 0 else 1.0 - share
    second = int(np.argsort(-total)[1])
    if best != kz:
        note, weak = f"{kept}the lines lean to {_vec(_signed(P, s, best)[0])} (score lead {lead:.2f})", True
    elif rival.any():
        k = int(np.flatnonzero(rival)[0])
        note, weak = f"{kept}{_vec(_signed(P, s, k)[0])} has more vertical structure and a smaller extent", True
    elif below_z < params.upside_down_share:
        note = (f"the lines put {1.0 - below_z:.0%} of their length above the middle of the input's z axis: pass "
                "--up -z if the input is upside down")
        return UpEstimate(up, "lines", sign_share=share, note=note, weak=True, kept_z=True)
    elif total[kz] - total[second] < params.weak_margin:
        note, weak = (f"kept the input's z axis as up; the lines barely tell it from {_vec(_signed(P, s, second)[0])} "
                      f"(score margin {total[kz] - total[second]:.2f})"), False
    else:
        return UpEstimate(up, "lines", sign_share=share, kept_z=True)
    return UpEstimate(up, "lines", sign_share=share, note=note + ": pass --up if the map is not upright",
                      weak=weak, kept_z=True)


def up_from_lines(lines: np.ndarray, principal: np.ndarray,
                  params: GravityParams = GravityParams()) -> UpEstimate:
    """Up from lines alone (module docstring): the chosen principal direction, signed so that most
    of the line length lies below the middle of its robust extent (``sign_share`` >= 0.5)."""
    P = np.asarray(principal, dtype=np.float64)
    s = axis_scores(lines, P, params.axis_tol_deg)
    cos_z = np.abs(P @ Z)
    if cos_z.max() >= np.cos(np.radians(params.keep_deg)):
        return _z_kept_or_overridden(P, s, int(np.argmax(cos_z)), params)
    total = s.total
    order = np.argsort(-total)
    best, margin = int(order[0]), float(total[order[0]] - total[order[1]])
    up, share = _signed(P, s, best)
    odd = [what for what, ok in (("more vertical structure", s.structure[best] >= s.structure.max()),
                                 ("a smaller extent", s.extent[best] <= s.extent.min())) if not ok]
    weak = margin < params.weak_margin or share < params.weak_share or bool(odd)
    note = (f"up axis {'barely ' if weak else ''}told by the lines (score margin {margin:.2f}, {share:.0%} of "
            f"the line length on the floor side{'; another axis has ' + ' and '.join(odd) if odd else ''}): "
            "pass --up if the map is not upright")
    return UpEstimate(up, "lines", sign_share=share, note=note, weak=weak)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(float(a @ b), -1.0, 1.0))))


def estimate_up(lines: np.ndarray, up: np.ndarray | None = None, camera_down: np.ndarray | None = None,
                params: GravityParams = GravityParams()) -> tuple[UpEstimate, np.ndarray]:
    """The input's up axis (module docstring) and the lines' principal directions (3, 3) it used."""
    L = _longest(lines, params.max_lines)
    P = principal_directions_3d(L)
    note, agreement = "", None
    if up is None and camera_down is not None and len(camera_down) >= params.min_cameras:
        cam_up, agreement = up_from_cameras(camera_down)
        if agreement >= params.min_camera_agreement:
            up = cam_up
        else:
            note = f"the {len(camera_down)} cameras disagree on down (agreement {agreement:.2f}): "
    if up is None:
        est = up_from_lines(L, P, params)
        return (replace(est, camera_agreement=agreement, note=note + est.note) if note else est), P
    source = "user" if agreement is None else "cameras"
    u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    cos = P @ u
    k = int(np.argmax(np.abs(cos)))
    snapped = None
    ang = _angle_deg(np.sign(cos[k]) * P[k], u)
    if ang <= params.snap_deg:
        u, snapped = np.sign(cos[k]) * P[k], ang
    if source == "cameras":
        note = f"up axis from {len(camera_down)} cameras (agreement {agreement:.2f})"
    return UpEstimate(u, source, snapped, agreement, None, note), P


def map_rotation(est: UpEstimate, principal: np.ndarray, params: GravityParams = GravityParams()) -> np.ndarray:
    """The rotation input -> map: identity when ``est.up`` is within ``keep_deg`` of +z (for lines,
    whose sign is a guess, of either +z or -z), else up to +z with the strongest horizontal
    principal direction to +x (so that walls run along the axes and lattices)."""
    ang = _angle_deg(est.up, Z)
    if ang <= params.keep_deg or (est.source == "lines" and 180.0 - ang <= params.keep_deg):
        return np.eye(3)
    P = np.asarray(principal, dtype=np.float64)
    horiz = [p for p in P if abs(p @ est.up) < np.sin(np.radians(45.0))]
    return rotation_to_z(est.up, horiz[0] if horiz else None)
