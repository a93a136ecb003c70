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
3. Gauss-Newton on the point-to-great-circle residuals ``x . n_l`` with Huber weights (or
   another kernel per pose, :data:`KERNELS`; iteratively re-weighted), all K poses batched, over
   the 6 pose parameters (rotation vector applied in the world frame, and the camera centre), with
   exact Jacobians. A point's Jacobian is
   linear in the point (``D_l x``), so the normal equations sum over lines, not points
   (``D_l S_l D_l^T`` with ``S_l`` the weighted scatter of the line's points). The rotation is also
   held by the vanishing points: each grouped arc's great circle should pass through its group's
   direction (residual ``n . R p_g``, rotation only), and the first ``fixed_rotation_rounds``
   move the translation alone, the rotation from the search being already good to about a degree.
4. Steps 2-3 repeat while the association angle shrinks (``assoc_deg`` -> ``final_assoc_deg``).
   Poses that meet a better-ranked one (``merge_m``, ``merge_deg``) go on as one. Each pose works
   on the lines seen from its candidate translation; all in float32 about the poses' mean centre.

A refinement that moves the pose by more than ``max_move_m`` or ``max_turn_deg`` (FGPL's 1 m and
60 deg), or that ends with fewer than ``min_points`` matched points, is rejected: that candidate
keeps its coarse pose, flagged. :func:`refine_and_keep` (the refinement stage on a map) then scores
the refined poses with the search's exact loss and keeps a refined pose only where that loss is
within ``keep_within`` of its start's; :mod:`ldlloc.pipeline` picks the winner. Which poses are
refined, and how (:func:`refinement_plan`): the best with Huber weights, the best few again from a
wider first association and again with Geman-McClure weights, all competing. Clutter (95 % of a
furnished room's lines, against a layout map) slides Huber's pose along the creases it hides;
Geman-McClure's lets it go near the truth but pulls less from far.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.map.translations import candidate_spacing
from ldlloc.rotation import ARC_GROUP_TOL
from ldlloc.search.pose_search import SearchParams, score_on_map

torch = lazy_module("torch")
spatial = lazy_module("scipy.spatial")

KERNELS = ("huber", "geman", "mixture")  # GeometricParams.kernel


@dataclass(frozen=True)
class GeometricParams:
    """Parameters of :func:`refine_poses_geometric`."""

    max_poses: int = 20
    """Refine the best this many search poses, the rest stay coarse (docs/measurements.md#geometric-max-poses)."""
    samples: int = 3
    """Points per 2D arc (more cost time, no accuracy: docs/measurements.md#geometric-samples)."""
    rounds: int = 10
    """Association rounds."""
    steps: int = 2
    """Gauss-Newton steps per round."""
    assoc_deg: float = 12.0
    """Association angle of the first round."""
    final_assoc_deg: float = 1.5
    """Association angle of the last round (the angle shrinks from assoc_deg to this)."""
    wide_poses: int = 5
    """The best this many poses are refined a second time from wide_assoc_deg; both results compete."""
    wide_assoc_deg: float = 20.0
    """First association angle of the second refinement (docs/measurements.md#geometric-wide-assoc)."""
    second_kernel: str = "geman"
    """Weights of the third refinement (:data:`KERNELS`; from assoc_deg, see second_kernel_poses)."""
    second_kernel_poses: int = 5
    """The best this many poses are refined once more with second_kernel's weights, which let clutter
    go near the truth where Huber's slide along it; all results compete
    (docs/benchmarks.md#furnished-rooms-layout-only-maps)."""
    huber_deg: float = 0.5
    """Huber threshold of the residuals."""
    group_tol: float = ARC_GROUP_TOL
    """|n . R p_g| below this: the arc belongs to group g."""
    extent_margin_deg: float = 2.0
    """A point may lie this far past a projected line's end."""
    min_points: int = 20
    """Fewer matched points: the refinement is rejected."""
    max_move_m: float = 1.0
    """A larger move is divergence (FGPL's bound): rejected."""
    max_turn_deg: float = 60.0
    """A larger turn is divergence (FGPL's bound): rejected."""
    damping: float = 1e-3
    """Levenberg-Marquardt damping, relative to the mean diagonal."""
    fixed_rotation_rounds: int = 5
    """The first rounds move the translation only (docs/measurements.md#geometric-fixed-rotation)."""
    vp_weight: float = 5.0
    """Weight of each arc's vanishing-point residual ``n . R p_g`` (1 per matched point)."""
    support_weight: float = 1.0
    """The winner maximizes -loss / max|loss| + this x map-line support."""
    support_deg: float = 1.0
    """A map line's point is supported within this angle of a query arc."""
    support_within: float = 0.25
    """Only poses whose loss is within this fraction of the best compete on support."""
    merge_m: float = 0.01
    """Poses this near (and merge_deg) a better-ranked one share its refinement from then on (0: never)."""
    merge_deg: float = 0.2
    """The angle of merge_m's rule (docs/measurements.md#geometric-merge)."""
    height_margin_m: float = 0.0
    """With a known camera-height band, each step keeps the camera within this of it."""
    keep_within: float = 0.15
    """A refined pose is kept when its exact loss is at most this fraction worse than its start's."""
    kernel: str = "huber"
    """Weights of the matched points (:data:`KERNELS`): huber, geman (Geman-McClure) or mixture
    (an outlier process: a Gaussian inlier and a uniform outlier, fitted per pose and step;
    docs/benchmarks.md#furnished-rooms-layout-only-maps)."""
    length_power: float = 0.0
    """Each point is weighted by its arc's length (over the mean) to this power (0: all arcs alike)."""


@dataclass
class GeometricResult:
    """Refined poses of the K candidates (the coarse pose where refinement was rejected)."""

    rotations: np.ndarray  # (K, 3, 3)
    centers: np.ndarray  # (K, 3)
    accepted: np.ndarray  # (K,) bool: refinement kept
    matched: np.ndarray  # (K,) matched 2D points in the last round
    residual_deg: np.ndarray  # (K,) median angle (deg) of the matched points to their lines
    fit: np.ndarray  # (K,) the matched points counted by how near their lines they lie: each
    # 1 - (angle / final association angle)^2 (a pose that matches many points loosely is not the better one)


def _so3_exp(w):
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues)."""
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
    f = (torch.arange(samples, dtype=arcs.dtype, device=arcs.device) + 0.5) / samples
    P = arcs[:, None, 0] * (1 - f)[None, :, None] + arcs[:, None, 1] * f[None, :, None]
    P = P / torch.linalg.vector_norm(P, dim=-1, keepdim=True).clamp_min(1e-12)
    idx = torch.arange(len(arcs), device=arcs.device).repeat_interleave(samples)
    return P.reshape(-1, 3), idx


def _line_geometry(R, t, L):
    """Camera-frame unit normals (K, L, 3) of the great circles of the poses' lines (K, L, 2, 3) and
    their projected ends."""
    a, b = L[:, :, 0] - t[:, None], L[:, :, 1] - t[:, None]  # (K, L, 3) world, from t
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
                           params: GeometricParams = GeometricParams(),
                           height_band: tuple[float, float] | None = None,
                           assoc_deg: np.ndarray | None = None, kernels=None) -> GeometricResult:
    """Refine K poses (world -> camera ``rotations`` (K, 3, 3), camera ``centers`` (K, 3)) against
    the map's lines (L, 2, 3) with their principal groups (L,) and the map's principal directions
    (3, 3), from the query's 2D arcs (N, 2, 3; camera frame). ``visible`` (K, L) bool: the lines
    seen from each pose's candidate translation (None: all). ``height_band``: (min, max) world z of
    the camera when known (:attr:`ldlmap.map.contents.LdlMap.camera_height_band`); every step keeps the
    centres within ``params.height_margin_m`` of it. ``assoc_deg`` (K,): each pose's first-round
    association angle (None: ``params.assoc_deg`` for all). ``kernels`` (K,): each pose's weights
    (:data:`KERNELS` names; None: ``params.kernel`` for all). See the module docstring.
    """
    A = np.asarray(arcs, dtype=np.float64)
    if A.ndim != 3 or A.shape[1:] != (2, 3) or not np.isfinite(A).all():
        raise InputError(f"arcs must be finite with shape (N, 2, 3), got {A.shape}")
    # float32 throughout (faster than float64: docs/measurements.md#geometric-float32), about an origin
    # at the poses' mean centre so that maps in large coordinates (UTM) keep their precision.
    dt = torch.float32
    C0 = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    origin = C0.mean(0)
    R0 = torch.as_tensor(np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3), dtype=dt)
    t0 = torch.as_tensor(C0 - origin, dtype=dt)
    K = len(R0)
    kernel = pose_kernels(kernels, params.kernel, K)  # (K,) index into KERNELS
    # Each pose works on its own list of the grouped lines it sees (padded to the longest list; the
    # padding has group -1 and is never matched): (K, Lk, 2, 3) lines and (K, Lk) groups.
    grp = np.asarray(line_groups, dtype=np.int64)
    seen = np.tile(grp >= 0, (K, 1)) if visible is None else np.asarray(visible, dtype=bool) & (grp >= 0)
    slots, real = _padded_members(torch.as_tensor(seen))
    L = torch.as_tensor(np.asarray(lines, dtype=np.float64) - origin, dtype=dt)[slots]
    G3 = torch.where(real, torch.as_tensor(grp)[slots], torch.full_like(slots, -1))
    P3 = torch.as_tensor(np.asarray(principal, dtype=np.float64), dtype=dt)
    arcs_t = torch.as_tensor(A, dtype=dt)
    X, arc_of = _sample_arcs(arcs_t, max(1, int(params.samples)))
    XX = (X[:, :, None] * X[:, None, :]).reshape(-1, 9)
    point_w = _length_weights(arcs_t, params.length_power)[arc_of]
    n2 = torch.linalg.cross(arcs_t[:, 0], arcs_t[:, 1], dim=-1)
    n2 = n2 / torch.linalg.vector_norm(n2, dim=-1, keepdim=True).clamp_min(1e-12)
    margin = np.sin(np.radians(params.extent_margin_deg))
    huber = np.sin(np.radians(params.huber_deg))
    R, t = R0.clone(), t0.clone()
    z_lo = z_hi = None
    if height_band is not None:
        lo, hi = sorted(float(z) for z in height_band)
        z_lo, z_hi = lo - origin[2] - params.height_margin_m, hi - origin[2] + params.height_margin_m
    assoc0 = torch.as_tensor(np.full(K, params.assoc_deg) if assoc_deg is None else np.asarray(assoc_deg, float).reshape(K),
                             dtype=dt)  # each pose's first-round association angle (deg)
    rep = torch.arange(K)  # the pose whose refinement each pose shares (itself, or a better-ranked twin)
    active = torch.arange(K)  # the poses still refined, in rank order
    rounds = max(1, int(params.rounds))
    for k in range(rounds):
        if k > 0 and params.merge_m > 0:  # poses that met a better-ranked one follow it from here on
            keep_a, twin = _merge_twins(R, t, params.merge_m, params.merge_deg, kernel[active])
            rep[active] = active[twin]
            active, R, t, L, G3 = active[keep_a], R[keep_a], t[keep_a], L[keep_a], G3[keep_a]
        a = assoc0[active]
        thr = torch.sin(torch.deg2rad(a + (params.final_assoc_deg - a) * k / max(rounds - 1, 1)))  # (A,)
        match, arc_group = _associate(R, t, X, arc_of, n2, L, G3, P3, params.group_tol, margin, thr)
        vp = (n2, P3, arc_group, params.vp_weight) if params.vp_weight > 0 else None
        for _ in range(max(1, int(params.steps))):
            robust = (kernel[active], (thr / 3).clamp_min(huber)[:, None], thr[:, None], huber, point_w)
            R, t = _gauss_newton_step(R, t, X, XX, L, match, robust, params.damping,
                                      fix_rotation=k < params.fixed_rotation_rounds, vp=vp)
            if z_lo is not None:
                t[:, 2].clamp_(z_lo, z_hi)
    r = _point_residuals(_line_operators(R, t, L)[0], X, match).abs().masked_fill_(match < 0, float("nan"))
    for _ in range(K):  # follow merges to the pose that was refined to the end
        rep = rep[rep]
    slot = torch.full((K,), -1, dtype=torch.long)
    slot[active] = torch.arange(len(active))
    at = slot[rep]  # (K,) each pose's row among the active ones
    R, t, match, r = R[at], t[at], match[at], r[at]
    matched = (match >= 0).sum(1)
    med_deg, fit = residual_stats(r, params.final_assoc_deg)
    move = torch.linalg.vector_norm(t - t0, dim=-1)
    turn = torch.rad2deg(torch.arccos(((torch.einsum("kij,kij->k", R, R0) - 1) / 2).clamp(-1, 1)))
    ok = (move <= params.max_move_m) & (turn <= params.max_turn_deg) & (matched >= params.min_points) \
        & torch.isfinite(t).all(-1) & torch.isfinite(R).all((-1, -2))
    keep = ok.numpy()
    U, _, Vt = np.linalg.svd(R.double().numpy())  # the nearest rotations (float32 steps drift ~1e-7)
    rots = np.where(keep[:, None, None], U @ Vt, np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3))
    cens = np.where(keep[:, None], t.double().numpy() + origin, C0)
    return GeometricResult(rots, cens, keep, matched.numpy(), med_deg, fit)


def residual_stats(r, final_assoc_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """From the matched points' residual sines ``r`` (K, X; NaN: unmatched): each pose's median residual in
    degrees (90 when none matched) and its fit, the points counted by how near their lines they lie (each
    1 - (residual / final association angle)^2: :attr:`GeometricResult.fit`)."""
    med = torch.nan_to_num(torch.nanmedian(r, dim=1).values, nan=1.0).clamp(max=1.0)
    final = float(np.sin(np.radians(final_assoc_deg)))
    fit = (1.0 - (r / final) ** 2).clamp_min(0.0).nan_to_num(0.0).sum(1)
    return np.degrees(np.arcsin(med.double().numpy())), fit.double().numpy()


def pose_kernels(kernels, default: str, K: int):
    """(K,) index into :data:`KERNELS` of each pose's weights (``kernels``: K names, None: ``default``
    for all); an unknown name is refused."""
    names = [default] * K if kernels is None else [str(k) for k in np.asarray(kernels).reshape(-1)]
    unknown = sorted(set(names) - set(KERNELS))
    if unknown or len(names) != K:
        raise InputError(f"unknown refinement kernel {unknown[0]!r} (one of {', '.join(KERNELS)})" if unknown
                         else f"{len(names)} refinement kernels for {K} poses")
    return torch.as_tensor([KERNELS.index(k) for k in names], dtype=torch.long)


def _merge_twins(R, t, merge_m: float, merge_deg: float, kernel):
    """Which of the (rank-ordered) poses to keep refining (A,) bool, and for each pose the first one
    within ``merge_m`` and ``merge_deg`` of it with the same weights (``kernel`` (A,)) (itself when
    none is earlier): poses that have met go on as one."""
    near = (torch.cdist(t, t) < merge_m) & (kernel[:, None] == kernel[None, :])
    cos = (torch.einsum("aij,bij->ab", R, R) - 1) / 2
    near &= cos > np.cos(np.radians(merge_deg))
    first = torch.argmax(near.to(torch.uint8), dim=1)  # the diagonal is True: first <= own index
    return first == torch.arange(len(R)), first


def _padded_members(member):
    """Indices (B, M) of the True entries of each row of ``member`` (B, N), padded to the largest
    row count M, and which of them are real (B, M)."""
    count = member.sum(1)
    order = torch.sort((~member).to(torch.uint8), dim=1, stable=True).indices[:, :max(int(count.max()), 1)]
    return order, torch.arange(order.shape[1], device=member.device)[None] < count[:, None]


def _associate(R, t, X, arc_of, n2, L, G3, P3, group_tol, margin, thr):
    """(K, X) index of the line matched to each point (-1: none) among the pose's lines ``L``
    (K, Lk, 2, 3) with groups ``G3`` (K, Lk), see the module docstring, and (K, N) the principal
    group of each arc under each pose (-1: none).

    The points of group ``g`` under pose ``k`` meet only the pose's lines of group ``g``: the
    K x 3 (pose, group) blocks are padded to common sizes and batched, one float32 matmul for the
    three dot products of each point with each line: the distance to its circle and the two
    extent planes through the circle's axis and each end (``(n x s) . x`` and ``(e x n) . x``,
    shifted by the margin; an arc is shorter than 180 deg, so the two planes bound one lune). The
    points carry a homogeneous 1 so the margin, and a large negative value for the padding lines,
    enter as the planes' offsets."""
    f = torch.float32
    K, nx, ng = len(R), len(X), len(P3)
    # Group of each arc under each pose: the principal direction its great circle passes through.
    d = torch.einsum("kij,gj->kgi", R, P3)  # (K, G, 3) R p_g
    c = torch.einsum("ni,kgi->kng", n2, d).abs()  # (K, N, G)
    cmin, g2 = c.min(-1)
    g2 = torch.where(cmin < group_tol, g2, torch.full_like(g2, -1))
    gx = torch.gather(g2, 1, arc_of[None].expand(K, -1))  # (K, X)
    groups = torch.arange(ng, device=X.device)
    pts, pts_ok = _padded_members((gx[:, None, :] == groups[None, :, None]).reshape(K * ng, nx))  # (GK, P)
    lns, lns_ok = _padded_members((G3[:, None, :] == groups[None, :, None]).reshape(K * ng, -1))
    n, s, e = _line_geometry(R, t, L)  # (K, L, 3)
    V = torch.stack([n, torch.linalg.cross(n, s, dim=-1), torch.linalg.cross(e, n, dim=-1)], 2).to(f)  # (K, L, 3, 3)
    pose = torch.arange(K, device=X.device).repeat_interleave(ng)[:, None]  # (GK, 1)
    Vb = V[pose, lns]  # (3K, Lb, 3, 3)
    offset = torch.where(lns_ok, float(margin), -10.0).to(f)  # (3K, Lb): padding lines fail the extent
    Vb = torch.cat([Vb, torch.stack([torch.zeros_like(offset), offset, offset], -1)[..., None]], -1)  # (3K, Lb, 3, 4)
    Xh = torch.cat([X.to(f), torch.ones((nx, 1), dtype=f, device=X.device)], 1)[pts]  # (3K, P, 4)
    dots = torch.matmul(Vb.reshape(K * ng, -1, 4), Xh.transpose(1, 2)).reshape(K * ng, lns.shape[1], 3, -1)
    inside = torch.minimum(dots[:, :, 1], dots[:, :, 2]) > 0
    best, idx = torch.where(inside, dots[:, :, 0].abs(), 2.0).min(1)  # (3K, P)
    line = torch.where(best < thr.repeat_interleave(ng)[:, None], torch.gather(lns, 1, idx), torch.full_like(idx, -1))
    match = torch.full((K, nx + 1), -1, dtype=torch.long, device=X.device)  # column nx: the padding
    match[pose.expand_as(pts), torch.where(pts_ok, pts, torch.full_like(pts, nx))] = line
    return match[:, :nx], g2


