"""The one place that turns `registration.backend`, `registration.opencv_fallback` and `device`
into a registrar."""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..image_ops import to_gray_u8
from .registrar import Features, Registrar, Registration, RegistrationConfig
from .torch_registrar import TorchFeatures, TorchRegistrar

__all__ = ['FallbackFeatures', 'FallbackRegistrar', 'make_registrar']


@dataclass
class FallbackFeatures:
    """Features of one frame for FallbackRegistrar: the primary (torch) features, the frame's image
    (kept for the fallback: its grey levels are made only if a pair fails) and, once a pair needed
    it, the OpenCV features (described lazily)."""

    primary: TorchFeatures
    image: np.ndarray
    fallback: Features | None = None

    def __len__(self) -> int:
        return len(self.primary)


class FallbackRegistrar:
    """The torch registrar, with the OpenCV registrar as a second opinion on the pairs it fails.

    Frames are described by the torch registrar only; when a pair fails (too few matches or
    inliers, no consensus, an implausible estimate), both frames are described by OpenCV SIFT
    (once per frame, cached) and the pair is registered again. A pair that the fallback registers
    carries extras['fallback_opencv'] = 1 and no covariance (the OpenCV registrar estimates none);
    one that both fail keeps the torch result and reason, so textureless frames still fail
    explicitly. On the real survey stills (data/sequences/brighton_beach) the torch features find
    too few inliers on one pair (scale 0.91 with 110 px motion) that SIFT registers.
    """

    #: register() takes second_opinion (callers of optional registrations turn it off)
    has_second_opinion = True
    #: track() and describe(keypoints=False) exist (TorchRegistrar.track)
    tracks = True

    def __init__(self, primary: TorchRegistrar, fallback: Registrar) -> None:
        self.primary = primary
        self.fallback = fallback
        self.config = primary.config
        self.device = primary.device

    def describe(self, image: np.ndarray, **kwargs: Any) -> FallbackFeatures:
        """Torch features of a frame ((H, W) or (H, W, 3), uint8/uint16/float), the frame kept
        (kwargs: TorchRegistrar.describe's, e.g. keypoints)."""
        return FallbackFeatures(self.primary.describe(image, **kwargs), image)

    def track(self, prev: FallbackFeatures, cur: FallbackFeatures, predicted: np.ndarray, **kwargs: Any) -> Registration:
        """The torch registrar's photometric tracking (TorchRegistrar.track); no second opinion (a
        pair it fails is registered by register, which has one)."""
        return self.primary.track(prev.primary, cur.primary, predicted, **kwargs)

    def _fallback_features(self, features: FallbackFeatures) -> Features:
        if features.fallback is None:
            features.fallback = self.fallback.describe(to_gray_u8(features.image))
        return features.fallback

    def register(self, prev: FallbackFeatures, cur: FallbackFeatures, *, second_opinion: bool = True) -> Registration:
        """prev_H_cur from two frames described by this registrar (see the class docstring).

        second_opinion False: the torch result only (for optional registrations, such as a keyframe
        to the mosaic, whose failure costs nothing, and SIFT on both images costs more than the frame's budget)."""
        t0 = time.perf_counter()
        reg = self.primary.register(prev.primary, cur.primary)
        if reg.ok or not second_opinion:
            return reg
        return self.second_opinion(prev, cur, reg, t0=t0)

    def second_opinion(self, prev: FallbackFeatures, cur: FallbackFeatures, reg: Registration, *,
                       t0: float | None = None) -> Registration:
        """The OpenCV registrar's try at a pair the torch registrar failed (``reg``, its result):
        register()'s second half, for callers that first try many pairs without it."""
        t0 = time.perf_counter() if t0 is None else t0
        second = self.fallback.register(self._fallback_features(prev), self._fallback_features(cur))
        if not second.ok:
            return replace(reg, extras={**reg.extras, 'fallback_opencv': 0.0},
                           reason=f'{reg.reason} (the OpenCV fallback failed too: {second.reason})')
        return replace(second, time_s=time.perf_counter() - t0,
                       extras={**second.extras, 'fallback_opencv': 1.0, 'torch_inliers': float(reg.inliers)})


def make_registrar(config: RegistrationConfig, device: str = 'auto') -> Registrar | TorchRegistrar | FallbackRegistrar:
    """The registrar selected by config.backend: 'torch' runs on `device` (auto | cpu | cuda,
    resolved by core.device), with the OpenCV registrar as fallback on failed pairs when
    config.opencv_fallback is set; 'opencv' always runs on the CPU (the device does not apply)."""
    if config.backend == 'torch':
        torch_registrar = TorchRegistrar(config, device=device)
        if config.opencv_fallback:
            return FallbackRegistrar(torch_registrar, Registrar(config))
        return torch_registrar
    return Registrar(config)
