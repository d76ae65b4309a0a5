"""Render a camera frame of the flat world through an exact homography, without aliasing.

Image formation (the observation model y = D B W x of DESIGN, on a continuous scene):

1. the scene is the world image, bilinearly interpolated (pixel centres at integers);
2. each sensor pixel integrates the scene over its area, modelled as a Gaussian of
   ``PIXEL_SIGMA_PX`` = 1/sqrt(12) px (the variance of a 1-px box), and the optics blur with a
   Gaussian PSF of ``psf_sigma_px``; together a Gaussian of
   sigma_eff = sqrt(psf_sigma_px^2 + PIXEL_SIGMA_PX^2) sensor pixels, uniform over the image plane;
3. decimation D by an integer factor d keeps one sample per d x d block: low-resolution pixel
   (u, v) is the sensor point (d u + (d - 1) / 2, d v + (d - 1) / 2), the centre of its block;
4. Gaussian noise, rounding and clipping to 8 bits.

How: the sensor plane is sampled on a supersampled grid (q points per sensor pixel, q about the
number of world pixels per sensor pixel, at most ``max_supersample``) aligned so that every output
sample falls exactly on a grid point; the world is bilinearly sampled there (float64 coordinates,
no fixed-point rounding), the grid is blurred by sigma_eff in sensor pixels (so the PSF is right
even where the scale varies across an oblique view), and the output samples are picked. When even
q points per pixel are coarser than the world (steep demagnification), the world crop is first
prefiltered by 0.5 sqrt(delta^2 - 1) world pixels (delta = grid spacing in world pixels) and the
sensor-plane blur reduced by the same amount, so the total stays sigma_eff at the frame centre;
for delta >= 2 most of that prefilter is an exact block average (fast for tiny frames).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from .buildings import Building, trace

__all__ = ['Relief', 'PIXEL_SIGMA_PX', 'effective_sigma_px', 'frame_blur_px', 'local_scales', 'render_frame', 'quantize',
           'reference_render', 'hr_H_lr']

PIXEL_SIGMA_PX = 1.0 / math.sqrt(12.0)


def effective_sigma_px(psf_sigma_px: float) -> float:
    """Total Gaussian blur in sensor pixels: optical PSF and pixel integration."""
    return math.sqrt(psf_sigma_px**2 + PIXEL_SIGMA_PX**2)


def frame_blur_px(psf_sigma_px: float, decimate: int = 1) -> float:
    """The blur of the published (decimated) frames in their own pixels: what ``sr.psf_sigma`` should be.

    Decimation samples one point per d x d block (step 3 above), so the sensor's blur shrinks by d.
    """
    return effective_sigma_px(psf_sigma_px) / int(decimate)


def hr_H_lr(decimate: int) -> np.ndarray:
    """(3, 3) low-resolution (decimated) pixel -> sensor pixel: x_hr = d x_lr + (d - 1) / 2."""
    d = float(decimate)
    o = (d - 1.0) / 2.0
    return np.array([[d, 0.0, o], [0.0, d, o], [0.0, 0.0, 1.0]])


def local_scales(world_px_H_img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Singular values (N, 2) of the Jacobian of the homography at image points (N, 2).

    They are the local magnification, world pixels per image pixel, along the two principal
    directions.
    """
    H = np.asarray(world_px_H_img, dtype=np.float64)
    pts = np.asarray(pts, dtype=np.float64)
    w = pts @ H[2, :2] + H[2, 2]
    xy = (pts @ H[:2, :2].T + H[:2, 2]) / w[:, None]
    # d(xy)/d(pts) = (H[:2,:2] - xy h3^T) / w
    jac = (H[None, :2, :2] - xy[:, :, None] * H[None, 2:3, :2]) / w[:, None, None]
    return np.linalg.svd(jac, compute_uv=False)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples, float32 (*x.shape[, C]), of img (h, w[, C]) at float64 coordinates x, y.

    Coordinates are clamped to the image (edge pixels extend outward). Exact float64 positions:
    no fixed-point rounding of the coordinates (unlike cv2.remap's 1/32 px tables).
    """
    h, w = img.shape[:2]
    x = np.clip(x, 0.0, w - 1.0)
    y = np.clip(y, 0.0, h - 1.0)
    xf = np.minimum(np.floor(x), max(w - 2, 0))
    yf = np.minimum(np.floor(y), max(h - 2, 0))
    fx = (x - xf).astype(np.float32).ravel()
    fy = (y - yf).astype(np.float32).ravel()
    i00 = (yf * w + xf).astype(np.intp).ravel()
    dx = 1 if w > 1 else 0
    dy = w if h > 1 else 0
    planes = cv2.split(img) if img.ndim == 3 else [img]
    out = []
    for plane in planes:
        p = np.ascontiguousarray(plane).reshape(-1)
        a = p.take(i00).astype(np.float32)
        b = p.take(i00 + dx).astype(np.float32)
        top = a + (b - a) * fx
        a = p.take(i00 + dy).astype(np.float32)
        b = p.take(i00 + dy + dx).astype(np.float32)
        bottom = a + (b - a) * fx
        out.append((top + (bottom - top) * fy).reshape(x.shape))
    return out[0] if img.ndim == 2 else cv2.merge(out)


def _crop(world: np.ndarray, x: np.ndarray, y: np.ndarray, pad: int) -> tuple[np.ndarray, int, int]:
    """Crop (a view) of the world covering coordinates x, y plus ``pad`` pixels, and its origin."""
    h, w = world.shape[:2]
    x0 = max(0, int(math.floor(float(x.min()))) - pad)
    y0 = max(0, int(math.floor(float(y.min()))) - pad)
    x1 = min(w, int(math.ceil(float(x.max()))) + pad + 1)
    y1 = min(h, int(math.ceil(float(y.max()))) + pad + 1)
    if x1 - x0 < 2 or y1 - y0 < 2:  # entirely outside: clamp to the nearest border strip
        x0, x1 = min(max(0, x0), w - 2), min(max(2, x1), w)
        y0, y1 = min(max(0, y0), h - 2), min(max(2, y1), h)
    return world[y0:y1, x0:x1], x0, y0


@dataclass(frozen=True)
class Relief:
    """3-D structure on the ground for :func:`render_frame`: the buildings, the camera centre above the
    ground (x, y world px; height m) and the world's metres per pixel."""

    buildings: list[Building]
    camera_xy_px: tuple[float, float]
    camera_height_m: float
    gsd_m: float


def render_frame(world: np.ndarray, world_px_H_hr: np.ndarray, hr_size: tuple[int, int], *,
                 decimate: int = 1, psf_sigma_px: float = 0.7, max_supersample: int = 4,
                 relief: Relief | None = None,
                 row_homographies: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Noise-free frame, float32 in 0..255, (h, w, C) for an (H, W, C) world or (h, w) for a mono one.

    Args:
        world: (H, W, 3) or (H, W) uint8 world image.
        world_px_H_hr: (3, 3) sensor pixel (before decimation) -> world pixel.
        hr_size: (width, height) of the sensor before decimation.
        decimate: integer factor d; the output is (height // d, width // d).
        psf_sigma_px: optical Gaussian PSF, sensor pixels.
        max_supersample: cap on supersampling points per sensor pixel (per axis).
        relief: buildings standing on the ground (None: a flat world). ``world`` must then hold their
            roofs (:func:`~srmosaic_ros.sim.buildings.paint_roofs`); every supersampled ray is traced
            through them, so roofs shift by their height, walls show and hide the ground behind.
        row_homographies: a rolling shutter: sensor row coordinates (n,) -> (n, 3, 3) sensor pixel ->
            world pixel of the pose when that row was exposed (None: every row at ``world_px_H_hr``,
            which then also sets the sampling and blur).

    Convention: pixel centres at integer coordinates; output pixel (u, v) is the sensor point
    (d u + (d - 1) / 2, d v + (d - 1) / 2) (see :func:`hr_H_lr`).
    """
    H = np.asarray(world_px_H_hr, dtype=np.float64)
    w_hr, h_hr = int(hr_size[0]), int(hr_size[1])
    d = int(decimate)
    w_lr, h_lr = w_hr // d, h_hr // d
    probe = np.array([[x, y] for x in (0.0, (w_hr - 1) / 2.0, w_hr - 1.0) for y in (0.0, (h_hr - 1) / 2.0, h_hr - 1.0)])
    sv = local_scales(H, probe)
    s_max = float(sv.max())
    s_ref = float(np.sqrt(np.prod(local_scales(H, probe[4:5])[0])))  # centre: sqrt |det J|
    q = int(min(max(1, math.ceil(s_max - 1e-6)), max_supersample))
    sigma_eff = effective_sigma_px(psf_sigma_px)
    delta = s_ref / q  # grid spacing in world pixels at the centre
    sigma_pre_world = 0.5 * math.sqrt(delta**2 - 1.0) if delta > 1.0 else 0.0
    sigma_cam = math.sqrt(max(sigma_eff**2 - (sigma_pre_world / s_ref) ** 2, 0.0))  # sensor px
    sigma_sub = sigma_cam * q  # supersampled-grid px
    margin = int(math.ceil(4.0 * sigma_sub)) + 1
    step = q * d
    offset = (d - 1) / 2.0
    nx = step * (w_lr - 1) + 2 * margin + 1
    ny = step * (h_lr - 1) + 2 * margin + 1
    gx = offset + (np.arange(nx, dtype=np.float64) - margin) / q
    gy = offset + (np.arange(ny, dtype=np.float64) - margin) / q
    if row_homographies is None:
        den = H[2, 0] * gx[None, :] + H[2, 1] * gy[:, None] + H[2, 2]
        wx = (H[0, 0] * gx[None, :] + H[0, 1] * gy[:, None] + H[0, 2]) / den
        wy = (H[1, 0] * gx[None, :] + H[1, 1] * gy[:, None] + H[1, 2]) / den
    else:
        Hr = np.asarray(row_homographies(gy), dtype=np.float64)  # (ny, 3, 3): each grid row its own pose
        den = Hr[:, 2, 0, None] * gx[None, :] + (Hr[:, 2, 1] * gy + Hr[:, 2, 2])[:, None]
        wx = (Hr[:, 0, 0, None] * gx[None, :] + (Hr[:, 0, 1] * gy + Hr[:, 0, 2])[:, None]) / den
        wy = (Hr[:, 1, 0, None] * gx[None, :] + (Hr[:, 1, 1] * gy + Hr[:, 1, 2])[:, None]) / den
    traced = None
    if relief is not None and relief.buildings:
        sx, sy = np.broadcast_to(gx[None, :], wx.shape), np.broadcast_to(gy[:, None], wx.shape)
        traced = trace(relief.buildings, np.asarray(relief.camera_xy_px), relief.camera_height_m, wx, wy,
                       relief.gsd_m, (sx, sy, np.linalg.inv(H)))
        wx, wy = traced.x, traced.y
    reduce = int(math.floor(delta)) if delta >= 2.0 else 1
    pad = int(math.ceil(4.0 * sigma_pre_world)) + 2 + reduce
    crop, x0, y0 = _crop(world, wx, wy, pad)
    cx, cy = wx - x0, wy - y0
    if reduce > 1:
        # Strong demagnification: average reduce x reduce blocks first (exact box filter, pixel j of
        # the reduced crop is the crop point reduce * j + (reduce - 1) / 2); the box and the coarser
        # bilinear interpolation account for (reduce^2 - 1) / 4 of the prefilter variance.
        h_c, w_c = (crop.shape[0] // reduce) * reduce, (crop.shape[1] // reduce) * reduce
        crop = cv2.resize(crop[:h_c, :w_c].astype(np.float32), (w_c // reduce, h_c // reduce),
                          interpolation=cv2.INTER_AREA)
        cx, cy = (cx - (reduce - 1) / 2.0) / reduce, (cy - (reduce - 1) / 2.0) / reduce
        sigma_rest = math.sqrt(max(sigma_pre_world**2 - (reduce**2 - 1) / 4.0, 0.0)) / reduce
    else:
        sigma_rest = sigma_pre_world
    if sigma_rest > 0.0:
        crop = cv2.GaussianBlur(crop.astype(np.float32), (0, 0), sigma_rest, borderType=cv2.BORDER_REFLECT)
    grid = _bilinear(crop, cx, cy)
    if traced is not None and np.any(traced.wall):
        walls = traced.wall_rgb if grid.ndim == 3 else traced.wall_rgb @ np.float32([0.299, 0.587, 0.114])
        grid[traced.wall] = walls
    if sigma_sub > 0.0:
        grid = cv2.GaussianBlur(grid, (0, 0), sigma_sub, borderType=cv2.BORDER_REFLECT)
    out = grid[margin::step, margin::step]
    return np.ascontiguousarray(out[:h_lr, :w_lr])


def quantize(image: np.ndarray, noise_sigma: float, rng: np.random.Generator | None) -> np.ndarray:
    """Add Gaussian noise (sigma in 0..255 units), round and clip to uint8."""
    img = np.asarray(image, dtype=np.float32)
    if noise_sigma > 0.0 and rng is not None:
        img = img + np.float32(noise_sigma) * rng.standard_normal(img.shape, dtype=np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def reference_render(world: np.ndarray, world_px_H_frame: np.ndarray, size: tuple[int, int],
                     sigma_world_px: float) -> np.ndarray:
    """Check renderer: blur the world by ``sigma_world_px`` then sample it at the frame's pixels.

    A different route to the same image for near-uniform scale (blur in the world instead of on the
    sensor; no supersampling): float32 (h, w[, C]) in 0..255. ``size`` is (width, height).
    """
    H = np.asarray(world_px_H_frame, dtype=np.float64)
    w, h = int(size[0]), int(size[1])
    gx = np.arange(w, dtype=np.float64)
    gy = np.arange(h, dtype=np.float64)
    den = H[2, 0] * gx[None, :] + H[2, 1] * gy[:, None] + H[2, 2]
    wx = (H[0, 0] * gx[None, :] + H[0, 1] * gy[:, None] + H[0, 2]) / den
    wy = (H[1, 0] * gx[None, :] + H[1, 1] * gy[:, None] + H[1, 2]) / den
    pad = int(math.ceil(4.0 * sigma_world_px)) + 2
    crop, x0, y0 = _crop(world, wx, wy, pad)
    if sigma_world_px > 0.0:
        crop = cv2.GaussianBlur(crop.astype(np.float32), (0, 0), sigma_world_px, borderType=cv2.BORDER_REFLECT)
    return _bilinear(crop, wx - x0, wy - y0)