def _skew(v):
    """Cross-product matrices (..., 3, 3) of vectors (..., 3): ``_skew(a) @ b == a x b``."""
    z = torch.zeros_like(v[..., 0])
    return torch.stack([z, -v[..., 2], v[..., 1], v[..., 2], z, -v[..., 0], -v[..., 1], v[..., 0], z],
                       -1).reshape(v.shape + (3,))


def _line_operators(R, t, L):
    """Per pose and line (``L``: (K, L, 2, 3), each pose's lines): the camera-frame unit normal ``n`` (K, L, 3) of the plane through the
    camera centre and the line, and ``D`` (K, L, 6, 3) such that a point ``x`` on the sphere has
    the residual ``r = n . x`` and the exact derivatives ``D x`` by the update of :func:`_apply`.

    With ``y = R^T x``, ``m = (P1 - t) x (P2 - t)``, ``m^ = m / |m|`` and ``d = (P2 - P1) / |m|``:
    ``r = y . m^``, ``dr/dw = m^ x y`` and ``dr/dt = (y - r m^) x d``; both are linear in ``x``, so
    the points matched to one line share one 3 x 6 operator and the normal equations sum over
    lines (:func:`_gauss_newton_step`) instead of over points."""
    a, b = L[:, :, 0] - t[:, None], L[:, :, 1] - t[:, None]  # (K, L, 3) world, from t
    m = torch.linalg.cross(a, b, dim=-1)
    norm = torch.linalg.vector_norm(m, dim=-1, keepdim=True).clamp_min(1e-12)
    mh, d = m / norm, (b - a) / norm
    Rt = R.transpose(-1, -2)[:, None]  # (K, 1, 3, 3)
    d_w = _skew(mh) @ Rt
    d_t = -(_skew(d) + torch.linalg.cross(mh, d, dim=-1)[..., None] * mh[..., None, :]) @ Rt
    n = torch.einsum("kij,klj->kli", R, mh)
    return n, torch.cat([d_w, d_t], -2)


