"""Huber prior over second-order clique differences (5.3, 5.4, 5.7 to 5.11) and its weight lambda (5.6).

The prior of (5.3) is ``lambda * sum_g rho(g, alpha)`` over ``g = G x``: the four second-order
differences of every interior HR pixel (vertical (5.8), horizontal (5.9) and the two diagonals
(5.10, 5.11), the diagonals with weights 1/2, -1, 1/2). ``G`` maps ``(B, C, H, W)`` to
``(B, 4 C, H - 2, W - 2)`` (only where all neighbours exist, so ``G^T`` is its exact adjoint, a
transposed convolution); channel ``4 c + j`` holds difference ``j + 1`` of channel ``c``.

Intensities are in [0, 1], so ``alpha`` is a second difference in those units.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

__all__ = [
    'CLIQUE_KERNELS',
    'huber',
    'huber_derivative',
    'huber_sum',
    'huber_sum_parts',
    'huber_irls_weight',
    'clique_differences',
    'clique_differences_adjoint',
    'HuberPrior',
    'adaptive_lambda',
    'paper_lambda',
]

# (4, 3, 3) correlation kernels over x[n1 + i - 1, n2 + j - 1], n1 the row, n2 the column.
CLIQUE_KERNELS = torch.tensor([
    [[0.0, 1.0, 0.0], [0.0, -2.0, 0.0], [0.0, 1.0, 0.0]],   # (5.8)  x[n1-1,n2] - 2x + x[n1+1,n2]
    [[0.0, 0.0, 0.0], [1.0, -2.0, 1.0], [0.0, 0.0, 0.0]],   # (5.9)  x[n1,n2-1] - 2x + x[n1,n2+1]
    [[0.0, 0.0, 0.5], [0.0, -1.0, 0.0], [0.5, 0.0, 0.0]],   # (5.10) x[n1+1,n2-1]/2 - x + x[n1-1,n2+1]/2
    [[0.5, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.5]],   # (5.11) x[n1-1,n2-1]/2 - x + x[n1+1,n2+1]/2
], dtype=torch.float64)

def huber(g: torch.Tensor, alpha: float) -> torch.Tensor:
    """rho(g, alpha) of (5.4): g^2 where |g| <= alpha, 2 alpha |g| - alpha^2 elsewhere (elementwise)."""
    a = g.abs()
    return torch.where(a <= alpha, g * g, 2.0 * alpha * a - alpha * alpha)


def huber_derivative(g: torch.Tensor, alpha: float) -> torch.Tensor:
    """rho'(g, alpha) of (5.7): 2 g clipped to [-2 alpha, 2 alpha] (elementwise)."""
    return 2.0 * g.clamp(-alpha, alpha)


def huber_irls_weight(g: torch.Tensor, alpha: float) -> torch.Tensor:
    """IRLS weight omega = rho'(g) / (2 g): 1 where |g| <= alpha, alpha / |g| elsewhere.

    ``sum omega g^2`` majorises ``sum rho(g)`` up to a constant and has the same gradient at g: the
    Gauss-Newton Hessian of the prior is ``2 G^T diag(omega) G``.
    """
    return alpha / g.abs().clamp_min(alpha)


_weights: dict[tuple[int, torch.dtype, torch.device], torch.Tensor] = {}


