"""3D line segments from an unorganized point cloud (paper sec. 3.1).

An equivalent of Lu Xiaohu et al. 2019 ("Fast 3D line segment detection from unorganized point
cloud") on numpy / scipy / OpenCV:

1. voxel downsampling (``planes.voxel_size``) when the cloud is denser than that, the points in the
   voxels' Z-order (fast neighbour queries, the same result for any input order);
2. normals and surface variation ``lambda_0 / (lambda_0 + lambda_1 + lambda_2)`` from k-nearest
   neighbour covariances (one scipy k-d tree query, which also links the plane graph);
3. planar regions (robust to scan noise, down to 8 cm faces): dominant normal orientations
   (greedy peaks of the sign-free normal histogram on an icosphere), then per orientation the
   strongest peaks of the histogram of offsets ``x . n`` claim, strongest first, every point
   within ``planes.plane_tol`` whose normal agrees; each plane is split into kNN-connected pieces and
   each piece gets a least-squares plane. Offsets pool all points of a plane, so a table leg's
   face or a frame 4 cm in front of a wall is found although few of its points have a clean
   normal;
4. per plane: points projected to 2D plane coordinates, rasterised to an occupancy image
   (``boundaries.cell_size``), morphologically closed, boundary contours approximated by polygons
   (Douglas-Peucker) whose sides are lifted back to 3D; sides with no other surface nearby
   (rims of occlusion shadows and of the scan's reach, not edges of the scene) are dropped
   unless the scene was scanned past them on both sides of the plane (an object's edge whose
   other face is hidden, :func:`seen_past`), and so are sides across which the surface goes on
   in nearly the same plane (facets of a curved wall); long sides along a structural direction
   regain the length the raster's rounded corners took (:func:`extend_sides`);
   narrow pieces (``boundaries.strip_width``: a table leg, the front of a shelf board, the side of a table
   top) give both long sides directly, placed by percentiles of their points, since one of the
   two faces at such an edge is often never scanned;
5. intersection lines of adjacent, non-parallel planes, clipped to where both supports lie near
   the line;
6. merge of collinear overlapping pieces (intersection lines, being more accurate, fix the
   position of the merged segment), then a final join of the pieces of one line across gaps up
   to ``merge.join_gap`` and removal of short noise pieces (:func:`join_lines`), so that long edges
   come out whole and the raw output holds what a line detector reports;
7. lines across which the scanned surface goes on without a crease or a step (the facets of a
   vault or a curved wall, bending less than ``smooth.crease_deg``) are dropped
   (:func:`ldlmap.lines3d.smooth.smooth_lines`);
8. lines are cut to where the planes near them run with them (:func:`ldlmap.lines3d.along.cut_to_edges`):
   a straight chord or tangent of a curved crease (a floor meeting a curved wall) keeps only the
   stretches where the arc's facets hold its direction, pieces shorter than ``merge.min_line`` dropped.

Then the paper's length filter (:func:`filter_by_length`) drops segments shorter than
``lambda (b_x + b_y + b_z) / 3`` of the scene's robust box (:func:`robust_bounds`), optionally
keeping at least / at most a number of the longest lines. :func:`line_precision_recall` measures
extracted segments against true edges.
"""


from __future__ import annotations

from dataclasses import replace

import numpy as np

from ldlmap.core.timing import StageClock
from ldlmap.lines3d.along import cut_to_edges
from ldlmap.lines3d.boundaries import (boundary_segments, edge_supported, extend_sides, find_strips, inside_strips,
                                       seen_past, smooth_continuation, strip_sides)
from ldlmap.lines3d.intersections import intersection_segments, linear_segments
from ldlmap.lines3d.merge import join_lines, merge_collinear
from ldlmap.lines3d.params import Lines3DParams, check_points
from ldlmap.lines3d.planes import segment_planes
from ldlmap.lines3d.smooth import smooth_lines


def extract_lines_with_stats(points: np.ndarray, params: Lines3DParams = Lines3DParams()) -> tuple[np.ndarray, dict]:
    """:func:`extract_lines` plus per-stage seconds and counts (for benchmarks and the CLI).

    Per stage ``NAME_s`` is its wall time and ``NAME_cpu_s`` the process's CPU time in it (all
    threads: what compares with a single-threaded tool)."""
    stats: dict = {}
    lap = StageClock(stats, stats, key=lambda name: f"{name}_s", cpu_key=lambda name: f"{name}_cpu_s").lap
    reg = segment_planes(points, params)
    lap("planes")
    stats["points_processed"] = len(reg.points)
    stats["planes"] = len(reg.normals)
    bparams = replace(params, boundaries=replace(params.boundaries, cell_size=max(params.boundaries.cell_size, reg.spacing)))
    bnd = [boundary_segments(reg.points[m], reg.centroids[i], reg.normals[i], bparams)
           for i, m in enumerate(reg.members)]
    B = np.concatenate(bnd) if bnd else np.zeros((0, 2, 3))
    owner = np.repeat(np.arange(len(bnd)), [len(b) for b in bnd])
    stats["boundary_sides"] = len(B)
    supported = edge_supported(B, owner, reg, params)
    if params.boundaries.see_past:
        supported[~supported] = seen_past(B[~supported], owner[~supported], reg)
    keep = supported & ~smooth_continuation(B, owner, reg, params)
    B, owner = B[keep], owner[keep]
    if params.boundaries.extend_sides:
        B = extend_sides(B, owner, reg)
    lap("boundary")
    X = intersection_segments(reg, params)
    lap("intersections")
    stats["boundary_segments"], stats["intersection_segments"] = len(B), len(X)
    T = linear_segments(reg, params)
    lap("linear")
    stats["linear_segments"] = len(T)
    strips, strip_owner = find_strips(reg, params)
    S = strip_sides(strips, strip_owner, reg, params)
    stats["strip_segments"] = len(S)
    lap("strips")
    raw = np.concatenate([X, B, T])
    w = np.concatenate([np.full(len(X), 2.0), np.ones(len(B) + len(T))])
    out = merge_collinear(raw, w, params.merge.angle_deg, params.merge.dist, params.merge.gap)
    out = np.concatenate([out[~inside_strips(out, strips)], S])
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


def extract_lines(points: np.ndarray, params: Lines3DParams = Lines3DParams()) -> np.ndarray:
    """3D line segments (N, 2, 3) of a point cloud (N_p, 3), before the length filter: from
    geometry only (plane boundaries and plane intersections), as in Lu et al. 2019."""
    P = check_points(points)
    return extract_lines_with_stats(P, params)[0]