def _point_residuals(n, X, match):
    """Residuals ``x . n_l`` (K, X) of the points to their matched lines' great circles (0: unmatched)."""
    j = match.clamp_min(0)
    r = (torch.gather(n, 1, j[..., None].expand(-1, -1, 3)) * X).sum(-1)
    return torch.where(match >= 0, r, torch.zeros_like(r))


def _vp_residuals(R, n2, P3, arc_group):
    """Residuals ``n . R p_g`` (K, N) of each arc's great circle to its group's vanishing point and
    their derivatives (K, N, 3) by the rotation update: ``d/dw = p_g x (R^T n)``. No group: 0."""
    g = arc_group.clamp_min(0)
    p = P3[g]  # (K, N, 3)
    m = torch.einsum("kji,nj->kni", R, n2)  # R^T n
    r = (m * p).sum(-1)
    J = torch.linalg.cross(p, m, dim=-1)
    valid = arc_group >= 0
    return torch.where(valid, r, torch.zeros_like(r)), J * valid[..., None]


def _huber_weights(r, huber):
    """Iteratively re-weighted least squares weights of residuals ``r`` for a Huber threshold."""
    a = r.abs()
    return torch.where(a < huber, torch.ones_like(a), huber / a.clamp_min(1e-12))


def mixture_weights(r, valid, scale, thr, floor, iters: int = 5):
    """Inlier probabilities (K, X) of the residuals ``r`` of the ``valid`` points under a zero-mean
    Gaussian inlier (sigma from ``scale``, at least ``floor``) and a uniform outlier on
    ``[-thr, thr]`` (the association window), sigma and the inlier share fitted by EM per pose: a
    point far from its line in a pose whose other points fit tightly counts for little (clutter),
    while a start far off, whose points all lie far, keeps a wide sigma and the pull of them all."""
    v = valid.to(r.dtype)
    sig, share = scale.clone(), torch.full_like(scale, 0.5)
    w = v
    for _ in range(iters):
        g = share * torch.exp(-0.5 * (r / sig) ** 2) / (sig * np.sqrt(2 * np.pi))
        w = g / (g + (1 - share) / (2 * thr)) * v
        n = w.sum(1, keepdim=True).clamp_min(1e-6)
        sig = torch.minimum(((w * r ** 2).sum(1, keepdim=True) / n).sqrt().clamp_min(floor), thr)
        share = (n / v.sum(1, keepdim=True).clamp_min(1)).clamp(0.01, 0.99)
    return w