def _clique_weight(channels: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    key = (channels, dtype, device)
    if key not in _weights:
        w = CLIQUE_KERNELS.to(dtype=dtype, device=device)[:, None]          # (4, 1, 3, 3)
        _weights[key] = w.repeat(channels, 1, 1, 1).contiguous()             # (4C, 1, 3, 3)
    return _weights[key]


def _use_conv(x: torch.Tensor, impl: str) -> bool:
    if impl not in ('auto', 'conv', 'slices'):
        msg = f"impl must be 'auto', 'conv' or 'slices', got {impl!r}."
        raise ValueError(msg)
    return impl == 'conv' or (impl == 'auto' and x.is_cuda)


def clique_differences(x: torch.Tensor, *, impl: str = 'auto') -> torch.Tensor:
    """G x: ``(B, C, H, W)`` -> ``(B, 4 C, H - 2, W - 2)``, the differences (5.8) to (5.11).

    On a CPU (``impl='auto'``) computed with shifted slices (memory-bound adds, far cheaper than a
    3x3 convolution there); on a GPU one depthwise convolution with :data:`CLIQUE_KERNELS`.
    """
    if _use_conv(x, impl):
        return F.conv2d(x, _clique_weight(x.shape[1], x.dtype, x.device), groups=x.shape[1])
    b, ch, h, w = x.shape
    c = x[..., 1:-1, 1:-1]
    if x.requires_grad:  # out= kernels do not record autograd graphs
        return torch.stack([x[..., :-2, 1:-1] + x[..., 2:, 1:-1] - 2.0 * c,
                            x[..., 1:-1, :-2] + x[..., 1:-1, 2:] - 2.0 * c,
                            0.5 * (x[..., 2:, :-2] + x[..., :-2, 2:]) - c,
                            0.5 * (x[..., :-2, :-2] + x[..., 2:, 2:]) - c], dim=2).flatten(1, 2)
    out = x.new_empty((b, ch, 4, h - 2, w - 2))
    d1, d2, d3, d4 = out.unbind(2)
    torch.add(x[..., :-2, 1:-1], x[..., 2:, 1:-1], out=d1).sub_(c, alpha=2.0)          # (5.8)
    torch.add(x[..., 1:-1, :-2], x[..., 1:-1, 2:], out=d2).sub_(c, alpha=2.0)          # (5.9)
    torch.add(x[..., 2:, :-2], x[..., :-2, 2:], out=d3).mul_(0.5).sub_(c)              # (5.10)
    torch.add(x[..., :-2, :-2], x[..., 2:, 2:], out=d4).mul_(0.5).sub_(c)              # (5.11)
    return out.view(b, ch * 4, h - 2, w - 2)


def clique_differences_adjoint(g: torch.Tensor, *, impl: str = 'auto') -> torch.Tensor:
    """G^T g: ``(B, 4 C, h, w)`` -> ``(B, C, h + 2, w + 2)``, the exact adjoint of :func:`clique_differences`."""
    b, c4, h, w = g.shape
    if _use_conv(g, impl):
        return F.conv_transpose2d(g, _clique_weight(c4 // 4, g.dtype, g.device), groups=c4 // 4)
    g0, g1, g2, g3 = g.view(b, c4 // 4, 4, h, w).unbind(2)
    out = g.new_zeros((b, c4 // 4, h + 2, w + 2))
    out[..., 1:-1, 1:-1].add_(g0, alpha=-2.0).add_(g1, alpha=-2.0).sub_(g2).sub_(g3)
    out[..., :-2, 1:-1].add_(g0)
    out[..., 2:, 1:-1].add_(g0)
    out[..., 1:-1, :-2].add_(g1)
    out[..., 1:-1, 2:].add_(g1)
    out[..., 2:, :-2].add_(g2, alpha=0.5)
    out[..., :-2, 2:].add_(g2, alpha=0.5)
    out[..., :-2, :-2].add_(g3, alpha=0.5)
    out[..., 2:, 2:].add_(g3, alpha=0.5)
    return out


def huber_sum_parts(g: torch.Tensor, alpha: float) -> torch.Tensor:
    """(3,) tensor ``(sum c^2, sum |g|, sum c)`` with c = min(|g|, alpha), on g's device: the sum of
    rho is ``sum c^2 + 2 alpha (sum |g| - sum c)`` (no elementwise rho array, no synchronisation)."""
    a = g.abs().reshape(-1)
    c = a.clamp(max=alpha)
    return torch.stack([torch.vdot(c, c), a.sum(), c.sum()])


def huber_sum(g: torch.Tensor, alpha: float) -> float:
    """sum_g rho(g, alpha) as a Python float, from :func:`huber_sum_parts`."""
    cc, a_sum, c_sum = huber_sum_parts(g, alpha).tolist()
    return cc + 2.0 * alpha * (a_sum - c_sum)


@dataclass(frozen=True)
class HuberPrior:
    """sum_g rho(g, alpha) over the cliques of (5.8) to (5.11); ``alpha`` in intensity units ([0, 1])."""

    alpha: float = 0.02

    def __post_init__(self) -> None:
        if not self.alpha > 0:
            msg = f'the Huber threshold alpha must be > 0, got {self.alpha}.'
            raise ValueError(msg)

    def value(self, x: torch.Tensor) -> torch.Tensor:
        """sum rho(G x, alpha) (0-dim tensor)."""
        return huber(clique_differences(x), self.alpha).sum()

    def gradient(self, x: torch.Tensor) -> torch.Tensor:
        """d/dx sum rho(G x) = G^T rho'(G x, alpha), shape of x."""
        return clique_differences_adjoint(huber_derivative(clique_differences(x), self.alpha))


def adaptive_lambda(frame_rms: torch.Tensor, frame_weights: torch.Tensor, mean_rho: torch.Tensor | float,
                    *, gamma: float = 1.0, floor: float = 1e-12, cap: float = 1e3) -> torch.Tensor:
    """lambda(n) of (5.6), normalised per pixel so that it does not depend on the tile's size.

    (5.6) prints ``lambda = (sum_k ||r_k||_2 / (K sum_g rho(g)))^2``: the ratio of the frames'
    residual to the prior's activity. As printed it scales like 1 / N with the number N of pixels
    (and is not dimensionless), so a tile twice as wide would get a four times weaker prior. Here the
    same ratio is taken per observed pixel and per clique::

        lambda = gamma * (sum_k w_k RMS_k / sum_k w_k)^2 / mean_g rho(g, alpha)

    with ``RMS_k = ||r_k|| / sqrt(N_k)`` the root mean square residual of frame k over its N_k
    observed pixels (the numerator of (5.6), at the current iterate) and ``w_k`` the per-frame
    weights: a noise variance over a prior variance, the classic regularisation ratio. Which
    image ``mean_rho`` is measured on is the caller's choice (see
    :class:`~srmosaic_ros.core.sr.solvers.LambdaRule`). Clipped to ``cap``.

    ``frame_rms`` (K,), ``frame_weights`` (K,), ``mean_rho`` 0-dim; returns a 0-dim tensor.
    """
    wsum = frame_weights.sum().clamp_min(1e-30)
    sigma = (frame_weights * frame_rms).sum() / wsum
    rho = torch.as_tensor(mean_rho, dtype=sigma.dtype).clamp_min(floor)
    return (gamma * sigma * sigma / rho).clamp_max(cap)


def paper_lambda(frame_norms: torch.Tensor, sum_rho: torch.Tensor, *, floor: float = 1e-30) -> torch.Tensor:
    """(5.6) exactly as printed: (sum_k ||r_k||_2 / (K sum_g rho(g)))^2. For comparison only."""
    k = frame_norms.numel()
    return (frame_norms.sum() / (k * sum_rho.clamp_min(floor))) ** 2
