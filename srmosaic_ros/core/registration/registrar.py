"""Registrar: the homography between consecutive frames (Table 1 of the reference), with OpenCV.

SIFT keypoints (sub-pixel by construction), ratio-test + mutual nearest-neighbour matching,
MAGSAC++ robust estimation, least-squares re-estimation on all inliers (Levenberg-Marquardt on the
reprojection error, inside cv2.findHomography), one round of guided matching with the estimate.
This is the CPU-only 'opencv' backend and FallbackRegistrar's second opinion; TorchRegistrar
(torch_registrar.py) implements the same interface with torch tensor ops.

Convention: prev_H_cur maps current-frame pixels to previous-frame pixels, x right, y down, pixel
centres at integers.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, fields

import cv2
import numpy as np

from ..homography import apply_homography
from ..image_ops import to_gray_u8
from ..settings import check_settings, setting
from .validity import check_homography

__all__ = ['BACKENDS', 'Features', 'Registrar', 'Registration', 'RegistrationConfig']

#: Registration implementations selectable with `registration.backend`.
BACKENDS = ('torch', 'opencv')


@dataclass(frozen=True)
class RegistrationConfig:
    """Registration settings; the field names are the keys under `registration.` in params/*.yaml.

    backend: 'torch' (TorchRegistrar: torch tensor ops on the pipeline's device, photometric
    refinement, homography covariance) or 'opencv' (Registrar: OpenCV SIFT + MAGSAC++, CPU only,
    no covariance). opencv_fallback: with the torch backend, register a pair that fails once more
    with the OpenCV registrar (FallbackRegistrar). See make_registrar. max_width: the pipeline
    registers frames wider than this on the pyramid level that brings them to it or less
    (pyramid.PyramidRegistrar; 0: full size); the pixel thresholds are then in pixels of that level.
    photometric_loss: the torch backend's photometric refinement loss, 'huber' or 'tukey' (torch_refine).
    track_frames: the pipeline registers consecutive video frames by photometric tracking alone
    (torch backend: TorchRegistrar.track, from the previous pair's motion; tracking.py) for up to
    this many pairs in a row minus one, then one pair by features again; 0 or 1: every pair by
    features. The opencv backend does not track.
    """

    backend: str = setting('torch', choices=BACKENDS)
    opencv_fallback: bool = True
    max_features: int = setting(1000, lo=8, hi=100000)
    contrast_threshold: float = setting(0.02, gt=0.0, lt=1.0)
    ratio: float = setting(0.8, gt=0.0, hi=1.0)
    ransac_threshold_px: float = setting(1.5, lo=0.01, hi=50.0, unit='px')
    ransac_confidence: float = setting(0.999, lo=0.5, hi=0.999999)
    ransac_max_iterations: int = setting(5000, lo=1, hi=1000000)
    min_inliers: int = setting(15, lo=4, hi=100000)
    min_inlier_ratio: float = setting(0.15, lo=0.0, hi=1.0)
    max_rms_px: float = setting(1.5, lo=0.01, hi=50.0, unit='px')
    max_scale_change: float = setting(1.6, lo=1.0, hi=10.0)
    max_perspective: float = setting(0.3, lo=0.001, hi=10.0)
    guided_radius_px: float = setting(3.0, lo=0.0, hi=100.0, unit='px')
    max_width: int = setting(1280, lo=64, hi=100000, zero=True, unit='px')
    photometric_loss: str = setting('huber', choices=('huber', 'tukey'))
    track_frames: int = setting(10, lo=0, hi=100000)

    def __post_init__(self) -> None:
        check_settings(self, 'registration')

    @classmethod
    def keys(cls) -> list[str]:
        return [f.name for f in fields(cls)]


@dataclass
class Features:
    """Keypoints and descriptors of one frame.

    keypoints_px: (N, 2) float32 (x, y) pixel positions; descriptors: (N, D) float32;
    size: (width, height) of the frame.
    """

    keypoints_px: np.ndarray
    descriptors: np.ndarray
    size: tuple[int, int]

    def __len__(self) -> int:
        return len(self.keypoints_px)


@dataclass(frozen=True)
class Registration:
    """Result of registering the current frame to the previous one.

    prev_H_cur: (3, 3) float64, current pixels -> previous pixels (None when ok is False and no
    estimate exists). covariance: (8, 8) covariance of (h00..h21) with h22 = 1, or None when the
    registrar does not estimate it. rms_px: RMS transfer error of the inliers in pixels.
    """

    ok: bool
    prev_H_cur: np.ndarray | None
    matches: int = 0
    inliers: int = 0
    rms_px: float = float('nan')
    reason: str = ''
    covariance: np.ndarray | None = None
    time_s: float = 0.0
    extras: dict[str, float] = field(default_factory=dict)


class Registrar:
    """Detects features and registers frame pairs. Stateless between calls: callers cache Features."""

    def __init__(self, config: RegistrationConfig | None = None) -> None:
        self.config = config or RegistrationConfig()
        self._make_tools()

    def _make_tools(self) -> None:
        self._sift = cv2.SIFT_create(nfeatures=self.config.max_features,
                                     contrastThreshold=self.config.contrast_threshold)
        self._matcher = cv2.BFMatcher(cv2.NORM_L2)

    def __getstate__(self) -> dict:
        """Picklable (checkpoints): the OpenCV objects are rebuilt from the config."""
        return {'config': self.config}

    def __setstate__(self, state: dict) -> None:
        self.config = state['config']
        self._make_tools()

    def describe(self, image: np.ndarray) -> Features:
        """Features of an edge image ((H, W) or (H, W, 3), uint8/uint16/float)."""
        gray = to_gray_u8(image)
        kps, desc = self._sift.detectAndCompute(gray, None)
        pts = np.array([kp.pt for kp in kps], dtype=np.float32).reshape(-1, 2)
        if desc is None:
            desc = np.zeros((0, 128), dtype=np.float32)
        return Features(pts, desc.astype(np.float32), (gray.shape[1], gray.shape[0]))

    def _putative(self, prev: Features, cur: Features) -> tuple[np.ndarray, np.ndarray]:
        """Ratio-test matches that are also mutual nearest neighbours: (M,) prev and cur indices."""
        if len(prev) < 2 or len(cur) < 2:
            return np.zeros(0, int), np.zeros(0, int)
        fwd = self._matcher.knnMatch(cur.descriptors, prev.descriptors, k=2)
        bwd = self._matcher.match(prev.descriptors, cur.descriptors)
        back = {m.queryIdx: m.trainIdx for m in bwd}
        ci, pi = [], []
        for pair in fwd:
            if len(pair) < 2:
                continue
            best, second = pair
            if best.distance < self.config.ratio * second.distance and back.get(best.trainIdx) == best.queryIdx:
                ci.append(best.queryIdx)
                pi.append(best.trainIdx)
        return np.asarray(pi, int), np.asarray(ci, int)

    def _guided(self, prev: Features, cur: Features, prev_H_cur: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Guided matching (Table 1, step 5): nearest descriptor among prev keypoints within a radius of the transfer."""
        from scipy.spatial import cKDTree

        radius = self.config.guided_radius_px
        pred = apply_homography(prev_H_cur, cur.keypoints_px.astype(np.float64))
        tree = cKDTree(prev.keypoints_px.astype(np.float64))
        # Candidate pairs (cur i, prev j) whose transferred positions are within the radius.
        pairs = tree.query_ball_point(pred, r=radius)
        ci = np.repeat(np.arange(len(pairs)), [len(p) for p in pairs])
        if len(ci) == 0:
            return np.zeros(0, int), np.zeros(0, int)
        pj = np.fromiter((j for p in pairs for j in p), dtype=int, count=len(ci))
        dist = ((cur.descriptors[ci] - prev.descriptors[pj]) ** 2).sum(axis=1)
        # Per current keypoint, the closest descriptor; then each previous keypoint used once.
        order = np.lexsort((dist, ci))
        first_c = order[np.r_[True, ci[order][1:] != ci[order][:-1]]]
        ci, pj, dist = ci[first_c], pj[first_c], dist[first_c]
        order = np.argsort(dist)
        _, first_p = np.unique(pj[order], return_index=True)
        sel = order[first_p]
        return pj[sel], ci[sel]

    def register(self, prev: Features, cur: Features) -> Registration:
        """Estimate prev_H_cur from the features of two frames."""
        t0 = time.perf_counter()
        cfg = self.config
        pi, ci = self._putative(prev, cur)
        n_matches = len(pi)
        if n_matches < max(cfg.min_inliers, 4):
            return Registration(False, None, n_matches, 0, reason=f'too few matches ({n_matches} < {cfg.min_inliers}); '
                                'textureless frame or too little overlap', time_s=time.perf_counter() - t0)
        src = cur.keypoints_px[ci].astype(np.float64)
        dst = prev.keypoints_px[pi].astype(np.float64)
        H, mask = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, cfg.ransac_threshold_px,
                                     maxIters=cfg.ransac_max_iterations, confidence=cfg.ransac_confidence)
        if H is None or mask is None:
            return Registration(False, None, n_matches, 0, reason='robust estimation found no consensus',
                                time_s=time.perf_counter() - t0)
        inl = mask.ravel().astype(bool)
        # Optimal estimation (Table 1, step 4) and guided matching (step 5), iterated while the
        # inlier set grows.
        for _ in range(3):
            if inl.sum() < 4:
                break
            H_ls, _ = cv2.findHomography(src[inl], dst[inl], 0)
            if H_ls is not None:
                H = H_ls
            if cfg.guided_radius_px <= 0:
                break
            gpi, gci = self._guided(prev, cur, H)
            if len(gpi) < 4:
                break
            gsrc = cur.keypoints_px[gci].astype(np.float64)
            gdst = prev.keypoints_px[gpi].astype(np.float64)
            err = np.linalg.norm(apply_homography(H, gsrc) - gdst, axis=1)
            ginl = err <= cfg.ransac_threshold_px
            if ginl.sum() <= inl.sum():
                break
            src, dst, inl = gsrc, gdst, ginl
            n_matches = max(n_matches, len(gpi))
        H = H / H[2, 2]
        err = np.linalg.norm(apply_homography(H, src[inl]) - dst[inl], axis=1)
        n_inl = int(inl.sum())
        rms = float(np.sqrt(np.mean(err ** 2))) if n_inl else float('nan')
        reason = ''
        if n_inl < cfg.min_inliers:
            reason = f'too few inliers ({n_inl} < {cfg.min_inliers})'
        elif n_inl < cfg.min_inlier_ratio * n_matches:
            reason = f'inlier ratio {n_inl / n_matches:.2f} below {cfg.min_inlier_ratio:.2f}'
        elif rms > cfg.max_rms_px:
            reason = f'inlier RMS {rms:.2f} px above {cfg.max_rms_px:.2f} px'
        else:
            reason = check_homography(H, cur.size[0], cur.size[1], max_scale_change=cfg.max_scale_change,
                                      max_perspective=cfg.max_perspective)
        return Registration(not reason, H, n_matches, n_inl, rms, reason, None, time.perf_counter() - t0)
