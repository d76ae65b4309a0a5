"""The CPU fast paths of describe agree with the plain tensor formulations they replace."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from srmosaic_ros.core.registration.torch_features import (
    FeatureOptions,
    _gaussian_stack,
    _gradients_into,
    _is_max,
    _max3,
    _maxima_cpu,
    _nms_max,
    describe_candidates,
    detect,
    gaussian_blur,
    half_size,
    image_to_gray_tensor,
)
from srmosaic_ros.core.registration.torch_refine import make_template


def _textured(h: int, w: int, seed: int = 0) -> torch.Tensor:
    """(1, 1, h, w) smooth random texture in [0, 1], with flat patches (ties in the block maxima)."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 1, h // 8 + 2, w // 8 + 2, generator=g)
    img = F.interpolate(coarse, size=(h, w), mode='bicubic', align_corners=False)
    img = img + 0.2 * torch.rand(1, 1, h, w, generator=g)
    img[..., : h // 4, : w // 4] = 0.5   # flat: every pixel of a block ties
    return img.clamp(0.0, 1.0)


def _block_argmax_reference(image: torch.Tensor, points: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Block maxima (hb, wb) of the squared central-difference gradient and, per block, the flat index
    (into the cropped level) of its first maximum in row-major order within the block."""
    _, _, h, w = image.shape
    b = max(1, round(math.sqrt(h * w / points)))
    hb, wb = h // b, w // b
    p = F.pad(image, (1, 1, 1, 1), mode='replicate')[0, 0]
    gx = torch.sub(p[1:hb * b + 1, 2:wb * b + 2], p[1:hb * b + 1, :wb * b]).mul_(0.5)
    gy = torch.sub(p[2:hb * b + 2, 1:wb * b + 1], p[:hb * b, 1:wb * b + 1]).mul_(0.5)
    mag = torch.addcmul(gx * gx, gy, gy)
    blocks = mag.view(hb, b, wb, b).permute(0, 2, 1, 3).reshape(hb * wb, b * b)
    bmax = blocks.amax(1)
    first = (blocks == bmax[:, None]).to(torch.uint8).argmax(1)     # first True
    by, bx = torch.arange(hb * wb) // wb, torch.arange(hb * wb) % wb
    lin = (by * b + first // b) * (wb * b) + bx * b + first % b
    return bmax.view(hb, wb), lin


@pytest.mark.parametrize(('h', 'w', 'points'), [(480, 640, 16000), (540, 960, 16000), (121, 163, 900)])
@pytest.mark.parametrize('static', [False, True])
def test_make_template_picks_the_first_block_maximum(h: int, w: int, points: int, static: bool) -> None:
    img = _textured(h, w, seed=h)
    t = make_template(img, 0, points=points, static=static)
    bmax, lin = _block_argmax_reference(img, points)
    s = max(w, h) / 2.0
    x = torch.round(t.xn[0] * s + (w - 1) / 2.0).long()
    y = torch.round(t.xn[1] * s + (h - 1) / 2.0).long()
    wc = bmax.shape[1] * round(math.sqrt(h * w / points))
    got = y * wc + x
    b = round(math.sqrt(h * w / points))
    block = (y // b) * bmax.shape[1] + x // b
    assert torch.equal(got, lin[block])
    # the kept blocks are the strongest interior ones
    inner = bmax.clone()
    inner[0] = inner[-1] = -1.0
    inner[:, 0] = inner[:, -1] = -1.0
    kept = inner.view(-1)[block]
    assert kept.min() >= 0.0
    others = inner.view(-1).clone()
    others[block] = -2.0
    assert others.max() <= kept.min()
    np.testing.assert_array_equal(t.values.numpy(), img[0, 0].reshape(-1)[y * w + x].numpy())


def _blur_reference(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """The separable blur as two convolutions with replicated borders (the path of other devices)."""
    r = max(1, math.ceil(3.0 * sigma))
    t = torch.arange(-r, r + 1, dtype=torch.float64)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = (k / k.sum()).to(torch.float32)
    b, c, h, w = x.shape
    y = x.reshape(b * c, 1, h, w)
    y = F.conv2d(F.pad(y, (r, r, 0, 0), mode='replicate'), k.view(1, 1, 1, -1))
    y = F.conv2d(F.pad(y, (0, 0, r, r), mode='replicate'), k.view(1, 1, -1, 1))
    return y.reshape(b, c, h, w)


@pytest.mark.parametrize('sigma', [0.6, 1.25, 1.52, 2.7])
def test_cpu_gaussian_blur_equals_the_convolution(sigma: float) -> None:
    x = torch.rand(2, 3, 37, 53, generator=torch.Generator().manual_seed(1))
    got = gaussian_blur(x, sigma)
    assert got.shape == x.shape
    torch.testing.assert_close(got, _blur_reference(x, sigma), rtol=0.0, atol=1e-6)
    torch.testing.assert_close(gaussian_blur(x[:, :, :, 5:40], sigma), _blur_reference(x[:, :, :, 5:40], sigma),
                               rtol=0.0, atol=1e-6)   # a non-contiguous input


def test_gaussian_stack_is_the_blur_cascade() -> None:
    x = _textured(40, 60)
    steps = [0.9, 1.1, 1.4]
    got = _gaussian_stack(x, steps)
    lv = [x]
    for s in steps:
        lv.append(_blur_reference(lv[-1], s))
    torch.testing.assert_close(got, torch.cat(lv, 1)[0], rtol=0.0, atol=1e-6)


def test_gradients_equal_padded_central_differences() -> None:
    stack = torch.rand(5, 23, 31, generator=torch.Generator().manual_seed(2))
    out = torch.full((2, 5, 23, 31), float('nan'))
    _gradients_into(stack, out)
    p = F.pad(stack[None], (1, 1, 1, 1), mode='replicate')[0]
    assert torch.equal(out[0], (p[:, 1:-1, 2:] - p[:, 1:-1, :-2]) * 0.5)
    assert torch.equal(out[1], (p[:, 2:, 1:-1] - p[:, :-2, 1:-1]) * 0.5)


def test_nms_max_equals_the_running_maxima() -> None:
    resp = torch.rand(5, 29, 41, generator=torch.Generator().manual_seed(3))
    resp[:, 10:14, 10:14] = 0.5    # plateaus: ties
    ref = _max3(_max3(_max3(resp, 2), 1), 0)
    assert torch.equal(_nms_max(resp), ref)


def test_detect_with_two_octaves_leaves_no_garbage_in_the_gradient_buffer() -> None:
    img = _textured(200, 300)
    opts = FeatureOptions(octaves=2)
    c = detect(img, 0, opts)
    assert torch.isfinite(c.tall).all()
    w1 = int(c.size[1, 0])
    r1 = int(c.row0[1])
    assert torch.equal(c.tall[0, :, r1:, w1:], torch.zeros_like(c.tall[0, :, r1:, w1:]))
    kps = describe_candidates(c, 0, 100)
    assert len(kps) > 20
    assert torch.isfinite(kps.descriptors).all()


@pytest.mark.parametrize(('h', 'w'), [(40, 60), (41, 63), (3, 2)])
def test_half_size_equals_avg_pool(h: int, w: int) -> None:
    x = torch.rand(2, 3, h, w, generator=torch.Generator().manual_seed(4))
    got = half_size(x)
    torch.testing.assert_close(got, F.avg_pool2d(x, 2), rtol=0.0, atol=1e-7)
    torch.testing.assert_close(half_size(x.double()), F.avg_pool2d(x.double(), 2), rtol=0.0, atol=0.0)


@pytest.mark.parametrize('border', [0, 2])
def test_cpu_maxima_are_those_of_the_mask(border: int) -> None:
    g = torch.Generator().manual_seed(5)
    resp = torch.rand(5, 31, 47, generator=g) * 1e-4
    resp[:, 10:13, 20:23] = 5e-5      # a plateau: ties are maxima
    resp[2, 5, 5] = 0.5e-5            # a maximum below the threshold
    threshold = 1e-5
    resp[2, 25, 30] = threshold       # at the threshold: not above it
    resp[2, 24:27, 29:32] = torch.minimum(resp[2, 24:27, 29:32], torch.tensor(threshold))
    idx = _is_max(resp, threshold, border).nonzero()
    s, y, x = _maxima_cpu(resp, threshold, border + 1)
    assert s.numel() > 10
    assert torch.equal(s, idx[:, 0] + 1)
    assert torch.equal(y, idx[:, 1] + 1)
    assert torch.equal(x, idx[:, 2] + 1)
    e = _maxima_cpu(torch.zeros(5, 20, 20), threshold, 1)
    assert all(t.numel() == 0 for t in e)


def test_rgb_uint8_to_gray_equals_the_luma_weights() -> None:
    rgb = np.random.default_rng(6).integers(0, 256, (37, 53, 3), dtype=np.uint8)
    got = image_to_gray_tensor(rgb, torch.device('cpu'))
    assert got.shape == (1, 1, 37, 53)
    assert got.dtype == torch.float32
    ref = torch.from_numpy(rgb).to(torch.float32) @ torch.tensor([0.299, 0.587, 0.114]) / 255.0
    torch.testing.assert_close(got[0, 0], ref, rtol=0.0, atol=1e-6)
    # a non-contiguous frame (a crop)
    crop = rgb[3:30, 5:40]
    torch.testing.assert_close(image_to_gray_tensor(crop, torch.device('cpu'))[0, 0], ref[3:30, 5:40], rtol=0.0,
                               atol=1e-6)


@pytest.mark.parametrize('band_pixels', [1, 100, 1000, 1 << 16])
def test_rgb_uint8_to_gray_by_bands_of_rows_is_the_whole_frame_conversion(band_pixels: int, monkeypatch) -> None:
    """The 8-bit RGB conversion runs by bands of rows (no float copy of the whole frame): the same
    values bit for bit as one pass over the frame, however the rows split (one row a band, uneven
    last band, one band)."""
    import cv2

    from srmosaic_ros.core.registration import torch_features

    rgb = np.random.default_rng(7).integers(0, 256, (37, 53, 3), dtype=np.uint8)
    whole = cv2.transform(rgb.astype(np.float32), torch_features._luma_row()).reshape(37, 53)
    monkeypatch.setattr(torch_features, 'GRAY_BAND_PIXELS', band_pixels)
    got = image_to_gray_tensor(rgb, torch.device('cpu'))[0, 0].numpy()
    assert np.array_equal(got, whole)
