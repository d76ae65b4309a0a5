"""A robust data term: per-pixel weights of the frames' residuals, re-estimated during the solve (IRLS).

(5.3) fits every observed LR pixel by least squares, so a pixel the model cannot explain (a car or
a person that moved, an occlusion, a patch misregistered by more than the flow could correct)
pulls the estimate as hard as its squared residual. Replacing the square by a robust norm rho and
minimising by iteratively reweighted least squares gives each pixel the weight ``w = rho'(e) / e``
of its current residual ``e = y - D B W x`` (Holland and Welsch 1977; Zomet, Rav-Acha and Peleg 2001
for SR), with the scale ``t = scale * sigma``, sigma the residuals' robust std (1.4826 MAD) and at
least the frames' noise std::

    huber:       w = min(1, t / |e|)
    lorentzian:  w = 1 / (1 + (e / t)^2)

The weights multiply the square of the observation mask (the mask M of A = M D B W becomes
``M sqrt(w)``), so the operator stays linear with an exact adjoint between two reweightings.
"""
from __future__ import annotations

import torch

from .modes import ROBUST_NORMS

__all__ = ['ROBUST_NORMS', 'pixel_weights']



def pixel_weights(r: torch.Tensor, mask: torch.Tensor, *, norm: str = 'huber', scale: float = 2.0,
                  noise: float = 0.0) -> torch.Tensor:
    """(K, 1, h, w) IRLS weights in [0, 1] of the residual ``r`` (K, C, h, w) observed where ``mask``
    (K, 1, h, w) > 0 (``r`` is the masked residual ``M (y - A x)``; it is divided back by M);
    ``norm`` 'huber' or 'lorentzian', ``scale`` the threshold in robust stds, ``noise`` (intensity) the
    smallest std taken. Unobserved pixels get weight 1 (their mask keeps them out)."""
    if norm not in ROBUST_NORMS or norm == 'off':
        msg = f"a robust norm is 'huber' or 'lorentzian', got {norm!r}."
        raise ValueError(msg)
    seen = mask > 0
    e = torch.sqrt((r.double() ** 2).mean(dim=1, keepdim=True)) / mask.double().clamp_min(1e-12)
    vals = e[seen]
    if vals.numel() < 16:
        return torch.ones_like(mask)
    sigma = max(float(1.4826 * vals.median()), float(noise), 1e-6)  # |e| is half-normal: its median is 0.674 sigma
    t = scale * sigma
    if norm == 'huber':
        w = (t / e.clamp_min(1e-12)).clamp_max(1.0)
    else:
        w = 1.0 / (1.0 + (e / t) ** 2)
    return torch.where(seen, w, torch.ones_like(w)).to(mask.dtype)
