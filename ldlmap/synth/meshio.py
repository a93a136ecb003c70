"""Write a :class:`SceneMesh` as a textured Wavefront OBJ (``.obj`` + ``.mtl`` + ``.png``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ldlmap.core.errors import LdlError, atomic_file
from ldlmap.io.imagefile import write_image
from ldlmap.synth.types import SceneMesh


def write_textured_obj(mesh: SceneMesh, path_obj: str | os.PathLike) -> Path:
    """Write ``path_obj``, ``<stem>.mtl`` and ``<stem>.png`` beside it (each atomically); return the OBJ path.

    Texture coordinates are written per triangle corner (``vt``), faces as ``f v/vt``.
    """
    path = Path(path_obj)
    stem = path.stem
    mtl_path, png_path = path.with_suffix(".mtl"), path.with_suffix(".png")
    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.triangles, dtype=np.int64)
    uv = np.asarray(mesh.tri_uvs, dtype=np.float64).reshape(-1, 2)
    with atomic_file(png_path) as tmp:
        try:
            write_image(tmp, mesh.atlas[..., ::-1], suffix=".png")
        except ValueError:
            raise LdlError(f"cannot write texture {png_path}") from None
    with atomic_file(mtl_path) as tmp:
        tmp.write_text(f"newmtl {stem}\nKa 1.000 1.000 1.000\nKd 1.000 1.000 1.000\nKs 0.000 0.000 0.000\n"
                       f"d 1.0\nillum 1\nmap_Kd {png_path.name}\n")
    v_txt = "".join("v " + line + "\n" for line in (" ".join(r) for r in np.char.mod("%.6f", V))) if len(V) else ""
    vt_txt = "".join("vt " + line + "\n" for line in (" ".join(r) for r in np.char.mod("%.6f", uv))) if len(uv) else ""
    corner = np.arange(1, 3 * len(F) + 1).reshape(-1, 3)
    fv = np.char.add(np.char.add(np.char.mod("%d", F + 1), "/"), np.char.mod("%d", corner))
    f_txt = "".join("f " + " ".join(r) + "\n" for r in fv)
    with atomic_file(path) as tmp:
        tmp.write_text(f"# ldl synthetic scene {mesh.name}: {len(V)} vertices, {len(F)} triangles\n"
                       f"mtllib {mtl_path.name}\no {stem}\n{v_txt}{vt_txt}usemtl {stem}\n{f_txt}")
    return path
