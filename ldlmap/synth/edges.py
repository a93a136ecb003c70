"""Ground-truth 3D edges of a scene mesh: where two non-coplanar faces meet.

What is included (computed per part, i.e. per closed solid / the room shell, using
``SceneMesh.tri_part`` or, when absent, the connected components of the welded mesh):

* creases of every part: mesh edges shared by exactly two triangles of the part whose normals
  differ by at least ``min_angle_deg`` (wall-wall corners, floor and ceiling lines, all box
  edges, frame edges). Because each solid is handled on its own, T-junctions between solids do
  not matter, and the edges of a solid's face that lies on the floor or a wall are kept: they
  are the creases where the solid meets that surface;
* collinear, touching or overlapping pieces (also from different parts) are merged into maximal
  segments.

Excluded: triangulation diagonals (coplanar neighbours); boundary edges of open parts (door
and window panels, posters: flat decals a few mm in front of the wall, no geometric edge); and
flush seams, creases of one solid where a face of another solid continues one of its faces in
the same plane and orientation (the side board and the back board of a shelf that share one
flat back surface: the union has no edge there, only a joint, which no scan can show).
Known approximation: frame edges on the wall plane are reported at the wall (the panel inside
the frame is a few mm in front of it).
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.synth.types import SceneMesh

o3d = lazy_module("open3d")
sparse = lazy_module("scipy.sparse")
csgraph = lazy_module("scipy.sparse.csgraph")


def _weld(vertices: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Index of a representative for each vertex (positions equal up to ``tol``)."""
    keys = np.round(np.asarray(vertices, dtype=np.float64) / tol).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    return inverse.reshape(-1)


def _parts(mesh: SceneMesh, weld: np.ndarray) -> np.ndarray:
    """Part index (F,) of each triangle: ``mesh.tri_part``, else the connected components of the welded mesh."""
    if getattr(mesh, "tri_part", None) is not None:
        return np.asarray(mesh.tri_part, dtype=np.int64)
    tri = weld[np.asarray(mesh.triangles)]
    n = int(weld.max()) + 1
    rows = np.concatenate([tri[:, 0], tri[:, 1]])
    cols = np.concatenate([tri[:, 1], tri[:, 2]])
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, labels = csgraph.connected_components(graph, directed=False)
    return labels[tri[:, 0]]


def _flush(mesh: SceneMesh, mid: np.ndarray, out_dir: np.ndarray, normal: np.ndarray,
           eps: float = 0.005, tol: float = 5e-4) -> np.ndarray:
    """Mask: just beyond the edge midpoints ``mid``, across the edge in a face's plane
    (``out_dir``), the mesh surface continues that face (a point on a face of equal normal)."""
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                     o3d.core.Tensor(np.asarray(mesh.triangles, np.uint32)))
    q = (mid + eps * out_dir).astype(np.float32)
    ans = rs.compute_closest_points(o3d.core.Tensor(q))
    dist = np.linalg.norm(ans["points"].numpy() - q, axis=1)
    n = ans["primitive_normals"].numpy()
    return (dist <= tol) & (np.einsum("ij,ij->i", n, normal) > 0.999)


