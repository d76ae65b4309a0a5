"""Covariance of an estimated homography by the unscented transform (reference, 4.40 to 4.43).

The residual spread of the n inlier correspondences (4.40),

    sigma = sqrt(sum_i ||dst_i - H(src_i)||**2 / n),

is taken as isotropic noise of the destination points (4.41): P = sigma**2 / 2 * I (2n x 2n),
so that one point's residual has the observed mean square sigma**2. The L = 2n destination
coordinates are the UT state; its 2L + 1 = 4n + 1 sigma points (4.42), with L + kappa = 3, are

    chi_0 = dst,   chi_{j+-} = dst +- sqrt(3 sigma**2 / 2) e_j,   j = 1 .. 2n,

each is mapped to a homography by the re-estimation of Table 1 (the reprojection-error fit from
the estimate), normalised to h22 = 1 (4.29), and the covariance of h = (h00 .. h21) is (4.43)

    P_h = sum_{i=1}^{4n} W_i (gamma_i - gamma_0)(gamma_i - gamma_0)^T,   W_i = 1 / (2 (L + kappa)) = 1/6.

(The reference prints the weight as 1 / 2n over "2n" points; with its own sigma-point spread
sqrt((L + kappa) P) that would not reproduce P for a linear map. The standard UT weight does:
for a linear estimator P_h = K P K^T exactly.)

Convention: src = current-frame pixels, dst = previous-frame pixels, H = prev_H_cur; the 8-vector
is the row-major H with h22 = 1 removed: (h00, h01, h02, h10, h11, h12, h20, h21).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .torch_ransac import _denormalize, _H3, _h8, _residuals_jacobian, normalize_points, refine_lm

__all__ = ['HomographyCovariance', 'homography_covariance_ut']

_F64 = torch.float64
_L_PLUS_KAPPA = 3.0


@dataclass(frozen=True)
class HomographyCovariance:
    """covariance: (8, 8) float64 of (h00 .. h21) with h22 = 1; sigma_px: residual RMS (4.40);
    samples: number of sigma points (4n + 1)."""

    covariance: torch.Tensor
    sigma_px: float
    samples: int


def homography_covariance_ut(
    dst_H_src: torch.Tensor,
    src: torch.Tensor,
    dst: torch.Tensor,
    *,
    iterations: int = 1,
    chunk: int = 512,
) -> HomographyCovariance:
    """Unscented-transform covariance of dst_H_src from its n inlier correspondences (n >= 5).

    Args:
        dst_H_src: (3, 3) estimate (prev_H_cur).
        src, dst: (n, 2) inlier correspondences (current, previous pixels).
        iterations: re-estimation applied to each sigma point, started from dst_H_src: 1 is one
            Gauss-Newton step of the reprojection-error fit (all sigma points share its Jacobian,
            so the 4n + 1 fits cost one matrix product); more runs that many Levenberg-Marquardt
            steps per sigma point (batched in chunks), which only matters for large noise.
        chunk: sigma points per batch when iterations > 1.
    """
    n = src.shape[0]
    if n < 5:
        msg = f'the homography covariance needs at least 5 inliers, got {n}.'
        raise ValueError(msg)
    H = dst_H_src.to(_F64)
    H = H / H[2, 2]
    s64, d64 = src.to(_F64), dst.to(_F64)
    sn, ts = normalize_points(s64)
    dn, td = normalize_points(d64)
    scale_d = td[0, 0]
    hn = _h8((td @ H @ torch.linalg.inv(ts))[None])        # (1, 8)
    r, J = _residuals_jacobian(hn, sn[None], dn[None])      # (1, 2n), (1, 2n, 8); pixels * scale_d
    sigma2 = float((r**2).sum() / (scale_d**2 * n))         # (4.40), pixels**2
    c = (_L_PLUS_KAPPA * sigma2 / 2.0) ** 0.5               # sqrt((L + kappa) P), (4.41, 4.42)
    m = 2 * n
    if iterations <= 1:
        # One Gauss-Newton step from H for every sigma point: delta_i = (J^T J)^-1 J^T r_i, with
        # r_{j+-} = r_0 +- c e_j (state = dst coordinates ordered (x_1, y_1, x_2, ...) like r).
        jt = J[0].T
        K = torch.linalg.solve(jt @ J[0], jt)  # 8, 2n
        d0 = K @ r[0]
        dj = (c * scale_d) * K.T                            # (2n, 8)
        deltas = torch.cat([d0[None], d0[None] + dj, d0[None] - dj], 0)
        Hn_all = _H3(hn + deltas)  # 4n + 1, 3, 3
        gammas = _h8(_denormalize(Hn_all, ts[None], td[None]))
    else:
        eye = torch.eye(m, dtype=_F64, device=s64.device) * c
        offsets = torch.cat([torch.zeros(1, m, dtype=_F64, device=s64.device), eye, -eye], 0)  # (4n+1, 2n)
        out = []
        for a in range(0, offsets.shape[0], chunk):
            o = offsets[a:a + chunk]
            chi = d64[None] + o.view(-1, n, 2)                            # (b, n, 2)
            b = chi.shape[0]
            Hs = refine_lm(s64[None].expand(b, n, 2), chi, H[None].expand(b, 3, 3), iterations=iterations)
            out.append(_h8(Hs))
        gammas = torch.cat(out, 0)
    dev = gammas[1:] - gammas[:1]
    w = 1.0 / (2.0 * _L_PLUS_KAPPA)
    cov = w * dev.T @ dev                                   # (4.43) with UT weights
    return HomographyCovariance(0.5 * (cov + cov.T), sigma2**0.5, 2 * m + 1)
