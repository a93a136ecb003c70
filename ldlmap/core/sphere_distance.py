"""Spherical point-to-arc distance (paper eq. 2) in torch, shared by the map and the localizer.

This is the 3D-side primitive that :mod:`ldlmap.map.fields3d` needs to precompute distance fields at
map-build time (``ldlmap`` never imports ``ldlloc``); :mod:`ldlloc.search.ldf` re-exports
:func:`point_arc_distance` under its public name and builds the line distance functions on it.

For a unit point ``x`` and an arc ``(s, e)`` (the minor great-circle arc from ``s`` to ``e``)
with unit normal ``n = s x e / |s x e|``::

    D = asin(|x . n|)                 if x.s - (s.e)(x.e) > 0 and x.e - (s.e)(x.s) > 0
    D = min(acos(x.s), acos(x.e))     otherwise

Degenerate arcs (``|s x e| < 1e-9``) use the endpoint branch only. Empty line sets give
:data:`EMPTY_DISTANCE` = pi.
"""

from __future__ import annotations

import math
from typing import Sequence, TYPE_CHECKING

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module

torch = lazy_module("torch")

if TYPE_CHECKING:  # pragma: no cover
    import torch

EMPTY_DISTANCE = math.pi  # value of a distance function over an empty set of lines
DEGENERATE_EPS = 1e-9  # |s x e| below this: the arc's great circle is undefined


def as_tensor(a, device=None, dtype=None) -> "torch.Tensor":
    """``a`` as a torch tensor on ``device``; numpy input becomes float32 unless ``dtype`` is given."""
    if isinstance(a, torch.Tensor):
        t = a
        if dtype is not None and t.dtype != dtype:
            t = t.to(dtype)
        if device is not None:
            t = t.to(device)
        return t
    arr = np.array(a)  # a copy: numpy inputs may be read-only
    return torch.as_tensor(arr, dtype=dtype or torch.float32, device=device)


def check_finite(name: str, t: "torch.Tensor") -> None:
    """Raise InputError when ``t`` holds NaN or infinite values."""
    if t.numel() and not bool(torch.isfinite(t).all()):
        raise InputError(f"{name} contains NaN or infinite values")


def check_last(name: str, t: "torch.Tensor", dims: Sequence[int]) -> None:
    """Raise InputError unless the trailing dimensions of ``t`` are ``dims``."""
    k = len(dims)
    if t.dim() < k or tuple(t.shape[-k:]) != tuple(dims):
        want = "(..., " + ", ".join(map(str, dims)) + ")"
        raise InputError(f"{name} must have shape {want}, got {tuple(t.shape)}")


def point_arc_distance(x, s, e) -> "torch.Tensor":
    """Spherical distance (radians) from points to arcs, paper eq. 2.

    Args:
        x: (..., Q, 3) unit points.
        s, e: (..., L, 3) unit arc start and end points (leading dims broadcast with ``x``).

    Returns:
        (..., Q, L) distances in [0, pi].
    """
    x = as_tensor(x)
    s = as_tensor(s, x.device, x.dtype)
    e = as_tensor(e, x.device, x.dtype)
    check_last("points", x, (3,))
    check_last("arc starts", s, (3,))
    if s.shape != e.shape:
        raise InputError(f"arc starts and ends differ in shape: {tuple(s.shape)} vs {tuple(e.shape)}")
    n = torch.linalg.cross(s, e, dim=-1)
    nn = torch.linalg.vector_norm(n, dim=-1)  # (..., L)
    ok = nn > DEGENERATE_EPS
    n = n / torch.where(ok, nn, torch.ones_like(nn)).unsqueeze(-1)
    c = (s * e).sum(-1).unsqueeze(-2)  # (..., 1, L)
    xs = torch.matmul(x, s.transpose(-1, -2))  # (..., Q, L)
    xe = torch.matmul(x, e.transpose(-1, -2))
    xn = torch.matmul(x, n.transpose(-1, -2))
    inside = (xs - c * xe > 0) & (xe - c * xs > 0) & ok.unsqueeze(-2)
    d_circle = torch.asin(xn.abs().clamp(max=1.0))
    d_end = torch.acos(torch.maximum(xs, xe).clamp(-1.0, 1.0))
    return torch.where(inside, d_circle, d_end)


def project_lines(lines: "torch.Tensor", centers: "torch.Tensor") -> tuple["torch.Tensor", "torch.Tensor"]:
    """Unit bearings of 3D segment ends seen from each centre (identity rotation).

    Args:
        lines: (L, 2, 3) segment endpoints (world).
        centers: (c, 3) camera centres (world).

    Returns:
        ``s, e``: (c, L, 3) arc starts and ends, ``normalize(X - t)``.
    """
    s = lines[None, :, 0, :] - centers[:, None, :]
    e = lines[None, :, 1, :] - centers[:, None, :]
    s = s / torch.linalg.vector_norm(s, dim=-1, keepdim=True).clamp_min(1e-12)
    e = e / torch.linalg.vector_norm(e, dim=-1, keepdim=True).clamp_min(1e-12)
    return s, e


