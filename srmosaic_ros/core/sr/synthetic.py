"""Synthetic LR frames of a tile with known HR ground truth, for tests and benchmarks.

The frames follow the observation model (5.1) but are rendered independently of the solver's
operators (no "inverse crime"): the HR ground image is blurred by the Gaussian PSF (OpenCV), then
sampled at every LR frame pixel's centre by bicubic interpolation (``cv2.warpPerspective``), then
noise is added and the frame is quantised to 8 bits. The solver models the same physics with a
bilinear warp on the HR grid followed by the PSF, so the two differ by interpolation and by the
order of blur and warp, as real data differ from any model.

Convention: ``world`` is the HR ground image (H, W, C) float32 in [0, 1]; the tile's HR pixel (u, v)
is world pixel (x0 + u, y0 + v); LR tile pixel (p, q) is at HR tile point (s (p + 0.5) - 0.5, ...).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..homography import translation as _translation
from .operators import hr_H_lr

__all__ = ['SyntheticTile', 'make_synthetic_tile', 'random_tile_H_frame', 'perturb_homography']


@dataclass
class SyntheticTile:
    """truth (H s, W s, C) float32; frames (h, w, C) uint8; tile_H_frames true homographies."""

    truth: np.ndarray
    frames: list[np.ndarray]
    tile_H_frames: list[np.ndarray]
    tile_shape: tuple[int, int]
    factor: int


def random_tile_H_frame(rng: np.random.Generator, tile_shape: tuple[int, int], frame_shape: tuple[int, int], *,
                        max_shift: float = 3.0, max_rot_deg: float = 3.0, max_scale: float = 0.03,
                        perspective: float = 0.01) -> np.ndarray:
    """A small random homography frame LR pixels -> tile LR pixels, frame centre near the tile centre.

    Shift uniform in +-max_shift LR px, rotation +-max_rot_deg, scale 1 +- max_scale, and a
    perspective that changes the scale by up to +-perspective across the frame.
    """
    hf, wf = frame_shape
    ht, wt = tile_shape
    a = np.deg2rad(rng.uniform(-max_rot_deg, max_rot_deg))
    sc = 1.0 + rng.uniform(-max_scale, max_scale)
    rot = np.array([[sc * np.cos(a), -sc * np.sin(a), 0.0], [sc * np.sin(a), sc * np.cos(a), 0.0], [0, 0, 1.0]])
    persp = np.eye(3)
    persp[2, 0] = rng.uniform(-perspective, perspective) / max(wf, 1)
    persp[2, 1] = rng.uniform(-perspective, perspective) / max(hf, 1)
    shift = rng.uniform(-max_shift, max_shift, size=2)
    h = (_translation((wt - 1) / 2 + shift[0], (ht - 1) / 2 + shift[1]) @ rot @ persp
         @ _translation(-(wf - 1) / 2, -(hf - 1) / 2))
    return h / h[2, 2]


def perturb_homography(tile_H_frame: np.ndarray, frame_shape: tuple[int, int], corner_sigma_px: float,
                       rng: np.random.Generator) -> np.ndarray:
    """A homography whose four frame corners land ``N(0, corner_sigma_px^2)`` (tile px) off the given one.

    Models the registration error of a homography (its corner error).
    """
    hf, wf = frame_shape
    c = np.array([[0, 0], [wf - 1, 0], [wf - 1, hf - 1], [0, hf - 1]], dtype=np.float64)
    q = np.c_[c, np.ones(4)] @ tile_H_frame.T
    q = q[:, :2] / q[:, 2:]
    q = q + rng.normal(0.0, corner_sigma_px, q.shape)
    h = cv2.getPerspectiveTransform(c.astype(np.float32), q.astype(np.float32)).astype(np.float64)
    return h / h[2, 2]


def make_synthetic_tile(world: np.ndarray, origin: tuple[int, int], tile_shape: tuple[int, int], factor: int,
                        n_frames: int, *, frame_shape: tuple[int, int] | None = None, psf_sigma: float = 0.5,
                        noise_sigma: float = 0.0, seed: int = 0, max_shift: float = 3.0,
                        max_rot_deg: float = 3.0, max_scale: float = 0.03,
                        perspective: float = 0.01) -> SyntheticTile:
    """LR frames y_k = quantise(sample_k(G_sigma * world) + n_k) of the tile at ``origin = (x0, y0)``.

    world: (H, W, C) float32 HR ground image in [0, 1]; tile_shape (H_t, W_t) LR; factor s;
    frame_shape (h, w) LR, default the tile plus 12 px each side; psf_sigma in LR pixels;
    noise_sigma in grey levels of 255. Raises ValueError when the frames reach outside ``world``.
    """
    s = int(factor)
    ht, wt = tile_shape
    hf, wf = frame_shape if frame_shape is not None else (ht + 24, wt + 24)
    x0, y0 = origin
    if world.ndim == 2:
        world = world[:, :, None]
    truth = np.ascontiguousarray(world[y0:y0 + ht * s, x0:x0 + wt * s])
    if truth.shape[:2] != (ht * s, wt * s):
        msg = f'the tile at {origin} of {ht * s}x{wt * s} HR px leaves the {world.shape[:2]} world.'
        raise ValueError(msg)
    rng = np.random.default_rng(seed)
    world_H_hrtile = _translation(x0, y0)
    mats = [random_tile_H_frame(rng, (ht, wt), (hf, wf), max_shift=max_shift, max_rot_deg=max_rot_deg,
                                max_scale=max_scale, perspective=perspective) for _ in range(n_frames)]
    corners = np.array([[0, 0, 1], [wf - 1, 0, 1], [wf - 1, hf - 1, 1], [0, hf - 1, 1]], dtype=np.float64).T
    pts = []
    for m in mats:
        q = world_H_hrtile @ hr_H_lr(s) @ m @ corners
        pts.append((q[:2] / q[2]).T)
    pts_all = np.concatenate(pts)
    sigma_hr = psf_sigma * s
    pad = int(np.ceil(4 * sigma_hr)) + 4
    bx0, by0 = (np.floor(pts_all.min(axis=0)) - pad).astype(int)
    bx1, by1 = (np.ceil(pts_all.max(axis=0)) + pad).astype(int)
    if bx0 < 0 or by0 < 0 or bx1 >= world.shape[1] or by1 >= world.shape[0]:
        msg = f'the frames reach outside the world image ({bx0}, {by0})-({bx1}, {by1}); move the tile inward.'
        raise ValueError(msg)
    region = np.ascontiguousarray(world[by0:by1 + 1, bx0:bx1 + 1].astype(np.float32))
    if sigma_hr > 0:
        region = cv2.GaussianBlur(region, (0, 0), sigmaX=sigma_hr, sigmaY=sigma_hr,
                                  borderType=cv2.BORDER_REFLECT)
    if region.ndim == 2:
        region = region[:, :, None]
    frames = []
    for m in mats:
        region_H_frame = _translation(-bx0, -by0) @ world_H_hrtile @ hr_H_lr(s) @ m
        f = cv2.warpPerspective(region, region_H_frame, (wf, hf),
                                flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
        if f.ndim == 2:
            f = f[:, :, None]
        if noise_sigma > 0:
            f = f + rng.normal(0.0, noise_sigma / 255.0, f.shape).astype(np.float32)
        frames.append(np.clip(np.rint(f * 255.0), 0, 255).astype(np.uint8))
    return SyntheticTile(truth=truth, frames=frames, tile_H_frames=mats, tile_shape=(ht, wt), factor=s)
