"""Lines cut to where the surfaces along them run with them: the final check that keeps a straight
line only where the planes beside it hold its direction, so that a straight chord or tangent of a
curved crease (a floor or ceiling meeting a curved wall, a vault meeting its end wall) is cut down
to the stretches of the crease it follows.

Every ``along_step`` along a line two tests look at the scan points (one per ``along_grid`` cell)
and the plane pieces they belong to. A straight edge is the meeting line of surfaces that each
contain its direction (a floor and a wall, a table top and its side, or one face ending there), so
a sample is off the edge when

- ``along_share`` or more of the points on planes within ``along_near`` across the line and
  ``along_slab`` along it lie on planes turned from the line by more than ``along_angle_deg`` (the
  next facet of a curved wall, past the end of the facet the line came from), or
- the points of one plane piece within ``along_face_reach`` across and ``along_face_slab`` along,
  fitted with a plane of their own, turn from the line by more than ``along_face_deg`` (a plane
  piece fitted across several facets of an arc holds the chord; its points turn with the facets).

Runs of ``along_min_run`` or more samples off the edge are cut out of the line; pieces shorter
than ``min_line`` are dropped. Points on no plane count for neither test, so a stretch with none
of them (a hole in the scan, an occluded crease) stays.

Stated behaviour on curved creases: the extractor returns the stretches of a straight line along
which the surfaces beside it hold its direction within about 5 deg, so along an arc that turns
more than that (the generator's fine polygons: 0.3 m facets turning 5-14 deg) it gives pieces about
as long as the stretch of arc within 5 deg of one direction, mostly below the paper's length
threshold, and no long chord. Where the scan holds few points beside the crease (fewer than
``along_face_points`` within reach: a crease seen from afar or at a grazing angle) the tests do not
decide and a chord can stay; measured in docs/measurements.md#along-lines.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlmap.lines3d.metrics import sample_segments
from ldlmap.lines3d.params import Lines3DParams
from ldlmap.lines3d.planes import PlaneRegions
from ldlmap.lines3d.smooth import thin_points

spatial = lazy_module("scipy.spatial")

FACE_BLOCK = 20_000  # samples per block of the local plane fits (bounds memory)


def _off_edge(x: np.ndarray, u: np.ndarray, reg: PlaneRegions, Q: np.ndarray, tree, params: Lines3DParams) -> np.ndarray:
    """Per sample point ``x`` (S, 3) on a line of direction ``u`` (S, 3): do the planes of the near
    points ``Q`` (indices into ``reg.points``) turn away from the line (see the module docstring)?"""
    k = min(params.along.neighbours, len(Q))
    d, j = tree.query(x, k=k, distance_upper_bound=np.hypot(params.along.near, params.along.slab), workers=-1)
    d, j = d.reshape(len(x), -1), j.reshape(len(x), -1)
    found = np.isfinite(d)
    q = Q[np.minimum(j, len(Q) - 1)]
    R = reg.points[q] - x[:, None, :]
    along = np.einsum("skj,sj->sk", R, u)
    across = np.linalg.norm(R - along[..., None] * u[:, None, :], axis=2)
    near = found & (np.abs(along) <= params.along.slab) & (across <= params.along.near)
    lab = reg.labels[q]
    on_plane = near & (lab >= 0)
    cos_n = np.abs(np.einsum("skj,sj->sk", reg.normals[np.maximum(lab, 0)], u))
    turned = on_plane & (cos_n > np.sin(np.radians(params.along.angle_deg)))
    n_turned, n_on = turned.sum(1), on_plane.sum(1)
    off = (n_turned >= params.along.min_points) & (n_turned >= params.along.share * np.maximum(n_on, 1))
    if params.along.face_reach > 0:
        # In blocks of samples: a building's lines have 10^5 samples, each with up to 300 neighbours.
        for b in range(0, len(x), FACE_BLOCK):
            off[b:b + FACE_BLOCK] |= _faces_turned(x[b:b + FACE_BLOCK], u[b:b + FACE_BLOCK], reg, Q, tree, params)
    return off


def _faces_turned(x: np.ndarray, u: np.ndarray, reg: PlaneRegions, Q: np.ndarray, tree, params: Lines3DParams) -> np.ndarray:
    """Per sample: does a plane piece near the line, fitted locally with a plane of its own, turn
    from the line (see the module docstring)? Per (sample, plane piece): moments, then eigh."""
    k = min(params.along.face_neighbours, len(Q))
    d, j = tree.query(x, k=k, distance_upper_bound=np.hypot(params.along.face_reach, params.along.face_slab), workers=-1)
    d, j = d.reshape(len(x), -1), j.reshape(len(x), -1)
    q = Q[np.minimum(j, len(Q) - 1)]
    R = reg.points[q] - x[:, None, :]
    along = np.einsum("skj,sj->sk", R, u)
    across = np.linalg.norm(R - along[..., None] * u[:, None, :], axis=2)
    lab = reg.labels[q]
    m = np.isfinite(d) & (np.abs(along) <= params.along.face_slab) & (across <= params.along.face_reach) & (lab >= 0)
    n_lab = len(reg.normals)
    cell = (np.arange(len(x))[:, None] * n_lab + np.maximum(lab, 0))[m]
    used, cell = np.unique(cell, return_inverse=True)
    cnt = np.bincount(cell, minlength=len(used))
    r = R[m]
    mean = np.stack([np.bincount(cell, r[:, i], len(used)) for i in range(3)], 1) / cnt[:, None]
    C = np.zeros((len(used), 3, 3))
    for i in range(3):
        for k2 in range(i, 3):
            C[:, i, k2] = C[:, k2, i] = np.bincount(cell, r[:, i] * r[:, k2], len(used)) / cnt - mean[:, i] * mean[:, k2]
    nrm = np.linalg.eigh(C)[1][:, :, 0]  # smallest eigenvector: the local plane's normal
    s = used // n_lab
    tilt = np.abs(np.einsum("gj,gj->g", nrm, u[s]))
    bad = (cnt >= params.along.face_points) & (tilt > np.sin(np.radians(params.along.face_deg)))
    return np.bincount(s[bad], minlength=len(x)) > 0


def cut_to_edges(lines: np.ndarray, reg: PlaneRegions, params: Lines3DParams) -> np.ndarray:
    """``lines`` (N, 2, 3) without the runs of ``along_min_run`` or more samples off the edge of the
    planes in ``reg`` (see the module docstring), pieces shorter than ``min_line`` dropped."""
    if len(lines) == 0 or params.along.min_run <= 0 or len(reg.points) == 0:
        return lines
    Q = thin_points(reg.points, params.along.grid)
    x, seg = sample_segments(lines, params.along.step)
    u = lines[:, 1] - lines[:, 0]
    u = u / np.maximum(np.linalg.norm(u, axis=1), 1e-12)[:, None]
    off = _off_edge(x, u[seg], reg, Q, spatial.cKDTree(reg.points[Q]), params)
    # Runs of equal flags within a line; runs off the edge shorter than along_min_run are kept.
    line_start = np.r_[True, seg[1:] != seg[:-1]]
    new = line_start | np.r_[True, off[1:] != off[:-1]]
    run = np.cumsum(new) - 1
    start = np.flatnonzero(new)
    count = np.diff(np.r_[start, len(x)])
    keep = ~(off[start] & (count >= params.along.min_run))[run]
    # Pieces: maximal runs of kept samples within a line, each sample standing for an equal share of it.
    i0 = np.flatnonzero(keep & (line_start | ~np.r_[True, keep[:-1]]))
    i1 = np.flatnonzero(keep & (np.r_[line_start[1:], True] | ~np.r_[keep[1:], True]))
    n_s = np.bincount(seg, minlength=len(lines))
    first = np.cumsum(n_s) - n_s
    s = seg[i0]
    f0, f1 = (i0 - first[s]) / n_s[s], (i1 + 1 - first[s]) / n_s[s]
    d = lines[s, 1] - lines[s, 0]
    out = np.stack([lines[s, 0] + f0[:, None] * d, lines[s, 0] + f1[:, None] * d], axis=1)
    return out[np.linalg.norm(out[:, 1] - out[:, 0], axis=1) >= max(params.merge.min_line, params.merge.min_segment)]
