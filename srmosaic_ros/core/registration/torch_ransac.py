"""Homography estimation as torch ops: normalised DLT, batched RANSAC, Levenberg-Marquardt.

Table 1 of the reference, steps 3 and 4 (Hartley and Zisserman, algorithm 4.6):
- `dlt_homography`: the normalised direct linear transform on N >= 4 correspondences (null
  vector of the 2N x 9 design matrix by SVD, Hartley normalisation of both point sets).
- `ransac_homography`: hypotheses from 4-point samples are solved all at once (batched 8 x 8
  systems with h22 = 1, in the Hartley-normalised coordinates of all matches), scored at once
  against all matches (MSAC: truncated squared transfer error), in rounds whose number adapts to
  the best inlier ratio w: N = log(1 - confidence) / log(1 - w**4).
- `homography_from_4`: the same minimal solver for given samples, each normalised on its own.
- `refine_lm`: maximum-likelihood re-estimation on all inliers, minimising the reprojection
  (transfer) error sum ||dst - H(src)||**2 by Levenberg-Marquardt over the 8 entries with
  h22 = 1, batched over independent problems.

Convention: points (..., N, 2) as (x, y) pixels; homographies (..., 3, 3) map src (current frame)
to dst (previous frame): dst ~ H @ [x, y, 1]. Estimation runs in float64.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .torch_features import cached_constant

__all__ = ['RansacResult', 'dlt_homography', 'homography_from_4', 'normalize_points', 'ransac_homography', 'refine_lm']

_F64 = torch.float64


def normalize_points(pts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Hartley normalisation: centroid to the origin, mean distance sqrt(2).

    pts: (..., N, 2) -> (normalised points (..., N, 2), T (..., 3, 3)) with p_n = T @ p (float64).
    """
    p = pts.to(_F64)
    c = p.mean(-2, keepdim=True)                                   # (..., 1, 2)
    d = p - c
    s = (math.sqrt(2.0) / d.norm(dim=-1).mean(-1).clamp_min(1e-12))[..., None, None]   # (..., 1, 1)
    pn = d * s
    t = -c * s                                                      # (..., 1, 2)
    z = torch.zeros_like(s)
    T = torch.cat([torch.cat([s, z, t[..., 0:1]], -1), torch.cat([z, s, t[..., 1:2]], -1),
                   torch.cat([z, z, torch.ones_like(s)], -1)], -2)
    return pn, T


def _denormalize(hn: torch.Tensor, t_src: torch.Tensor, t_dst: torch.Tensor) -> torch.Tensor:
    """H = T_dst^-1 @ Hn @ T_src, scaled to h22 = 1."""
    H = torch.linalg.solve(t_dst, hn @ t_src)
    return H / H[..., 2:3, 2:3]


