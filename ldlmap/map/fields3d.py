"""Precomputed 3D line distance fields (docs/method.md): the map-build side.

Rotation invariance gives ``f3D_g(q; R, t) = f3D_g(R^T q; I, t)``: the decomposed 3D distance
function of principal group ``g`` seen from a candidate translation ``t`` is one fixed function on
the sphere per (t, g), whatever the rotation. This module samples it once per translation on a
spherical grid at map-build time; :mod:`ldlloc.search.fields` interpolates it at query time, turning the
N_t x N_r x |Q| x 3 exact evaluations of :func:`ldlloc.search.ldf.ldf_3d` into bilinear look-ups.

Grid (``kind = "equirect_nodes"``). ``rows`` = G latitude intervals; nodes sit on

* polar angle ``theta_i = i * pi / G`` for ``i = 0..G`` (``G + 1`` rows, both poles included:
  every node of a pole row is the same point and holds the same value), and
* azimuth ``phi_j = -pi + j * pi / G`` for ``j = 0..2G-1`` (``2G`` columns, periodic),

of the direction ``(sin theta cos phi, sin theta sin phi, cos theta)`` in the *world-aligned*
frame at ``t`` (the camera frame of the identity rotation, ``p = X - t``; ``theta`` measured from
+z, ``phi = atan2(y, x)``). Node grids make bilinear interpolation exact at the nodes, continuous
across the azimuth seam and at the poles. An equirectangular grid was chosen over a cube map:
for the same largest cell (``pi / G`` at the equator) it needs fewer samples (2 G^2 against
6 (2G/pi)^2 ~ 2.4 G^2), and its look-up is a single affine index computation.

Map layout (``/fields`` group of :mod:`ldlmap.map.mapfile`):

* ``/fields/distances`` (N_t, 3, G + 1, 2G) float16: ``f3D_g`` in radians, [0, pi]; pi where the
  group has no line (:data:`ldlmap.core.sphere_distance.EMPTY_DISTANCE`). float16 spacing is below
  2e-3 rad on [0, pi] (quantization error <= 1e-3 rad).
* attrs ``kind`` ("equirect_nodes"), ``rows`` (G), ``num_groups`` (3), ``version`` (1). The map file
  stores them as uint8 square-root codes (format version 3, :mod:`ldlmap.map.mapfile`), half the
  float16 size; they are read back as float16.

Size: ``N_t * 3 * (G + 1) * 2G * 2`` bytes before compression; with the default G = 64,
49.9 kB per translation: 40 MB for N_t = 800 and 85 MB for N_t = 1700, less after the map
file's gzip+shuffle. Stored size and computing time: docs/measurements.md#fields-cost.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.core.sphere_distance import arc_products, group_order, grouped_min_distance, project_lines

torch = lazy_module("torch")

FIELD_KIND = "equirect_nodes"
FIELD_VERSION = 1


@dataclass(frozen=True)
class FieldParams:
    """Parameters of the precomputed 3D distance fields."""

    rows: int = 64  # G: latitude intervals (node spacing pi / G = 2.8 deg); 2G azimuth columns
    num_groups: int = 3  # decomposed functions, one per principal direction (k_3D = 3)
    chunk_translations: int = 4  # translations per batch
    work_elements: int = 800_000  # dot products per batch (translations x 5 lines x nodes); 3.2 MB
    dtype: str = "float16"  # storage dtype (float16: <= 1e-3 rad quantization on [0, pi])


def grid_directions(rows: int) -> np.ndarray:
    """Unit directions of the field nodes, (G + 1, 2G, 3) in the world-aligned frame."""
    G = int(rows)
    if G < 2:
        raise InputError(f"field grid needs at least 2 rows, got {G}")
    theta = np.arange(G + 1) * np.pi / G
    phi = -np.pi + np.arange(2 * G) * np.pi / G
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    return np.stack([st * np.cos(phi)[None], st * np.sin(phi)[None], np.broadcast_to(ct, (G + 1, 2 * G))], -1)


def compute_fields(lines: np.ndarray, groups: np.ndarray, translations: np.ndarray,
                   params: FieldParams = FieldParams(), device: str = "cpu",
                   progress: Callable[[int, int], None] | None = None,
                   visibility: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Sample the decomposed 3D distance functions of every translation on the node grid.

    Args:
        lines: (L, 2, 3) 3D segments (world).
        groups: (L,) principal group of each line (-1: none; such lines are not in any field).
        translations: (N_t, 3) candidate camera centres.
        visibility: optional (N_t, L) bool, the lines seen from each translation (walls hide the
            others, :mod:`ldlmap.map.visibility`); None: every line.

    Returns:
        ``distances`` (N_t, G_groups, G + 1, 2G) in ``params.dtype`` and the attrs to store with
        them (see the module docstring).
    """
    lines = np.asarray(lines, dtype=np.float64)
    T = np.asarray(translations, dtype=np.float64)
    if lines.ndim != 3 or lines.shape[1:] != (2, 3):
        raise InputError(f"3D lines must have shape (L, 2, 3), got {lines.shape}")
    if T.ndim != 2 or T.shape[1] != 3:
        raise InputError(f"translations must have shape (N_t, 3), got {T.shape}")
    grp = np.asarray(groups, dtype=np.int64)
    if grp.shape != (len(lines),):
        raise InputError(f"groups must have shape ({len(lines)},), got {grp.shape}")
    if not (np.isfinite(lines).all() and np.isfinite(T).all()):
        raise InputError("lines or translations contain NaN or infinite values")
    G, ng = int(params.rows), int(params.num_groups)
    dirs = grid_directions(G)
    out = np.empty((len(T), ng, G + 1, 2 * G), dtype=np.dtype(params.dtype))
    dt = torch.float32
    x = torch.as_tensor(dirs.reshape(-1, 3), dtype=dt, device=device)
    index, bounds = group_order(torch.as_tensor(grp, device=device), ng)
    L = torch.as_tensor(lines, dtype=dt, device=device)[index]
    vis = None
    if visibility is not None:
        vis_np = np.asarray(visibility, dtype=bool)
        if vis_np.shape != (len(T), len(lines)):
            raise InputError(f"visibility must have shape ({len(T)}, {len(lines)}), got {vis_np.shape}")
        vis = torch.as_tensor(vis_np, device=device)[:, index]
    if L.shape[0] == 0:
        out[:] = np.pi
    else:
        Tt = torch.as_tensor(T, dtype=dt, device=device)
        step = max(1, int(params.chunk_translations))
        # Nodes per batch: keep the (step, 5L, nodes) dot products near ``work_elements`` so the element-wise
        # passes of grouped_min_distance run in cache (docs/measurements.md#fields-work-elements).
        pc = max(64, int(params.work_elements) // (step * 5 * L.shape[0]))
        flat = out.reshape(len(T), ng, -1)
        with torch.no_grad():
            for a in range(0, len(T), step):  # chunks of translations x chunks of nodes
                s, e = project_lines(L, Tt[a:a + step])
                products = arc_products(s, e, bounds)  # the same arcs for every node batch
                for p in range(0, x.shape[0], pc):
                    f = grouped_min_distance(x[p:p + pc], s, e, bounds, None if vis is None else vis[a:a + step],
                                             products=products)  # (c, G_groups, nodes)
                    flat[a:a + step, :, p:p + pc] = f.cpu().numpy()
                if progress:
                    progress(min(a + step, len(T)), len(T))
    attrs = {"kind": FIELD_KIND, "rows": G, "num_groups": ng, "version": FIELD_VERSION}
    return out, attrs


def field_bytes(num_translations: int, rows: int = FieldParams.rows, num_groups: int = 3,
                itemsize: int = 2) -> int:
    """Uncompressed size of ``/fields/distances`` in bytes."""
    return int(num_translations) * num_groups * (rows + 1) * 2 * rows * itemsize
