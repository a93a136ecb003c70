"""Parameters of the 3D line extractor (metres and degrees), one small class per stage, and input checks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ldlmap.core.errors import InputError


@dataclass(frozen=True)
class PlaneParams:
    """Planar regions (:mod:`ldlmap.lines3d.planes`)."""

    voxel_size: float = 0.01
    """Downsampling grid; 0 disables it."""
    max_points: int = 400_000
    """The grid grows (surfaces: ~ 1 / voxel^2) until at most this many points remain per ``max_points_area_m2``."""
    max_points_area_m2: float = 50.0
    """Footprint (the scan's two largest extents) per ``max_points``, so that a building floor keeps a room's
    density (docs/measurements.md#lines3d-floor-cap)."""
    normal_k: int = 16
    """Neighbours for normals and surface variation."""
    graph_k: int = 10
    """Neighbours linked into connected plane pieces."""
    max_curvature: float = 0.06
    """Surface variation above which a point does not vote for planes."""
    orient_radius_deg: float = 6.0
    """Plane orientations: vote smoothing radius."""
    orient_cone_deg: float = 15.0
    """Normals this close to a found orientation belong to it."""
    min_orientation_points: int = 60
    """Smallest normal cluster that makes an orientation."""
    max_orientations: int = 60
    """At most this many orientations."""
    offset_bin: float = 0.002
    """Histogram bin of plane offsets x . n."""
    offset_sigma: float = 0.004
    """Smoothing of the offset histogram (about the scan noise)."""
    max_planes_per_orientation: int = 300
    """At most this many parallel planes per orientation."""
    assign_angle_deg: float = 35.0
    """A point joins a plane when its normal is within this angle and it lies within ``plane_tol``."""
    plane_tol: float = 0.015
    """Distance to the plane within which a point joins it."""
    link_dist: float = 0.08
    """Neighbours farther apart than this do not connect plane pieces."""
    min_region_points: int = 40
    """Smallest planar piece kept."""
    min_plane_voters: int = 20
    """Flat points (clean normal) needed to start a plane hypothesis."""
    max_plane_rms: float = 0.02
    """Pieces less planar than this RMS are not planes."""


@dataclass(frozen=True)
class BoundaryParams:
    """Plane outlines and narrow strips (:mod:`ldlmap.lines3d.boundaries`)."""

    cell_size: float = 0.025
    """Raster cell of the per-plane occupancy images."""
    close_cells: int = 2
    """Closing radius (cells) that bridges sampling gaps."""
    poly_eps: float = 0.03
    """Douglas-Peucker tolerance of boundary polygons."""
    edge_radius: float = 0.06
    """Boundary sides need points of another surface this close, along ``edge_support`` of their length."""
    edge_support: float = 0.3
    """Share of a side's length that needs another surface near (else: an occlusion shadow's rim)."""
    extend_sides: bool = True
    """Lengthen boundary sides over the corners rounded by the raster."""
    see_past: bool = True
    """Keep unsupported sides past which the scene was scanned on both sides."""
    strip_width: float = 0.12
    """Planes narrower than this (legs, board fronts, frame sides) give both long sides."""


@dataclass(frozen=True)
class IntersectionParams:
    """Plane-plane creases (:func:`ldlmap.lines3d.intersections.intersection_segments`)."""

    min_plane_angle_deg: float = 20.0
    """Planes meeting at a smaller angle give no intersection."""
    support_dist: float = 0.05
    """Points this close to an intersection line support it."""
    support_bin: float = 0.05
    """Bins along an intersection line that need support from both planes."""
    support_gap: float = 0.25
    """Unsupported stretches up to this long are bridged (sparse scans)."""
    min_adjacent_links: int = 5
    """kNN links needed between two planes to call them adjacent."""


@dataclass(frozen=True)
class LinearParams:
    """Thin structures (legs, rails, frames; :func:`ldlmap.lines3d.intersections.linear_segments`)."""

    min_linearity: float = 0.7
    """Points whose neighbourhood has 1 - lambda_1 / lambda_2 above this are linear."""
    min_linear_points: int = 12
    """Smallest cluster of linear points that gives a segment."""
    normal_angle_deg: float = 12.0
    """Max axis difference of linked neighbours."""
    linear_tol: float = 0.025
    """Max offset of linked neighbours from the axis."""


@dataclass(frozen=True)
class MergeParams:
    """Merge of collinear pieces and the final join (:mod:`ldlmap.lines3d.merge`)."""

    min_segment: float = 0.08
    """Raw pieces shorter than this are dropped before merging."""
    angle_deg: float = 5.0
    """Collinear pieces merge within this direction difference, ``dist`` and ``gap``."""
    dist: float = 0.04
    """Largest distance between the lines of pieces that merge."""
    gap: float = 0.03
    """Largest gap along the line of pieces that merge."""
    join_angle_deg: float = 3.0
    """Final join of collinear pieces of one line: direction difference."""
    join_dist: float = 0.03
    """Final join: largest distance between the lines."""
    join_gap: float = 0.25
    """Final join: largest gap along the line bridged."""
    min_line: float = 0.1
    """Joined lines shorter than this are dropped (noise pieces)."""


@dataclass(frozen=True)
class SmoothParams:
    """Lines on smooth surfaces, dropped (:mod:`ldlmap.lines3d.smooth`)."""

    crease_deg: float = 15.0
    """Lines across which the surface goes on bending less than this (no step) are dropped: facets of vaults and
    curved walls (5-10 deg), not edges; below the generator's 20 deg crease angle because a line a few cm off a
    crease sees both faces on one side (a 23 deg crease measured 10-20); 0 keeps all."""
    step: float = 0.01
    """No step: the two sides' surfaces meet this closely at the line (a frame: 4 cm)."""
    rms: float = 0.0075
    """Each side one surface this flat (scan noise; two surfaces 2 cm apart are not)."""
    on: float = 0.025
    """Each side's surface passes this close to the line (lines lie up to ``plane_tol`` off a facet)."""
    reach: tuple[float, float] = (0.02, 0.10)
    """The sides: points this far across the line."""
    slab: float = 0.05
    """The sides: points this far along the line from each sample (every 5 cm)."""
    grid: float = 0.02
    """The sides' points thinned to one per cell of this grid."""
    neighbours: int = 160
    """Of which at most this many nearest per sample."""
    min_points: int = 5
    """And at least this many on each side."""
    share: float = 0.5
    """Lines with this share of their samples smooth are dropped."""


@dataclass(frozen=True)
class AlongParams:
    """Lines cut to where the planes near them run with them (:mod:`ldlmap.lines3d.along`)."""

    min_run: int = 3
    """Runs of this many samples where a plane beside a line turns away from it are cut out of the line (chords
    of curved creases); 0 keeps all (2: a 23 deg crease's line cut)."""
    step: float = 0.05
    """Samples every this far along the line."""
    slab: float = 0.025
    """Each sample: the points this far along the line from it."""
    near: float = 0.03
    """Each sample: the points this far across the line."""
    angle_deg: float = 3.5
    """On planes turned by more than this from the line (an arc's 0.3 m facets: 5-14)."""
    share: float = 0.3
    """For this share of the near points on planes."""
    min_points: int = 3
    """And at least this many."""
    face_reach: float = 0.06
    """Or the points of one plane piece this far across the line."""
    face_slab: float = 0.08
    """And this far along it."""
    face_deg: float = 5.0
    """Fit a local plane turned from the line by more than this."""
    face_points: int = 15
    """From at least this many points."""
    face_neighbours: int = 300
    """Of at most this many nearest."""
    grid: float = 0.015
    """The points thinned to one per cell of this grid."""
    neighbours: int = 80
    """Of which at most this many nearest per sample."""


@dataclass(frozen=True)
class Lines3DParams:
    """Parameters of :func:`ldlmap.lines3d.extract.extract_lines`, one group per stage in the order they run."""

    planes: PlaneParams = field(default_factory=PlaneParams)
    """Planar regions."""
    boundaries: BoundaryParams = field(default_factory=BoundaryParams)
    """Plane outlines and strips."""
    intersections: IntersectionParams = field(default_factory=IntersectionParams)
    """Plane-plane creases."""
    linear: LinearParams = field(default_factory=LinearParams)
    """Thin structures."""
    merge: MergeParams = field(default_factory=MergeParams)
    """Merge and final join of collinear pieces."""
    smooth: SmoothParams = field(default_factory=SmoothParams)
    """Lines on smooth surfaces."""
    along: AlongParams = field(default_factory=AlongParams)
    """Lines cut to where planes run with them."""


def check_points(points: np.ndarray) -> np.ndarray:
    """The point cloud as float64 (N, 3); refuses (one line) another shape, no points or non-finite ones."""
    P = np.asarray(points)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"point cloud must have shape (N, 3), got {P.shape}")
    if len(P) == 0:
        raise InputError("point cloud is empty")
    P = P.astype(np.float64, copy=False)
    if not np.all(np.isfinite(P)):
        raise InputError("point cloud contains NaN or infinite coordinates")
    return P


def check_lines(lines: np.ndarray) -> np.ndarray:
    """The segments as float64 (N, 2, 3); refuses (one line) another shape or non-finite ends."""
    L = np.asarray(lines, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (2, 3):
        raise InputError(f"lines must have shape (N, 2, 3), got {L.shape}")
    if not np.all(np.isfinite(L)):
        raise InputError("lines contain NaN or infinite coordinates")
    return L
