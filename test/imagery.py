"""Real aerial texture for unit tests: crops of the bundled orthophoto, warped by known homographies."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

WORLD = Path(__file__).resolve().parent.parent / 'data' / 'worlds' / 'caliterra_IMG_9360.jpg'


@lru_cache(maxsize=1)
def world_rgb(scale: float = 0.25) -> np.ndarray:
    """The caliterra orthophoto downscaled by `scale` (area filter), RGB uint8 (~1000x750)."""
    bgr = cv2.imread(str(WORLD), cv2.IMREAD_COLOR)
    bgr = cv2.resize(bgr, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def view(world_H_frame: np.ndarray, width: int, height: int, *, noise: float = 0.0, seed: int = 0,
         image: np.ndarray | None = None) -> np.ndarray:
    """Render a width x height frame whose pixel p shows world pixel world_H_frame @ p (uint8 RGB)."""
    src = world_rgb() if image is None else image
    frame = cv2.warpPerspective(src, world_H_frame, (width, height),
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
    if noise > 0:
        rng = np.random.default_rng(seed)
        frame = np.clip(frame + rng.normal(0.0, noise, frame.shape), 0, 255).astype(np.uint8)
    return frame


def similarity(angle_deg: float, scale: float, tx: float, ty: float, cx: float = 0.0, cy: float = 0.0) -> np.ndarray:
    """Rotation by angle about (cx, cy), scaling, then translation by (tx, ty)."""
    a = np.deg2rad(angle_deg)
    R = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    H = np.eye(3)
    H[:2, :2] = R
    H[:2, 2] = np.array([cx, cy]) - R @ np.array([cx, cy]) + np.array([tx, ty])
    return H
