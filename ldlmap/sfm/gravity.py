"""The input's up axis, and the rotation that makes a map z-up (DESIGN.md section 11).

Sources, first that applies:

1. ``--up AXIS`` (the user's word: x, y, z, -x, -y, -z of the input frame);
2. registered cameras (COLMAP): photos are mostly upright, so the mean of the images' +y axes
   (image down) in world coordinates points down; used when they agree (mean resultant length
   >= ``min_camera_agreement``: random orientations give ~1 / sqrt(M));
3. the lines (:func:`up_from_lines`), a heuristic scored per principal direction, sum of:

   * its share of the line length along the three directions (within 5 degrees) minus its share
     of their robust extents: a plain box has edge length along each axis in proportion to its
     extent, and a room or building adds vertical edges beyond that (wall corners, door and
     window jambs, furniture legs and sides; docs/measurements.md#gravity-vertical-share);
   * the share of all the length it explains as vertical or horizontal: a vertical explains
     horizontal edges of every azimuth (walls at any angle, turned furniture), a horizontal axis
     only its own lines and those exactly perpendicular to it, so off-Manhattan horizontals, or
     a second horizontal direction that is not at 90 degrees (SfM maps), count for the vertical;
   * how lopsided the line length is along it: gravity puts furniture, doors and windows on the
     floor (most of the length lies below the middle). The same share gives the sign, the floor
     side down: a guess that the build reports. A bare box, or a facade without depth, leaves the
     axis ambiguous: ``--up``.

An estimate from the user or the cameras is then snapped to the lines' principal direction
within ``snap_deg`` (photos tilted up at a facade bias the camera mean; a frame's axis is only
roughly vertical): the vertical edges of the structure are the precise vertical. A frame whose up
lies within ``keep_deg`` of +z is kept as it is (scans and datasets are levelled; the search
tolerates small tilts), so z-up inputs give the identity; from the lines alone, whose sign is a
guess, so is one whose up lies within ``keep_deg`` of -z (never turn a scan upside down).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.errors import InputError


@dataclass(frozen=True)
class GravityParams:
    """Parameters of :func:`estimate_up` and :func:`map_rotation`."""

    min_camera_agreement: float = 0.75  # |mean of the cameras' down axes| needed to trust them
    min_cameras: int = 3
    snap_deg: float = 10.0  # user / camera up moved onto a principal direction this close
    keep_deg: float = 5.0  # an up this close to +z keeps the input frame (identity)
    axis_tol_deg: float = 5.0  # a line is vertical / horizontal within this angle
    max_lines: int = 3000  # the longest lines used (voting cost)


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
    return (-m / r if r > 1e-12 else np.array([0.0, 0.0, 1.0])), r


def up_from_lines(lines: np.ndarray, principal: np.ndarray, tol_deg: float = 5.0) -> tuple[np.ndarray, float, float]:
    """Up from lines alone (module docstring): ``(up, sign_share, margin)``: the chosen principal
    direction, signed so that ``sign_share`` (>= 0.5) of the line length lies below the middle of
    the robust extent along it, and the margin of its score over the next direction's."""
    from ldlmap.lines3d.principal import line_directions

    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    P = np.asarray(principal, dtype=np.float64)
    d, w = line_directions(L)
    w = w / max(w.sum(), 1e-12)
    c = np.abs(d @ P.T)  # (N, 3)
    par = c >= np.cos(np.radians(tol_deg))
    perp = c <= np.sin(np.radians(tol_deg))
    h = L.reshape(-1, 3) @ P.T  # end points along each direction
    lo, hi = np.percentile(h, [2.0, 98.0], axis=0)
    extent = np.maximum(hi - lo, 0.0)
    along = w @ par
    mid = (L.mean(1) @ P.T) < 0.5 * (lo + hi)  # (N, 3) line below the middle along each direction
    below = w @ mid
    score = (along / max(along.sum(), 1e-12) - extent / max(extent.sum(), 1e-12) + w @ (par | perp)
             + np.abs(below - 0.5))
    order = np.argsort(-score)
    k = int(order[0])
    return (P[k] if below[k] >= 0.5 else -P[k]), max(below[k], 1.0 - below[k]), float(score[k] - score[order[1]])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(float(a @ b), -1.0, 1.0))))


def estimate_up(lines: np.ndarray, up: np.ndarray | None = None, camera_down: np.ndarray | None = None,
                params: GravityParams = GravityParams()) -> tuple[UpEstimate, np.ndarray]:
    """The input's up axis (module docstring) and the lines' principal directions (3, 3) it used."""
    from ldlmap.lines3d.principal import principal_directions_3d

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
        v, share, margin = up_from_lines(L, P, params.axis_tol_deg)
        weak = margin < 0.05 or share < 0.55
        note += (f"up axis {'barely ' if weak else ''}told by the lines (score margin {margin:.2f}, {share:.0%} of "
                 "the line length on the floor side): pass --up if the map is not upright")
        return UpEstimate(v, "lines", None, agreement, share, note, weak), P
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
    from ldlmap.core.frame import rotation_to_z

    z = np.array([0.0, 0.0, 1.0])
    ang = _angle_deg(est.up, z)
    if ang <= params.keep_deg or (est.source == "lines" and 180.0 - ang <= params.keep_deg):
        return np.eye(3)
    P = np.asarray(principal, dtype=np.float64)
    horiz = [p for p in P if abs(p @ est.up) < np.sin(np.radians(45.0))]
    return rotation_to_z(est.up, horiz[0] if horiz else None)
