"""3D line segments from an unorganized point cloud (DESIGN.md 5.1, paper sec. 3.1).

An equivalent of Lu Xiaohu et al. 2019 ("Fast 3D line segment detection from unorganized point
cloud") on numpy / scipy / OpenCV:

1. voxel downsampling (``voxel_size``) when the cloud is denser than that, the points in the
   voxels' Z-order (fast neighbour queries, the same result for any input order);
2. normals and surface variation ``lambda_0 / (lambda_0 + lambda_1 + lambda_2)`` from k-nearest
   neighbour covariances (one scipy k-d tree query, which also links the plane graph);
3. planar regions (robust to scan noise, down to 8 cm faces): dominant normal orientations
   (greedy peaks of the sign-free normal histogram on an icosphere), then per orientation the
   strongest peaks of the histogram of offsets ``x . n`` claim, strongest first, every point
   within ``plane_tol`` whose normal agrees; each plane is split into kNN-connected pieces and
   each piece gets a least-squares plane. Offsets pool all points of a plane, so a table leg's
   face or a frame 4 cm in front of a wall is found although few of its points have a clean
   normal;
4. per plane: points projected to 2D plane coordinates, rasterised to an occupancy image
   (``cell_size``), morphologically closed, boundary contours approximated by polygons
   (Douglas-Peucker) whose sides are lifted back to 3D; sides with no other surface nearby
   (rims of occlusion shadows and of the scan's reach, not edges of the scene) are dropped
   unless the scene was scanned past them on both sides of the plane (an object's edge whose
   other face is hidden, :func:`_seen_past`), and so are sides across which the surface goes on
   in nearly the same plane (facets of a curved wall); long sides along a structural direction
   regain the length the raster's rounded corners took (:func:`_extend_sides`);
   narrow pieces (``strip_width``: a table leg, the front of a shelf board, the side of a table
   top) give both long sides directly, placed by percentiles of their points, since one of the
   two faces at such an edge is often never scanned;
5. intersection lines of adjacent, non-parallel planes, clipped to where both supports lie near
   the line;
6. merge of collinear overlapping pieces (intersection lines, being more accurate, fix the
   position of the merged segment), then a final join of the pieces of one line across gaps up
   to ``join_gap`` and removal of short noise pieces (:func:`join_lines`), so that long edges
   come out whole and the raw output holds what a line detector reports;
7. lines across which the scanned surface goes on without a crease or a step (the facets of a
   vault or a curved wall, bending less than ``smooth_crease_deg``) are dropped
   (:func:`ldlmap.lines3d.smooth.smooth_lines`);
8. lines are cut to where the planes near them run with them (:func:`ldlmap.lines3d.along.cut_to_edges`):
   a straight chord or tangent of a curved crease (a floor meeting a curved wall) keeps only the
   stretches where the arc's facets hold its direction, pieces shorter than ``min_line`` dropped.

Then the paper's length filter (:func:`filter_by_length`) drops segments shorter than
``lambda (b_x + b_y + b_z) / 3`` of the scene's robust box (:func:`robust_bounds`), optionally
keeping at least / at most a number of the longest lines. :func:`line_precision_recall` measures
extracted segments against true edges.
"""


from __future__ import annotations

import time

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.lines3d.along import cut_to_edges
from ldlmap.lines3d.boundaries import (_boundary_segments, _edge_supported, _extend_sides, _inside_strips, _seen_past,
                                       _smooth_continuation, _strip_sides, _strips)
from ldlmap.lines3d.intersections import _intersection_segments, _linear_segments
from ldlmap.lines3d.merge import join_lines, merge_collinear
from ldlmap.lines3d.params import Lines3DParams, _check_points
from ldlmap.lines3d.planes import segment_planes
from ldlmap.lines3d.smooth import smooth_lines


class _Laps:
    """Stage timer: each call records the wall and CPU seconds since the previous one."""

    def __init__(self, stats: dict):
        self.stats = stats
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def __call__(self, name: str) -> None:
        wall, cpu = time.perf_counter(), time.process_time()
        self.stats[f"{name}_s"], self.stats[f"{name}_cpu_s"] = wall - self.wall, cpu - self.cpu
        self.wall, self.cpu = wall, cpu


def extract_lines_with_stats(points: np.ndarray, params: Lines3DParams = Lines3DParams()) -> tuple[np.ndarray, dict]:
    """:func:`extract_lines` plus per-stage seconds and counts (for benchmarks and the CLI).

    Per stage ``NAME_s`` is its wall time and ``NAME_cpu_s`` the process's CPU time in it (all
    threads: what compares with a single-threaded tool)."""
    stats: dict = {}
    lap = _Laps(stats)
    reg = segment_planes(points, params)
    lap("planes")
    stats["points_processed"] = len(reg.points)
    stats["planes"] = len(reg.normals)
    from dataclasses import replace

    bparams = replace(params, cell_size=max(params.cell_size, reg.spacing))
    bnd = [_boundary_segments(reg.points[m], reg.centroids[i], reg.normals[i], bparams)
           for i, m in enumerate(reg.members)]
    B = np.concatenate(bnd) if bnd else np.zeros((0, 2, 3))
    owner = np.repeat(np.arange(len(bnd)), [len(b) for b in bnd])
    stats["boundary_sides"] = len(B)
    supported = _edge_supported(B, owner, reg, params)
    if params.see_past:
        supported[~supported] = _seen_past(B[~supported], owner[~supported], reg)
    keep = supported & ~_smooth_continuation(B, owner, reg, params)
    B, owner = B[keep], owner[keep]
    if params.extend_sides:
        B = _extend_sides(B, owner, reg)
    lap("boundary")
    X = _intersection_segments(reg, params)
    lap("intersections")
    stats["boundary_segments"], stats["intersection_segments"] = len(B), len(X)
    T = _linear_segments(reg, params)
    lap("linear")
    stats["linear_segments"] = len(T)
    strips, strip_owner = _strips(reg, params)
    S = _strip_sides(strips, strip_owner, reg, params)
    stats["strip_segments"] = len(S)
    lap("strips")
    raw = np.concatenate([X, B, T])
    w = np.concatenate([np.full(len(X), 2.0), np.ones(len(B) + len(T))])
    out = merge_collinear(raw, w, params.merge_angle_deg, params.merge_dist, params.merge_gap)
    out = np.concatenate([out[~_inside_strips(out, strips)], S])
    stats["merged_pieces"] = len(out)
    out = join_lines(out, params)
    lap("merge")
    smooth = smooth_lines(out, reg.points, params)
    stats["smooth_lines"] = int(smooth.sum())
    out = out[~smooth]
    lap("smooth")
    n_before = len(out)
    out = cut_to_edges(out, reg, params)
    stats["along_cut"] = n_before - len(out)
    lap("along")
    stats["lines"] = len(out)
    return out, stats


def extract_lines(points: np.ndarray, colors: np.ndarray | None = None,
                  params: Lines3DParams = Lines3DParams()) -> np.ndarray:
    """3D line segments (N, 2, 3) of a point cloud (N_p, 3), before the length filter.

    ``colors`` is accepted for interface symmetry and currently unused: lines come from
    geometry only (plane boundaries and plane intersections), as in Lu et al. 2019.
    """
    P = _check_points(points)
    if colors is not None and len(np.asarray(colors)) != len(P):
        raise InputError("colors must have one row per point")
    return extract_lines_with_stats(P, params)[0]
