"""How far a mosaic of 3-D ground is from the true orthophoto, by kind of ground.

A homography mosaic places every frame with the ground plane's motion: what stands above the ground
(roofs, walls) lands where its frame saw it, displaced by its relief, and frames seeing it from
other places disagree there. So errors are reported apart for three kinds of mosaic pixel, read from
the true orthophoto's geometry: ``roofs`` (on a building's footprint), ``near`` (open ground within
``near_m`` of a footprint: where walls and displaced roofs fall and ground is hidden from some
views) and ``open`` (the rest: plane ground, where the mosaic can be exact).

Images are compared in the mosaic's own plane: the orthophoto is sampled at the world pixel of every
mosaic pixel (``world_px_H_mosaic``), so no resampling error of the mosaic enters.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .buildings import Building, footprint_mask

__all__ = ['REGIONS', 'RegionErrors', 'ortho_in_plane', 'region_masks', 'region_errors']

REGIONS = ('open', 'near', 'roofs')


@dataclass(frozen=True)
class RegionErrors:
    """PSNR (dB, intensities in 0..1) and pixel count per region; NaN PSNR where a region is empty."""

    psnr_db: dict[str, float]
    pixels: dict[str, int]


def ortho_in_plane(ortho: np.ndarray, world_px_H_plane: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """float32 (h, w[, C]) in 0..1: the orthophoto (uint8) sampled at every pixel of a plane of ``size``
    (width, height) whose pixel p is world pixel ``world_px_H_plane @ p`` (bilinear, area-reduced
    first where the plane is coarser than the world, so the truth is not aliased)."""
    H = np.asarray(world_px_H_plane, float)
    w, h = size
    centre = np.array([w / 2.0, h / 2.0, 1.0])
    J = H[:2, :2] - np.outer((H @ centre)[:2] / (H @ centre)[2], H[2, :2])
    scale = float(np.sqrt(abs(np.linalg.det(J / (H @ centre)[2]))))  # world px per plane px at the centre
    img = ortho.astype(np.float32) / 255.0
    if scale > 1.5:
        sigma = 0.5 * np.sqrt(scale**2 - 1.0)
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    return cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_REFLECT)


def region_masks(buildings: list[Building], world_px_H_plane: np.ndarray, size: tuple[int, int],
                 gsd_m: float, near_m: float) -> dict[str, np.ndarray]:
    """bool (h, w) per region of a plane of ``size`` (width, height) (see the module docstring)."""
    H = np.asarray(world_px_H_plane, float)
    roofs = footprint_mask(buildings, size, np.linalg.inv(H))
    # distance to the nearest footprint, in metres on the ground: measured in the world, then sampled
    w, h = size
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    den = H[2, 0] * xs + H[2, 1] * ys + H[2, 2]
    wx = (H[0, 0] * xs + H[0, 1] * ys + H[0, 2]) / den
    wy = (H[1, 0] * xs + H[1, 1] * ys + H[1, 2]) / den
    near = np.zeros((h, w), bool)
    reach = near_m / gsd_m
    for b in buildings:
        u_ax, v_ax = b.axes
        dx, dy = wx - b.centre_px[0], wy - b.centre_px[1]
        du = np.maximum(np.abs(dx * u_ax[0] + dy * u_ax[1]) - 0.5 * b.length_px, 0.0)
        dv = np.maximum(np.abs(dx * v_ax[0] + dy * v_ax[1]) - 0.5 * b.width_px, 0.0)
        near |= np.hypot(du, dv) <= reach
    near &= ~roofs
    return {'open': ~(roofs | near), 'near': near, 'roofs': roofs}


def region_errors(image: np.ndarray, covered: np.ndarray, truth: np.ndarray,
                  masks: dict[str, np.ndarray]) -> RegionErrors:
    """PSNR of ``image`` (h, w[, C], 0..1) against ``truth`` (same shape) over each region's covered pixels."""
    err = (np.asarray(image, np.float32) - np.asarray(truth, np.float32)) ** 2
    if err.ndim == 3:
        err = err.mean(axis=2)
    psnr, pixels = {}, {}
    for name in REGIONS:
        sel = masks[name] & covered
        n = int(sel.sum())
        pixels[name] = n
        psnr[name] = float(10.0 * np.log10(1.0 / max(float(err[sel].mean()), 1e-12))) if n else float('nan')
    return RegionErrors(psnr, pixels)
