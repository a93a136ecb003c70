"""Geometric refinement: precise poses from lines alone (no features), for the top-K search poses.

A lines-only map (room layout, Line3D++ / 3DLineDetection lines) stops at the search's coarse pose,
the nearest candidate translation (0.1-0.5 m off). Following the idea of FGPL (Kim et al.,
CVPR 2024: align 2D and projected 3D lines of the same principal group on the sphere, then
re-score), each of the K poses is optimized continuously:

1. Points are sampled along every 2D arc (``samples`` per arc). Under the current pose an arc
   joins principal group ``g`` when its great circle passes through ``R p_g`` (the map's
   direction ``g`` seen in the camera); a 3D line keeps the map's group.
2. Association: each point takes the nearest projected 3D line of its group (among the lines seen
   from the pose's candidate translation), measured as ``|x . n_l|`` (the sine of the angle to
   the line's great circle, ``n_l ~ R ((P1 - t) x (P2 - t))``) and only where the point lies
   within the line's extent; points farther than the association angle stay unmatched.
3. Gauss-Newton on the point-to-great-circle residuals ``x . n_l`` with Huber weights
   (iteratively re-weighted), all K poses batched, over the 6 pose parameters (rotation vector
   applied in the world frame, and the camera centre), with exact Jacobians. The rotation is also
   held by the vanishing points: each grouped arc's great circle should pass through its group's
   direction (residual ``n . R p_g``, rotation only), and the first ``fixed_rotation_rounds``
   move the translation alone, the rotation from the search being already good to about a degree.
4. Steps 2-3 repeat while the association angle shrinks (``assoc_deg`` -> ``final_assoc_deg``).

A refinement that moves the pose by more than ``max_move_m`` or ``max_turn_deg`` (FGPL's 1 m and
60 deg), or that ends with fewer than ``min_points`` matched points, is rejected: that candidate
keeps its coarse pose, flagged. The caller scores the refined poses with the line distance
functions and keeps the best (:mod:`ldlloc.pipeline`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.errors import InputError


@dataclass(frozen=True)
class GeometricParams:
    """Parameters of :func:`refine_poses_geometric`."""

    max_poses: int = 10  # refine the best this many of the K search poses (the rest stay coarse;
    # on the real home 10 gave the accuracy of all 20 in two thirds of the time)
    samples: int = 5  # points per 2D arc
    rounds: int = 10  # association rounds
    steps: int = 2  # Gauss-Newton steps per round
    assoc_deg: float = 12.0  # association angle of the first round ...
    final_assoc_deg: float = 1.5  # ... shrinking to this one in the last round
    huber_deg: float = 0.5  # Huber threshold of the residuals
    group_tol: float = 0.05  # |n . R p_g| below this: the arc belongs to group g
    extent_margin_deg: float = 2.0  # a point may lie this far past a projected line's end
    min_points: int = 20  # fewer matched points: the refinement is rejected
    max_move_m: float = 1.0  # larger moves are divergence (FGPL)
    max_turn_deg: float = 60.0
    damping: float = 1e-3  # Levenberg-Marquardt damping, relative to the mean diagonal
    fixed_rotation_rounds: int = 5  # the first rounds refine the translation only: the rotation
    # from the vanishing points is good to ~1 deg, and joint steps from a pose 0.3 m off, with wide
    # associations, turned it by 5-20 deg on the real home (19 of 59 good starts ended within
    # 0.1 m / 3 deg; 31 with these two settings)
    vp_weight: float = 5.0  # weight of each arc's vanishing-point residual (``n . R p_g``), against 1
    # per matched point: parallel lines keep pointing at their vanishing points while the translation moves
    support_weight: float = 1.0  # the winner maximizes -loss / max|loss| + this x map-line support
    support_deg: float = 1.0  # a map line's point is supported within this angle of a query arc
    support_within: float = 0.25  # only poses whose loss is within this fraction of the best compete
    # on support (the others cannot win; symmetric twins on the real home were within 15 %)
    keep_within: float = 0.05  # the caller keeps a refined pose when its exact loss is at most this
    # fraction worse than its coarse pose's (the inlier loss, tau = 0.1 rad, cannot see a few cm:
    # a pose refined to 3 cm may count a few inliers less than the coarse one 11 cm off)


@dataclass
class GeometricResult:
    """Refined poses of the K candidates (the coarse pose where refinement was rejected)."""

    rotations: np.ndarray  # (K, 3, 3)
    centers: np.ndarray  # (K, 3)
    accepted: np.ndarray  # (K,) bool: refinement kept
    matched: np.ndarray  # (K,) matched 2D points in the last round
    residual_deg: np.ndarray  # (K,) median angle (deg) of the matched points to their lines


def _so3_exp(w):
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues)."""
    import torch

    theta = torch.linalg.vector_norm(w, dim=-1, keepdim=True).clamp_min(1e-12)
    k = w / theta
    K = torch.zeros(w.shape[:-1] + (3, 3), dtype=w.dtype, device=w.device)
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - K.transpose(-1, -2)
    s, c = torch.sin(theta)[..., None], torch.cos(theta)[..., None]
    eye = torch.eye(3, dtype=w.dtype, device=w.device)
    return eye + s * K + (1 - c) * (K @ K)


