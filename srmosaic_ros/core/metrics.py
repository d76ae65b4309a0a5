"""Accuracy figures against ground truth: corner errors of homographies."""
from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from .homography import apply_homography
from .registration.validity import frame_corners

__all__ = ['apply_homography', 'corner_error_px', 'mosaic_corner_errors']


def corner_error_px(H_est: np.ndarray, H_true: np.ndarray, width: int, height: int) -> float:
    """Mean distance (px, in the target image) between the frame corners mapped by both homographies."""
    c = frame_corners(width, height)
    return float(np.linalg.norm(apply_homography(H_est, c) - apply_homography(H_true, c), axis=1).mean())


def mosaic_corner_errors(
    mosaic_H_frames: Sequence[np.ndarray],
    world_H_frames: Sequence[np.ndarray],
    width: int,
    height: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Corner errors (px, mosaic pixels) of frame-to-mosaic homographies against the truth.

    The mosaic plane is only defined up to a homography of the ground, so mosaic_H_world is
    fitted by least squares to all frame corners at once (no frame is privileged; drift shows up
    as growing error along the flight). Returns (per-frame mean corner error (N,), mosaic_H_world).
    """
    if len(mosaic_H_frames) != len(world_H_frames) or not mosaic_H_frames:
        msg = 'need the same, non-zero number of estimated and true homographies'
        raise ValueError(msg)
    c = frame_corners(width, height)
    est = np.concatenate([apply_homography(H, c) for H in mosaic_H_frames])
    world = np.concatenate([apply_homography(H, c) for H in world_H_frames])
    mosaic_H_world, _ = cv2.findHomography(world, est, 0)
    if mosaic_H_world is None:
        msg = 'could not fit the mosaic plane to the ground truth (degenerate corners)'
        raise ValueError(msg)
    pred = apply_homography(mosaic_H_world, world)
    err = np.linalg.norm(pred - est, axis=1).reshape(-1, 4).mean(axis=1)
    return err, mosaic_H_world
