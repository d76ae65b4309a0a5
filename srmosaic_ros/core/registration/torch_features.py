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
results up to float32 rounding, several times faster than torch's one-thread ops there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..image_ops import to_gray_float01

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

DESCRIPTOR_SIZE = 128
_ORI_BINS = 36
_ORI_GRID = 9            # orientation window: 9 x 9 samples ...
_ORI_SPACING = 1.0       # ... spaced by 1 sigma, Gaussian weight of 1.5 sigma (SIFT)
_ORI_WEIGHT_SIGMA = 1.5
_DESC_GRID = 12          # descriptor window: 12 x 12 samples over 4 x 4 cells of 3 sigma (SIFT)
_DESC_CELLS = 4
_DESC_BINS = 8
_DESC_CELL_SIGMAS = 3.0
_DESC_CLIP = 0.2
_SIGMA_IN = 0.5          # blur assumed in the detection-level image (pixel integration)
_LUMA = (0.299, 0.587, 0.114)  # Rec. 601, as image_ops.to_gray_float01


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


@dataclass
class KeypointSet:
    """Keypoints of one frame, all tensors on one device.

    xy: (N, 2) float32 (x, y) in full-resolution pixels; scale: (N,) float32 sigma of the
    keypoint in full-resolution pixels; angle: (N,) float32 dominant orientation, radians,
    measured from +x toward +y; response: (N,) float32 DoH response; descriptors: (N, 128)
    float32 unit vectors.
    """

    xy: torch.Tensor
    scale: torch.Tensor
    angle: torch.Tensor
    response: torch.Tensor
    descriptors: torch.Tensor

    def __len__(self) -> int:
        return int(self.xy.shape[0])


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
        # One OpenCV pass (the weighted sum of the float channels): half the time of torch's here.
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
    rounding, a few times faster than torch's ops there); on other devices as two convolutions.
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

    On the CPU by OpenCV (cv2.resize INTER_AREA: the same averages up to float32 rounding, some
    twenty times faster than avg_pool2d there).
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


_RECT3 = np.ones((3, 3), np.uint8)


def _nms_max(resp: torch.Tensor) -> torch.Tensor:
    """Largest value of the 3 x 3 x 3 neighbourhood of each interior point of resp (S, H, W)
    -> (S - 2, H - 2, W - 2)."""
    scale = torch.maximum(torch.maximum(resp[:-2], resp[1:-1]), resp[2:])      # (S - 2, H, W), contiguous
    if _on_cpu32(resp):
        n, h, w = scale.shape
        # One 3 x 3 dilation of the levels stacked vertically: the rows where two levels meet
        # mix them, but those are border rows of a level, cropped below.
        d = cv2.dilate(scale.numpy().reshape(n * h, w), _RECT3)
        return torch.from_numpy(d).view(n, h, w)[:, 1:-1, 1:-1]
    return _max3(_max3(scale, 2), 1)


def _max3(a: torch.Tensor, dim: int) -> torch.Tensor:
    """Running max over 3 neighbours along dim (size shrinks by 2)."""
    n = a.shape[dim]
    return torch.maximum(torch.maximum(a.narrow(dim, 0, n - 2), a.narrow(dim, 1, n - 2)), a.narrow(dim, 2, n - 2))


def _is_max(resp: torch.Tensor, threshold: float, border: int) -> torch.Tensor:
    """(S, H - 4, W - 4) bool: resp (S + 2, H - 2, W - 2) at offset (1, 1, 1) is its 3 x 3 x 3
    neighbourhood's maximum and above threshold, and at least border from the edges of the mask."""
    centre = resp[1:-1, 1:-1, 1:-1]
    is_max = (centre >= _nms_max(resp)) & (centre > threshold)
    if border:
        is_max[:, :border, :] = False
        is_max[:, -border:, :] = False
        is_max[:, :, :border] = False
        is_max[:, :, -border:] = False
    return is_max