def _sample_arcs(arcs, samples: int):
    """(N * S, 3) unit points along the arcs and the (N * S,) arc index of each."""
    import torch

    f = (torch.arange(samples, dtype=arcs.dtype, device=arcs.device) + 0.5) / samples
    P = arcs[:, None, 0] * (1 - f)[None, :, None] + arcs[:, None, 1] * f[None, :, None]
    P = P / torch.linalg.vector_norm(P, dim=-1, keepdim=True).clamp_min(1e-12)
    idx = torch.arange(len(arcs), device=arcs.device).repeat_interleave(samples)
    return P.reshape(-1, 3), idx


def _line_geometry(R, t, L):
    """Camera-frame unit normals (K, L, 3) of the lines' great circles and their projected ends."""
    import torch

    a, b = L[None, :, 0] - t[:, None], L[None, :, 1] - t[:, None]  # (K, L, 3) world, from t
    m = torch.linalg.cross(a, b, dim=-1)
    n = torch.einsum("kij,klj->kli", R, m)
    n = n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp_min(1e-12)
    s = torch.einsum("kij,klj->kli", R, a)
    e = torch.einsum("kij,klj->kli", R, b)
    s = s / torch.linalg.vector_norm(s, dim=-1, keepdim=True).clamp_min(1e-12)
    e = e / torch.linalg.vector_norm(e, dim=-1, keepdim=True).clamp_min(1e-12)
    return n, s, e


