"""glTF 2.0 meshes (``.glb``, ``.gltf``): phone LiDAR scans (Polycam, Scaniverse, 3D Scanner App).

Read with ``trimesh`` (its scene graph gives each mesh its node's world transform, and its glTF
reader decodes the textures with Pillow). The triangles are sampled uniformly by area (seeded,
like :func:`ldlmap.io.mesh.sample_mesh` for ``.obj``) and coloured by the base-colour texture at
each sample's interpolated texture coordinate (times the material's base-colour factor), else by
the interpolated vertex colours, else not at all.

Axes: glTF 2.0 defines +Y as up (the specification's "Coordinate System and Units": right-handed,
+Y up, +Z forward, metres), so every file is turned into our z-up frame by the fixed rotation
:data:`Z_UP_FROM_GLTF`, ``(x, y, z) -> (x, -z, y)``: the specification, not a guess from the data.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, atomic_file, require_file
from ldlmap.core.lazy import lazy_module
from ldlmap.io.cloud import PointCloud

pil_image = lazy_module("PIL.Image")
trimesh = lazy_module("trimesh")

GLTF_SUFFIXES: tuple[str, ...] = (".glb", ".gltf")
Z_UP_FROM_GLTF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # glTF +Y up -> our +Z up
AXES_NOTE = "glTF: +Y up by the glTF 2.0 specification, turned into z-up ((x, y, z) -> (x, -z, y))"


def _load_scene(p: Path):
    """The file's scene loaded by trimesh, or one line saying where it breaks."""
    if p.suffix.lower() == ".gltf":  # a JSON file: say where it breaks rather than trimesh's internal message
        try:
            json.loads(p.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read glTF file {p}: not JSON ({str(exc).splitlines()[0]})") from None

    try:
        return trimesh.load(str(p), force="scene")
    except Exception as exc:  # trimesh raises ValueError, KeyError, json errors ... on damaged files
        text = str(exc).strip().splitlines()
        raise InputError(f"cannot read glTF file {p}: {text[0] if text else type(exc).__name__}") from None


def _world_meshes(scene) -> list:
    """Each triangle mesh of the scene with its node's world transform applied (glTF axes)."""
    out = []
    for node in sorted(scene.graph.nodes_geometry):  # sorted: the same samples whatever the dict order
        matrix, name = scene.graph[node]
        geom = scene.geometry.get(name)
        if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
            g = geom.copy()
            g.apply_transform(matrix)
            out.append(g)
    return out


def _sample_colors(mesh, faces: np.ndarray, bary: np.ndarray) -> np.ndarray | None:
    """(n, 3) uint8 colours of samples ``bary`` on ``faces`` of ``mesh``: texture, vertex colours or None."""
    vis = mesh.visual
    corners = mesh.faces[faces]  # (n, 3) vertex indices
    if isinstance(vis, trimesh.visual.TextureVisuals) and vis.uv is not None and len(vis.uv) == len(mesh.vertices):
        mat = vis.material
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        factor = np.asarray(getattr(mat, "baseColorFactor", None) if getattr(mat, "baseColorFactor", None) is not None
                            else [255, 255, 255, 255], dtype=np.float64)
        factor = factor / 255.0 if factor.max() > 1.0 else factor
        if image is not None:
            uv = np.einsum("nk,nkj->nj", bary, np.asarray(vis.uv, dtype=np.float64)[corners])
            rgb = trimesh.visual.uv_to_color(uv, image)[:, :3].astype(np.float64) * factor[:3]
            return np.rint(np.clip(rgb, 0, 255)).astype(np.uint8)
        if getattr(mat, "baseColorFactor", None) is not None:
            return np.tile(np.rint(np.clip(factor[:3] * 255, 0, 255)).astype(np.uint8), (len(faces), 1))
        return None
    if isinstance(vis, trimesh.visual.ColorVisuals) and vis.kind == "vertex":
        vc = np.asarray(vis.vertex_colors, dtype=np.float64)[:, :3]
        return np.rint(np.einsum("nk,nkj->nj", bary, vc[corners])).astype(np.uint8)
    return None


def read_gltf(path: str | os.PathLike, num_points: int, seed: int = 0) -> tuple[PointCloud, str]:
    """``num_points`` samples of a glTF/GLB file's triangles, z-up, coloured; and a one-line note."""
    p = require_file(path, "glTF file")
    if num_points <= 0:
        raise InputError(f"number of mesh samples must be positive, got {num_points}")
    meshes = _world_meshes(_load_scene(p))
    if not meshes:
        raise InputError(f"glTF file has no triangle mesh (points, lines or an empty scene only): {p}")
    areas = [m.area_faces for m in meshes]
    total = np.concatenate(areas)
    if not np.all(np.isfinite(total)) or total.sum() <= 0:
        raise InputError(f"glTF mesh has zero surface area or non-finite vertices: {p}")
    rng = np.random.default_rng(seed)
    owner = np.repeat(np.arange(len(meshes)), [len(a) for a in areas])
    pick = rng.choice(len(total), size=int(num_points), p=total / total.sum())
    r1, r2 = rng.random(num_points), rng.random(num_points)
    s = np.sqrt(r1)
    bary = np.stack([1.0 - s, s * (1.0 - r2), s * r2], axis=1)  # uniform barycentric coordinates
    starts = np.concatenate([[0], np.cumsum([len(a) for a in areas])])
    pts = np.empty((num_points, 3))
    cols: list[np.ndarray | None] = []
    order = np.argsort(owner[pick], kind="stable")
    pick, bary = pick[order], bary[order]
    for i, m in enumerate(meshes):  # per mesh (a handful), vectorized over its samples
        sel = owner[pick] == i
        faces = pick[sel] - starts[i]
        tri = np.asarray(m.vertices, dtype=np.float64)[m.faces[faces]]
        pts[sel] = np.einsum("nk,nkj->nj", bary[sel], tri)
        cols.append(_sample_colors(m, faces, bary[sel]) if sel.any() else np.zeros((0, 3), np.uint8))
    colors = None if any(c is None for c in cols) else np.concatenate(cols)
    cloud = PointCloud(pts @ Z_UP_FROM_GLTF.T, colors).validate(p)
    what = "texture colours" if colors is not None else "no colours (no texture or vertex colours)"
    note = (f"{AXES_NOTE}; {len(meshes)} mesh(es), {len(total)} triangles sampled with {num_points} points, {what}")
    return cloud, note


def write_glb(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray, tri_uvs: np.ndarray | None = None,
              texture: np.ndarray | None = None) -> Path:
    """Write a z-up triangle mesh as GLB (turned to glTF's y-up), with an RGB ``texture`` image and
    per-corner texture coordinates ``tri_uvs`` (F, 3, 2; OBJ convention, v up) when given; atomically."""
    V = np.asarray(vertices, dtype=np.float64) @ Z_UP_FROM_GLTF  # inverse rotation: our z-up -> glTF y-up
    F = np.asarray(triangles, dtype=np.int64)
    if tri_uvs is not None and texture is not None:
        corners = V[F].reshape(-1, 3)  # one vertex per corner: texture seams need their own coordinates
        material = trimesh.visual.material.PBRMaterial(
            baseColorTexture=pil_image.fromarray(np.asarray(texture, dtype=np.uint8)), baseColorFactor=[255, 255, 255, 255],
            metallicFactor=0.0, roughnessFactor=1.0)
        visual = trimesh.visual.TextureVisuals(uv=np.asarray(tri_uvs, dtype=np.float64).reshape(-1, 2), material=material)
        mesh = trimesh.Trimesh(corners, np.arange(len(corners)).reshape(-1, 3), visual=visual, process=False)
    else:
        mesh = trimesh.Trimesh(V, F, process=False)
    target = Path(path)
    with atomic_file(target, suffix=".glb") as tmp:
        tmp.write_bytes(trimesh.Scene(mesh).export(file_type="glb"))
    return target
