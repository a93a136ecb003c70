"""3D line segments from scans, by stage (paper sec. 3.1).

``params`` (parameters, input checks) -> ``planes`` (planar regions) -> ``boundaries`` (plane
outlines) and ``intersections`` (plane-plane creases) -> ``merge`` (collinear pieces) ->
``smooth`` (lines on smooth surfaces) -> ``along`` (lines cut to where planes run with them) -> ``extract`` (the whole extractor) -> ``filter`` (the paper's length filter); ``principal``
(principal 3D directions), ``metrics`` (precision / recall against true edges) and ``outputs``
(line files, top-view pictures) beside them. The names below are the public API.
"""

from ldlmap.lines3d.extract import extract_lines, extract_lines_with_stats
from ldlmap.lines3d.filter import filter_by_length, length_threshold, robust_bounds
from ldlmap.lines3d.merge import join_lines, merge_collinear
from ldlmap.lines3d.metrics import line_precision_recall
from ldlmap.lines3d.outputs import draw_top_view, top_view_image, write_line_files
from ldlmap.lines3d.params import (AlongParams, BoundaryParams, IntersectionParams, LinearParams, Lines3DParams,
                                   MergeParams, PlaneParams, SmoothParams)

__all__ = ["AlongParams", "BoundaryParams", "IntersectionParams", "LinearParams", "Lines3DParams", "MergeParams",
           "PlaneParams", "SmoothParams", "draw_top_view", "extract_lines", "extract_lines_with_stats", "filter_by_length",
           "join_lines", "length_threshold", "line_precision_recall", "merge_collinear", "robust_bounds",
           "top_view_image", "write_line_files"]
