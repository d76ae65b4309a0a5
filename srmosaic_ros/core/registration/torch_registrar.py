"""TorchRegistrar: frame-to-frame homographies as torch tensor ops, on the CPU or a GPU.

Same interface as the OpenCV `Registrar` (describe once per frame, register consecutive pairs,
callers cache Features) and the same `Registration` result, with `covariance` filled. The steps
follow Table 1 of the reference, with a direct photometric refinement on top:

1. describe: luminance pyramid (slightly smoothed); DoH keypoints with sub-pixel positions,
   orientations and RootSIFT descriptors on the detection level (half resolution by default,
   the 250 strongest; the other candidates are kept); the photometric template of the frame
   (high-gradient pixels, steepest-descent images) on the refinement levels (full resolution).
2. putative matches: mutual nearest neighbours that pass the ratio test.
3. batched RANSAC on 4-point normalised DLT hypotheses, adaptive number of rounds.
4. guided matching with the linear fit (normalised DLT) of the RANSAC inliers, then
5. Levenberg-Marquardt on the reprojection error of all inliers; 4 and 5 again while the
   inlier set grows.
6. covariance of h (h22 = 1) by the unscented transform of the inlier residuals (4.40 to 4.43),
   i.e. of the feature estimate. When the photometric refinement below is applied, the returned
   covariance is instead that of the refined estimate (Gauss-Newton, torch_refine), several
   times tighter: drift control and the georeferencing filter weigh the chain by it.
7. inverse-compositional Lucas-Kanade on the intensities (coarse to fine if several levels are
   configured), from the feature estimate: the sub-pixel accuracy that super-resolution needs. The template is the frame with
   the finer ground sampling (both frames' templates are cached). A refinement that moves a frame
   corner by more than max_refine_shift_px from the feature estimate is discarded (the feature
   estimate is returned, extras['refined'] = 0), unless it converged, moves no corner by more than
   max_refine_shift_converged_px and still explains the feature inliers (their reprojection RMS at
   most 1.25 x theirs under the feature estimate + 0.05 px): at scale changes near 1.5 the feature
   estimate extrapolates 2 to 4 px wrong to the frame corners, and the refinement is then right.
8. failure is explicit: too few keypoints / matches / inliers, low inlier ratio, high residual,
   or an implausible homography (validity.check_homography) give ok = False and the reason. A pair
   that fails for too few matches or inliers is first retried once with more keypoints (up to
   RegistrationConfig.max_features, described from the cached candidates of both frames).

Every tensor lives on the device resolved once from `device` (core.device.resolve_device); on a GPU
the estimation on correspondences (steps 3 to 6: a few hundred points, float64, many tiny kernels
that would each cost a launch) runs on the host unless options.estimation_on_host is False.
Convention: prev_H_cur maps current-frame pixels to previous-frame pixels, x right, y down, pixel
centres at integers.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
import torch

from ...errors import RegistrationError
from ..device import resolve_device
from ..homography import corner_shift_px
from ..settings import check_settings, setting
from .covariance import homography_covariance_ut
from .registrar import Features, Registration, RegistrationConfig
from .static_describe import StaticDescriber
from .torch_features import (
    FeatureOptions,
    KeypointSet,
    ScaleSpaceCandidates,
    build_pyramid,
    concat_keypoints,
    describe_candidates,
    detect,
    image_to_gray_tensor,
)
from .torch_matching import descriptor_sq_distances, guided_matches, mutual_ratio_matches, transfer_points
from .torch_ransac import dlt_homography, ransac_homography, refine_lm
from .torch_refine import (
    PhotometricOptions,
    PhotometricResult,
    PhotometricTemplate,
    inverse_covariance,
    make_template,
    refine_photometric,
)
from .validity import check_homography

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = ['TorchFeatures', 'TorchRegistrar', 'TorchRegistrarOptions']

_LM_TOL = 1e-8              # relative cost decrease at which Levenberg-Marquardt stops
_GUIDED_MIN_GROWTH = 0.05   # guided matching iterates while the inlier set grows by more than this
#: track: the least share of the template that must land inside the other frame
TRACK_MIN_VALID = 0.75


@dataclass(frozen=True)
class TorchRegistrarOptions:
    """Settings of the torch registrar beyond RegistrationConfig (which it honours as well).

    features: detector / descriptor settings; the keypoint count is the smaller of
        features.max_keypoints and RegistrationConfig.max_features.
    photometric: refinement settings, None to return the feature estimate.
    pyramid_sigma: Gaussian blur (pixels) of the full-resolution luminance before the pyramid;
        it tames aliasing and noise for the photometric refinement.
    ransac_batch: hypotheses scored at once per RANSAC round.
    lm_iterations: Levenberg-Marquardt steps per re-estimation.
    guided_rounds: guided matching + re-estimation rounds at most (stops when inliers stop growing).
    covariance: compute the UT covariance; covariance_iterations: re-estimation steps per sigma
        point (1: one Gauss-Newton step, see covariance.homography_covariance_ut).
    max_refine_shift_px: largest corner shift the photometric refinement may apply to the feature
        estimate before it is distrusted; max_refine_shift_converged_px: the same for a refinement
        that converged and still fits the feature inliers (see the module docstring, step 7).
    estimation_on_host: on a GPU device, run the estimation on correspondences (RANSAC, LM,
        covariance: a few hundred points, float64, hundreds of tiny kernels) on the CPU; images,
        features, matching and the photometric refinement stay on the GPU. No effect on the CPU.
    static_shapes: describe with fixed tensor shapes (static_describe.py: no host synchronisation
        inside describe); None: on a GPU only. cuda_graphs: there, record describe as a CUDA graph
        per frame size and replay it (one launch instead of some 800); off by default: not yet
        verified on a GPU (bench/device_check.sh, test_cuda_graph_describe_matches_eager_and_registers).
        static_candidates: scale-space candidates kept per octave with fixed shapes (the strongest;
        640x480 frames have 400 to 550).
    seed: RANSAC sampling seed (reset at every register call: results do not depend on history).
    track_radius_px: the largest corner move from the prediction that :meth:`TorchRegistrar.track`
        accepts (pixels of the registered level): the full-resolution refinement's basin is a few
        pixels, a larger move means the prediction was outside it.
    """

    features: FeatureOptions = field(default_factory=FeatureOptions)
    photometric: PhotometricOptions | None = field(default_factory=PhotometricOptions)
    pyramid_sigma: float = setting(1.25, lo=0.0, hi=3.0)
    ransac_batch: int = setting(256, lo=8)
    lm_iterations: int = setting(10, lo=1)
    guided_rounds: int = setting(2, lo=0)
    covariance: bool = True
    covariance_iterations: int = setting(1, lo=1)
    max_refine_shift_px: float = setting(2.0, gt=0.0)
    max_refine_shift_converged_px: float = 6.0
    estimation_on_host: bool = True
    static_shapes: bool | None = None
    cuda_graphs: bool = False
    static_candidates: int = setting(2048, lo=16)
    seed: int = 0
    track_radius_px: float = setting(4.0, gt=0.0)

    def __post_init__(self) -> None:
        check_settings(self, 'torch registrar')
        if not self.max_refine_shift_converged_px >= self.max_refine_shift_px:
            msg = (f'invalid torch registrar settings: max_refine_shift_converged_px={self.max_refine_shift_converged_px!r} '
                   f'is below max_refine_shift_px={self.max_refine_shift_px!r}.')
            raise ValueError(msg)


@dataclass
class TorchFeatures(Features):
    """Features of one frame for TorchRegistrar: the base fields (numpy copies of keypoints_px
    (N, 2) and descriptors (N, 128), size (w, h)) plus what stays on the device for the next pair:
    keypoints (KeypointSet), the luminance pyramid [(1, 1, h_l, w_l)], the photometric templates
    (coarse to fine) and the scale-space candidates not yet described (the registrar describes
    more of them, once, when a pair fails with the first keypoints; the object is then updated).

    A frame described with ``keypoints=False`` (TorchRegistrar.describe) has its pyramid and
    templates only: keypoints_px, descriptors, keypoints and candidates are None until
    :meth:`ensure_keypoints` detects them on ``detect_level`` with ``feature_options`` (register
    does; a frame that is only tracked never needs them)."""

    keypoints: KeypointSet | None
    pyramid: list[torch.Tensor]
    templates: list[PhotometricTemplate]
    candidates: ScaleSpaceCandidates | None
    detect_level: int = 0
    feature_options: FeatureOptions | None = None

    def __len__(self) -> int:
        self.ensure_keypoints()
        return len(self.keypoints_px)

    def ensure_keypoints(self) -> None:
        """Detect and describe the keypoints of a frame described without them (no-op otherwise)."""
        if self.keypoints is not None:
            return
        assert self.feature_options is not None
        self.candidates = detect(self.pyramid[self.detect_level], self.detect_level, self.feature_options)
        self.keypoints = describe_candidates(self.candidates, 0, self.feature_options.max_keypoints)
        self.keypoints_px = self.keypoints.xy.cpu().numpy()
        self.descriptors = self.keypoints.descriptors.cpu().numpy()

    def extend(self, count: int) -> bool:
        """Describe candidates until `count` keypoints exist; False when none were added."""
        self.ensure_keypoints()
        have = len(self.keypoints)
        if count <= have or len(self.candidates) <= have:
            return False
        more = describe_candidates(self.candidates, have, count)
        self.keypoints = concat_keypoints(self.keypoints, more)
        self.keypoints_px = self.keypoints.xy.cpu().numpy()
        self.descriptors = self.keypoints.descriptors.cpu().numpy()
        return True


def _fail(reason: str, t0: float, matches: int = 0, inliers: int = 0, H: np.ndarray | None = None,
          extras: Mapping[str, float] | None = None) -> Registration:
    return Registration(False, H, matches, inliers, reason=reason, time_s=time.perf_counter() - t0,
                        extras=dict(extras or {}))


class TorchRegistrar:
    """Detects features and registers frame pairs with torch ops. Stateless between calls: callers
    cache the Features of the previous frame (describe once per frame)."""

    #: track() and describe(keypoints=False) exist
    tracks = True

    def __init__(self, config: RegistrationConfig | None = None, *, device: str | torch.device = 'auto',
                 options: TorchRegistrarOptions | None = None) -> None:
        self.config = config or RegistrationConfig()
        self.options = options or TorchRegistrarOptions()
        ph = self.options.photometric
        if ph is not None and ph.loss != self.config.photometric_loss:  # the config names the loss
            self.options = replace(self.options, photometric=replace(ph, loss=self.config.photometric_loss))
        self.device = device if isinstance(device, torch.device) else resolve_device(device)
        f = self.options.features
        if self.config.max_features < f.max_keypoints:
            f = FeatureOptions(**{**f.__dict__, 'max_keypoints': self.config.max_features})
        self._features = f
        ph = self.options.photometric
        self._levels = max([f.detect_level, *(ph.levels if ph else ())]) + 1
        host = self.options.estimation_on_host and self.device.type != 'cpu'
        self._est_device = torch.device('cpu') if host else self.device
        self._generator = torch.Generator(device=self._est_device)
        static = self.options.static_shapes if self.options.static_shapes is not None else self.device.type == 'cuda'
        self._static = StaticDescriber(self._levels, self.options.pyramid_sigma, f, ph,
                                       static_k=max(self.options.static_candidates, f.max_keypoints),
                                       cuda_graphs=self.options.cuda_graphs) if static else None

    def __getstate__(self) -> dict:
        """Picklable (checkpoints): settings and the device name; the generator is rebuilt (it is
        reseeded at every register call, so nothing is lost)."""
        return {'config': self.config, 'options': self.options, 'device': str(self.device)}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state['config'], device=state['device'], options=state['options'])

    def describe(self, image: np.ndarray | torch.Tensor, *, keypoints: bool = True) -> TorchFeatures:
        """Features of a frame: numpy (H, W) / (H, W, 3) uint8, uint16 or float, or a tensor in [0, 1].

        keypoints False: the pyramid and photometric templates only (what :meth:`track` needs); the
        keypoints are detected when a registration first needs them (TorchFeatures.ensure_keypoints).
        Fixed-shape describing (static_shapes) always detects them."""
        gray = image_to_gray_tensor(image, self.device)
        _, _, h, w = gray.shape
        if self._static is not None:
            out = self._static.run(gray)
            kps = out.keypoints
            return TorchFeatures(kps.xy.cpu().numpy(), kps.descriptors.cpu().numpy(), (w, h), kps, out.pyramid,
                                 out.templates, out.candidates)
        pyr = build_pyramid(gray, self._levels, sigma=self.options.pyramid_sigma)
        templates: list[PhotometricTemplate] = []
        ph = self.options.photometric
        if ph is not None:
            for level, points in zip(ph.levels, ph.points, strict=True):
                templates.append(make_template(pyr[level], level, points=points))
        features = TorchFeatures(None, None, (w, h), None, pyr, templates, None,  # type: ignore[arg-type]
                                 detect_level=self._features.level_for(w), feature_options=self._features)
        if keypoints:
            features.ensure_keypoints()
        return features

    def register(self, prev: Features, cur: Features) -> Registration:
        """Estimate prev_H_cur from the features of two frames (both from this registrar's describe).

        A pair that fails for too few matches or inliers is tried once more with up to
        RegistrationConfig.max_features keypoints per frame (described from the cached candidates).
        """
        t0 = time.perf_counter()
        if not isinstance(prev, TorchFeatures) or not isinstance(cur, TorchFeatures):
            msg = ('TorchRegistrar.register needs Features from TorchRegistrar.describe (not from another registrar): '
                   'describe both frames with the registrar that registers them.')
            raise RegistrationError(msg)
        prev.ensure_keypoints()
        cur.ensure_keypoints()
        reg = self._register_once(prev, cur, t0)
        if not reg.ok and reg.reason.startswith('too few') and len(prev.keypoints) >= 4 and len(cur.keypoints) >= 4:
            grew_prev = prev.extend(self.config.max_features)
            grew_cur = cur.extend(self.config.max_features)
            if grew_prev or grew_cur:
                reg = self._register_once(prev, cur, t0)
                reg.extras['retry_keypoints'] = float(min(len(prev.keypoints), len(cur.keypoints)))
        return reg

    def track(self, prev: Features, cur: Features, predicted: np.ndarray, *, max_rms: float) -> Registration:
        """prev_H_cur by the photometric refinement alone (step 7), started from ``predicted`` (3, 3)
        instead of a feature estimate: consecutive video frames whose motion the previous pair
        predicts to within the refinement's basin need no keypoints. The estimate is accepted only
        when the refinement converged, kept at least TRACK_MIN_VALID of its template inside the
        other frame, moved no frame corner more than options.track_radius_px from the prediction
        (beyond that the prediction was outside the basin), left a robust intensity RMS of at most
        ``max_rms`` (the caller's reference: a pair verified by features; a false minimum leaves
        more) and passes validity.check_homography; otherwise ok is False with the reason (callers
        then register the pair by features). The result carries the refinement's covariance,
        extras['tracked'] = 1, no matches or inliers and rms_px NaN (no feature residuals)."""
        t0 = time.perf_counter()
        cfg, ph = self.config, self.options.photometric
        if not isinstance(prev, TorchFeatures) or not isinstance(cur, TorchFeatures):
            msg = 'TorchRegistrar.track needs Features from TorchRegistrar.describe: describe both frames with it.'
            raise RegistrationError(msg)
        if ph is None or prev.size != cur.size or not prev.templates or not cur.templates:
            return _fail('no photometric templates to track with (photometric refinement off or frame sizes differ)', t0)
        H = np.asarray(predicted, dtype=np.float64)
        H = H / H[2, 2]
        w, h = cur.size
        res, H_ref, template_prev = self._refine(prev, cur, H)
        cov = self._refined_covariance(res, template_prev)
        shift = corner_shift_px(H_ref, H, w, h) if np.all(np.isfinite(H_ref)) else float('inf')
        extras = {'tracked': 1.0, 'refined': 1.0, 'photometric_iterations': float(res.iterations),
                  'photometric_rms': res.rms, 'photometric_valid': res.valid_fraction, 'track_shift_px': shift}
        radius = self.options.track_radius_px
        if not res.converged:
            reason = f'photometric tracking did not converge in {res.iterations} iterations'
        elif res.valid_fraction < TRACK_MIN_VALID:
            reason = f'only {res.valid_fraction:.0%} of the template inside the other frame'
        elif shift > radius:
            reason = f'tracking moved the frame {shift:.1f} px from the prediction (more than {radius:g} px)'
        elif not res.rms <= max_rms:
            reason = f'tracking residual {res.rms:.4f} above {max_rms:.4f}'
        elif self.options.covariance and cov is None:
            reason = 'tracking left the estimate without a covariance'
        else:
            reason = check_homography(H_ref, w, h, max_scale_change=cfg.max_scale_change,
                                      max_perspective=cfg.max_perspective)
        if reason:
            return Registration(False, H_ref, 0, 0, float('nan'), reason, None, time.perf_counter() - t0, extras)
        return Registration(True, H_ref, 0, 0, float('nan'), '', cov if self.options.covariance else None,
                            time.perf_counter() - t0, extras)

    def _refine(self, prev: TorchFeatures, cur: TorchFeatures, H: np.ndarray) -> tuple[PhotometricResult, np.ndarray, bool]:
        """(result, prev_H_cur refined (h22 = 1), whether prev was the template) of the photometric
        refinement from prev_H_cur ``H``. Template = the frame with the finer ground sampling
        (prev_H_cur scales up: prev), so that the other is sampled densely."""
        ph = self.options.photometric
        assert ph is not None
        template_prev = float(np.sqrt(abs(np.linalg.det(H[:2, :2])))) > 1.0
        if template_prev:
            res = refine_photometric(cur.pyramid, prev.templates, np.linalg.inv(H), ph)
            H_ref = np.linalg.inv(res.image_H_template)
        else:
            res = refine_photometric(prev.pyramid, cur.templates, H, ph)
            H_ref = res.image_H_template
        return res, H_ref / H_ref[2, 2], template_prev

    @staticmethod
    def _refined_covariance(res: PhotometricResult, template_prev: bool) -> np.ndarray | None:
        """(8, 8) covariance of the refined prev_H_cur's h, from the refinement's (of image_H_template)."""
        if res.covariance is None or not template_prev:
            return res.covariance
        return inverse_covariance(res.image_H_template, res.covariance)

    def _refinement_trusted(self, shift: float, converged: bool, H_ref: np.ndarray, src: torch.Tensor,
                            dst: torch.Tensor, rms_feat: float) -> bool:
        """Whether the photometric estimate replaces the feature one (module docstring, step 7)."""
        opt = self.options
        if shift <= opt.max_refine_shift_px:
            return True
        if not (converged and shift <= opt.max_refine_shift_converged_px):
            return False
        h = torch.as_tensor(H_ref, dtype=torch.float64, device=src.device)
        rms_ref = float(((transfer_points(h, src) - dst) ** 2).sum(-1).mean().sqrt())
        return rms_ref <= 1.25 * rms_feat + 0.05

    def _register_once(self, prev: TorchFeatures, cur: TorchFeatures, t0: float) -> Registration:
        cfg, opt = self.config, self.options
        kp, kc = prev.keypoints, cur.keypoints
        if len(kp) < 4 or len(kc) < 4:
            return _fail(f'too few keypoints ({len(kp)} previous, {len(kc)} current); textureless frame '
                         '(sea, cloud) or too dark', t0)
        dd = descriptor_sq_distances(kc.descriptors, kp.descriptors)
        pi, ci, _ = mutual_ratio_matches(kp.descriptors, kc.descriptors, ratio=cfg.ratio, sq_dist=dd)
        n_matches = int(pi.numel())
        if n_matches < max(cfg.min_inliers, 4):
            return _fail(f'too few matches ({n_matches} < {cfg.min_inliers}); textureless frame or too '
                         'little overlap', t0, n_matches)
        edev = self._est_device
        src, dst = kc.xy[ci].to(edev), kp.xy[pi].to(edev)
        self._generator.manual_seed(opt.seed)
        rs = ransac_homography(src, dst, threshold_px=cfg.ransac_threshold_px, confidence=cfg.ransac_confidence,
                               max_iterations=cfg.ransac_max_iterations, batch_size=opt.ransac_batch,
                               generator=self._generator)
        n_inl = int(rs.inliers.sum())
        extras = {'putative_matches': float(n_matches), 'ransac_hypotheses': float(rs.iterations)}
        if rs.dst_H_src is None or n_inl < max(cfg.min_inliers, 5):
            return _fail(f'too few inliers ({n_inl} < {cfg.min_inliers}) after RANSAC; unrelated frames or '
                         'too little overlap', t0, n_matches, n_inl, extras=extras)
        # Guided matching (step 5) with the linear (normalised DLT) fit of the RANSAC inliers, then
        # the maximum-likelihood re-estimation (step 4, Levenberg-Marquardt), again while inliers grow.
        t2 = cfg.ransac_threshold_px**2
        src, dst = src[rs.inliers].to(torch.float64), dst[rs.inliers].to(torch.float64)
        H = dlt_homography(src, dst)
        lm_done = False
        for _ in range(opt.guided_rounds if cfg.guided_radius_px > 0 else 0):
            gp, gc, gdist = guided_matches(kp.xy, kc.xy, kp.descriptors, kc.descriptors, H.to(self.device),
                                           radius_px=cfg.guided_radius_px, sq_dist=dd)
            ginl = gdist <= cfg.ransac_threshold_px
            n_new = int(ginl.sum())
            if n_new <= src.shape[0]:
                break
            grew = n_new > (1.0 + _GUIDED_MIN_GROWTH) * src.shape[0]
            n_matches = max(n_matches, int(gp.numel()))
            src = kc.xy[gc[ginl]].to(device=edev, dtype=torch.float64)
            dst = kp.xy[gp[ginl]].to(device=edev, dtype=torch.float64)
            H = refine_lm(src, dst, H, iterations=opt.lm_iterations, tol=_LM_TOL)
            lm_done = True
            if not grew:
                break
        if not lm_done:
            H = refine_lm(src, dst, H, iterations=opt.lm_iterations, tol=_LM_TOL)
        err2 = ((transfer_points(H, src) - dst) ** 2).sum(-1)
        keep = err2 <= t2
        src, dst = src[keep], dst[keep]
        n_inl = int(keep.sum())
        H_feat = (H / H[2, 2]).cpu().numpy()
        rms_feat = float(err2[keep].mean().sqrt()) if n_inl else float('nan')
        extras['feature_rms_px'] = rms_feat
        w, h = cur.size
        reason = ''
        if n_inl < max(cfg.min_inliers, 5):
            reason = f'too few inliers ({n_inl} < {cfg.min_inliers})'
        elif n_inl < cfg.min_inlier_ratio * n_matches:
            reason = f'inlier ratio {n_inl / n_matches:.2f} below {cfg.min_inlier_ratio:.2f}'
        elif rms_feat > cfg.max_rms_px:
            reason = f'inlier RMS {rms_feat:.2f} px above {cfg.max_rms_px:.2f} px'
        else:
            reason = check_homography(H_feat, w, h, max_scale_change=cfg.max_scale_change,
                                      max_perspective=cfg.max_perspective)
        if reason:
            return Registration(False, H_feat, n_matches, n_inl, rms_feat, reason, None, time.perf_counter() - t0,
                                extras)
        cov = None
        H_out = H_feat
        extras['refined'] = 0.0
        ph = opt.photometric
        if ph is not None and prev.size == cur.size and cur.templates and prev.templates:
            res, H_ref, template_prev = self._refine(prev, cur, H_feat)
            shift = corner_shift_px(H_ref, H_feat, w, h) if np.all(np.isfinite(H_ref)) else float('inf')
            extras.update(photometric_iterations=float(res.iterations), photometric_rms=res.rms,
                          photometric_valid=res.valid_fraction, refine_shift_px=shift,
                          photometric_template_prev=float(template_prev))
            if self._refinement_trusted(shift, res.converged, H_ref, src, dst, rms_feat) and not check_homography(
                    H_ref, w, h, max_scale_change=cfg.max_scale_change, max_perspective=cfg.max_perspective):
                H_out = H_ref
                extras['refined'] = 1.0
                if opt.covariance and res.covariance is not None:
                    # The returned estimate is the photometric one: its Gauss-Newton covariance
                    # (the feature covariance above bounds it from above).
                    cov = self._refined_covariance(res, template_prev)
                    extras['covariance_from'] = 1.0
        if opt.covariance and cov is None:
            # The feature estimate is returned (or the refinement gave no covariance): its UT
            # covariance from the inlier residuals (eqs. 4.40-4.43). Not computed when the
            # refinement's own covariance replaces it.
            c = homography_covariance_ut(H, src, dst, iterations=opt.covariance_iterations)
            cov = c.covariance.cpu().numpy()
            extras['sigma_px'] = c.sigma_px
        Ht = torch.as_tensor(H_out, dtype=torch.float64, device=src.device)
        rms = float(((transfer_points(Ht, src) - dst) ** 2).sum(-1).mean().sqrt())
        return Registration(True, H_out, n_matches, n_inl, rms, '', cov, time.perf_counter() - t0, extras)
