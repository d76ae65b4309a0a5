"""The settings of one tile's super-resolution (:class:`SRConfig`, the ``sr.*`` keys) and its errors."""
from __future__ import annotations

from dataclasses import dataclass

from ...errors import SrMosaicError
from ..settings import Bounds, check_settings, setting
from .modes import ALIGN_MODES, CLAMP_MODES, FLOW_MODES, LAMBDA_MODES, ROBUST_NORMS, SOLVERS, WARP_MODES

__all__ = ['COLOR_MODES', 'SRConfig', 'SRError', 'SRFramesDisagree']

COLOR_MODES = ('luma', 'rgb')


class SRError(SrMosaicError):
    """A super-resolution request cannot be served (no frame covers the tile, bad shapes...)."""


class SRFramesDisagree(SRError):
    """Fewer than two of a tile's frames see the same picture (core/sr/consistency.py): the tile is
    left to the mosaic. Expected over 3-D ground or motion; counted apart from real errors."""


@dataclass(frozen=True)
class SRConfig:
    """Settings of :func:`reconstruct_tile` (the keys of the ``sr`` parameter block).

    psf_sigma: std of the Gaussian PSF in LR (frame) pixels; the HR kernel has std
        ``psf_sigma * factor`` (ignored when ``psf`` is given to :func:`reconstruct_tile`).
    psf_ladder: sigmas from which ``srmosaic process --sr`` chooses the flight's PSF by predicting
        held-out frames (core/sr/psf_select.py); empty: ``psf_sigma`` as given. Not read by
        :func:`reconstruct_tile` itself.
    solver: 'sd' | 'cg' | 'lm'.  iterations: cap.  tol: stop when ||x_{n+1} - x_n|| / ||x_n|| < tol.
    lambda_mode: 'adaptive' (5.6, normalised) | 'fixed' (``lam``) | 'paper' (5.6 as printed).
    lambda_gamma, lambda_reference: the adaptive lambda at iteration n is::

            lambda(n) = lambda_gamma / s^2 * sigma(n)^2 / rho0

        sigma(n) the weighted mean RMS residual of the frames at the current iterate (the numerator
        of (5.6)) and rho0 the mean Huber activity per clique of the initial estimate (the
        interpolated mosaic) when ``lambda_reference='initial'``; the s^2 undoes the smoothing of
        the bicubic upsampling (HR second differences are about 1/s^2 of the LR ones), so
        s^2 rho0 measures the scene's activity at the frames' resolution. With
        ``lambda_reference='current'`` rho0 is the activity of the current iterate, as (5.6) reads,
        and the gamma is ``lambda_gamma / s`` (its own calibration): it collapses on sharp scenes
        (see :class:`~srmosaic_ros.core.sr.solvers.LambdaRule`). On simulated frames the
        best fixed lambda lies at 0.05 to 0.23 times sigma^2 / (s^2 rho0) over scenes, factors 2
        and 4 and noise 0 to 5 (bench/sr.py compares the rule with the best fixed lambda of each);
        real video wants more: its frames' compression is spatially correlated, the solve fits it
        and sigma(n) falls with it, so lambda_gamma = 0.3 (bench/sr_video.py on two real videos;
        on simulated tiles 0.3 loses at most a tenth of a dB to 0.1, docs/results.md).
    lambda_noise_cap: in the adaptive modes, the frames' RMS residuals in sigma(n) are capped at
        this many times their noise std (Immerkaer's estimate on the frames, core/sr/consistency.py);
        0: not capped (the default: (5.6) as it reads). Where the model fits the residual is below
        the noise and the cap changes nothing; on real frames it is several times the noise and the
        cap lowers lambda, which real footage does not want (bench/sr_video.py, bench/sr_real.py).
    huber_alpha: Huber threshold (intensity, [0, 1]).
    color: 'luma' | 'rgb' (see the module docstring).  margin: LR pixels reconstructed around the
        tile and cut away (the tile's border then sees as many frames as its interior).
    robust: per-frame outlier weights.  reweight_at: iterations after which they are re-estimated.
    outlier_threshold, outlier_power: the weight rule.  device: 'auto' | 'cpu' | 'cuda'.
    consistency: frames that do not see the same picture on the tile are left out before the solve
        (pairwise NCC below this fraction of what their noise allows; core/sr/consistency.py), and
        a tile where fewer than two agree is refused (SRError); 0 turns the test off.
    self_check: frames held out per tile to check that SR predicts them better than the mosaic
        (core/sr/self_check.py: a tile that does not is left to the mosaic); 0: no check (the
        default: on real video the check's verdict does not follow the tiles' gain, docs/results.md). Read
        by :func:`~srmosaic_ros.core.sr.self_check.reconstruct_checked_tile`, not by reconstruct_tile.
    fallback: frames held out per tile by `process --sr` to decide between SR and the best frame's
        upsampling (core/sr/fallback.py: a tile whose SR predicts them no better than that frame shows
        the frame upsampled, and says so in tiles.json); 0: only tiles SR cannot serve fall back. Read
        by :func:`~srmosaic_ros.core.sr.fallback.super_resolve_or_fallback`, not by reconstruct_tile.
    moving: frames' LR pixels that differ from the per-pixel median of the frames on the tile by
        more than this (intensity; core/sr/moving.py) saw something move and weigh 0 in the data
        term and the initial estimate; 0: off.
    local_align: each frame aligned to the reference on the tile before the solve ('affine',
        'translation' or 'off'; core/sr/local_align.py); local_align_max_px: the largest correction
        applied (LR pixels at the tile's corners).
    photometric: each frame's exposure and white balance matched to the reference's on the tile
        (gain and offset per channel; core/sr/local_align.py).
    warp: the interpolation of W_k in the observation model (operators.WARP_MODES): 'bilinear', or
        'bicubic', whose response falls less towards the HR Nyquist (the model then blurs less than
        the resampling it stands for); twice the warp's cost.
    dense_flow: after the ECC alignment, a dense residual flow of each frame to the reference on the
        tile (core/sr/dense_flow.py; a DIS preset or 'off') moves the warp's sampling points per pixel,
        and the flows' forward-backward consistency weights the frame's pixels in the data term;
        dense_flow_max_px clips the flow (LR px), dense_flow_smooth smooths it (Gaussian std, LR px),
        dense_flow_fb_px is the forward-backward disagreement at which a pixel's weight falls to 1/e.
    robust_pixels: the robust data term (core/sr/robust_pixels.py): 'huber' or 'lorentzian' per-pixel
        IRLS weights of the frames' residuals, re-estimated at the ``reweight_at`` iterations (the
        solve restarts there), so that moving objects, occlusions and misregistered pixels stop
        pulling the estimate; 'off': least squares. robust_pixels_scale: the norm's threshold in
        robust stds of the residual (at least the frames' noise std).
    lm_inner: inner CG iterations of LM.
    anchor: after the solve, the reference frame's residual is back-projected onto the estimate
        (core/sr/anchor.py), so the tile shows what the mosaic around it shows (the same moving
        objects, the same side of a building, its colour; module docstring) with the detail the
        fusion recovered. A tile whose reference the consistency test or the robust weights
        (below 0.5) set aside is refused (SRFramesDisagree): fused from the others, it would
        disagree with the mosaic around it.
    anchor_noise: the reference's residual (and colour difference) is shrunk by this many noise
        stds first, scaled down where it is several times the noise (anchor.py
        ``structure_threshold``); 0: the tile takes the reference's band exactly.
    anchor_compression: the threshold is also scaled down where the reference's residual is
        spatially correlated (what compression leaves; anchor.py): the tile then reproduces the
        reference frame as recorded, its compression included, instead of the ground.
    clamp: each HR pixel of the result kept within the range of the LR pixels around it (the
        frames' average and the reference; core/sr/ringing.py): 'cell' (the 2 x 2 around its LR
        point), 'wide' (4 x 4) or 'off'. Against ringing where the PSF is over-estimated. 'auto' (the
        default): 'cell' for a PSF given here, 'off' where `process --sr` chose the flight's PSF from
        its frames (ringing.resolve_clamp: that choice rules the over-estimated PSF out, and the clamp
        would only cut real detail).
    """

    psf_sigma: float = setting(0.5, lo=0.0, hi=10.0, unit='LR px')
    psf_ladder: tuple[float, ...] = setting((0.2, 0.35, 0.5, 0.7, 0.9), items=Bounds(lo=0.0, hi=10.0))
    solver: str = setting('cg', choices=SOLVERS)
    iterations: int = setting(10, lo=0, hi=10000)
    tol: float = setting(1e-4, lo=0.0)
    lambda_mode: str = setting('adaptive', choices=LAMBDA_MODES)
    lam: float = setting(0.01, lo=0.0)
    lambda_gamma: float = setting(0.3, lo=0.0)
    lambda_reference: str = setting('initial', choices=('initial', 'current'))
    lambda_noise_cap: float = setting(0.0, lo=0.0)
    lambda_noise_floor: float = setting(0.0, lo=0.0)
    huber_alpha: float = setting(0.02, gt=0.0)
    color: str = setting('luma', choices=COLOR_MODES)
    margin: int = setting(4, lo=0, hi=256, unit='LR px')
    robust: bool = True
    reweight_at: tuple[int, ...] = (3, 6)
    outlier_threshold: float = 3.0
    outlier_power: float = 2.0
    consistency: float = setting(0.8, lo=0.0, lt=1.0)
    self_check: int = setting(0, lo=0, hi=8)
    fallback: int = setting(1, lo=0, hi=8)
    moving: float = setting(0.0, lo=0.0, lt=1.0)
    min_observed: int = 16
    lm_inner: int = setting(8, lo=1)
    anchor: bool = True
    anchor_noise: float = setting(2.0, lo=0.0)
    anchor_compression: bool = False
    clamp: str = setting('auto', choices=CLAMP_MODES)
    local_align: str = setting('affine', choices=ALIGN_MODES)
    local_align_max_px: float = setting(1.5, gt=0.0, unit='LR px')
    photometric: bool = True
    warp: str = setting('bilinear', choices=WARP_MODES)
    dense_flow: str = setting('off', choices=FLOW_MODES)
    dense_flow_max_px: float = setting(1.0, gt=0.0, hi=4.0, unit='LR px')
    dense_flow_smooth: float = setting(1.5, lo=0.0, hi=10.0, unit='LR px')
    dense_flow_fb_px: float = setting(0.5, gt=0.0, unit='LR px')
    robust_pixels: str = setting('huber', choices=ROBUST_NORMS)
    robust_pixels_scale: float = setting(3.0, gt=0.0)
    device: str = 'auto'

    def __post_init__(self) -> None:
        try:
            check_settings(self, 'sr')
        except ValueError as exc:
            raise SRError(str(exc)) from None
