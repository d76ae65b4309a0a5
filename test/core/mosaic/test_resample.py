"""Tests of how the canvas samples frames (srmosaic_ros.core.mosaic.resample, mosaic.interpolation)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.mosaic import CanvasError, MosaicConfig, TiledCanvas
from srmosaic_ros.core.mosaic import resample


def translation(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def detailed(h: int, w: int, c: int = 3, seed: int = 0) -> np.ndarray:
    """Seeded texture with detail up to about 0.3 cycles per pixel (noise through a 0.7-px Gaussian,
    a camera's PSF), float32 (h, w, c) in [0.1, 0.9]."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, c)).astype(np.float32), (0, 0), 0.7).reshape(h, w, c)
    img = (img - img.min()) / (img.max() - img.min())
    return (0.1 + 0.8 * img).astype(np.float32)


def stripes(h: int, w: int) -> np.ndarray:
    """Hard-edged bars 3 px wide, 0.1 and 0.9, float32 (h, w, 3): the worst case for ringing."""
    x = np.arange(w)
    row = np.where((x // 3) % 2 == 0, 0.1, 0.9).astype(np.float32)
    return np.repeat(np.repeat(row[None, :, None], h, axis=0), 3, axis=2)


def painted(frame: np.ndarray, m: np.ndarray, interpolation: str,
            ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int]]:
    """(render, covered, bounds) of ``frame`` painted alone at mosaic_H_frame ``m``, over the bounds."""
    c = TiledCanvas(frame.shape[2], tile_size=64, blend='bestview', interpolation=interpolation)
    c.paint(frame, m)
    out, cov = c.render()
    return out.reshape(*cov.shape, -1), cov, c.bounds()


def detail_energy(img: np.ndarray) -> float:
    """Mean squared difference of an image (h, w, C) and its 1-px Gaussian blur: its detail."""
    d = img - cv2.GaussianBlur(img, (0, 0), 1.0).reshape(img.shape)
    return float(np.mean(d * d))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((a.astype(np.float64) - b) ** 2)))


@pytest.mark.parametrize('interpolation', ['cubic', 'lanczos'])
def test_a_frame_painted_at_a_subpixel_offset_keeps_its_detail(interpolation: str) -> None:
    """Painted half a pixel off the mosaic's grid and sampled back: bilinear loses about half the
    detail, the clamped bicubic and Lanczos keep most of it."""
    frame = detailed(64, 80)
    m = translation(20.5, 10.5)
    energy = detail_energy(frame[4:-4, 4:-4])
    figures = {}
    for interp in ('linear', interpolation):
        out, _, (x0, y0, _, _) = painted(frame, m, interp)
        back = resample.warp(out, np.linalg.inv(translation(-x0, -y0) @ m), (80, 64), interp)
        inner = (slice(4, -4), slice(4, -4))
        figures[interp] = (detail_energy(out[4:-4, 4:-4]) / energy, psnr(back[inner], frame[inner]))
    lin_keep, lin_psnr = figures['linear']
    keep, trip = figures[interpolation]
    assert lin_keep < 0.5 and keep > 0.7, figures  # the bilinear low-pass at t = 1/2 halves the detail
    assert lin_psnr < 27.0 and trip > 29.0, figures  # frame -> mosaic -> frame


@pytest.mark.parametrize('interpolation', ['cubic', 'lanczos'])
@pytest.mark.parametrize('m', [translation(5.37, -3.61), np.array([[0.97, 0.26, 3.2], [-0.26, 0.97, 40.7], [1e-4, -2e-4, 1.0]])],
                         ids=['subpixel', 'rotated'])
