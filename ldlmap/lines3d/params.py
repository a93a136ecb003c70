"""Parameters of the 3D line extractor (metres and degrees) and input checks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.errors import InputError


@dataclass(frozen=True)
class Lines3DParams:
    """Parameters of :func:`extract_lines` (metres and degrees)."""

    voxel_size: float = 0.01  # downsampling grid; 0 disables it
    max_points: int = 400_000  # the grid grows (surfaces: ~ 1 / voxel^2) until at most this many remain ...
    max_points_area_m2: float = 50.0  # ... per this much footprint (the scan's two largest extents), so that a
    # building floor keeps a room's density (docs/measurements.md#lines3d-floor-cap)
    normal_k: int = 16  # neighbours for normals and surface variation
    graph_k: int = 10  # neighbours linked into connected plane pieces
    max_curvature: float = 0.06  # surface variation above which a point does not vote for planes
    orient_radius_deg: float = 6.0  # plane orientations: vote smoothing radius
    orient_cone_deg: float = 15.0  # normals this close to a found orientation belong to it
    min_orientation_points: int = 60  # smallest normal cluster that makes an orientation
    max_orientations: int = 60  # at most this many orientations
    offset_bin: float = 0.002  # histogram bin of plane offsets x . n
    offset_sigma: float = 0.004  # smoothing of the offset histogram (about the scan noise)
    max_planes_per_orientation: int = 300  # at most this many parallel planes per orientation
    assign_angle_deg: float = 35.0  # a point joins a plane when its normal is within this angle ...
    plane_tol: float = 0.015  # ... and it lies this close to the plane
    link_dist: float = 0.08  # neighbours farther apart than this do not connect plane pieces
    min_region_points: int = 40  # smallest planar piece kept
    min_plane_voters: int = 20  # flat points (clean normal) needed to start a plane hypothesis
    max_plane_rms: float = 0.02  # pieces less planar than this RMS are not planes
    cell_size: float = 0.025  # raster cell of the per-plane occupancy images
    close_cells: int = 2  # closing radius (cells) that bridges sampling gaps
    poly_eps: float = 0.03  # Douglas-Peucker tolerance of boundary polygons
    min_segment: float = 0.08  # raw pieces shorter than this are dropped before merging
    min_plane_angle_deg: float = 20.0  # planes meeting at a smaller angle give no intersection
    support_dist: float = 0.05  # points this close to an intersection line support it
    support_bin: float = 0.05  # bins along an intersection line that need support from both planes
    support_gap: float = 0.25  # unsupported stretches up to this long are bridged (sparse scans)
    min_adjacent_links: int = 5  # kNN links needed between two planes to call them adjacent
    min_linearity: float = 0.7  # thin structures (legs, rails, frames): 1 - lambda_1 / lambda_2 above this
    min_linear_points: int = 12  # smallest cluster of linear points that gives a segment
    normal_angle_deg: float = 12.0  # linear structures: max axis difference of linked neighbours
    linear_tol: float = 0.025  # linear structures: max offset of linked neighbours from the axis
    merge_angle_deg: float = 5.0  # collinear pieces: direction difference ...
    merge_dist: float = 0.04  # ... distance between the lines ...
    merge_gap: float = 0.03  # ... and largest gap along the line to still merge
    edge_radius: float = 0.06  # boundary sides need points of another surface this close ...
    edge_support: float = 0.3  # ... along this fraction of their length (else: occlusion shadow)
    extend_sides: bool = True  # lengthen boundary sides over the corners rounded by the raster
    see_past: bool = True  # keep unsupported sides past which the scene was scanned on both sides
    strip_width: float = 0.12  # planes narrower than this (legs, board fronts, frame sides) give both long sides
    join_angle_deg: float = 3.0  # final join of collinear pieces of one line: direction difference ...
    join_dist: float = 0.03  # ... distance between the lines ...
    join_gap: float = 0.25  # ... and largest gap along the line bridged
    min_line: float = 0.1  # joined lines shorter than this are dropped (noise pieces)
    lam: float = 0.1  # lambda: length filter ratio of the paper (sec. 3.1)
    smooth_crease_deg: float = 15.0  # lines across which the surface goes on bending less than this (no step) are
    # dropped: facets of vaults and curved walls (5-10 deg), not edges; below the generator's 20 deg crease angle
    # because a line a few cm off a crease sees both faces on one side (a 23 deg crease measured 10-20); 0 keeps all
    smooth_step: float = 0.01  # ... no step: the two sides' surfaces meet this closely at the line (a frame: 4 cm) ...
    smooth_rms: float = 0.0075  # ... each side one surface this flat (scan noise; two surfaces 2 cm apart are not) ...
    smooth_on: float = 0.025  # ... passing this close to the line (lines lie up to ``plane_tol`` off a facet)
    smooth_reach: tuple[float, float] = (0.02, 0.10)  # ... the sides: points this far across the line
    smooth_slab: float = 0.05  # ... and this far along it from each sample (every 5 cm)
    smooth_grid: float = 0.02  # ... thinned to one point per cell of this grid
    smooth_neighbours: int = 160  # ... of which at most this many nearest per sample
    smooth_min_points: int = 5  # ... and at least this many on each side
    smooth_share: float = 0.5  # lines with this share of their samples smooth are dropped
    along_min_run: int = 3  # runs of this many samples where a plane beside a line turns away from it are cut out
    # of the line (chords of curved creases; ``ldlmap.lines3d.along``); 0 keeps all (2: a 23 deg crease's line cut)
    along_step: float = 0.05  # ... samples every this far along the line ...
    along_slab: float = 0.025  # ... each with the points this far along the line from it ...
    along_near: float = 0.03  # ... and this far across it ...
    along_angle_deg: float = 3.5  # ... on planes turned by more than this from the line (an arc's 0.3 m facets: 5-14)
    along_share: float = 0.3  # ... for this share of the near points on planes ...
    along_min_points: int = 3  # ... and at least this many
    along_face_reach: float = 0.06  # ... or the points of one plane piece this far across the line ...
    along_face_slab: float = 0.08  # ... and this far along it ...
    along_face_deg: float = 5.0  # ... fit a local plane turned from the line by more than this ...
    along_face_points: int = 15  # ... from at least this many points ...
    along_face_neighbours: int = 300  # ... of at most this many nearest
    along_grid: float = 0.015  # ... the points thinned to one per cell of this grid ...
    along_neighbours: int = 80  # ... of which at most this many nearest per sample


def _check_points(points: np.ndarray) -> np.ndarray:
    P = np.asarray(points)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"point cloud must have shape (N, 3), got {P.shape}")
    if len(P) == 0:
        raise InputError("point cloud is empty")
    P = P.astype(np.float64, copy=False)
    if not np.all(np.isfinite(P)):
        raise InputError("point cloud contains NaN or infinite coordinates")
    return P


def _check_lines(lines: np.ndarray) -> np.ndarray:
    L = np.asarray(lines, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (2, 3):
        raise InputError(f"lines must have shape (N, 2, 3), got {L.shape}")
    if not np.all(np.isfinite(L)):
        raise InputError("lines contain NaN or infinite coordinates")
    return L