def crease_edges(mesh: SceneMesh, min_angle_deg: float = 20.0) -> np.ndarray:
    """Un-merged crease edges (M, 2, 3) of each part, flush seams excluded (see the module docstring)."""
    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.triangles, dtype=np.int64)
    if len(F) == 0:
        return np.zeros((0, 2, 3))
    weld = _weld(V)
    tri = weld[F]
    part = _parts(mesh, weld)
    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area2 = np.linalg.norm(normals, axis=1)
    normals = normals / np.maximum(area2, 1e-300)[:, None]
    keep = area2 > 1e-12
    # Every triangle edge as (part, welded a, welded b) with a < b.
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e.sort(axis=1)
    owner = np.tile(np.arange(len(F)), 3)
    ok = np.tile(keep, 3)
    e, owner = e[ok], owner[ok]
    keys = np.column_stack([part[owner], e])
    order = np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0]))
    keys, owner = keys[order], owner[order]
    same_next = np.all(keys[1:] == keys[:-1], axis=1)
    # Groups of exactly two triangles: start i with same_next[i] and no neighbours on either side.
    idx = np.flatnonzero(same_next)
    prev_same = np.concatenate([[False], same_next[:-1]])
    next2_same = np.concatenate([same_next[1:], [False]])
    pairs = idx[~prev_same[idx] & ~next2_same[idx]]
    n1, n2 = normals[owner[pairs]], normals[owner[pairs + 1]]
    angle = np.degrees(np.arccos(np.clip(np.sum(n1 * n2, axis=1), -1.0, 1.0)))
    sel = pairs[angle >= min_angle_deg]
    # Map welded ids back to coordinates: the first vertex of each welded group.
    rep = np.zeros(int(weld.max()) + 1, dtype=np.int64)
    rep[weld[::-1]] = np.arange(len(weld))[::-1]
    a, b = V[rep[keys[sel, 1]]], V[rep[keys[sel, 2]]]
    if len(sel) == 0:
        return np.zeros((0, 2, 3))
    # Flush seams: beyond the edge, in the plane of either face, another face continues it.
    mid, e = np.tile((a + b) / 2, (2, 1)), np.tile(b - a, (2, 1))
    t = np.concatenate([owner[sel], owner[sel + 1]])  # the two faces of every edge
    n = normals[t]
    w = np.cross(e, n)
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    inward = np.einsum("ij,ij->i", V[F[t]].mean(1) - mid, w) > 0
    w[inward] *= -1.0  # point away from the face, across the edge
    seam = _flush(mesh, mid, w, n).reshape(2, -1).any(axis=0)
    return np.stack([a, b], axis=1)[~seam]


def merge_collinear(segs: np.ndarray, tol: float = 1e-5) -> np.ndarray:
    """Merge collinear segments that touch or overlap into maximal segments (N, 2, 3)."""
    segs = np.asarray(segs, dtype=np.float64).reshape(-1, 2, 3)
    if len(segs) == 0:
        return segs
    d = segs[:, 1] - segs[:, 0]
    length = np.linalg.norm(d, axis=1)
    segs, d, length = segs[length > tol], d[length > tol], length[length > tol]
    d = d / length[:, None]
    # Canonical direction sign: the largest-magnitude component positive.
    big = np.argmax(np.abs(d), axis=1)
    d = d * np.sign(d[np.arange(len(d)), big])[:, None]
    s0 = np.einsum("ij,ij->i", segs[:, 0], d)
    s1 = np.einsum("ij,ij->i", segs[:, 1], d)
    lo, hi = np.minimum(s0, s1), np.maximum(s0, s1)
    foot = segs[:, 0] - s0[:, None] * d  # point of the line closest to the origin
    key = np.column_stack([np.round(d / 1e-6), np.round(foot / tol)]).astype(np.int64)
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = group.reshape(-1)
    order = np.lexsort((lo, group))
    g, lo, hi, d, foot = group[order], lo[order], hi[order], d[order], foot[order]
    span = float(np.max(np.abs(np.concatenate([lo, hi])))) * 4 + 1.0
    shifted_hi = hi + g * span
    run_max = np.maximum.accumulate(shifted_hi)
    new = np.ones(len(g), dtype=bool)
    new[1:] = (g[1:] != g[:-1]) | (lo[1:] + g[1:] * span > run_max[:-1] + tol)
    start = np.flatnonzero(new)
    end_hi = np.maximum.reduceat(hi, start)
    p0 = foot[start] + lo[start, None] * d[start]
    p1 = foot[start] + end_hi[:, None] * d[start]
    return np.stack([p0, p1], axis=1)


def mesh_edges(mesh: SceneMesh, min_angle_deg: float = 20.0) -> np.ndarray:
    """Ground-truth 3D edges (N, 2, 3) as maximal segments (start, end) in world coordinates."""
    if len(np.asarray(mesh.vertices)) == 0:
        raise InputError("mesh has no vertices")
    return merge_collinear(crease_edges(mesh, min_angle_deg))


def edges_longer_than(edges: np.ndarray, length: float) -> np.ndarray:
    """The segments of ``edges`` (N, 2, 3) whose length exceeds ``length`` (metres)."""
    edges = np.asarray(edges, dtype=np.float64).reshape(-1, 2, 3)
    return edges[np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1) > length]