def _maxima_cpu(resp: torch.Tensor, threshold: float, border: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The points of _is_max (same order) by OpenCV: (s, y, x) long, coordinates in resp (S + 2, H, W),
    at least border (>= 1) from its spatial edges."""
    scale = torch.maximum(torch.maximum(resp[:-2], resp[1:-1]), resp[2:])       # (S, H, W), contiguous
    n, h, w = scale.shape
    a = scale.numpy().reshape(n * h, w)
    # centre > threshold  <=>  centre >= the next float32 above it: folded into the maximum.
    np.maximum(a, np.nextafter(np.float32(threshold), np.float32(np.inf)), out=a)
    # 3 x 3 dilation of the levels stacked vertically: rows where two levels meet mix them, but
    # they lie in the cleared border.
    mask = cv2.compare(resp[1:-1].numpy().reshape(n * h, w), cv2.dilate(a, _RECT3), cv2.CMP_GE)
    m = mask.reshape(n, h, w)
    m[:, :border] = 0
    m[:, h - border:] = 0
    m[:, :, :border] = 0
    m[:, :, w - border:] = 0
    pts = cv2.findNonZero(mask)                                   # (K, 1, 2) int32 (x, y), row-major
    if pts is None:
        e = torch.zeros(0, dtype=torch.long)
        return e, e, e
    pts = torch.from_numpy(pts.reshape(-1, 2)).long()
    row = pts[:, 1]
    return row // h + 1, row % h, pts[:, 0]


@dataclass
class _Octave:
    index: int                # octave number o (octave image = detection level / 2**o)
    xy: torch.Tensor          # (K, 2) refined (x, y), octave pixels
    sub_s: torch.Tensor       # (K,) refined level index (float)
    response: torch.Tensor    # (K,)


def _detect_octave(levels: torch.Tensor, sigmas: list[float], index: int, opts: FeatureOptions,
                   static_k: int | None = None) -> _Octave:
    """Scale-normalised DoH maxima of one octave; levels: (S + 2, H, W) Gaussian stack.

    static_k: None selects every maximum (``nonzero``: the count is data-dependent, a host
    synchronisation on a GPU); an int selects the static_k strongest positions of the masked
    response instead (``topk``: fixed shapes, no synchronisation, what a CUDA graph can capture),
    the positions that are no maximum carrying response -inf (they sort last).
    """
    dev = levels.device
    n_s, h, w = levels.shape
    sig = cached_constant(tuple(sigmas), dev)
    c = levels[:, 1:-1, 1:-1]
    lxx = torch.add(levels[:, 1:-1, 2:], levels[:, 1:-1, :-2]).sub_(c, alpha=2.0)
    lyy = torch.add(levels[:, 2:, 1:-1], levels[:, :-2, 1:-1]).sub_(c, alpha=2.0)
    lxy4 = torch.sub(levels[:, 2:, 2:], levels[:, 2:, :-2]).sub_(levels[:, :-2, 2:]).add_(levels[:, :-2, :-2])
    # (S+2, H-2, W-2), offset 1 from the level pixels.
    resp = lxx.mul_(lyy).addcmul_(lxy4, lxy4, value=-1.0 / 16.0).mul_((sig**4).view(-1, 1, 1))
    b = max(opts.border_px - 2, 0)
    hr, wr = h - 2, w - 2
    invalid = None
    if static_k is None and _on_cpu32(resp):
        s, y, x = _maxima_cpu(resp, opts.response_threshold, b + 1)
        if s.numel() == 0:
            z = torch.zeros(0, device=dev)
            return _Octave(index, torch.zeros(0, 2, device=dev), z, z)
    elif static_k is None:
        is_max = _is_max(resp, opts.response_threshold, b)
        idx = is_max.nonzero()  # (K, 3): s-1, y-2, x-2
        if idx.shape[0] == 0:
            z = torch.zeros(0, device=dev)
            return _Octave(index, torch.zeros(0, 2, device=dev), z, z)
        s = idx[:, 0] + 1
        y = idx[:, 1] + 1     # in resp coordinates (offset 1)
        x = idx[:, 2] + 1
    else:
        is_max = _is_max(resp, opts.response_threshold, b)
        centre = resp[1:-1, 1:-1, 1:-1]
        masked = torch.where(is_max, centre, torch.full_like(centre, -math.inf)).view(-1)
        top = masked.topk(min(static_k, masked.numel()))
        invalid = torch.isinf(top.values)
        hc, wc = h - 4, w - 4     # is_max is (S, h - 4, w - 4)
        s = top.indices // (hc * wc) + 1
        y = (top.indices // wc) % hc + 1
        x = top.indices % wc + 1
    flat = resp.reshape(-1)
    base = (s * hr + y) * wr + x
    offs = cached_constant((0, 1, -1, wr, -wr, wr + 1, wr - 1, -wr + 1, -wr - 1, hr * wr, -hr * wr), dev, torch.long)
    v = flat.index_select(0, (base[:, None] + offs[None, :]).view(-1)).view(-1, offs.numel())   # (K, 11)
    v0 = v[:, 0]
    dx = 0.5 * (v[:, 1] - v[:, 2])
    dy = 0.5 * (v[:, 3] - v[:, 4])
    dxx = v[:, 1] + v[:, 2] - 2.0 * v0
    dyy = v[:, 3] + v[:, 4] - 2.0 * v0
    dxy = 0.25 * (v[:, 5] - v[:, 6] - v[:, 7] + v[:, 8])
    ds = 0.5 * (v[:, 9] - v[:, 10])
    dss = v[:, 9] + v[:, 10] - 2.0 * v0
    det = dxx * dyy - dxy * dxy
    good = det > 1e-12 * v0.abs().clamp_min(1e-12) ** 2
    safe = torch.where(good, det, torch.ones_like(det))
    ox = torch.where(good, -(dyy * dx - dxy * dy) / safe, torch.zeros_like(det)).clamp(-0.5, 0.5)
    oy = torch.where(good, -(dxx * dy - dxy * dx) / safe, torch.zeros_like(det)).clamp(-0.5, 0.5)
    os_ = torch.where(dss < 0, -ds / torch.where(dss < 0, dss, -torch.ones_like(dss)),
                      torch.zeros_like(dss)).clamp(-0.5, 0.5)
    xy = torch.stack([x.float() + 1.0 + ox, y.float() + 1.0 + oy], dim=1)
    peak = v0 + 0.5 * (dx * ox + dy * oy)
    if invalid is not None:
        peak = peak.masked_fill(invalid, -math.inf)
    return _Octave(index, xy, s.float() + os_, peak)


def _sample_tall(tall: torch.Tensor, pts: torch.Tensor, row0: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of the gradient buffer at (P, K, 2) points -> (C, P, K).

    tall: (1, C, R, W), the Gaussian levels of all octaves stacked vertically (octave o, level l
    at rows row0_o + l * h_o); row0: (K,) first row of each keypoint's level; hi: (K, 2) its
    largest (x, y). Points are clamped to their level (border padding), then offset into it, so
    one 2-D grid_sample serves every octave and level.
    """
    _, _, ht, w = tall.shape
    dev, dt = pts.device, pts.dtype
    scale = cached_constant((2.0 / (w - 1), 2.0 / (ht - 1)), dev, dt)
    shift = torch.stack([torch.zeros_like(row0), row0], -1)                            # (K, 2)
    grid = torch.minimum(pts.clamp_min(0.0), hi).add_(shift).mul_(scale).sub_(1.0)
    out = F.grid_sample(tall, grid[None], mode='bilinear', padding_mode='border', align_corners=True)
    return out[0]


@lru_cache(maxsize=8)
def _orientation_offsets(device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    r = (_ORI_GRID - 1) / 2.0
    u = (torch.arange(_ORI_GRID, dtype=torch.float32) - r) * _ORI_SPACING
    yy, xx = torch.meshgrid(u, u, indexing='ij')
    off = torch.stack([xx.reshape(-1), yy.reshape(-1)], 1)
    keep = (off**2).sum(1) <= (r * _ORI_SPACING + 0.5) ** 2
    off = off[keep]
    wgt = torch.exp(-0.5 * (off**2).sum(1) / _ORI_WEIGHT_SIGMA**2)
    return off.to(device), wgt.to(device)


@lru_cache(maxsize=8)
def _descriptor_layout(device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sample offsets (P, 2) in units of sigma; pooling (16, P): bilinear cell assignment times the
    Gaussian window (sigma = half the window), as SIFT; bin directions (8,) radians."""
    n = _DESC_GRID
    width = _DESC_CELLS * _DESC_CELL_SIGMAS          # window side in sigmas
    step = width / n
    u = (torch.arange(n, dtype=torch.float32) + 0.5) * step - 0.5 * width
    yy, xx = torch.meshgrid(u, u, indexing='ij')
    off = torch.stack([xx.reshape(-1), yy.reshape(-1)], 1)          # (P, 2)
    cell = (off + 0.5 * width) / _DESC_CELL_SIGMAS - 0.5               # cell coordinates
    centers = torch.arange(_DESC_CELLS, dtype=torch.float32)
    wx = (1.0 - (cell[:, 0:1] - centers[None]).abs()).clamp_min(0.0)  # (P, 4)
    wy = (1.0 - (cell[:, 1:2] - centers[None]).abs()).clamp_min(0.0)
    spatial = (wy[:, :, None] * wx[:, None, :]).reshape(-1, _DESC_CELLS * _DESC_CELLS)  # (P, 16) row-major cells
    gauss = torch.exp(-0.5 * (off**2).sum(1) / (0.5 * width) ** 2)
    bins = torch.arange(_DESC_BINS, dtype=torch.float32) * (2.0 * math.pi / _DESC_BINS)
    return off.to(device), (spatial * gauss[:, None]).T.contiguous().to(device), bins.to(device)


def _rotated_points(xy: torch.Tensor, off: torch.Tensor, sigma: torch.Tensor,
                    angle: torch.Tensor | None) -> torch.Tensor:
    """xy (K, 2) + sigma (K,) * R(angle) @ off (P, 2) -> (P, K, 2) (sample-major, as grid_sample wants)."""
    ox, oy = off[:, 0, None, None], off[:, 1, None, None]                      # (P, 1, 1)
    if angle is None:
        return torch.addcmul(xy[None], off[:, None, :], sigma[None, :, None])
    c, s = torch.cos(angle) * sigma, torch.sin(angle) * sigma
    col0 = torch.stack([c, s], -1)[None]                                        # R[:, 0] * sigma, (1, K, 2)
    col1 = torch.stack([-s, c], -1)[None]
    return torch.addcmul(torch.addcmul(xy[None], ox, col0), oy, col1)


def _orientation(tall: torch.Tensor, xy: torch.Tensor, sigma: torch.Tensor, row0: torch.Tensor,
                 hi: torch.Tensor) -> torch.Tensor:
    """Dominant gradient orientation (K,) radians: peak of a 36-bin histogram of gradient angles in
    a Gaussian window of 1.5 sigma (weighted by magnitude, smoothed, parabolic peak), as SIFT."""
    off, wgt = _orientation_offsets(xy.device)
    g = _sample_tall(tall, _rotated_points(xy, off, sigma, None), row0, hi).transpose(1, 2)  # (2, K, P)
    mag = torch.sqrt(g[0] * g[0] + g[1] * g[1]) * wgt
    b = torch.atan2(g[1], g[0]) * (_ORI_BINS / (2.0 * math.pi)) + _ORI_BINS   # in (0.5 B, 1.5 B]
    lo = b.floor()
    frac = b - lo
    lo_i = lo.long() % _ORI_BINS
    hist = torch.zeros(xy.shape[0], _ORI_BINS + 1, device=xy.device)
    hist.scatter_add_(1, lo_i, mag * (1.0 - frac))
    hist.scatter_add_(1, lo_i + 1, mag * frac)
    hist = hist[:, :_ORI_BINS].index_add(1, torch.zeros(1, dtype=torch.long, device=xy.device), hist[:, _ORI_BINS:])
    # Circular smoothing [1 4 6 4 1] / 16 and parabolic interpolation of the peak.
    ext = torch.cat([hist[:, -3:], hist, hist[:, :3]], 1)
    sm = (6.0 * ext[:, 2:-2] + 4.0 * (ext[:, 1:-3] + ext[:, 3:-1]) + ext[:, :-4] + ext[:, 4:]) / 16.0   # (K, B + 2)
    core = sm[:, 1:-1]
    peak = core.argmax(1, keepdim=True)
    trio = sm.gather(1, torch.cat([peak, peak + 1, peak + 2], 1))
    hm, h0, hp = trio[:, 0], trio[:, 1], trio[:, 2]
    den = hm - 2.0 * h0 + hp
    shift = 0.5 * (hm - hp) / torch.where(den < 0, den, -torch.ones_like(den))
    return (peak[:, 0].to(torch.float32) + shift.clamp(-0.5, 0.5)) * (2.0 * math.pi / _ORI_BINS)


def _descriptor(tall: torch.Tensor, xy: torch.Tensor, sigma: torch.Tensor, row0: torch.Tensor, hi: torch.Tensor,
                angle: torch.Tensor) -> torch.Tensor:
    """(K, 128) RootSIFT-like unit descriptors.

    Gradients on a 12 x 12 grid (rotated by the keypoint angle, spanning 4 x 4 cells of 3 sigma)
    are projected on 8 directions relative to the keypoint angle and half-wave rectified (the
    orientation maps of DAISY: a cosine-shaped soft binning that needs no angle computation),
    pooled into the cells with bilinear and Gaussian weights, L2-normalised, clipped at 0.2, and
    square-rooted after L1 normalisation.
    """
    off, pool, bins = _descriptor_layout(xy.device)
    k = xy.shape[0]
    g = _sample_tall(tall, _rotated_points(xy, off, sigma, angle), row0, hi)          # (2, P, K)
    # Rectified projections of the gradients on 8 directions relative to the keypoint angle.
    dirs = angle[:, None] + bins[None]                                                 # (K, 8)
    proj = torch.addcmul(g[0][..., None] * torch.cos(dirs), g[1][..., None], torch.sin(dirs)).clamp_min_(0.0)
    d = torch.matmul(pool, proj.view(proj.shape[0], k * _DESC_BINS))                     # (16, K * 8)
    d = d.view(_DESC_CELLS * _DESC_CELLS, k, _DESC_BINS).transpose(0, 1).reshape(k, DESCRIPTOR_SIZE)
    d = F.normalize(d, dim=1).clamp_max_(_DESC_CLIP)
    return torch.sqrt(F.normalize(d, p=1.0, dim=1))


@dataclass
class ScaleSpaceCandidates:
    """All DoH maxima of a frame, strongest first, kept with the gradient buffer so that more of
    them can be described later (describe_candidates) without recomputing the scale space.

    level: detection pyramid level; xy: (N, 2) positions in their octave's pixels; sub_level:
    (N,) refined level index within the octave; octave: (N,) long; response: (N,); tall:
    (1, 2, R, W) gradients (gx, gy) of every Gaussian level of every octave, stacked vertically;
    row0: (O,) first row of each octave in tall; size: (O, 2) (w, h) of each octave;
    sigma0, scales_per_octave: the scale space (sigma_i = sigma0 * 2**(i / S)); count: with fixed
    shapes (detect's static_k), a 0-d long tensor, the number of real candidates (the first count
    entries; the rest have response -inf), else None (every entry is real).
    """

    level: int
    xy: torch.Tensor
    sub_level: torch.Tensor
    octave: torch.Tensor
    response: torch.Tensor
    tall: torch.Tensor
    row0: torch.Tensor
    size: torch.Tensor
    sigma0: float
    scales_per_octave: int
    count: torch.Tensor | None = None

    def __len__(self) -> int:
        return int(self.response.numel()) if self.count is None else int(self.count)


def detect(level_image: torch.Tensor, level: int, opts: FeatureOptions, *,
           static_k: int | None = None) -> ScaleSpaceCandidates:
    """Scale-space maxima of a pyramid level image (1, 1, h, w), strongest first.

    Scale space (per octave o, S = scales_per_octave): sigma_i = sigma0 * 2**(i / S), i = 0..S+1,
    on the detection level downscaled by 2**o; DoH = sigma**4 (Lxx Lyy - Lxy**2); candidates are its
    3 x 3 x 3 maxima above response_threshold. static_k: fixed shapes (see _detect_octave): at most
    static_k candidates per octave, ``count`` of them real; the first ``count`` are those of the
    data-dependent path when no octave has more than static_k.
    """
    dev = level_image.device
    s_per = opts.scales_per_octave
    n_lv = s_per + 2
    sig = [opts.sigma0 * 2.0 ** (i / s_per) for i in range(n_lv)]
    _, _, h0, w0 = level_image.shape
    sizes = []
    h, w = h0, w0
    for _ in range(opts.octaves):
        if min(h, w) < 4 * opts.border_px + 8:
            break
        sizes.append((w, h))
        h, w = h // 2, w // 2
    rows = [0]
    for _, h_o in sizes:
        rows.append(rows[-1] + n_lv * h_o)
    tall = level_image.new_empty(1, 2, max(rows[-1], 1), w0)
    if not sizes:
        tall.zero_()
    octs: list[_Octave] = []
    base = gaussian_blur(level_image, math.sqrt(max(sig[0] ** 2 - _SIGMA_IN**2, 1e-6)))
    steps = [math.sqrt(sig[i] ** 2 - sig[i - 1] ** 2) for i in range(1, n_lv)]
    for o, (w_o, h_o) in enumerate(sizes):
        stack = _gaussian_stack(base, steps)
        octs.append(_detect_octave(stack, sig, o, opts, static_k))
        _gradients_into(stack, tall[0, :, rows[o]:rows[o + 1], :w_o].view(2, n_lv, h_o, w_o))
        if w_o < w0:  # bilinear samples at a level's right edge read (with weight 0) the column beyond
            tall[0, :, rows[o]:rows[o + 1], w_o:] = 0.0
        if o + 1 < len(sizes):
            # Next octave from the level at 2 sigma0 (index S), 2 x 2 averaged: sigma ~ sigma0 again.
            base = half_size(stack[s_per][None, None])
    z = torch.zeros(0, device=dev)
    if not octs:
        return ScaleSpaceCandidates(level, torch.zeros(0, 2, device=dev), z, z.long(), z, tall,
                                    z.long(), torch.zeros(0, 2, device=dev), opts.sigma0, s_per)
    resp = torch.cat([o.response for o in octs])
    order = resp.argsort(descending=True, stable=True)
    octave = torch.cat([torch.full((o.response.numel(),), o.index, device=dev, dtype=torch.long) for o in octs])
    count = None if static_k is None else torch.isfinite(resp).sum()
    return ScaleSpaceCandidates(
        level, torch.cat([o.xy for o in octs]).index_select(0, order),
        torch.cat([o.sub_s for o in octs]).index_select(0, order), octave.index_select(0, order),
        resp.index_select(0, order), tall, cached_constant(tuple(rows[:-1]), dev), cached_constant(tuple(sizes), dev),
        opts.sigma0, s_per, count)


def _empty_keypoints(dev: torch.device) -> KeypointSet:
    e = torch.zeros(0, device=dev)
    return KeypointSet(torch.zeros(0, 2, device=dev), e, e, e, torch.zeros(0, DESCRIPTOR_SIZE, device=dev))


def describe_candidates(cands: ScaleSpaceCandidates, start: int, stop: int) -> KeypointSet:
    """Keypoints (orientation, descriptor, full-resolution position and scale) of the candidates
    ranked start .. stop - 1, all octaves at once."""
    dev = cands.response.device
    sl = slice(start, stop)
    if cands.response[sl].numel() == 0:
        return _empty_keypoints(dev)
    oct_ = cands.octave[sl]
    sub = cands.sub_level[sl]
    kxy = cands.xy[sl]
    n_lv = cands.scales_per_octave + 2
    lev = sub.round().clamp(0, n_lv - 1)
    sigma = cands.sigma0 * torch.pow(2.0, sub / cands.scales_per_octave)     # octave pixels
    size = cands.size[oct_]                                                   # (K, 2) (w, h)
    row0 = cands.row0[oct_] + lev * size[:, 1]
    hi = size - 1.0
    ang = _orientation(cands.tall, kxy, sigma, row0, hi)
    desc = _descriptor(cands.tall, kxy, sigma, row0, hi, ang)
    f = torch.pow(2.0, oct_.to(torch.float32))                                # octave -> level pixels
    xy = full_from_level(kxy * f[:, None] + (f[:, None] - 1.0) * 0.5, cands.level)
    return KeypointSet(xy, sigma * f * float(2**cands.level), ang, cands.response[sl], desc)


def concat_keypoints(a: KeypointSet, b: KeypointSet) -> KeypointSet:
    """Keypoints of a followed by those of b."""
    return KeypointSet(*(torch.cat([getattr(a, f), getattr(b, f)]) for f in
                         ('xy', 'scale', 'angle', 'response', 'descriptors')))


def detect_and_describe(level_image: torch.Tensor, level: int, opts: FeatureOptions) -> KeypointSet:
    """The max_keypoints strongest keypoints of a pyramid level image (1, 1, h, w), described;
    positions in full-resolution pixels (see detect and describe_candidates)."""
    return describe_candidates(detect(level_image, level, opts), 0, opts.max_keypoints)
