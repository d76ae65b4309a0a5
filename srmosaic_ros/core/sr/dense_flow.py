"""Dense per-pixel registration of each frame to the reference on the tile, after the homography and ECC.

The homographies and the tile's affine ECC correction (local_align.py) leave a smooth residual
misregistration of a fraction of an LR pixel that varies across the tile (3-D ground, lens, rolling
shutter); the fusion reads it as detail placed a fraction of a pixel off. Here a dense optical flow
of every frame warped into the LR tile to the reference warped there (OpenCV's DIS flow, Kroeger et
al. 2016, with its variational refinement) estimates that residual per pixel::

    ref(p) ~= warped_k(p + f_k(p))          (LR tile pixels, (x, y) order)

so frame k's content seen at tile point p' belongs at p' - f_k(p'). The flow is a refinement: it
is smoothed with a Gaussian (``smooth`` LR px), clipped to ``max_px`` LR pixels, and trusted per
pixel by its forward-backward consistency ``c_k(p) = exp(-(|f_k(p) + b_k(p + f_k(p))| / fb_px)^2)``
with b_k the flow of the reference to frame k: an occlusion, a moving object or a flat patch where
the two flows disagree gets a low confidence, which weights that frame's pixels in the data term.

The flows are computed on the tile upsampled by ``upsample`` (DIS's 8-px patches need more than a
64-px tile's worth of pixels to resolve a field; the flow is scaled back to LR pixels).
"""
from __future__ import annotations

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from .modes import FLOW_MODES

__all__ = ['FLOW_MODES', 'dense_flow_to_reference', 'remap_tile', 'sample_field']

_PRESETS = {'ultrafast': cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, 'fast': cv2.DISOPTICAL_FLOW_PRESET_FAST,
            'medium': cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


def _dis(preset: str) -> cv2.DISOpticalFlow:
    dis = cv2.DISOpticalFlow.create(_PRESETS[preset])
    dis.setFinestScale(0)  # patches matched down to the input's own scale: the flow sought is sub-pixel
    dis.setVariationalRefinementIterations(max(5, dis.getVariationalRefinementIterations()))
    return dis


def _to_u8(img: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return np.clip((img - lo) * (255.0 / max(hi - lo, 1e-6)) + 0.5, 0, 255).astype(np.uint8)


def dense_flow_to_reference(warped: torch.Tensor, covered: torch.Tensor, ref: int, *, preset: str = 'medium',
                            max_px: float = 1.0, smooth: float = 1.5, fb_px: float = 0.5,
                            upsample: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    """Residual flows of every frame to the reference on the LR tile, and their confidences.

    warped: (K, 1, H, W) the frames' luminance in the LR tile, [0, 1]; covered: (K, 1, H, W) 1 where the
    frame covers; ref: the reference's position. Returns ``(flow (K, 2, H, W), confidence (K, 1, H, W))``
    on ``warped``'s device: f_k in LR tile pixels (module docstring; 0 for the reference, for frames that
    share less than a quarter of the tile with it, and where the frame does not cover), and c_k in [0, 1]
    (1 for the reference).
    """
    if preset not in _PRESETS:
        msg = f'dense flow preset must be one of {tuple(_PRESETS)}, got {preset!r}.'
        raise ValueError(msg)
    k_frames, _, h, w = warped.shape
    flow = np.zeros((k_frames, 2, h, w), np.float32)
    conf = np.ones((k_frames, 1, h, w), np.float32)
    imgs = warped[:, 0].detach().float().cpu().numpy()
    cov = covered[:, 0].detach().cpu().numpy() > 0
    up = max(1, int(upsample))
    size = (w * up, h * up)
    # one intensity mapping for all frames (the photometric step has matched them): contrast
    # stretched to the reference's range so that DIS's uint8 input keeps sub-grey-level detail
    lo, hi = np.percentile(imgs[ref][cov[ref]], (0.5, 99.5)) if cov[ref].any() else (0.0, 1.0)

    def prep(k: int) -> np.ndarray:
        img = np.where(cov[k], imgs[k], imgs[ref])  # outside the frame: nothing to match, the reference's own
        return cv2.resize(_to_u8(img, float(lo), float(hi)), size, interpolation=cv2.INTER_CUBIC) if up > 1 else \
            _to_u8(img, float(lo), float(hi))

    dis = _dis(preset)
    tmpl = prep(ref)
    grid_x, grid_y = np.meshgrid(np.arange(size[0], dtype=np.float32), np.arange(size[1], dtype=np.float32))
    ksize = 2 * int(np.ceil(3 * smooth * up)) + 1
    for k in range(k_frames):
        if k == ref:
            continue
        both = cov[k] & cov[ref]
        if both.sum() < 0.25 * h * w:
            conf[k] = 0.0
            continue
        img = prep(k)
        fwd = dis.calc(tmpl, img, None)
        bwd = dis.calc(img, tmpl, None)
        # forward-backward: b at p + f(p) should be -f(p)
        b_at = cv2.remap(bwd, grid_x + fwd[..., 0], grid_y + fwd[..., 1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
        fb = np.hypot(*(fwd + b_at).transpose(2, 0, 1)) / up
        if smooth > 0:
            fwd = cv2.GaussianBlur(fwd, (ksize, ksize), smooth * up, borderType=cv2.BORDER_REPLICATE)
        f_lr = cv2.resize(fwd, (w, h), interpolation=cv2.INTER_AREA) / up if up > 1 else fwd
        fb_lr = cv2.resize(fb, (w, h), interpolation=cv2.INTER_AREA) if up > 1 else fb
        mag = np.hypot(f_lr[..., 0], f_lr[..., 1])
        f_lr *= np.minimum(1.0, max_px / np.maximum(mag, 1e-9))[..., None]   # clipped to max_px
        f_lr[~cov[k]] = 0.0
        flow[k] = f_lr.transpose(2, 0, 1)
        conf[k, 0] = np.exp(-((fb_lr / max(fb_px, 1e-6)) ** 2)) * cov[k]
    dev = warped.device
    return torch.from_numpy(flow).to(dev, warped.dtype), torch.from_numpy(conf).to(dev, warped.dtype)


def sample_field(field: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``field`` (K, C, H, W) at pixel points ``x``, ``y`` (K, h, w) -> (K, C, h, w);
    points outside read the nearest border value."""
    h, w = field.shape[-2:]
    gx = x * (2.0 / max(w - 1, 1)) - 1.0
    gy = y * (2.0 / max(h - 1, 1)) - 1.0
    grid = torch.stack([gx, gy], dim=-1).to(field.dtype)
    return F.grid_sample(field, grid, mode='bilinear', padding_mode='border', align_corners=True)


def remap_tile(img: torch.Tensor, flow: torch.Tensor, *, padding: str = 'zeros') -> torch.Tensor:
    """``img_k(p + f_k(p))``: (K, C, H, W) frames in the LR tile resampled along their flows (K, 2, H, W)
    so that they superpose the reference (bilinear)."""
    k, _, h, w = img.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=img.dtype, device=img.device),
                            torch.arange(w, dtype=img.dtype, device=img.device), indexing='ij')
    gx = (xs + flow[:, 0]) * (2.0 / max(w - 1, 1)) - 1.0
    gy = (ys + flow[:, 1]) * (2.0 / max(h - 1, 1)) - 1.0
    grid = torch.stack([gx, gy], dim=-1)
    return F.grid_sample(img, grid, mode='bilinear', padding_mode=padding, align_corners=True)