def arc_products(s: "torch.Tensor", e: "torch.Tensor", bounds: Sequence[int]) -> list["torch.Tensor | None"]:
    """The five vectors of :func:`grouped_min_distance` per group, ``(s, e, n, n x s, e x n)``
    stacked as (c, 5 k, 3) (None for an empty group): what one set of arcs needs for any number
    of point batches, so that a caller sampling many batches against the same arcs makes it once."""
    n = torch.linalg.cross(s, e, dim=-1)
    nn = torch.linalg.vector_norm(n, dim=-1, keepdim=True)
    n = torch.where(nn > DEGENERATE_EPS, n / nn.clamp_min(DEGENERATE_EPS), torch.zeros_like(n))
    a_side = torch.linalg.cross(n, s, dim=-1)  # x . (n x s) > 0: x on e's side of the s-plane
    b_side = torch.linalg.cross(e, n, dim=-1)  # x . (e x n) > 0: x on s's side of the e-plane
    out: list = []
    for g in range(len(bounds) - 1):  # G = 3 groups: contiguous slices of the sorted lines
        lo, hi = bounds[g], bounds[g + 1]
        out.append(None if hi == lo else
                   torch.cat([s[:, lo:hi], e[:, lo:hi], n[:, lo:hi], a_side[:, lo:hi], b_side[:, lo:hi]], dim=1))
    return out


def grouped_min_distance(x: "torch.Tensor", s: "torch.Tensor", e: "torch.Tensor",
                         bounds: Sequence[int], visible: "torch.Tensor | None" = None,
                         products: list | None = None) -> "torch.Tensor":
    """``min over lines of group g`` of eq. 2 for points ``x`` (P, 3) and arcs ``s, e`` (c, L, 3).

    ``x`` may also be (c, P, 3): its own points for each of the ``c`` arc sets (one pose each).

    Lines are sorted by group (``bounds``: G + 1 offsets). Uses two facts to stay cheap:
    (1) the endpoint distance ``min(acos x.s, acos x.e)`` is never below the true distance, so
    ``min_l D_l = min(min over inside l of asin|x.n_l|, min over all endpoints acos(x.p))``: the
    endpoint term needs no masking; (2) ``x`` is inside the lune of ``(s, e)`` iff
    ``x . (n x s) > 0`` and ``x . (e x n) > 0`` (the same conditions as eq. 2 up to positive
    factors), so all five dot products come from one batched matmul per group (a group's
    products stay in cache: docs/measurements.md#grouped-products). Returns (c, G, P).

    ``visible`` (c, L) bool, optional: lines that are not visible from the arc set's centre (hidden
    behind walls) are left out of the minimum. ``products``: :func:`arc_products` of ``s, e``,
    when the caller made them already.
    """
    if products is None:
        products = arc_products(s, e, bounds)
    c = s.shape[0]
    xt = x.transpose(-1, -2).contiguous()  # (3, P) or (c, 3, P): bmm on a contiguous operand is the fast path
    outs = []
    for g, V in enumerate(products):
        lo, hi = bounds[g], bounds[g + 1]
        if V is None:
            outs.append(torch.full((c, x.shape[-2]), EMPTY_DISTANCE, dtype=x.dtype, device=x.device))
            continue
        dots = torch.bmm(V, xt) if xt.dim() == 3 else torch.matmul(V, xt)  # (c, 5k, P): all dot products
        xs, xe, xn, xa, xb = dots.split(hi - lo, dim=1)
        inside = (xa > 0) & (xb > 0)
        end = torch.maximum(xs, xe)  # cos of the nearest endpoint distance
        if visible is not None:
            seen = visible[:, lo:hi].unsqueeze(-1)
            inside &= seen
            end.masked_fill_(~seen, -1.0)  # a hidden line is pi away
        c_min = torch.where(inside, xn.abs(), 2.0).amin(1)  # sin of the great-circle distance, or 2 (none)
        d_circ = torch.where(c_min <= 1.0, torch.asin(c_min.clamp(max=1.0)),
                             torch.full_like(c_min, EMPTY_DISTANCE))  # 2 (no lune) -> ignored
        d_end = torch.acos(end.amax(1).clamp(-1.0, 1.0))
        outs.append(torch.minimum(d_circ, d_end))
    return torch.stack(outs, dim=1)


def group_order(groups: "torch.Tensor", num_groups: int) -> tuple["torch.Tensor", list[int]]:
    """Indices of the lines of groups 0..G-1 sorted by group (stable), and the G + 1 slice bounds."""
    keep = torch.nonzero((groups >= 0) & (groups < num_groups)).reshape(-1)
    index = keep[torch.argsort(groups[keep], stable=True)]
    grp = groups[index]
    counts = torch.bincount(grp, minlength=num_groups).tolist() if len(grp) else [0] * num_groups
    return index, np.concatenate([[0], np.cumsum(counts)]).astype(int).tolist()


def sort_by_group(lines: "torch.Tensor", groups: "torch.Tensor", num_groups: int
                  ) -> tuple["torch.Tensor", list[int]]:
    """Lines of groups 0..G-1 sorted by group, and the G + 1 slice bounds of each group."""
    index, bounds = group_order(groups, num_groups)
    return lines[index], bounds
