"""Where an image lies on a segment's live plane: the text form of header.frame_id on the live topics.

An image of /srmosaic/mosaic_preview, /srmosaic/map_tiles or /srmosaic/sr_tile shows a region
(x0, y0, width, height) of a segment plane (see :class:`ImagePlacement`); an SR tile also carries its
factor (:class:`SRTilePlacement`, the tiles.json convention of DESIGN.md). numpy only, so that the
processes that only read these topics (the map server, the tile recorder) import no solver.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..errors import SrMosaicError

__all__ = ['ImagePlacement', 'SRTilePlacement']

# an image's region of a segment plane in header.frame_id; SR tiles add their factor
_PLACEMENT_RE = re.compile(r'^srmosaic_segment_(-?\d+);x0=(-?\d+);y0=(-?\d+);width=(\d+);height=(\d+)(?:;factor=(\d+))?$')


@dataclass(frozen=True)
class SRTilePlacement:
    """Where an SR tile lies: segment-plane region (x0, y0, width, height) in LR plane pixels, and
    the factor (the tile image is (height * factor, width * factor)); see the module docstring."""

    segment: int
    x0: int
    y0: int
    width: int
    height: int
    factor: int

    def frame_id(self) -> str:
        """The text form carried in sensor_msgs/Image header.frame_id of /srmosaic/sr_tile."""
        return (f'srmosaic_segment_{self.segment};x0={self.x0};y0={self.y0};width={self.width};'
                f'height={self.height};factor={self.factor}')

    @classmethod
    def parse(cls, frame_id: str) -> SRTilePlacement:
        """Inverse of :meth:`frame_id`; raises SrMosaicError on any other text."""
        m = _PLACEMENT_RE.match(frame_id.strip())
        if not m or m.group(6) is None:
            msg = (f'{frame_id!r} is not an SR tile placement; expected '
                   "'srmosaic_segment_<k>;x0=<int>;y0=<int>;width=<int>;height=<int>;factor=<int>'.")
            raise SrMosaicError(msg)
        segment, x0, y0, width, height, factor = (int(g) for g in m.groups())
        return cls(segment, x0, y0, width, height, factor)

    def plane_H_tile(self) -> np.ndarray:
        """(3, 3) tile (HR) pixels -> segment plane pixels: u -> x0 + (u + 0.5) / factor - 0.5."""
        s = float(self.factor)
        return np.array([[1.0 / s, 0.0, self.x0 + 0.5 / s - 0.5],
                         [0.0, 1.0 / s, self.y0 + 0.5 / s - 0.5],
                         [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ImagePlacement:
    """The region (x0, y0, width, height) of a segment's plane that an image shows, as its
    header.frame_id carries it: ``srmosaic_segment_<k>;x0=<int>;y0=<int>;width=<int>;height=<int>``
    (the mosaic preview), with ``;factor=<int>`` for an SR tile (live.sr.SRTilePlacement). The image
    spans the region: its pixel (u, v) shows plane point (x0 + (u + 0.5) width / image_width - 0.5,
    y0 + (v + 0.5) height / image_height - 0.5), which for an SR tile (image width = width * factor)
    is the tiles.json convention."""

    segment: int
    x0: int
    y0: int
    width: int
    height: int

    def frame_id(self) -> str:
        return f'srmosaic_segment_{self.segment};x0={self.x0};y0={self.y0};width={self.width};height={self.height}'

    @classmethod
    def parse(cls, frame_id: str) -> ImagePlacement:
        m = _PLACEMENT_RE.match(frame_id.strip())
        if not m:
            msg = (f'{frame_id!r} is not an image placement on the live plane; expected '
                   "'srmosaic_segment_<k>;x0=<int>;y0=<int>;width=<int>;height=<int>[;factor=<int>]'.")
            raise SrMosaicError(msg)
        return cls(*(int(g) for g in m.groups()[:5]))

    def plane_H_image(self, image_width: int, image_height: int) -> np.ndarray:
        """(3, 3) image pixel (centres at integers) -> plane pixel, for an image of that size."""
        if image_width < 1 or image_height < 1:
            msg = f'an image of {image_width}x{image_height} pixels cannot be placed.'
            raise SrMosaicError(msg)
        sx, sy = self.width / image_width, self.height / image_height
        return np.array([[sx, 0.0, self.x0 + 0.5 * sx - 0.5], [0.0, sy, self.y0 + 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
