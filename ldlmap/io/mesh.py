"""Sample a (textured) triangle mesh into a colored point cloud with pymeshlab.

Colors come from the mesh's texture (``.obj`` + ``.mtl`` + image: wedge texture coordinates are
looked up in the texture at each sample) or else from its per-vertex colors (``.ply``),
interpolated at the sample's position; a mesh with neither gives a cloud without colors.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ldlmap.core.errors import InputError, require_file
from ldlmap.core.lazy import lazy_module
from ldlmap.io.cloud import PointCloud
from ldlmap.io.ply import ply_header

pymeshlab = lazy_module("pymeshlab")

MESH_FORMATS: tuple[str, ...] = (".obj", ".ply", ".off", ".stl")


@dataclass(frozen=True)
class MeshSampling:
    """How a mesh is turned into points."""

    # area-uniform random (seeded; ~1 s per 10^6 points), or pymeshlab Poisson-disk (even spacing,
    # but minutes for 10^5 points: meant for small counts)
    method: Literal["montecarlo", "poisson"] = "montecarlo"
    seed: int = 0  # Monte-Carlo seed; Poisson-disk uses pymeshlab's own unseeded generator


def sample_mesh(path: str | os.PathLike, num_points: int, sampling: MeshSampling | None = None) -> PointCloud:
    """Sample ``num_points`` points on the surface of the mesh at ``path``, with colors.

    Poisson-disk sampling returns approximately ``num_points`` points. Raises
    :class:`InputError` for a missing or unreadable mesh, a mesh without faces, or a texture
    image that the mesh references but that cannot be found.
    """
    cfg = sampling or MeshSampling()
    p = require_file(path, "mesh")
    if p.suffix.lower() not in MESH_FORMATS:
        raise InputError(f"unsupported mesh format {p.suffix or '(none)'} for {p}; supported: {', '.join(MESH_FORMATS)}")
    if num_points <= 0:
        raise InputError(f"number of mesh samples must be positive, got {num_points}")
    if p.suffix.lower() == ".ply":
        ply_header(p)  # counts the file cannot hold are refused before pymeshlab allocates them
    if cfg.method not in ("montecarlo", "poisson"):
        raise InputError(f"unknown mesh sampling method {cfg.method!r}; choose montecarlo or poisson")
    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(p))
    except pymeshlab.PyMeshLabException as exc:
        raise InputError(f"cannot read mesh {p}: {str(exc).strip().splitlines()[0] if str(exc).strip() else exc}") from None
    mesh = ms.current_mesh()
    if mesh.face_number() == 0:
        raise InputError(f"mesh has no faces: {p}")
    if p.suffix.lower() == ".obj":
        _check_material_libraries(p)
    textured = mesh.has_wedge_tex_coord() and mesh.texture_number() > 0
    if textured:
        _check_textures(mesh, p)
    has_vertex_color = mesh.has_vertex_color() and not textured

    source = ms.current_mesh_id()
    if cfg.method == "montecarlo":
        pts = _sample_triangles(mesh.vertex_matrix(), mesh.face_matrix(), int(num_points), cfg.seed)
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=pts), "samples")
    else:
        ms.generate_sampling_poisson_disk(samplenum=int(num_points), exactnumflag=True)
    target = ms.current_mesh_id()
    if textured:
        ms.transfer_texture_to_color_per_vertex(sourcemesh=source, targetmesh=target)
    elif has_vertex_color:
        ms.transfer_attributes_per_vertex(sourcemesh=source, targetmesh=target, colortransfer=True)
    samples = ms.current_mesh()
    pts = np.array(samples.vertex_matrix(), dtype=np.float64)
    colors = None
    if textured or has_vertex_color:
        colors = np.rint(np.clip(samples.vertex_color_matrix()[:, :3], 0.0, 1.0) * 255.0).astype(np.uint8)
    return PointCloud(pts, colors).validate(p)


def _sample_triangles(vertices: np.ndarray, faces: np.ndarray, num: int, seed: int) -> np.ndarray:
    """``num`` points uniformly distributed by area over the triangles (vectorized, seeded)."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if not np.isfinite(area).all() or area.sum() <= 0:
        raise InputError("mesh has zero surface area or non-finite vertices")
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(F), size=num, p=area / area.sum())
    r1, r2 = rng.random(num), rng.random(num)
    s = np.sqrt(r1)  # uniform barycentric coordinates: (1 - s, s (1 - r2), s r2)
    return (1.0 - s)[:, None] * a[tri] + (s * (1.0 - r2))[:, None] * b[tri] + (s * r2)[:, None] * c[tri]


def _check_material_libraries(path: Path) -> None:
    """An ``.obj`` whose ``mtllib`` is missing would silently lose its texture: reject it."""
    with open(path, "rb") as f:
        data = f.read()
    for lib in re.findall(rb"^[ \t]*mtllib[ \t]+(.+?)[ \t]*\r?$", data, flags=re.M):
        name = lib.decode("utf-8", "replace")
        mtl = path.parent / name
        if not mtl.is_file():
            raise InputError(f"material library {name} referenced by {path} not found")
        for line in mtl.read_text(errors="replace").splitlines():
            words = line.split()
            if len(words) < 2 or words[0] != "map_Kd":
                continue
            tex = words[-1]  # options (-s u v w, ...) precede the file name
            if not ((mtl.parent / tex).is_file() or Path(tex).is_file()):
                raise InputError(f"texture image {tex} referenced by {mtl} not found")


def _check_textures(mesh, path: Path) -> None:
    """pymeshlab substitutes a blank ``dummy.png`` for a texture file it cannot find: reject that."""
    for name in mesh.textures():
        if not ((path.parent / name).is_file() or Path(name).is_file()):
            raise InputError(f"a texture image of {path} could not be loaded")
