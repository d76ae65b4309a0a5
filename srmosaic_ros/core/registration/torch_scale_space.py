"""The Gaussian scale space of the torch feature detector: blurs, 2 x 2 averages, pyramids, gradients.

Images (B, C, H, W) float32 in [0, 1]; a pyramid level l has pixel x_l with
x_full = 2**l * x_l + (2**l - 1) / 2 (levels are made by 2 x 2 averaging). On the CPU (float32)
the image-sized steps run in OpenCV on the tensors' memory (the same results up to float32
rounding, faster than torch's one-thread ops there); elsewhere as torch ops.
"""
from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np
import torch
import torch.nn.functional as F

__all__ = ['build_pyramid', 'cached_constant', 'full_from_level', 'gaussian_blur', 'half_size']


@lru_cache(maxsize=256)
def cached_constant(values: tuple, device: torch.device, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """A cached constant tensor (never modified in place): no host-to-device copy per call on a GPU."""
    return torch.tensor(values, device=device, dtype=dtype)


@lru_cache(maxsize=64)
def _gauss_taps(sigma: float) -> tuple[float, ...]:
    r = max(1, math.ceil(3.0 * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return tuple((k / k.sum()).tolist())


def _on_cpu32(x: torch.Tensor) -> bool:
    """Whether the OpenCV paths apply: float32 on the CPU (elsewhere torch ops, device-agnostic)."""
    return x.device.type == 'cpu' and x.dtype == torch.float32


def gaussian_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur (radius ceil(3 sigma)) with replicated borders; x: (B, C, H, W).

    On the CPU by OpenCV (cv2.sepFilter2D, same taps: equal to the convolution up to float32
    rounding, faster than torch's ops there); on other devices as two convolutions.
    """
    if sigma <= 0.0:
        return x
    b, c, h, w = x.shape
    if _on_cpu32(x):
        src = x.detach().reshape(b * c, h, w).contiguous().numpy()
        out = np.empty_like(src)
        for i in range(b * c):
            _blur_plane(src[i], sigma, out[i])
        return torch.from_numpy(out).view(b, c, h, w)
    taps = _gauss_taps(round(float(sigma), 4))
    r = (len(taps) - 1) // 2
    y = x.reshape(b * c, 1, h, w)
    k = cached_constant(taps, x.device, x.dtype)
    out = F.conv2d(F.pad(y, (r, r, 0, 0), mode='replicate'), k.view(1, 1, 1, -1))
    out = F.conv2d(F.pad(out, (0, 0, r, r), mode='replicate'), k.view(1, 1, -1, 1))
    return out.reshape(b, c, h, w)


@lru_cache(maxsize=64)
def _gauss_taps_np(sigma: float) -> np.ndarray:
    return np.asarray(_gauss_taps(sigma), dtype=np.float32)


def _blur_plane(src: np.ndarray, sigma: float, dst: np.ndarray) -> None:
    """gaussian_blur of one float32 plane (H, W) into dst (H, W), contiguous arrays (CPU path)."""
    taps = _gauss_taps_np(round(float(sigma), 4))
    cv2.sepFilter2D(src, cv2.CV_32F, taps, taps, dst=dst, borderType=cv2.BORDER_REPLICATE)


def _gaussian_stack(base: torch.Tensor, steps: list[float]) -> torch.Tensor:
    """(1 + len(steps), H, W): base (1, 1, H, W), then each level the previous one blurred by the next step."""
    _, _, h, w = base.shape
    if _on_cpu32(base):
        stack = base.new_empty(len(steps) + 1, h, w)
        stack[0] = base[0, 0]
        arr = stack.numpy()
        for i, s in enumerate(steps):
            _blur_plane(arr[i], s, arr[i + 1])
        return stack
    lv = [base]
    for s in steps:
        lv.append(gaussian_blur(lv[-1], s))
    return torch.cat(lv, 1)[0]


def build_pyramid(gray: torch.Tensor, levels: int, *, sigma: float = 0.0) -> list[torch.Tensor]:
    """[level 0, 1, ...]: level 0 is gray (blurred by sigma if > 0), each next one 2 x 2 averaged.

    gray: (1, 1, H, W). Level l has size (H // 2**l, W // 2**l); see the module's convention.
    """
    pyr = [gaussian_blur(gray, sigma) if sigma > 0 else gray]
    for _ in range(1, levels):
        pyr.append(half_size(pyr[-1]))
    return pyr


def half_size(x: torch.Tensor) -> torch.Tensor:
    """2 x 2 averages of x (B, C, H, W) -> (B, C, H // 2, W // 2) (an odd last row / column is dropped).

    On the CPU by OpenCV (cv2.resize INTER_AREA: the same averages up to float32 rounding, faster
    than avg_pool2d there).
    """
    b, c, h, w = x.shape
    h2, w2 = h // 2, w // 2
    if not _on_cpu32(x) or h2 == 0 or w2 == 0:
        return F.avg_pool2d(x, 2)
    src = x.detach().reshape(b * c, h, w).contiguous().numpy()
    out = np.empty((b * c, h2, w2), dtype=np.float32)
    for i in range(b * c):
        cv2.resize(src[i, :2 * h2, :2 * w2], (w2, h2), dst=out[i], interpolation=cv2.INTER_AREA)
    return torch.from_numpy(out).view(b, c, h2, w2)


def full_from_level(xy: torch.Tensor, level: int) -> torch.Tensor:
    """Level-l pixel coordinates (..., 2) -> full-resolution pixel coordinates."""
    f = float(2**level)
    return xy * f + (f - 1.0) * 0.5


def _gradients_into(stack: torch.Tensor, out: torch.Tensor) -> None:
    """Central differences of (S, H, W) with replicated borders (one-sided halves at the border),
    written to out (2, S, H, W) (gx, gy)."""
    gx, gy = out[0], out[1]
    torch.sub(stack[:, :, 2:], stack[:, :, :-2], out=gx[:, :, 1:-1])
    torch.sub(stack[:, :, 1:2], stack[:, :, :1], out=gx[:, :, :1])
    torch.sub(stack[:, :, -1:], stack[:, :, -2:-1], out=gx[:, :, -1:])
    torch.sub(stack[:, 2:], stack[:, :-2], out=gy[:, 1:-1])
    torch.sub(stack[:, 1:2], stack[:, :1], out=gy[:, :1])
    torch.sub(stack[:, -1:], stack[:, -2:-1], out=gy[:, -1:])
    out.mul_(0.5)