def refine_poses_geometric(arcs: np.ndarray, rotations: np.ndarray, centers: np.ndarray, lines: np.ndarray,
                           line_groups: np.ndarray, principal: np.ndarray, visible: np.ndarray | None = None,
                           params: GeometricParams = GeometricParams()) -> GeometricResult:
    """Refine K poses (world -> camera ``rotations`` (K, 3, 3), camera ``centers`` (K, 3)) against
    the map's lines (L, 2, 3) with their principal groups (L,) and the map's principal directions
    (3, 3), from the query's 2D arcs (N, 2, 3; camera frame). ``visible`` (K, L) bool: the lines
    seen from each pose's candidate translation (None: all). See the module docstring.
    """
    import torch

    A = np.asarray(arcs, dtype=np.float64)
    if A.ndim != 3 or A.shape[1:] != (2, 3) or not np.isfinite(A).all():
        raise InputError(f"arcs must be finite with shape (N, 2, 3), got {A.shape}")
    R0 = torch.as_tensor(np.asarray(rotations, dtype=np.float64)).reshape(-1, 3, 3)
    t0 = torch.as_tensor(np.asarray(centers, dtype=np.float64)).reshape(-1, 3)
    K = len(R0)
    dt = torch.float64
    grp = np.asarray(line_groups, dtype=np.int64)
    keep_l = grp >= 0
    L = torch.as_tensor(np.asarray(lines, dtype=np.float64)[keep_l])
    G3 = torch.as_tensor(grp[keep_l])
    if visible is not None:  # only lines seen from at least one of the poses take part
        keep_l &= np.asarray(visible, dtype=bool).any(0)
        L = torch.as_tensor(np.asarray(lines, dtype=np.float64)[keep_l])
        G3 = torch.as_tensor(grp[keep_l])
    vis = torch.ones((K, int(keep_l.sum())), dtype=torch.bool) if visible is None else \
        torch.as_tensor(np.asarray(visible, dtype=bool)[:, keep_l])
    P3 = torch.as_tensor(np.asarray(principal, dtype=np.float64))
    arcs_t = torch.as_tensor(A, dtype=dt)
    X, arc_of = _sample_arcs(arcs_t, max(1, int(params.samples)))
    n2 = torch.linalg.cross(arcs_t[:, 0], arcs_t[:, 1], dim=-1)
    n2 = n2 / torch.linalg.vector_norm(n2, dim=-1, keepdim=True).clamp_min(1e-12)
    margin = np.sin(np.radians(params.extent_margin_deg))
    huber = np.sin(np.radians(params.huber_deg))
    R, t = R0.clone(), t0.clone()
    match = torch.full((K, len(X)), -1, dtype=torch.long)
    rounds = max(1, int(params.rounds))
    for k in range(rounds):
        thr = np.sin(np.radians(params.assoc_deg + (params.final_assoc_deg - params.assoc_deg) * k / max(rounds - 1, 1)))
        match, arc_group = _associate(R, t, X, arc_of, n2, L, G3, vis, P3, params.group_tol, margin, thr)
        vp = (n2, P3, arc_group, params.vp_weight) if params.vp_weight > 0 else None
        for _ in range(max(1, int(params.steps))):
            R, t = _gauss_newton_step(R, t, X, L, match, max(huber, thr / 3), params.damping,
                                      fix_rotation=k < params.fixed_rotation_rounds, vp=vp)
    r = _residuals_and_jacobian(R, t, X, L, match)[0].abs().masked_fill_(match < 0, float("nan"))
    matched = (match >= 0).sum(1)
    med = torch.nan_to_num(torch.nanmedian(r, dim=1).values, nan=1.0)  # sine; 1 (90 deg) when none matched
    move = torch.linalg.vector_norm(t - t0, dim=-1)
    turn = torch.rad2deg(torch.arccos(((torch.einsum("kij,kij->k", R, R0) - 1) / 2).clamp(-1, 1)))
    ok = (move <= params.max_move_m) & (turn <= params.max_turn_deg) & (matched >= params.min_points) \
        & torch.isfinite(t).all(-1) & torch.isfinite(R).all((-1, -2))
    R = torch.where(ok[:, None, None], R, R0)
    t = torch.where(ok[:, None], t, t0)
    return GeometricResult(R.numpy(), t.numpy(), ok.numpy(), matched.numpy(),
                           np.degrees(np.arcsin(med.clamp(max=1.0).numpy())))