def _robust_weights(r, valid, kernel, scale, thr, floor):
    """Weights (K, X) of the matched (``valid``) points' residuals ``r`` by each pose's kernel
    (``kernel`` (K,): index into :data:`KERNELS`): ``scale`` (K, 1) the kernel's scale, ``thr`` (K, 1)
    the association window, ``floor`` the least sigma."""
    w = torch.zeros_like(r)
    for code in torch.unique(kernel).tolist():
        rows = kernel == code
        r_k, v_k, s_k = r[rows], valid[rows], scale[rows]
        if KERNELS[code] == "mixture":
            w[rows] = mixture_weights(r_k, v_k, s_k, thr[rows], floor)
        elif KERNELS[code] == "geman":
            w[rows] = v_k / (1 + (r_k / s_k) ** 2) ** 2
        else:
            w[rows] = _huber_weights(r_k, s_k) * v_k
    return w


def _length_weights(arcs, power: float):
    """(N,) weight of each arc: its length over the mean length, to ``power`` (0: ones)."""
    if power == 0:
        return torch.ones(len(arcs), dtype=arcs.dtype, device=arcs.device)
    length = torch.arccos((arcs[:, 0] * arcs[:, 1]).sum(-1).clamp(-1, 1))
    return (length / length.mean().clamp_min(1e-12)) ** power


