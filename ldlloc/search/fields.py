"""Interpolated look-ups in precomputed 3D distance fields: the fast pose-search path.

The fields (:mod:`ldlmap.map.fields3d` documents the grid and the map layout) hold, per candidate
translation ``t`` and principal group ``g``, the decomposed 3D line distance function
``f3D_g(p; I, t)`` sampled on an equirectangular node grid of ``G + 1`` rows (polar angle
``theta_i = i pi / G`` from +z) by ``2G`` periodic columns (azimuth ``phi_j = -pi + j pi / G``).
By rotation invariance ``f3D_g(q; R, t) = f3D_g(R^T q; I, t)``; the look-up point ``R^T q`` does
not depend on ``t``, so the bilinear corners and weights of the N_r x |Q| rotated query points
are computed once and every translation's value comes from the same 4 corners:

    f3D[r, q, g, t] = sum_k w[r q, k] * table[corner[r q, k], g, t]

which is one ``torch.nn.functional.embedding_bag`` (a fused, weighted row gather) over a table
of shape ``(nodes, G_groups * N_t)``.

Accuracy against :func:`ldlloc.search.ldf.ldf_3d` (``tests/test_fields.py``, ``bench/bench_search.py``;
measured: docs/measurements.md#fields-accuracy): the interpolation error is largest on the kinks of
the functions (on a line; where two lines are equidistant) and can never exceed the cell diagonal
(sqrt(2) pi / G = 0.069 rad for G = 64: f is 1-Lipschitz and the interpolant a convex combination
of corner values). It stays below the inlier threshold tau = 0.1 rad but moves a pose's inlier
count by a few terms, so the field losses alone rank ties and near-ties differently from the
exact path. :func:`ldlloc.search.pose_search.search_poses` therefore re-scores the best
``SearchParams.rescore`` field poses exactly: the returned top-K losses are exact (the exact path's
whenever its top K are among those poses).

Memory at query time: the table keeps the stored float16 values, ``N_t * 3 * (G + 1) * 2G * 2``
bytes: 40 MB for N_t = 800 and 85 MB for N_t = 1700 with G = 64 (use ``dtype=torch.float32`` to
trade twice the memory for float32 interpolation arithmetic; it changes the values by less than
1e-3 rad). The table (a transpose) is prepared once per map (docs/measurements.md#fields-setup).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.map.fields3d import FIELD_KIND  # the only grid kind the map writes (version 1)

torch = lazy_module("torch")
F = lazy_module("torch.nn.functional")



def _all_finite(a: np.ndarray) -> bool:
    """``np.isfinite(a).all()``; for float16 from the bits (finite unless the exponent bits are all
    ones), much faster than a float16 pass (docs/measurements.md#float16-checks)."""
    if a.dtype == np.float16:
        return int((a.view(np.uint16) & 0x7FFF).max(initial=0)) < 0x7C00
    return bool(np.isfinite(a).all())


@dataclass
class DistanceFields:
    """Distance fields of one map prepared for look-ups (build once per map, reuse per query)."""

    table: "torch.Tensor"  # (nodes, G_groups * N_t): row = grid node, column = g * N_t + t
    rows: int  # G: the grid has G + 1 rows and 2G columns
    num_translations: int
    num_groups: int

    @classmethod
    def from_arrays(cls, distances: np.ndarray, attrs: Mapping[str, Any] | None = None,
                    device: str = "cpu", dtype=None) -> "DistanceFields":
        """Prepare the table from ``/fields/distances`` (N_t, G_groups, G + 1, 2G) and its attrs."""
        d = np.asarray(distances)
        attrs = dict(attrs or {})
        kind = str(attrs.get("kind", FIELD_KIND))
        if kind != FIELD_KIND:
            raise InputError(f"unknown distance field kind {kind!r} (this version reads {FIELD_KIND!r})")
        if d.ndim != 4 or d.shape[3] != 2 * (d.shape[2] - 1) or d.shape[2] < 3:
            raise InputError(f"distance fields must have shape (N_t, groups, G + 1, 2G), got {d.shape}")
        rows = int(attrs.get("rows", d.shape[2] - 1))
        if rows != d.shape[2] - 1:
            raise InputError(f"distance fields: attrs say {rows} rows, the array has {d.shape[2] - 1}")
        n_t, ng = d.shape[0], d.shape[1]
        if not _all_finite(d):
            raise InputError("distance fields contain NaN or infinite values")
        dt = dtype or (torch.float16 if d.dtype == np.float16 else torch.float32)
        # (N_t, g, nodes) -> (nodes, g, N_t): one contiguous row of all values per grid node.
        t = torch.as_tensor(np.ascontiguousarray(d.reshape(n_t, ng, -1).transpose(2, 1, 0)))
        table = t.reshape(t.shape[0], ng * n_t).to(device=device, dtype=dt).contiguous()
        return cls(table, rows, n_t, ng)

    @classmethod
    def from_map(cls, ldl_map, device: str = "cpu", dtype=None) -> "DistanceFields | None":
        """The map's fields ready for look-ups, or None when the map has none."""
        if not getattr(ldl_map, "fields", None) or "distances" not in ldl_map.fields:
            return None
        f = cls.from_arrays(ldl_map.fields["distances"], ldl_map.fields_attrs, device, dtype)
        if f.num_translations != len(ldl_map.translations):
            raise InputError(f"map {ldl_map.name}: distance fields for {f.num_translations} translations, "
                             f"the map has {len(ldl_map.translations)}: rebuild the map")
        return f

    def subset(self, translation_index: np.ndarray) -> "DistanceFields":
        """The fields of these translations only (a restricted search, ``ldlloc.pipeline.SearchNear``)."""
        idx = torch.as_tensor(np.asarray(translation_index, dtype=np.int64), device=self.table.device)
        t = self.table.view(self.table.shape[0], self.num_groups, self.num_translations)[:, :, idx]
        return DistanceFields(t.reshape(t.shape[0], -1).contiguous(), self.rows, len(idx), self.num_groups)

    @property
    def nbytes(self) -> int:
        return int(self.table.numel() * self.table.element_size())

    def corners(self, points: "torch.Tensor") -> tuple["torch.Tensor", "torch.Tensor"]:
        """Bilinear corners (P, 4) node indices and weights (P, 4) of unit points (P, 3)."""
        G = self.rows
        p = points.to(torch.float32)
        theta = torch.acos(p[:, 2].clamp(-1.0, 1.0))
        phi = torch.atan2(p[:, 1], p[:, 0])
        fi = theta * (G / math.pi)  # [0, G]
        fj = (phi + math.pi) * (G / math.pi)  # [0, 2G]
        i0 = fi.floor().clamp(0, G - 1)
        j0 = fj.floor()
        a = (fi - i0).clamp(0.0, 1.0)  # weight of row i0 + 1
        b = (fj - j0).clamp(0.0, 1.0)  # weight of column j0 + 1
        i0 = i0.long()
        j0 = j0.long() % (2 * G)
        j1 = (j0 + 1) % (2 * G)
        r0, r1 = i0 * (2 * G), (i0 + 1) * (2 * G)
        idx = torch.stack([r0 + j0, r0 + j1, r1 + j0, r1 + j1], dim=1)
        w = torch.stack([(1 - a) * (1 - b), (1 - a) * b, a * (1 - b), a * b], dim=1)
        return idx.to(self.table.device), w.to(self.table.device)

    def lookup(self, points) -> "torch.Tensor":
        """Interpolated ``f3D_g(p; I, t)`` for unit points (P, 3): (P, G_groups, N_t).

        Points are in the world-aligned frame; for a pose (R, t) pass ``R^T q``.
        """
        p = torch.as_tensor(points, device=self.table.device)
        if p.dim() != 2 or p.shape[1] != 3:
            raise InputError(f"look-up points must have shape (P, 3), got {tuple(p.shape)}")
        idx, w = self.corners(p)
        out = F.embedding_bag(idx, self.table, per_sample_weights=w.to(self.table.dtype), mode="sum")
        return out.view(-1, self.num_groups, self.num_translations)

    def ldf_3d(self, x, rotations) -> "torch.Tensor":
        """Interpolated decomposed 3D distance functions, (N_r, Q, G_groups, N_t).

        The same values as :func:`ldlloc.search.ldf.ldf_3d` (up to the interpolation error) in a
        look-up friendly layout; ``.permute(3, 0, 2, 1)`` gives its (N_t, N_r, G, Q) order.
        """
        x = torch.as_tensor(x, dtype=torch.float32, device=self.table.device)
        R = torch.as_tensor(np.asarray(rotations), dtype=torch.float32, device=self.table.device)
        if R.dim() != 3 or R.shape[1:] != (3, 3):
            raise InputError(f"rotations must have shape (N_r, 3, 3), got {tuple(R.shape)}")
        xr = torch.einsum("qi,rij->rqj", x, R).reshape(-1, 3)  # R^T q for every rotation
        return self.lookup(xr).view(R.shape[0], x.shape[0], self.num_groups, self.num_translations)


def inlier_loss_from_fields(f2d: "torch.Tensor", f3d: "torch.Tensor", tau: float = 0.1) -> "torch.Tensor":
    """Paper eq. 5 on look-up layout: f2d (N_r, G, Q), f3d (N_r, Q, G, N_t) -> (N_t, N_r) losses.

    Equal to ``ldf.pose_loss(f2d, f3d.permute(3, 0, 2, 1), "inlier", tau)`` but reduces over the
    contiguous layout of the look-up (no strided copy).
    """
    f3d = f3d.float()  # compare in float32, like the exact path (float16 differences round)
    f2d = f2d.to(device=f3d.device, dtype=f3d.dtype)
    if f2d.dim() == 2:  # one 2D grouping for all rotations
        f2d = f2d.unsqueeze(0)
    ref = f2d.transpose(1, 2).unsqueeze(-1)  # (N_r, Q, G, 1)
    inl = ((f3d - ref).abs_() < tau).flatten(1, 2)  # (N_r, Q*G, N_t)
    return -inl.sum(1, dtype=torch.int32).T.to(torch.float32)