def _associate(R, t, X, arc_of, n2, L, G3, vis, P3, group_tol, margin, thr):
    """(K, X) index of the line matched to each point (-1: none), see the module docstring.

    Per pose and principal group, the points of that group meet only the lines of that group
    (a third of the pairs): one float32 matmul for the four dot products of each point with each
    line (distance to its circle, the two extent planes, the near side)."""
    import torch

    f = torch.float32
    # Group of each arc under each pose: the principal direction its great circle passes through.
    d = torch.einsum("kij,gj->kgi", R, P3)  # (K, 3, 3) R p_g
    c = torch.einsum("ni,kgi->kng", n2, d).abs()  # (K, N, 3)
    cmin, g2 = c.min(-1)
    g2 = torch.where(cmin < group_tol, g2, torch.full_like(g2, -1))
    gx = torch.gather(g2, 1, arc_of[None].expand(len(R), -1))  # (K, X)
    n, s, e = _line_geometry(R, t, L)  # (K, L, 3)
    V = torch.stack([n, torch.linalg.cross(n, s, dim=-1), torch.linalg.cross(e, n, dim=-1), s + e], 2).to(f)  # (K, L, 4, 3)
    Xf = X.to(f)
    match = torch.full(gx.shape, -1, dtype=torch.long)
    for g in range(3):
        lines_g = torch.nonzero(G3 == g).reshape(-1)
        if len(lines_g) == 0:
            continue
        for k in range(len(R)):  # K x 3 blocks: the points of group g under pose k
            pts = torch.nonzero(gx[k] == g).reshape(-1)
            if len(pts) == 0:
                continue
            lk = lines_g[vis[k, lines_g]]
            if len(lk) == 0:
                continue
            dots = torch.matmul(V[k, lk].reshape(-1, 3), Xf[pts].T).reshape(len(lk), 4, len(pts))
            ok = (dots[:, 1] > -margin) & (dots[:, 2] > -margin) & (dots[:, 3] > 0)
            dist = dots[:, 0].abs().masked_fill_(~ok, 2.0)
            best, idx = dist.min(0)
            match[k, pts] = torch.where(best < thr, lk[idx], torch.full_like(idx, -1))
    return match, g2


def _residuals_and_jacobian(R, t, X, L, match):
    """Residuals ``x . n_l`` (K, X) and their exact derivatives (K, X, 6) by the update of
    :func:`_apply`: with ``y = R^T x`` and ``m = (P1 - t) x (P2 - t)``, ``r = y . m / |m|``,
    ``dr/dw = -(y x m_hat)`` and ``dr/dt = ((y - r m_hat) x (P2 - P1)) / |m|``. Unmatched: 0."""
    import torch

    j = match.clamp_min(0)
    P1, P2 = L[j, 0], L[j, 1]  # (K, X, 3) ends of each point's line
    tt = t[:, None, :]
    m = torch.linalg.cross(P1 - tt, P2 - tt, dim=-1)
    norm = torch.linalg.vector_norm(m, dim=-1, keepdim=True).clamp_min(1e-12)
    mh = m / norm
    y = torch.einsum("kji,xj->kxi", R, X)  # R^T x
    r = (y * mh).sum(-1)
    d_w = -torch.linalg.cross(y, mh, dim=-1)
    d_t = torch.linalg.cross(y - r[..., None] * mh, P2 - P1, dim=-1) / norm
    valid = (match >= 0)
    J = torch.cat([d_w, d_t], -1) * valid[..., None]
    return torch.where(valid, r, torch.zeros_like(r)), J


def _vp_residuals(R, n2, P3, arc_group):
    """Residuals ``n . R p_g`` (K, N) of each arc's great circle to its group's vanishing point and
    their derivatives (K, N, 3) by the rotation update: ``d/dw = p_g x (R^T n)``. No group: 0."""
    import torch

    g = arc_group.clamp_min(0)
    p = P3[g]  # (K, N, 3)
    m = torch.einsum("kji,nj->kni", R, n2)  # R^T n
    r = (m * p).sum(-1)
    J = torch.linalg.cross(p, m, dim=-1)
    valid = arc_group >= 0
    return torch.where(valid, r, torch.zeros_like(r)), J * valid[..., None]


def _huber_weights(r, huber):
    """Iteratively re-weighted least squares weights of residuals ``r`` for a Huber threshold."""
    import torch

    a = r.abs()
    return torch.where(a < huber, torch.ones_like(a), huber / a.clamp_min(1e-12))