def dlt_homography(src: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
    """Normalised DLT on N >= 4 correspondences: (..., N, 2), (..., N, 2) -> (..., 3, 3) float64, h22 = 1.

    Minimises the algebraic error of the normalised points (exact on exact correspondences).
    """
    if src.shape != dst.shape or src.shape[-2] < 4:
        msg = (f'DLT needs two (..., N, 2) point sets of equal shape with N >= 4, got {tuple(src.shape)} '
               f'and {tuple(dst.shape)}.')
        raise ValueError(msg)
    sn, ts = normalize_points(src)
    dn, td = normalize_points(dst)
    x, y = sn[..., 0], sn[..., 1]
    u, v = dn[..., 0], dn[..., 1]
    z, o = torch.zeros_like(x), torch.ones_like(x)
    r1 = torch.stack([-x, -y, -o, z, z, z, u * x, u * y, u], -1)
    r2 = torch.stack([z, z, z, -x, -y, -o, v * x, v * y, v], -1)
    A = torch.cat([r1, r2], -2)  # ..., 2N, 9
    _, _, vh = torch.linalg.svd(A, full_matrices=False)
    hn = vh[..., -1, :].reshape(*A.shape[:-2], 3, 3)
    return _denormalize(hn, ts, td)


def _solve_4(x: torch.Tensor, y: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The 8 x 8 systems of (B, 4) correspondences (x, y) -> (u, v) with h22 = 1 -> (B, 3, 3), info."""
    z, o = torch.zeros_like(x), torch.ones_like(x)
    r1 = torch.stack([x, y, o, z, z, z, -u * x, -u * y], -1)
    r2 = torch.stack([z, z, z, x, y, o, -v * x, -v * y], -1)
    h, info = torch.linalg.solve_ex(torch.cat([r1, r2], -2), torch.cat([u, v], -1)[..., None])
    return torch.cat([h[..., 0], o[..., :1]], -1).reshape(-1, 3, 3), info


def homography_from_4(src: torch.Tensor, dst: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Minimal solver, batched: (B, 4, 2), (B, 4, 2) -> (H (B, 3, 3) float64 with h22 = 1, ok (B,) bool).

    Each sample is normalised on its own, then the 8 x 8 system with h22 = 1 is solved; singular
    samples (collinear points) come back with ok = False.
    """
    sn, ts = normalize_points(src)
    dn, td = normalize_points(dst)
    hn, info = _solve_4(sn[..., 0], sn[..., 1], dn[..., 0], dn[..., 1])
    H = _denormalize(hn, ts, td)
    ok = (info == 0) & torch.isfinite(H).all(-1).all(-1)
    return torch.where(ok[:, None, None], H, torch.eye(3, dtype=_F64, device=H.device)), ok


def _orientation_consistent(src: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
    """(B, 4, 2) samples whose 4 triangles keep their orientation and are not degenerate -> (B,) bool.

    A homography between overlapping frames of a camera over the ground does not fold or mirror,
    so a sample whose triangles flip cannot be right; near-collinear samples are ill-posed.
    """
    tri = cached_constant(((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)), src.device, torch.long)

    def cross(p: torch.Tensor) -> torch.Tensor:
        a, b, c = p[:, tri[:, 0]], p[:, tri[:, 1]], p[:, tri[:, 2]]
        e1, e2 = b - a, c - a
        return e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]      # (B, 4)

    cs, cd = cross(src), cross(dst)
    scale_s = ((src - src.mean(1, keepdim=True)) ** 2).sum((1, 2))   # ~ spread**2
    scale_d = ((dst - dst.mean(1, keepdim=True)) ** 2).sum((1, 2))
    nondeg = (cs.abs() > 1e-3 * scale_s[:, None]).all(1) & (cd.abs() > 1e-3 * scale_d[:, None]).all(1)
    return ((cs * cd) > 0).all(1) & nondeg


@dataclass
class RansacResult:
    """Outcome of `ransac_homography`.

    dst_H_src: (3, 3) float64 best hypothesis (None if no valid hypothesis); inliers: (M,) bool;
    iterations: hypotheses drawn; cost: MSAC cost of the best hypothesis (px**2).
    """

    dst_H_src: torch.Tensor | None
    inliers: torch.Tensor
    iterations: int
    cost: float


def ransac_homography(
    src: torch.Tensor,
    dst: torch.Tensor,
    *,
    threshold_px: float,
    confidence: float,
    max_iterations: int,
    batch_size: int = 256,
    generator: torch.Generator | None = None,
) -> RansacResult:
    """Robust homography dst ~ H src from putative matches (M, 2), (M, 2), M >= 4.

    Both point sets are Hartley-normalised once; rounds of batch_size hypotheses (4-point samples
    with consistent orientation, 8 x 8 systems solved at once) are scored at once by the MSAC cost
    sum(min(e**2, t**2)) of the transfer errors e of all matches (in normalised units, where the
    threshold scales with the destination normalisation); rounds continue until the adaptive count
    log(1 - confidence) / log(1 - w**4) of the best hypothesis' inlier ratio w (or max_iterations)
    is reached.
    """
    m = src.shape[0]
    dev = src.device
    if m < 4:
        return RansacResult(None, torch.zeros(m, dtype=torch.bool, device=dev), 0, float('inf'))
    sn, ts = normalize_points(src)
    dn, td = normalize_points(dst)
    src_h = torch.cat([sn, torch.ones_like(sn[:, :1])], 1).T.contiguous()     # (3, M)
    dst_t = dn.T.contiguous()                                                  # (2, M)
    t2 = float((threshold_px * td[0, 0]) ** 2)
    best_cost = float('inf')
    best: torch.Tensor | None = None
    needed = max_iterations
    drawn = 0
    log_fail = math.log(1.0 - confidence)
    while drawn < needed:
        n = min(batch_size, max_iterations - drawn)
        idx = torch.randint(0, m, (n, 4), device=dev, generator=generator)
        distinct = ((idx[:, 0] != idx[:, 1]) & (idx[:, 0] != idx[:, 2]) & (idx[:, 0] != idx[:, 3])
                    & (idx[:, 1] != idx[:, 2]) & (idx[:, 1] != idx[:, 3]) & (idx[:, 2] != idx[:, 3]))
        ss, dd = sn[idx], dn[idx]
        hn, info = _solve_4(ss[..., 0], ss[..., 1], dd[..., 0], dd[..., 1])
        ok = (info == 0) & distinct & _orientation_consistent(ss, dd)
        p = hn @ src_h                                                        # (n, 3, M)
        e2 = ((p[:, :2] / p[:, 2:3] - dst_t) ** 2).sum(1)                      # (n, M)
        cost = torch.nan_to_num(e2, nan=t2).clamp_max_(t2).sum(1).masked_fill_(~ok, float('inf'))
        k = int(cost.argmin())
        c = float(cost[k])
        drawn += n
        if c < best_cost:
            best_cost = c
            best = hn[k]
            w = float((e2[k] < t2).sum()) / m
            if w >= 1.0:
                needed = 0
            elif w > 0.0:
                needed = min(max_iterations, math.ceil(log_fail / math.log1p(-(w**4))))
    if best is None:
        return RansacResult(None, torch.zeros(m, dtype=torch.bool, device=dev), drawn, best_cost)
    p = best @ src_h
    inliers = ((p[:2] / p[2:3] - dst_t) ** 2).sum(0) < t2
    return RansacResult(_denormalize(best, ts, td), inliers, drawn, best_cost / float(td[0, 0]) ** 2)


def _project(h: torch.Tensor, src_h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """H(src) for h (B, 8) (h22 = 1) and homogeneous src (B, N, 3) -> (uv (B, N, 2), 1 / w (B, N, 1))."""
    p = torch.matmul(src_h, _H3(h).transpose(-1, -2))
    iw = p[..., 2:3].reciprocal()
    return p[..., :2] * iw, iw


def _jacobian(src_h: torch.Tensor, uv: torch.Tensor, iw: torch.Tensor) -> torch.Tensor:
    """d H(src) / dh (B, 2N, 8), rows ordered (x_1, y_1, x_2, y_2, ...).

    du/dh = [x, y, 1, 0, 0, 0, -u x, -u y] / w,  dv/dh = [0, 0, 0, x, y, 1, -v x, -v y] / w.
    """
    xw = src_h * iw                                                   # (B, N, 3)
    J = src_h.new_zeros(*src_h.shape[:-1], 2, 8)
    J[..., 0, 0:3] = xw
    J[..., 1, 3:6] = xw
    J[..., 6:8] = -uv[..., :, None] * xw[..., None, :2]
    return J.flatten(-3, -2)


def _homogeneous(pts: torch.Tensor) -> torch.Tensor:
    return torch.cat([pts, torch.ones_like(pts[..., :1])], -1)


def _residuals_jacobian(h: torch.Tensor, src: torch.Tensor, dst: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """r = dst - H(src) (B, 2N) ordered (x_1, y_1, x_2, ...); J = d H(src) / dh (B, 2N, 8).

    h: (B, 8) entries h00..h21 (h22 = 1); src, dst: (B, N, 2).
    """
    src_h = _homogeneous(src)
    uv, iw = _project(h, src_h)
    return (dst - uv).flatten(-2), _jacobian(src_h, uv, iw)


def _h8(H: torch.Tensor) -> torch.Tensor:
    Hn = H / H[..., 2:3, 2:3]
    return Hn.reshape(*H.shape[:-2], 9)[..., :8]


def _H3(h: torch.Tensor) -> torch.Tensor:
    return torch.cat([h, torch.ones_like(h[..., :1])], -1).reshape(*h.shape[:-1], 3, 3)


def refine_lm(
    src: torch.Tensor,
    dst: torch.Tensor,
    dst_H_src: torch.Tensor,
    *,
    iterations: int = 10,
    weights: torch.Tensor | None = None,
    tol: float = 1e-12,
) -> torch.Tensor:
    """Levenberg-Marquardt on the transfer error sum w_i ||dst_i - H(src_i)||**2 (h22 = 1).

    Args:
        src, dst: (N, 2) or (B, N, 2) correspondences; dst_H_src: (3, 3) or (B, 3, 3) start.
        iterations: LM steps (each accepted or rejected with the usual damping update,
            (J^T J + lambda diag(J^T J)) delta = J^T r).
        weights: optional (N,) or (B, N) per-correspondence weights (0 drops a point).
        tol: stop when every problem's accepted step lowers the cost by less than this fraction
            (or moves h by less than this, relative).

    Returns (3, 3) or (B, 3, 3) float64 with h22 = 1. Runs in Hartley-normalised coordinates
    (a similarity of each image, which leaves the minimiser unchanged).
    """
    single = src.ndim == 2
    if single:
        src, dst, dst_H_src = src[None], dst[None], dst_H_src[None]
        weights = None if weights is None else weights[None]
    sn, ts = normalize_points(src)
    dn, td = normalize_points(dst)
    sh = _homogeneous(sn)
    h = _h8(td @ dst_H_src.to(_F64) @ torch.linalg.inv(ts))
    b = h.shape[0]
    wt = None if weights is None else weights.to(_F64)[..., None].expand(*weights.shape, 2).flatten(-2)

    def residual(hh: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        uv, iw = _project(hh, sh)
        r = (dn - uv).flatten(-2)
        c = (r * r).sum(-1) if wt is None else (wt * r * r).sum(-1)
        return c, r, uv, iw

    cost, r, uv, iw = residual(h)
    J = _jacobian(sh, uv, iw)
    lam = torch.full((b,), 1e-3, dtype=_F64, device=h.device)
    for _ in range(iterations):
        Jw = J if wt is None else J * wt[..., None]
        A = Jw.transpose(1, 2) @ J
        g = Jw.transpose(1, 2) @ r[..., None]
        A.diagonal(dim1=1, dim2=2).mul_(1.0 + lam[:, None])
        delta = torch.linalg.solve_ex(A, g)[0][..., 0]
        h_new = h + delta
        c_new, r_new, uv, iw = residual(h_new)
        better = torch.isfinite(c_new) & (c_new <= cost)
        rel = (cost - c_new) / cost.clamp_min(1e-300)
        small = delta.abs().amax(-1) <= tol * (1.0 + h.abs().amax(-1))
        if single:
            if bool(better[0]):
                h, r, cost = h_new, r_new, c_new
                J = _jacobian(sh, uv, iw)
                lam = lam * 0.1
            else:
                lam = lam * 10.0
        else:
            h = torch.where(better[:, None], h_new, h)
            r = torch.where(better[:, None], r_new, r)
            J = torch.where(better[:, None, None], _jacobian(sh, uv, iw), J)
            cost = torch.where(better, c_new, cost)
            lam = torch.where(better, lam * 0.1, lam * 10.0)
        lam = lam.clamp(1e-12, 1e8)
        if bool(((better & (rel < tol)) | small).all()):
            break
    H = _denormalize(_H3(h), ts, td)
    return H[0] if single else H
