"""Putative and guided matching of descriptors as torch ops (Table 1 of the reference, steps 2 and 5).

Descriptors are unit vectors (RootSIFT), so squared Euclidean distances come from one matrix
product: ||a - b||^2 = 2 - 2 a.b.
"""
from __future__ import annotations

import torch

__all__ = ['descriptor_sq_distances', 'guided_matches', 'mutual_ratio_matches', 'transfer_points']


def descriptor_sq_distances(desc_cur: torch.Tensor, desc_prev: torch.Tensor) -> torch.Tensor:
    """(Nc, D), (Np, D) unit descriptors -> (Nc, Np) squared Euclidean distances (>= 0)."""
    return torch.addmm(torch.full((1, 1), 2.0, device=desc_cur.device, dtype=desc_cur.dtype), desc_cur, desc_prev.T,
                       alpha=-2.0).clamp_min_(0.0)


def mutual_ratio_matches(
    desc_prev: torch.Tensor,
    desc_cur: torch.Tensor,
    *,
    ratio: float,
    sq_dist: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Matches that pass Lowe's ratio test and are mutual nearest neighbours.

    Args:
        desc_prev: (Np, D) unit descriptors of the previous frame.
        desc_cur: (Nc, D) unit descriptors of the current frame.
        ratio: a current descriptor's nearest previous one must be closer than ratio times the
            second nearest (distances, not squared).
        sq_dist: (Nc, Np) descriptor_sq_distances(desc_cur, desc_prev) if already computed.

    Returns:
        (idx_prev (M,), idx_cur (M,), distance (M,)) long, long, float32, on the descriptors' device,
        ordered by increasing distance (best first, which PROSAC-like sampling could use).
    """
    dev = desc_cur.device
    if desc_prev.shape[0] < 2 or desc_cur.shape[0] < 1:
        e = torch.zeros(0, dtype=torch.long, device=dev)
        return e, e, torch.zeros(0, device=dev)
    d2 = descriptor_sq_distances(desc_cur, desc_prev) if sq_dist is None else sq_dist   # (Nc, Np)
    best2 = d2.topk(2, dim=1, largest=False)
    nn_prev = best2.indices[:, 0]
    d1, d2nd = best2.values[:, 0], best2.values[:, 1]
    back = d2.argmin(dim=0)                                  # (Np,) best current for each previous
    cur_idx = torch.arange(desc_cur.shape[0], device=dev)
    keep = (d1 < (ratio * ratio) * d2nd) & (back[nn_prev] == cur_idx)
    ci = cur_idx[keep]
    pi = nn_prev[keep]
    dist = d1[keep].sqrt()
    order = dist.argsort()
    return pi[order], ci[order], dist[order]


def transfer_points(prev_H_cur: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
    """Map (..., N, 2) points by (..., 3, 3) homographies -> (..., N, 2) (in the dtype of pts)."""
    H = prev_H_cur.to(pts.dtype)
    p = torch.baddbmm(H[..., None, :, 2], pts, H[..., :, :2].transpose(-1, -2)) if pts.ndim == 3 and H.ndim == 3 else \
        torch.matmul(pts, H[..., :, :2].transpose(-1, -2)) + H[..., None, :, 2]      # (..., N, 3)
    return p[..., :2] / p[..., 2:3]


def guided_matches(
    xy_prev: torch.Tensor,
    xy_cur: torch.Tensor,
    desc_prev: torch.Tensor,
    desc_cur: torch.Tensor,
    prev_H_cur: torch.Tensor,
    *,
    radius_px: float,
    sq_dist: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Guided matching (Table 1, step 5): each current keypoint takes the previous keypoint with the
    closest descriptor among those within radius_px of its transfer by prev_H_cur; a previous
    keypoint is used once (mutual best).

    Args:
        xy_prev: (Np, 2), xy_cur: (Nc, 2) keypoint positions (pixels).
        desc_prev, desc_cur: (Np, D), (Nc, D) unit descriptors.
        prev_H_cur: (3, 3) current -> previous pixels.
        radius_px: search radius around the transfer (pixels of the previous frame).
        sq_dist: (Nc, Np) descriptor_sq_distances(desc_cur, desc_prev) if already computed.

    Returns:
        (idx_prev (M,), idx_cur (M,), transfer distance (M,) in pixels).
    """
    dev = xy_cur.device
    if xy_prev.shape[0] == 0 or xy_cur.shape[0] == 0:
        e = torch.zeros(0, dtype=torch.long, device=dev)
        return e, e, torch.zeros(0, device=dev)
    pred = transfer_points(prev_H_cur.to(torch.float64), xy_cur.to(torch.float64)).to(xy_prev.dtype)
    # Squared spatial distances |p|^2 + |q|^2 - 2 p.q (one matrix product).
    sp = (pred.square().sum(1, keepdim=True) + xy_prev.square().sum(1)[None]).addmm_(pred, xy_prev.T, alpha=-2.0)
    dd = descriptor_sq_distances(desc_cur, desc_prev) if sq_dist is None else sq_dist
    cost = dd.masked_fill(sp > radius_px * radius_px, float('inf'))
    best_prev = cost.argmin(dim=1)
    best_cur = cost.argmin(dim=0)
    cur_idx = torch.arange(xy_cur.shape[0], device=dev)
    ok = torch.isfinite(cost[cur_idx, best_prev]) & (best_cur[best_prev] == cur_idx)
    ci = cur_idx[ok]
    pi = best_prev[ok]
    return pi, ci, sp[ci, pi].clamp_min(0.0).sqrt()
