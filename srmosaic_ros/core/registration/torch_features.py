"""Keypoints and descriptors as torch tensor ops (Table 1 of the reference, step 1).

Detector: scale-normalised determinant of the Hessian (DoH) over a small Gaussian scale space
(`octaves` x `scales_per_octave`), computed on a downscaled pyramid level (half resolution by
default), with 3x3x3 non-maximum suppression and sub-pixel (and sub-scale) localisation by a
quadratic fit of the response. Blob-like DoH maxima are well localised and need no edge test.

Descriptor: SIFT-like, computed on the Gaussian level of the keypoint's scale: a dominant
gradient orientation from a 36-bin histogram (so that frame rotation does not matter), then
4 x 4 cells x 8 orientation bins of rotated gradients on a 12 x 12 grid spanning 12 sigma,
normalised, clipped at 0.2 and square-rooted (RootSIFT), so descriptors are unit vectors
and robust to contrast changes (IR) and blur.

Convention: images (B, C, H, W) float32 in [0, 1]; keypoint positions (x, y) in full-resolution
pixels, pixel centres at integers; a pyramid level l has pixel x_l with
x_full = 2**l * x_l + (2**l - 1) / 2 (levels are made by 2 x 2 averaging).

Device: torch ops throughout, except that on the CPU (float32) the image-sized steps (luminance,
blurs, 2 x 2 averages, the scale-space maxima) run in OpenCV on the tensors' memory: the same
results up to float32 rounding, faster than torch's one-thread ops there (docs/results.md,
"Registration").

Modules: torch_feature_options.py (the settings), torch_scale_space.py (blurs, pyramids,
gradients), torch_detect.py (DoH maxima), torch_describe.py (orientation, descriptors); this one
holds the image conversion and detect_and_describe, and re-exports their public names.
"""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
import torch

from ..image_ops import to_gray_float01
from .torch_describe import DESCRIPTOR_SIZE, KeypointSet, concat_keypoints, describe_candidates
from .torch_detect import ScaleSpaceCandidates, detect
from .torch_feature_options import FeatureOptions
from .torch_scale_space import build_pyramid, cached_constant, full_from_level, gaussian_blur, half_size

# private helpers re-exported for the tests of the CPU paths (test/core/registration/test_describe_cpu_paths.py)
from .torch_detect import _is_max, _max3, _maxima_cpu, _nms_max  # noqa: F401
from .torch_scale_space import _gaussian_stack, _gradients_into  # noqa: F401

__all__ = [
    'DESCRIPTOR_SIZE',
    'FeatureOptions',
    'KeypointSet',
    'ScaleSpaceCandidates',
    'build_pyramid',
    'concat_keypoints',
    'describe_candidates',
    'detect',
    'detect_and_describe',
    'full_from_level',
    'gaussian_blur',
    'half_size',
    'image_to_gray_tensor',
]

_LUMA = (0.299, 0.587, 0.114)  # Rec. 601, as image_ops.to_gray_float01


#: Pixels per band of image_to_gray_tensor's 8-bit RGB conversion (its float copy: 12 bytes a pixel).
GRAY_BAND_PIXELS = 1 << 16


def image_to_gray_tensor(image: np.ndarray | torch.Tensor, device: torch.device) -> torch.Tensor:
    """An edge image or a core tensor -> (1, 1, H, W) float32 luminance in [0, 1] on device.

    Accepts numpy (H, W) or (H, W, C) uint8 / uint16 / float (uint16 is stretched by
    image_ops.to_float01), or a torch tensor (H, W), (C, H, W) or (1, C, H, W) in [0, 1].
    """
    if isinstance(image, torch.Tensor):
        t = image.to(device=device, dtype=torch.float32)
        if t.ndim == 2:
            t = t[None, None]
        elif t.ndim == 3:
            t = t[None]
        if t.ndim != 4 or t.shape[0] != 1:
            msg = f'expected an image tensor (H, W), (C, H, W) or (1, C, H, W), got shape {tuple(image.shape)}.'
            raise ValueError(msg)
        if t.shape[1] >= 3:
            w = cached_constant(_LUMA, device).view(1, 3, 1, 1)
            t = (t[:, :3] * w).sum(1, keepdim=True)
        elif t.shape[1] != 1:
            t = t[:, :1]
        return t.contiguous()
    if not isinstance(image, np.ndarray) or image.ndim not in (2, 3):
        msg = 'expected a numpy image (H, W) or (H, W, C) or a torch tensor.'
        raise TypeError(msg)
    if image.dtype == np.uint8 and device.type == 'cpu' and image.ndim == 3 and image.shape[2] == 3:
        # One OpenCV pass (the weighted sum of the float channels): cheaper than torch's here.
        # By bands of rows: a float copy of the whole frame (11 MB at 720p) is fresh memory every
        # frame on a worker thread's heap, page-faulted in (malloc_tuning.py).
        h, w = image.shape[:2]
        gray = np.empty((h, w), np.float32)
        rows = max(1, GRAY_BAND_PIXELS // w)
        for r in range(0, h, rows):
            band = image[r:r + rows]
            gray[r:r + rows] = cv2.transform(band.astype(np.float32), _luma_row()).reshape(band.shape[0], w)
        return torch.from_numpy(gray)[None, None]
    if image.dtype == np.uint8:
        # Convert on the device: the uint8 transfer is a quarter of a float one.
        t = torch.from_numpy(np.ascontiguousarray(image)).to(device)
        if t.ndim == 3 and t.shape[2] >= 3:
            w = cached_constant(tuple(c / 255.0 for c in _LUMA), device)
            t = t[:, :, :3].to(torch.float32) @ w
        else:
            t = t.reshape(t.shape[0], t.shape[1], -1)[:, :, 0].to(torch.float32) * (1.0 / 255.0)
        return t[None, None].contiguous()
    gray = to_gray_float01(image)
    return torch.from_numpy(np.ascontiguousarray(gray, dtype=np.float32)).to(device)[None, None]


@lru_cache(maxsize=1)
def _luma_row() -> np.ndarray:
    """(1, 3) float32 luma weights of 8-bit RGB to luminance in [0, 1]."""
    return np.array([[c / 255.0 for c in _LUMA]], dtype=np.float32)


def detect_and_describe(level_image: torch.Tensor, level: int, opts: FeatureOptions) -> KeypointSet:
    """The max_keypoints strongest keypoints of a pyramid level image (1, 1, h, w), described;
    positions in full-resolution pixels (see detect and describe_candidates)."""
    return describe_candidates(detect(level_image, level, opts), 0, opts.max_keypoints)