def test_no_overshoot_beyond_the_source_neighbourhood(interpolation: str, m: np.ndarray) -> None:
    """At hard edges each painted value stays between the least and largest of the 2 x 2 frame
    pixels around its preimage (no halo, nothing outside the frame's range), where the unclamped
    kernel overshoots."""
    frame = stripes(40, 60)
    h, w = 40, 60
    size = (90, 90)
    out = resample.warp(frame, translation(20, 10) @ m, size, interpolation)
    raw = cv2.warpPerspective(frame, translation(20, 10) @ m, size, flags=resample.INTERPOLATIONS[interpolation],
                              borderMode=cv2.BORDER_REPLICATE)
    assert raw.max() > 0.92 and raw.min() < 0.08  # the kernel alone rings
    assert out.max() <= 0.9 + 1e-6 and out.min() >= 0.1 - 1e-6
    # the 2 x 2 cell of every preimage inside the frame
    ys, xs = np.mgrid[0:size[1], 0:size[0]]
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    pre = np.linalg.inv(translation(20, 10) @ m) @ pts
    u, v = pre[0] / pre[2], pre[1] / pre[2]
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    u0, v0 = np.floor(u[inside]).astype(int), np.floor(v[inside]).astype(int)
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    g = frame[:, :, 0]
    cell = np.stack([g[v0, u0], g[v0, u1], g[v1, u0], g[v1, u1]])
    got = out[:, :, 0].ravel()[inside]
    assert (got >= cell.min(axis=0) - 1e-5).all() and (got <= cell.max(axis=0) + 1e-5).all()


@pytest.mark.parametrize('interpolation', ['cubic', 'lanczos', 'linear'])
def test_an_integer_offset_paints_the_frame_exactly(interpolation: str) -> None:
    frame = detailed(30, 40)
    out, cov, _ = painted(frame, translation(-7, 12), interpolation)
    assert cov.all()
    np.testing.assert_allclose(out, frame, atol=1e-6)
    as_uint8 = np.round(frame * 255).astype(np.uint8)
    out, _, _ = painted(as_uint8, translation(3, 4), interpolation)
    np.testing.assert_allclose(out, as_uint8 / np.float32(255), atol=1e-6)


@pytest.mark.parametrize('interpolation', ['cubic', 'lanczos'])
def test_invalid_pixels_do_not_leak_through_the_wider_kernel(interpolation: str) -> None:
    """The kernel reads 2 (bicubic) or 4 (Lanczos) pixels beyond a valid one: invalid colour (NaN,
    or a masked-off value) never reaches a painted pixel."""
    frame = np.full((40, 50, 3), 0.5, np.float32)
    mask = np.ones((40, 50), bool)
    mask[:, 30:] = False
    frame[:, 30:40] = 7.0  # masked off, far outside the range
    frame[:, 40:] = np.nan
    c = TiledCanvas(3, tile_size=32, blend='bestview', interpolation=interpolation)
    c.paint(frame, translation(3.4, 2.7) @ np.array([[0.98, 0.17, 0.0], [-0.17, 0.98, 0.0], [0.0, 0.0, 1.0]]), mask=mask)
    out, cov = c.render()
    assert cov.any() and np.isfinite(out[cov]).all()
    np.testing.assert_allclose(out[cov], 0.5, atol=1e-5)


def test_more_channels_than_opencv_warps_at_once() -> None:
    frame = detailed(30, 40, c=6)
    m = translation(2.3, 1.6)
    out = resample.warp(frame, m, (45, 35), 'cubic')
    for k in (0, 3, 5):
        np.testing.assert_allclose(out[:, :, k], resample.warp(np.ascontiguousarray(frame[:, :, k]), m, (45, 35), 'cubic'),
                                   atol=1e-6)


def test_an_unknown_interpolation_is_refused() -> None:
    with pytest.raises(CanvasError, match='interpolation must be one of cubic, lanczos, linear'):
        TiledCanvas(3, interpolation='nearest')
    with pytest.raises(ValueError, match='mosaic.interpolation=.*must be one of'):
        MosaicConfig(interpolation='area')
    assert MosaicConfig().interpolation == TiledCanvas(3).interpolation == 'cubic'
