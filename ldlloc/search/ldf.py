"""Line distance functions and pose losses (paper section 3.3), in torch.

All functions run on CPU or CUDA, batched, in the dtype of their inputs (float32 by default
when numpy arrays are given; pass float64 tensors for reference-quality values).

Spherical point-to-arc distance (paper eq. 2). For a unit point ``x`` and an arc ``(s, e)``
(the minor great-circle arc from ``s`` to ``e``) with unit normal ``n = s x e / |s x e|``::

    D = asin(|x . n|)                 if x.s - (s.e)(x.e) > 0 and x.e - (s.e)(x.s) > 0
    D = min(acos(x.s), acos(x.e))     otherwise

The two conditions say that the projection of ``x`` onto the arc's plane is a positive
combination of ``s`` and ``e`` (``x`` lies in the spherical quadrilateral / lune of the arc), so
the nearest point of the great circle lies on the arc; this holds for arcs of any length below
180 degrees. Degenerate arcs (``|s x e| < 1e-9``: zero length, or antipodal ends whose great
circle is undefined) use the endpoint branch only.

Empty line sets (an empty principal group, or all lines masked out) give the distance
:data:`EMPTY_DISTANCE` = pi, the largest possible spherical distance ("no line anywhere").

Precision: the endpoint branch uses ``acos`` of a dot product, which in float32 is accurate to
about 5e-4 rad within a milliradian of an endpoint and to ~1e-6 rad elsewhere; the
great-circle branch is accurate everywhere. This is far below the inlier threshold tau = 0.1.

3D distance functions use rotation invariance: ``f3D(x; R, t) = f3D(R^T x; I, t)``. Lines are
projected once per translation (``normalize(X - t)``) and the query points are rotated by
``R^T`` for each candidate rotation instead of projecting lines per rotation.

The 3D functions can also come from the map's precomputed distance fields (bilinear look-ups,
:mod:`ldlloc.search.fields`); :func:`ldf_3d` stays the exact reference that the fast path is tested
against (:mod:`ldlloc.search.pose_search` selects the path).

Shapes used below: ``N_t`` translations, ``N_r`` rotations, ``Q`` query points, ``L`` lines,
``G`` groups (3 for the decomposed functions).
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.errors import InputError, check_choice
from ldlmap.core.geometry import icosphere_points
from ldlmap.core.lazy import lazy_module
# Shared with the map side (ldlmap never imports ldlloc): the torch point-arc distance and its
# helpers live in ldlmap.core.sphere_distance; these names keep ldlloc.search.ldf's public API.
from ldlmap.core.sphere_distance import (EMPTY_DISTANCE, as_tensor as _as_tensor, check_finite as _check_finite,
                                         check_last as _check_last, grouped_min_distance as _grouped_min_distance,
                                         point_arc_distance, project_lines as _project_lines,
                                         group_order as _group_order)

torch = lazy_module("torch")

LOSS_KINDS: tuple[str, ...] = ("inlier", "l1", "l2", "huber", "median")


def check_loss(kind: str, name: str = "loss") -> None:
    """A one-line InputError unless ``kind`` is one of :data:`LOSS_KINDS` (``name``: how the caller calls it)."""
    check_choice(kind, LOSS_KINDS, name)


# ------------------------------------------------------------------------------------- helpers


def query_points(level: int = 1, device=None, dtype=None) -> "torch.Tensor":
    """The query points Q: vertices of a level-``level`` icosphere (level 1: 42 points)."""
    return _as_tensor(np.array(icosphere_points(level)), device, dtype)


# ---------------------------------------------------------------------------- distance functions


def distance_function(x, arcs, mask=None) -> "torch.Tensor":
    """Line distance function ``f(x) = min over arcs D(x, l)`` (paper eq. 1).

    Args:
        x: (..., Q, 3) unit points.
        arcs: (..., L, 2, 3) arcs as start/end unit vectors.
        mask: optional (..., L) bool, True for arcs to use.

    Returns:
        (..., Q); :data:`EMPTY_DISTANCE` (pi) where no arc is used.
    """
    x = _as_tensor(x)
    arcs = _as_tensor(arcs, x.device, x.dtype)
    _check_last("arcs", arcs, (2, 3))
    if arcs.shape[-3] == 0:
        return torch.full(x.shape[:-1], EMPTY_DISTANCE, dtype=x.dtype, device=x.device)
    d = point_arc_distance(x, arcs[..., 0, :], arcs[..., 1, :])
    if mask is not None:
        mask = _as_tensor(mask, x.device, torch.bool)
        d = d.masked_fill(~mask.unsqueeze(-2), EMPTY_DISTANCE)
    return d.amin(-1).clamp(max=EMPTY_DISTANCE)


def _group_min(d: "torch.Tensor", labels: "torch.Tensor", num_groups: int) -> "torch.Tensor":
    """Min of ``d`` (..., Q, L) over the lines of each group -> (..., G, Q).

    ``labels`` broadcasts against (..., L); lines labelled outside 0..G-1 are ignored.
    """
    outs = []
    for g in range(num_groups):  # G = 3: a loop over groups, not over data
        m = (labels == g).unsqueeze(-2)
        outs.append(d.masked_fill(~m, EMPTY_DISTANCE).amin(-1) if d.shape[-1] else
                    torch.full(d.shape[:-1], EMPTY_DISTANCE, dtype=d.dtype, device=d.device))
    return torch.stack(outs, dim=-2)


def decomposed_distance_2d(x, arcs, labels, num_groups: int = 3) -> "torch.Tensor":
    """Decomposed 2D distance functions ``f2D(x; L_2D^i)``, one per principal group.

    Args:
        x: (Q, 3) query points.
        arcs: (L, 2, 3) 2D arcs (camera frame).
        labels: (L,) or (N_r, L) int group of each arc (-1: none). For rotation candidates use
            :func:`ldlloc.rotation.labels_for_rotations` so that 2D group ``i`` is the group
            paired with 3D principal direction ``i`` by that rotation.

    Returns:
        (G, Q) or (N_r, G, Q).
    """
    x = _as_tensor(x)
    _check_last("query points", x, (3,))
    arcs = _as_tensor(arcs, x.device, x.dtype)
    _check_last("arcs", arcs, (2, 3))
    labels = _as_tensor(labels, x.device, torch.long)
    if labels.shape[-1] != arcs.shape[0]:
        raise InputError(f"labels have {labels.shape[-1]} entries for {arcs.shape[0]} arcs")
    d = point_arc_distance(x, arcs[:, 0], arcs[:, 1])  # (Q, L)
    if labels.dim() == 1:
        return _group_min(d, labels, num_groups)
    return _group_min(d.unsqueeze(0), labels, num_groups)


def _inputs_3d(x, rotations, translations, lines3d, groups, num_groups: int, device, dtype, visibility=None):
    """Checked tensors of the 3D functions: x, R, T, grouped lines sorted by group, group bounds,
    and the (N_t, L') visibility of those sorted lines (None: all visible)."""
    x = _as_tensor(x, device, dtype)
    dev, dt = x.device, x.dtype
    R = _as_tensor(rotations, dev, dt)
    T = _as_tensor(translations, dev, dt)
    lines = _as_tensor(lines3d, dev, dt)
    grp = _as_tensor(groups, dev, torch.long)
    _check_last("query points", x, (3,))
    if R.dim() != 3 or R.shape[1:] != (3, 3):
        raise InputError(f"rotations must have shape (N_r, 3, 3), got {tuple(R.shape)}")
    if T.dim() != 2 or T.shape[1] != 3:
        raise InputError(f"translations must have shape (N_t, 3), got {tuple(T.shape)}")
    if lines.dim() != 3 or lines.shape[1:] != (2, 3):
        raise InputError(f"3D lines must have shape (L, 2, 3), got {tuple(lines.shape)}")
    if grp.shape != (lines.shape[0],):
        raise InputError(f"groups must have shape ({lines.shape[0]},), got {tuple(grp.shape)}")
    for name, t in (("query points", x), ("rotations", R), ("translations", T), ("3D lines", lines)):
        _check_finite(name, t)
    # Keep only grouped lines, sorted by group, so each group is a contiguous slice.
    index, bounds = _group_order(grp, num_groups)
    vis = None
    if visibility is not None:
        vis = _as_tensor(visibility, dev, torch.bool)
        if tuple(vis.shape) != (T.shape[0], lines.shape[0]):
            raise InputError(f"visibility must have shape ({T.shape[0]}, {lines.shape[0]}), got {tuple(vis.shape)}")
        vis = vis[:, index]
    return x, R, T, lines[index], bounds, vis


def ldf_3d(x, rotations, translations, lines3d, groups, num_groups: int = 3,
           chunk: int = 4, device=None, dtype=None, visibility=None) -> "torch.Tensor":
    """Decomposed 3D line distance functions for all poses.

    ``f3D_g(q; R, t) = min over lines l in group g of D(q, Pi_L(l; R, t))`` computed as
    ``D(R^T q, normalize(l - t))`` (rotation invariance): lines are projected once per
    translation and the query points are rotated per rotation.

    Args:
        x: (Q, 3) query points (camera frame).
        rotations: (N_r, 3, 3) world-to-camera rotations R.
        translations: (N_t, 3) camera centres t (world).
        lines3d: (L, 2, 3) 3D segment endpoints (world).
        groups: (L,) int principal group of each line (-1: none, ignored).
        chunk: translations per batch (peak memory ~ chunk * N_r * Q * L * 4 bytes * ~8; small
            chunks stay in CPU cache and are fastest there, use larger ones on CUDA).
        visibility: optional (N_t, L) bool: the lines seen from each translation (the map's,
            where walls hide lines); None: every line.

    Returns:
        (N_t, N_r, G, Q) distances.
    """
    x, R, T, lines, bounds, vis = _inputs_3d(x, rotations, translations, lines3d, groups, num_groups, device, dtype,
                                             visibility)
    n_t, n_r, q = T.shape[0], R.shape[0], x.shape[0]
    out = torch.full((n_t, n_r, num_groups, q), EMPTY_DISTANCE, dtype=x.dtype, device=x.device)
    if lines.shape[0] == 0 or n_t == 0 or n_r == 0:
        return out
    # R^T q for every rotation: (R^T q)_j = sum_i R_ij q_i -> q @ R.
    xr = torch.einsum("qi,rij->rqj", x, R).reshape(n_r * q, 3)
    step = max(1, int(chunk))
    for a in range(0, n_t, step):  # loop over chunks of translations, vectorized inside
        s, e = _project_lines(lines, T[a:a + step])
        v = None if vis is None else vis[a:a + step]
        out[a:a + step] = _grouped_min_distance(xr, s, e, bounds, v).reshape(-1, num_groups, n_r, q).transpose(1, 2)
    return out


AT_BATCH_VALUES = 1 << 22  # ldf_3d_at: poses per batch so that the 5 dot products per (pose, line, point)
# fill about 4 M float32 (16 MB); all 64 re-scored poses of a floor map at once (150 MB) took twice
# the CPU (docs/measurements.md#rescore-batches)


def ldf_3d_at(x, rotations, translations, lines3d, groups, translation_index, rotation_index,
              num_groups: int = 3, device=None, dtype=None, visibility=None) -> "torch.Tensor":
    """:func:`ldf_3d` at M chosen poses only: pose m is ``(rotations[rotation_index[m]],
    translations[translation_index[m]])``.

    The lines are projected once per distinct translation and the M poses go through batched
    evaluations (each pose with its own rotated query points; :data:`AT_BATCH_VALUES` per batch). Returns (M, G, Q), the
    values ``ldf_3d(...)[translation_index, rotation_index]`` (up to float rounding).
    """
    x, R, T, lines, bounds, vis = _inputs_3d(x, rotations, translations, lines3d, groups, num_groups, device, dtype,
                                             visibility)
    ti = _as_tensor(translation_index, x.device, torch.long).reshape(-1)
    ri = _as_tensor(rotation_index, x.device, torch.long).reshape(-1)
    if ti.shape != ri.shape:
        raise InputError(f"{ti.numel()} translation indices for {ri.numel()} rotation indices")
    if lines.shape[0] == 0 or ti.numel() == 0:
        return torch.full((ti.numel(), num_groups, x.shape[0]), EMPTY_DISTANCE, dtype=x.dtype, device=x.device)
    xr = torch.einsum("qi,mij->mqj", x, R[ri])  # (M, Q, 3): R^T q for each pose
    uniq, inv = torch.unique(ti, return_inverse=True)
    s, e = _project_lines(lines, T[uniq])  # once per distinct translation
    vis_m = None if vis is None else vis[ti]
    step = max(1, AT_BATCH_VALUES // (5 * lines.shape[0] * x.shape[0]))
    return torch.cat([_grouped_min_distance(xr[a:a + step], s[inv[a:a + step]], e[inv[a:a + step]], bounds,
                                            None if vis_m is None else vis_m[a:a + step])
                      for a in range(0, ti.numel(), step)])


# ------------------------------------------------------------------------------------- losses


def pose_loss(f2d, f3d, kind: str = "inlier", tau: float = 0.1, decompose: bool = True,
              huber_delta: float | None = None) -> "torch.Tensor":
    """Loss of every pose from its 2D and 3D distance functions (lower is better).

    Args:
        f2d: (G, Q) or (N_r, G, Q) 2D distance functions (per rotation when the 2D grouping
            depends on the rotation's triplet, see :func:`decomposed_distance_2d`).
        f3d: (N_t, N_r, G, Q) 3D distance functions from :func:`ldf_3d`.
        kind: ``inlier`` (paper eq. 5: minus the count of ``|f2D - f3D| < tau`` over groups
            and query points), or the ablations ``l1`` (sum of ``|diff|``), ``l2`` (sum of
            squares), ``huber`` (sum of Huber with ``delta = huber_delta or tau``), ``median``
            (median of ``|diff|``).
        decompose: when False, each side is first reduced to the undecomposed function by a
            min over groups (eq. 4: equal to the function of all grouped lines). To use every
            line, pass G = 1 functions computed with all lines in one group.

    Returns:
        (N_t, N_r) losses.
    """
    check_loss(kind)
    f3d = _as_tensor(f3d)
    f2d = _as_tensor(f2d, f3d.device, f3d.dtype)
    if f3d.dim() != 4:
        raise InputError(f"f3d must have shape (N_t, N_r, G, Q), got {tuple(f3d.shape)}")
    if f2d.dim() == 2:
        f2d = f2d.unsqueeze(0)
    if f2d.dim() != 3 or f2d.shape[-2:] != f3d.shape[-2:] or f2d.shape[0] not in (1, f3d.shape[1]):
        raise InputError(f"f2d shape {tuple(f2d.shape)} does not match f3d shape {tuple(f3d.shape)}")
    if not decompose:
        f2d = f2d.amin(-2, keepdim=True)
        f3d = f3d.amin(-2, keepdim=True)
    diff = (f2d.unsqueeze(0) - f3d).abs().flatten(-2)  # (N_t, N_r, G*Q)
    if kind == "inlier":
        return -(diff < tau).sum(-1).to(f3d.dtype)
    if kind == "l1":
        return diff.sum(-1)
    if kind == "l2":
        return (diff * diff).sum(-1)
    if kind == "huber":
        delta = tau if huber_delta is None else huber_delta
        quad = 0.5 * diff * diff
        lin = delta * (diff - 0.5 * delta)
        return torch.where(diff <= delta, quad, lin).sum(-1)
    return diff.median(-1).values  # median


def top_k_poses(loss, k: int = 20) -> tuple["torch.Tensor", "torch.Tensor", "torch.Tensor"]:
    """Indices (translation, rotation) and losses of the ``k`` lowest losses of an (N_t, N_r) grid.

    Ties keep the lower flat index (translation-major) first.
    """
    loss = _as_tensor(loss)
    flat = loss.reshape(-1)
    k = min(int(k), flat.numel())
    # Stable sort so equal losses keep a deterministic order.
    order = torch.sort(flat, stable=True).indices[:k]
    return order // loss.shape[1], order % loss.shape[1], flat[order]