def _gauss_newton_step(R, t, X, XX, L, match, robust, damping, fix_rotation=False, vp=None):
    """One damped, robustly weighted Gauss-Newton step for all K poses; ``XX`` (X, 9): the points'
    outer products ``x x^T``; ``robust``: ``(kernels (K,), scale (K, 1), window (K, 1), least sigma, point
    weights (X,))`` (:func:`_robust_weights`); ``fix_rotation``: the translation only; ``vp``:
    ``(n2, P3, arc_group, weight)`` adds the vanishing-point residuals (Huber-weighted at ``scale``). The normal equations gather the points per line
    (:func:`_line_operators`): ``H = sum_l D_l S_l D_l^T`` and ``b = -sum_l D_l S_l n_l`` with
    ``S_l = sum_x w_x x x^T`` over the points matched to line ``l``."""
    n, D = _line_operators(R, t, L)  # (K, L, 3), (K, L, 6, 3)
    K, nl = n.shape[:2]
    r0 = _point_residuals(n, X, match)
    kernel, huber, window, floor, point_w = robust
    w = _robust_weights(r0, match >= 0, kernel, huber, window, floor) * point_w
    slot = (match.clamp_min(0) + nl * torch.arange(K, device=match.device)[:, None]).reshape(-1)
    S = torch.zeros((K * nl, 9), dtype=X.dtype, device=X.device).index_add_(
        0, slot, (w[..., None] * XX).reshape(-1, 9)).reshape(K, nl, 3, 3)
    DS = D @ S  # (K, L, 6, 3)
    H = torch.einsum("klai,klbi->kab", DS, D)
    b = -torch.einsum("klai,kli->ka", DS, n)
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
    pose (the three dot products of the points with each arc's normal and end planes)."""
    L_all = np.asarray(lines, dtype=np.float64)
    grouped = np.asarray(line_groups) >= 0
    out = np.zeros(len(rotations))
    if len(arcs) == 0:
        return out
    planes = arc_planes(arcs)
    for k in range(len(rotations)):
        L = L_all[grouped if visible is None else grouped & np.asarray(visible[k], dtype=bool)]
        near, shown = seen_line_points(planes, rotations[k], centers[k], L, tol_deg, samples, band_deg)
        if shown.any():
            out[k] = float(near[shown].mean())
    return out


def arc_planes(arcs: np.ndarray) -> np.ndarray:
    """(3, 3N) float32 tensor of the arcs' great-circle normals and end planes (:func:`seen_line_points`)."""
    A = np.asarray(arcs, dtype=np.float64)
    s, e = A[:, 0], A[:, 1]
    n = np.cross(s, e)
    n /= np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)
    return torch.as_tensor(np.concatenate([n, np.cross(n, s), np.cross(e, n)], 0).T, dtype=torch.float32)


