"""A resolution target for simulated flights: tilted squares with sharp straight edges.

The ground of a PSF measurement (`srmosaic psf`, core/sr/psf_estimate.py): natural terrain has no
edges sharp enough to tell the camera's blur from the ground's, a printed target does.
"""
from __future__ import annotations

import os

import cv2
import numpy as np

__all__ = ['checkerboard', 'edge_chart', 'write_edge_chart']


def edge_chart(width: int = 2000, height: int = 1500, *, squares: int = 180, side_px: tuple[float, float] = (30.0, 110.0),
               seed: int = 0) -> np.ndarray:
    """(height, width) uint8: squares at random angles, dark (30) or light (220) on grey (110).

    Edges are drawn anti-aliased at 1/16 px (about a 1-px box blur of the chart itself); squares
    may overlap, which the edge measurement rejects where it happens.
    """
    rng = np.random.default_rng(seed)
    img = np.full((height, width), 110, np.uint8)
    for _ in range(squares):
        c = rng.uniform([0.0, 0.0], [width, height])
        r = rng.uniform(*side_px) / 2.0 * np.sqrt(2.0)
        a = rng.uniform(0.0, np.pi / 2)
        pts = np.array([[np.cos(a + k * np.pi / 2), np.sin(a + k * np.pi / 2)] for k in range(4)]) * r + c
        cv2.fillPoly(img, [np.round(pts * 16).astype(np.int32)], int(rng.choice([30, 220])),
                     lineType=cv2.LINE_AA, shift=4)
    return img


def checkerboard(width: int = 2000, height: int = 1500, *, square_px: float = 80.0, angle_deg: float = 12.0,
                 ) -> np.ndarray:
    """(height, width) uint8 checkerboard (30 / 220) turned by ``angle_deg``, area-averaged from 2x."""
    a = np.deg2rad(angle_deg)
    yy, xx = np.mgrid[0:2 * height, 0:2 * width] / 2.0 + 0.25
    u = xx * np.cos(a) + yy * np.sin(a)
    v = -xx * np.sin(a) + yy * np.cos(a)
    big = ((np.floor(u / square_px) + np.floor(v / square_px)) % 2 * 190 + 30).astype(np.float32)
    return np.rint(cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)).astype(np.uint8)


def write_edge_chart(path: str | os.PathLike[str], **kwargs: object) -> str:
    """Write :func:`edge_chart` (keywords passed on) as an image file; returns the path."""
    return _write(path, edge_chart(**kwargs))  # type: ignore[arg-type]


def _write(path: str | os.PathLike[str], img: np.ndarray) -> str:
    if not cv2.imwrite(str(path), img):
        msg = f'cannot write {path}.'
        raise OSError(msg)
    return str(path)
