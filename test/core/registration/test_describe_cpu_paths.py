"""The CPU fast paths of describe agree with the plain tensor formulations they replace."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

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