def seen_line_points(planes, R: np.ndarray, center: np.ndarray, lines: np.ndarray, tol_deg: float = 1.0,
                     samples: int = 24, band_deg: float = 70.0) -> tuple[np.ndarray, np.ndarray]:
    """Which of ``samples`` points along each map line (L, 2, 3) lie on a query arc (``planes``:
    :func:`arc_planes`) seen from the pose ``(R, center)``: ``near`` (L, samples), within ``tol_deg``
    of an arc's great circle and extent, and ``shown`` (L, samples), within ``band_deg`` of the horizon
    (the detector's cap hides the poles). What :func:`map_line_support` averages, per line."""
    L = np.asarray(lines, dtype=np.float64).reshape(-1, 2, 3)
    near = np.zeros((len(L), samples), dtype=bool)
    if len(L) == 0:
        return near, near.copy()
    f = (np.arange(samples) + 0.5) / samples
    P = (L[:, None, 0] + f[None, :, None] * (L[:, None, 1] - L[:, None, 0])).reshape(-1, 3)
    d = (P - np.asarray(center, dtype=np.float64)) @ np.asarray(R, dtype=np.float64).T
    d /= np.linalg.norm(d, axis=1, keepdims=True).clip(1e-12)
    shown = np.abs(d[:, 2]) < np.sin(np.radians(band_deg))
    if shown.any():
        N = planes.shape[1] // 3
        tol = np.sin(np.radians(tol_deg))
        D = torch.as_tensor(d[shown], dtype=torch.float32) @ planes  # (P, 3N)
        hit = (D[:, :N].abs() < tol) & (torch.minimum(D[:, N:2 * N], D[:, 2 * N:]) > -tol)  # arcs < 180 deg: one lune
        near.reshape(-1)[np.flatnonzero(shown)] = hit.any(1).numpy()
    return near, shown.reshape(len(L), samples)


