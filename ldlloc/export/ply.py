"""Cameras and map lines as one PLY file for a viewer (Open3D, MeshLab, CloudCompare).

Binary little-endian PLY with two elements:

- ``vertex``: ``double x, y, z``, ``float nx, ny, nz``, ``uchar red, green, blue``, ``int query``.
  Each camera has three vertices: its centre (normal = its viewing direction: the panorama's
  centre, our camera's +x axis), the tip of its viewing direction (:data:`FORWARD_M` ahead) and
  the tip of its up axis (:data:`UP_M` above, along the panorama's top); ``query`` is the camera's
  index in the export (the order of the results file). Then two vertices per map line (normal =
  the line's direction, ``query`` = -1).
- ``edge``: ``int vertex1, vertex2``, ``uchar red, green, blue``: per camera its viewing direction
  (coloured by verdict: :data:`VERDICT_RGB`) and its up axis (grey); per map line the line
  (coloured by principal group, as in the pictures: 0 red, 1 green, 2 blue, none grey).

Open3D reads the vertices with ``read_point_cloud`` (points, normals, colours) and the edges with
``read_line_set``; MeshLab and CloudCompare show both.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ldlmap.core.pictures import GROUP_COLORS_BGR

FORWARD_M = 0.3  # length of a camera's viewing-direction edge, in metres of the map frame
UP_M = 0.15  # length of its up-axis edge
# Camera colours by verdict (None: the results carry no verdict).
VERDICT_RGB = {"confident": (40, 200, 60), "ambiguous": (250, 160, 20), "failed": (220, 30, 30), None: (20, 170, 250)}
UP_RGB = (160, 160, 160)

_VERTEX = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                    ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("query", "<i4")])
_EDGE = np.dtype([("vertex1", "<i4"), ("vertex2", "<i4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def ply_elements(poses: list, lines: np.ndarray, groups: np.ndarray, unit: float | np.ndarray = 1.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The vertex and edge records of :func:`write_cameras_ply`; ``unit``: frame units per metre,
    one for all or one per pose (the edges' lengths are :data:`FORWARD_M` and :data:`UP_M` metres)."""
    n = len(poses)
    units = np.broadcast_to(np.asarray(unit, dtype=np.float64), (n,))
    segs = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    verts = np.zeros(3 * n + 2 * len(segs), dtype=_VERTEX)
    edges = np.zeros(2 * n + len(segs), dtype=_EDGE)
    for i, p in enumerate(poses):
        c, fwd, up = np.asarray(p.center, float), p.forward, p.up
        rgb = VERDICT_RGB.get(p.verdict, VERDICT_RGB[None])
        for k, xyz in enumerate((c, c + FORWARD_M * units[i] * fwd, c + UP_M * units[i] * up)):
            verts[3 * i + k] = (*xyz, *fwd, *(UP_RGB if k == 2 else rgb), i)
        edges[2 * i] = (3 * i, 3 * i + 1, *rgb)
        edges[2 * i + 1] = (3 * i, 3 * i + 2, *UP_RGB)
    if len(segs):
        first = 3 * n
        d = segs[:, 1] - segs[:, 0]
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        rgb = np.array([GROUP_COLORS_BGR.get(int(g), GROUP_COLORS_BGR[-1])[::-1] for g in groups], np.uint8)
        lv = verts[first:]
        lv["x"], lv["y"], lv["z"] = segs.reshape(-1, 3).T
        lv["nx"], lv["ny"], lv["nz"] = np.repeat(d, 2, axis=0).T
        lv["red"], lv["green"], lv["blue"] = np.repeat(rgb, 2, axis=0).T
        lv["query"] = -1
        le = edges[2 * n:]
        le["vertex1"] = first + 2 * np.arange(len(segs))
        le["vertex2"] = le["vertex1"] + 1
        le["red"], le["green"], le["blue"] = rgb.T
    return verts, edges


def write_cameras_ply(path: str | Path, poses: list, lines: np.ndarray, groups: np.ndarray,
                      unit: float | np.ndarray = 1.0,
                      comment: str = "") -> None:
    """Write the cameras of ``poses`` (:class:`ldlloc.export.poses.ExportPose`) and the map lines
    (L, 2, 3) with their principal groups (L,) to ``path`` (a temporary of the caller's atomic write)."""
    verts, edges = ply_elements(poses, lines, groups, unit)
    head = ["ply", "format binary_little_endian 1.0",
            f"comment ldlloc export: {len(poses)} cameras (3 vertices and 2 edges each), then "
            f"{len(np.asarray(lines).reshape(-1, 2, 3))} map lines (2 vertices and 1 edge each)"]
    head += [f"comment {c}" for c in comment.splitlines() if c]
    head += [f"element vertex {len(verts)}", "property double x", "property double y", "property double z",
             "property float nx", "property float ny", "property float nz", "property uchar red",
             "property uchar green", "property uchar blue", "property int query",
             f"element edge {len(edges)}", "property int vertex1", "property int vertex2", "property uchar red",
             "property uchar green", "property uchar blue", "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii", "replace"))
        f.write(verts.tobytes())
        f.write(edges.tobytes())
