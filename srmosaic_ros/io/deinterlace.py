"""Interlaced video: one field per frame, so that every frame is one instant.

An interlaced frame holds two fields, its even rows and its odd rows, exposed about 1/50 or 1/60 s
apart; when the camera or the scene moves between them every edge is combed, and no homography fits
both. Registration then locks onto either field from pair to pair (their motion differs by the
inter-field motion), and the mosaic of combed frames is torn. Keeping the top field and filling the
rows between by the mean of their neighbours (a "bob" of one field, FFmpeg yadif's spatial
fallback) halves the vertical resolution of the frame but keeps its geometry: frame row y stays
row y, every output frame is the top field's instant.
"""
from __future__ import annotations

import numpy as np

__all__ = ['top_field']


def top_field(image: np.ndarray) -> np.ndarray:
    """(h, w[, C]) uint8 -> same shape: even rows kept, each odd row the mean of the rows above and below
    (the last row, when odd, a copy of the one above)."""
    out = image.copy()
    h = image.shape[0]
    if h < 2:
        return out
    above = image[0:h - 1:2].astype(np.uint16)
    below = image[2:h:2].astype(np.uint16)
    n = below.shape[0]
    out[1:2 * n:2] = ((above[:n] + below + 1) >> 1).astype(image.dtype)
    if h % 2 == 0:  # the last row is odd and has no row below
        out[h - 1] = image[h - 2]
    return out