PHYSICAL_SPACING = 2.0  # a camera stands within this many candidate spacings of a candidate translation
# (true cameras: at most 0.84 spacings on layout lattices, 1.25 of the nearest candidate's own spacing on scans'
# octrees; docs/measurements.md#physical-poses)


def physical_poses(centers: np.ndarray, ldl_map, factor: float = PHYSICAL_SPACING) -> np.ndarray:
    """(K,) whether each camera centre (K, 3) stands where a camera can: the map's candidate
    translations fill its free space (in the camera-height band above its floors, out of walls),
    so a centre within ``factor`` spacings of its nearest candidate is physical, one farther is
    below a floor, above the band, inside a wall or outside the rooms. The spacing is the nearest
    candidate's distance to its own nearest neighbour, at least the map's median
    (:func:`ldlmap.map.translations.candidate_spacing`): an octree's large cells in open space hold
    their candidates farther apart. A map of one candidate: every centre is physical."""
    C = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(ldl_map.translations, dtype=np.float64).reshape(-1, 3)
    if len(T) < 2:
        return np.ones(len(C), dtype=bool)
    tree = spatial.cKDTree(T)
    d, i = tree.query(C)
    own = tree.query(T[i], k=2)[0][:, 1]  # each nearest candidate's own spacing
    return d <= factor * np.maximum(own, candidate_spacing(T))


