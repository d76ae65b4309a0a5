"""Settings of the torch feature detector and descriptor (torch_features.py)."""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ['FeatureOptions']


@dataclass(frozen=True)
class FeatureOptions:
    """Detector and descriptor settings of the torch registrar.

    detect_level: pyramid level features are detected on (0 full resolution, 1 half, 2 quarter),
        or a finer one where that level would be narrower than min_detect_width pixels.
    min_detect_width: smallest width of the detection level (small frames are detected finer).
    max_keypoints: keypoints described per frame (strongest responses); the registrar describes
        more of the remaining candidates, up to RegistrationConfig.max_features, for pairs that
        fail with these.
    octaves, scales_per_octave, sigma0: the Gaussian scale space on the detection level; keypoint
        scales range over sigma0 * 2**(1/S) .. sigma0 * 2**octaves (2.0 .. 3.2 detection-level
        pixels by default), so a blob is found in both frames for scale changes up to that ratio
        (1.6 with one octave: the plausible range of RegistrationConfig.max_scale_change).
    response_threshold: smallest scale-normalised DoH response (image in [0, 1]) of a keypoint;
        textureless frames (sea, cloud, lens cap) give no keypoints and fail explicitly.
    border_px: keypoints closer than this to the border of the detection level are dropped.
    """

    detect_level: int = 1
    min_detect_width: int = 320
    max_keypoints: int = 250
    octaves: int = 1
    scales_per_octave: int = 3
    sigma0: float = 1.6
    response_threshold: float = 5e-6
    border_px: int = 4

    def __post_init__(self) -> None:
        checks = {
            'detect_level': 0 <= self.detect_level <= 3,
            'min_detect_width': self.min_detect_width >= 16,
            'max_keypoints': self.max_keypoints >= 8,
            'octaves': 1 <= self.octaves <= 4,
            'scales_per_octave': 1 <= self.scales_per_octave <= 6,
            'sigma0': 0.5 < self.sigma0 < 4.0,
            'response_threshold': self.response_threshold >= 0.0,
            'border_px': self.border_px >= 2,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            values = ', '.join(f'{name}={getattr(self, name)!r}' for name in bad)
            msg = f'invalid feature options: {values}.'
            raise ValueError(msg)


    def level_for(self, width: int) -> int:
        """The detection level for frames `width` pixels wide."""
        level = self.detect_level
        while level > 0 and width // 2**level < self.min_detect_width:
            level -= 1
        return level
