"""How finely a canvas samples its plane (``mosaic.resolution``, ``mosaic.oversample``).

A frame painted onto a canvas coarser than its own pixels loses the detail between them, and even
at one canvas pixel per frame pixel the resample at a sub-pixel offset is a low-pass filter
(:mod:`.resample`); a canvas finer than the frames keeps what they show. The canvas's plane is fixed
by its first frame (its pixels, scaled to ``mosaic.max_width``, or the georeferenced raster), and
this module says by how much to refine it, the *zoom* z (canvas pixels per plane pixel, >= 1):

- ``first``: z = oversample; the first frame maps at ``oversample`` canvas pixels per pixel;
- ``finest``: the frames' linear scale on the plane, s_k (plane pixels per frame pixel where the frame is
  finest, sqrt(|det J|) = sqrt(|det m| / d**3) for a homography m with projective depth d there:
  :func:`frame_scale`), is known for the first frames of the segment; the sharpest of them, the
  ``FINEST_QUANTILE`` quantile s_q, set the canvas: z = oversample * s_ref / s_q with s_ref the first
  frame's own scale, so that those frames map as the first one would (1:1 below ``mosaic.max_width``),
  when s_ref / s_q reaches ``MIN_REFINEMENT`` (else z = oversample). A flight whose frames get finer
  (descending, zooming in, flying toward an oblique view's near field) gets a finer canvas; a steady
  one, or one whose frames get coarser, keeps the first's.

Either way z is capped: at ``MAX_ZOOM``, and with a bound on the tiles in memory
(``mosaic.max_tiles_in_memory`` > 0) so that one frame's footprint covers at most
``1 / FOOTPRINT_SHARE_OF_BOUND`` of the bound (a paint fetches every tile it writes). The canvas
pixel is then 1 / z plane pixels, which the georeference follows (the raster's gsd / z,
:meth:`..georef.placement.RasterPlacement.refine_raster`).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ['FINEST_QUANTILE', 'FOOTPRINT_SHARE_OF_BOUND', 'MAX_ZOOM', 'MIN_REFINEMENT', 'RESOLUTION_MODES', 'canvas_zoom', 'frame_scale',
           'zoom_homography']

from .config import RESOLUTION_MODES
#: The quantile of the frames' scales on the plane that sets a ``finest`` canvas: the sharpest tenth
#: of the frames map 1:1 (the very sharpest single frame would let one outlier set the memory bill).
FINEST_QUANTILE = 0.1
#: ``finest`` refines the first frame's sampling only when the sharpest frames are this much finer: a
#: steady flight, whose frames' scale wanders with its height and attitude, keeps the first's.
MIN_REFINEMENT = 1.1
#: A canvas is never refined more than this (linear): 16 times the tiles of the first frame's plane.
MAX_ZOOM = 4.0
#: With a bound on the tiles in memory, one frame's footprint may take at most this share of it.
FOOTPRINT_SHARE_OF_BOUND = 4


def frame_scale(plane_H_frame: np.ndarray, w: int, h: int) -> float:
    """Linear scale (plane pixels per frame pixel) of a w x h frame where it is finest on the plane,
    through the (3, 3) homography ``plane_H_frame``: sqrt(|det J|) with J the Jacobian of the map,
    sqrt(|det m| / d**3) at projective depth d (m's third row, signed positive over the frame), least at
    the largest depth over the frame (a corner: d is linear in the pixel). The finest part is what the best view shows of an
    oblique frame in a forward flight (its near field, which its predecessors saw from farther away).
    NaN for a degenerate m (zero depth over the whole frame)."""
    m = np.asarray(plane_H_frame, dtype=np.float64)
    corners = np.array([[-0.5, -0.5, 1.0], [w - 0.5, -0.5, 1.0], [w - 0.5, h - 0.5, 1.0], [-0.5, h - 0.5, 1.0]])
    depth = corners @ m[2]
    if (depth <= 0).all():  # m and -m are one homography (placement.checked_homography's sign)
        depth = -depth
    d = float(depth.max())
    if not d > 0:
        return math.nan
    return math.sqrt(abs(float(np.linalg.det(m))) / d**3)  # invariant to the scale of m


def canvas_zoom(mode: str, oversample: float, scales: Sequence[float], *, first_area_px: float, tile_size: int,
                max_tiles_in_memory: int) -> float:
    """The zoom z >= 1 (canvas pixels per plane pixel) of a canvas (module docstring).

    Args:
        mode: ``'first'`` or ``'finest'``.
        oversample: canvas pixels per frame pixel of the frames that set it (>= 1).
        scales: the frames' linear scales on the plane (:func:`frame_scale`), the first frame's first;
            non-finite ones are ignored.
        first_area_px: the first frame's footprint on the plane (plane pixels squared), for the
            memory bound.
        tile_size: the canvas's tile side T (px).
        max_tiles_in_memory: the canvas's bound on tiles in memory (0: none).
    """
    if mode not in RESOLUTION_MODES:
        msg = f"mosaic.resolution must be one of {', '.join(RESOLUTION_MODES)}, got {mode!r}."
        raise ValueError(msg)
    if not (math.isfinite(oversample) and oversample >= 1.0):
        msg = f'mosaic.oversample must be a number >= 1, got {oversample!r}.'
        raise ValueError(msg)
    z = float(oversample)
    s = np.asarray([v for v in scales if math.isfinite(v) and v > 0], dtype=np.float64)
    if mode == 'finest' and s.size:
        finer = float(s[0]) / float(np.quantile(s, FINEST_QUANTILE))
        z *= finer if finer >= MIN_REFINEMENT else 1.0
    z = min(z, MAX_ZOOM)
    if max_tiles_in_memory > 0 and first_area_px > 0:
        # the footprint z^2 A covers about z^2 A / T^2 tiles (and a ring of partial ones: the side + 1)
        budget_px = max_tiles_in_memory * tile_size**2 / FOOTPRINT_SHARE_OF_BOUND
        z = min(z, max(1.0, math.sqrt(budget_px / first_area_px)))
    return z


def zoom_homography(zoom: float) -> np.ndarray:
    """(3, 3) canvas_H_plane = diag(z, z, 1): plane pixel (x, y) is canvas pixel (z x, z y)."""
    return np.diag([float(zoom), float(zoom), 1.0])