def _gauss_newton_step(R, t, X, L, match, huber, damping, fix_rotation=False, vp=None):
    """One damped, Huber-weighted Gauss-Newton step for all K poses; ``fix_rotation``: the
    translation only; ``vp``: ``(n2, P3, arc_group, weight)`` adds the vanishing-point residuals."""
    import torch

    r0, J = _residuals_and_jacobian(R, t, X, L, match)  # (K, X), (K, X, 6)
    w = _huber_weights(r0, huber) * (match >= 0)
    H = torch.einsum("kxi,kx,kxj->kij", J, w, J)
    b = -torch.einsum("kxi,kx,kx->ki", J, w, r0)
    if vp is not None and not fix_rotation:
        n2, P3, arc_group, weight = vp
        rv, Jv = _vp_residuals(R, n2, P3, arc_group)
        wv = weight * _huber_weights(rv, huber) * (arc_group >= 0)
        H[:, :3, :3] += torch.einsum("kni,kn,knj->kij", Jv, wv, Jv)
        b[:, :3] -= torch.einsum("kni,kn,kn->ki", Jv, wv, rv)
    free = slice(3, 6) if fix_rotation else slice(0, 6)  # the parameters this step moves
    Hf = H[:, free, free]
    lam = damping * torch.diagonal(Hf, dim1=-2, dim2=-1).mean(-1, keepdim=True).clamp_min(1e-12) + 1e-9
    step = torch.zeros_like(b)
    step[:, free] = torch.nan_to_num(torch.linalg.solve(Hf + torch.diag_embed(lam.expand(-1, Hf.shape[-1])),
                                                        b[:, free, None])[..., 0])
    return _apply(R, t, step)


def _apply(R, t, v):
    """Pose after the update ``v`` (K, 6): ``R Exp(w)`` (w in the world frame) and ``t + dt``."""
    return R @ _so3_exp(v[:, :3]), t + v[:, 3:]


def map_line_support(arcs: np.ndarray, rotations: np.ndarray, centers: np.ndarray, lines: np.ndarray,
                     line_groups: np.ndarray, visible: np.ndarray | None = None, tol_deg: float = 1.0,
                     samples: int = 24, band_deg: float = 70.0) -> np.ndarray:
    """Share (K,) of what each pose's map predicts that the image shows: of the points along the
    map's grouped lines (seen from the pose: ``visible`` (K, L), None: all) that project within
    ``band_deg`` of the horizon (the detector's cap hides the poles), those within ``tol_deg`` of a
    query arc's great circle and extent. The inlier loss counts the query's lines that the map
    explains; this counts the map's lines that the query confirms, so a symmetric twin that puts a
    door or window frame where the image shows a plain wall loses support. One float32 matmul per
    pose (the four dot products of the points with each arc's normal, end planes and middle)."""
    import torch

    A = np.asarray(arcs, dtype=np.float64)
    if len(A) == 0:
        return np.zeros(len(rotations))
    s, e = A[:, 0], A[:, 1]
    n = np.cross(s, e)
    n /= np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)
    V = torch.as_tensor(np.concatenate([n, np.cross(n, s), np.cross(e, n), s + e], 0).T, dtype=torch.float32)  # (3, 4N)
    N = len(A)
    tol = np.sin(np.radians(tol_deg))
    L_all = np.asarray(lines, dtype=np.float64)
    grouped = np.asarray(line_groups) >= 0
    f = (np.arange(samples) + 0.5) / samples
    sin_band = np.sin(np.radians(band_deg))
    out = np.zeros(len(rotations))
    for k in range(len(rotations)):
        L = L_all[grouped if visible is None else grouped & np.asarray(visible[k], dtype=bool)]
        if len(L) == 0:
            continue
        P = (L[:, None, 0] + f[None, :, None] * (L[:, None, 1] - L[:, None, 0])).reshape(-1, 3)
        d = (P - centers[k]) @ np.asarray(rotations[k]).T
        d /= np.linalg.norm(d, axis=1, keepdims=True).clip(1e-12)
        d = d[np.abs(d[:, 2]) < sin_band]
        if len(d) == 0:
            continue
        D = torch.as_tensor(d, dtype=torch.float32) @ V  # (P, 4N)
        near = (D[:, :N].abs() < tol) & (D[:, N:2 * N] > -tol) & (D[:, 2 * N:3 * N] > -tol) & (D[:, 3 * N:] > 0)
        out[k] = float(near.any(1).float().mean())
    return out