def selection_scores(loss: np.ndarray, params: GeometricParams, support_of,
                     allowed: np.ndarray | None = None) -> np.ndarray:
    """The score that picks the final pose among refined ones (higher is better): ``-loss /
    max|loss| + support_weight x map-line support`` for the poses whose normalized loss is within
    ``support_within`` of the best, ``-inf`` for the others (they cannot win). ``support_of(idx)``
    returns the support of the poses ``idx`` (computed only for the contenders). ``allowed`` (K,)
    bool: only these poses compete (:func:`physical_poses`); when none is, all do (the caller
    judges the winner failed)."""
    loss = np.asarray(loss, dtype=np.float64)
    if allowed is not None and np.any(allowed):
        score = np.full(len(loss), -np.inf)
        score[allowed] = selection_scores(loss[allowed], params, lambda idx: support_of(np.flatnonzero(allowed)[idx]))
        return score
    score = -loss / max(float(np.abs(loss).max()), 1e-12)
    if params.support_weight <= 0:
        return score
    top = np.flatnonzero(score >= score.max() - params.support_within)
    full = np.full(len(score), -np.inf)
    full[top] = score[top] + params.support_weight * np.asarray(support_of(top), dtype=np.float64)
    return full


def refinement_plan(M: int, params: GeometricParams = GeometricParams()) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Which of M ranked search poses the refinement stage refines, and how: ``(candidate, assoc_deg,
    kernel)`` per refined pose. The best ``max_poses`` (at least one) with ``params.kernel`` from
    ``assoc_deg``; the best ``wide_poses`` of them again from ``wide_assoc_deg``; the best
    ``second_kernel_poses`` again with ``second_kernel``'s weights. All results compete."""
    n = max(1, min(M, int(params.max_poses)))
    w = max(0, min(n, int(params.wide_poses)))
    s = max(0, min(n, int(params.second_kernel_poses)))
    cand = np.r_[np.arange(n), np.arange(w), np.arange(s)].astype(int)
    assoc = np.r_[np.full(n, params.assoc_deg), np.full(w, params.wide_assoc_deg), np.full(s, params.assoc_deg)]
    return cand, assoc, [params.kernel] * (n + w) + [params.second_kernel] * s


def refine_and_keep(arcs: np.ndarray, rotations: np.ndarray, centers: np.ndarray, translation_index: np.ndarray,
                    n: int, ldl_map, params: GeometricParams = GeometricParams(),
                    search: SearchParams = SearchParams(), device: str = "cpu", group_tol: float = ARC_GROUP_TOL,
                    assoc_deg: np.ndarray | None = None, kernels=None,
                    height_band: tuple[float, float] | None = None) -> tuple[GeometricResult, np.ndarray, np.ndarray]:
    """The geometric refinement stage on a map: refine the first ``n`` of these poses from lines alone
    and score every pose with the search's exact loss (:func:`ldlloc.search.pose_search.score_on_map`).

    A refined pose is kept where refinement was accepted and its exact loss is within
    ``params.keep_within`` of its start's: the inlier loss cannot see a few centimetres
    (docs/measurements.md#geometric-keep-within). ``translation_index`` (M,): each pose's candidate
    translation (its visible lines); ``assoc_deg`` (n,): each refined pose's first association angle
    (None: the params'); ``kernels`` (n,): each refined pose's weights (None: the params');
    ``height_band``: the camera's (min, max) world z (None: the map's camera-height band). Returns
    the :class:`GeometricResult` of the first ``n``, ``kept`` (M,) and
    each pose's loss (M,) (the better of the two where kept)."""
    m = ldl_map
    ti = np.asarray(translation_index)
    vis = m.visibility[ti[:n]] if m.visibility is not None else None
    g = refine_poses_geometric(arcs, rotations[:n], centers[:n], m.lines, m.line_groups, m.principal_directions,
                               vis, params, m.camera_height_band if height_band is None else height_band,
                               assoc_deg, kernels)
    # a refined pose is scored with what is seen from the candidate translation nearest to it
    # (lines behind walls, mapped directions), not from its start's
    ti_ref = m.nearest_translation(g.centers)
    # the starts are scored once each (the wide second refinements repeat the best ones)
    _, first, back = np.unique(np.concatenate([rotations.reshape(-1, 9), centers], 1), axis=0,
                               return_index=True, return_inverse=True)
    loss = score_on_map(arcs, np.concatenate([g.rotations, rotations[first]]),
                        np.concatenate([g.centers, centers[first]]), m, search, device, group_tol,
                        translation_index=np.concatenate([ti_ref, ti[first]]))
    refined, start = loss[:n], loss[n:][back.reshape(-1)]
    kept = np.zeros(len(rotations), dtype=bool)
    kept[:n] = g.accepted & (refined <= start[:n] + params.keep_within * np.abs(start[:n]))
    best = start.copy()
    best[:n] = np.where(kept[:n], np.minimum(refined, start[:n]), start[:n])
    return g, kept, best
