"""The dynamic video mosaic (the reference's section 4.3): DIR/mosaic.mp4 shows the mosaic growing
frame by frame with the current frame's footprint outlined.

Frames are kept downscaled while the run goes (a few kB each); at the end they are replayed onto a
low-resolution canvas covering the main segment's final extent, one video frame per mosaic frame.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..core.metrics import apply_homography
from ..core.mosaic.canvas import TiledCanvas
from .video import write_video

__all__ = ['MosaicVideoRecorder']


def _scale(s: float) -> np.ndarray:
    return np.diag([s, s, 1.0])


class MosaicVideoRecorder:
    """Collect downscaled frames with their segment homographies; write the growing-mosaic video."""

    def __init__(self, frame_scale: float = 0.25) -> None:
        self.frame_scale = frame_scale
        self._items: list[tuple[int, np.ndarray, np.ndarray, tuple[int, int]]] = []

    def add(self, segment: int, image01: np.ndarray, seg_H_frame: np.ndarray) -> None:
        """Keep frame (float32 (H, W, C) in [0, 1]) painted into `segment` at seg_H_frame."""
        s = self.frame_scale
        h, w = image01.shape[:2]
        small = cv2.resize(image01, (max(2, round(w * s)), max(2, round(h * s))), interpolation=cv2.INTER_AREA)
        if small.ndim == 2:
            small = small[:, :, None]
        # small pixel p -> full frame pixel (p + 0.5) / s - 0.5 (pixel centres at integers)
        frame_H_small = np.array([[1 / s, 0, 0.5 / s - 0.5], [0, 1 / s, 0.5 / s - 0.5], [0, 0, 1]])
        self._items.append((segment, small, seg_H_frame @ frame_H_small, (w, h)))

    def write(self, path: Path, segment: int, bounds: tuple[int, int, int, int], *, fps: float = 10.0,
              max_side: int = 720) -> int:
        """Encode the growth of `segment` (whose canvas bounds are `bounds`) to `path`; returns frames written."""
        x0, y0, x1, y1 = bounds
        side = max(x1 - x0, y1 - y0, 1)
        s = min(1.0, max_side / side)
        # video pixel = s * (segment pixel - origin): pixel-centre convention as above
        video_H_seg = np.array([[s, 0, -s * x0 + 0.5 * s - 0.5], [0, s, -s * y0 + 0.5 * s - 0.5], [0, 0, 1]])
        width, height = max(2, int(np.ceil((x1 - x0) * s))), max(2, int(np.ceil((y1 - y0) * s)))
        items = [it for it in self._items if it[0] == segment]
        if not items:
            return 0
        canvas = TiledCanvas(items[0][1].shape[2], tile_size=256)

        def frames():
            for _, small, seg_H_small, (w, h) in items:
                canvas.paint(small, video_H_seg @ seg_H_small)
                image, covered = canvas.render((0, 0, width, height))
                if image.ndim == 2:
                    image = image[:, :, None]
                rgb = np.repeat(image, 3, axis=2) if image.shape[2] == 1 else image
                out = np.clip(np.where(covered[..., None], rgb, 0.0) * 255 + 0.5, 0, 255).astype(np.uint8)
                corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
                frame_to_small = np.linalg.inv(np.array([[1 / self.frame_scale, 0, 0.5 / self.frame_scale - 0.5],
                                                         [0, 1 / self.frame_scale, 0.5 / self.frame_scale - 0.5],
                                                         [0, 0, 1]]))
                quad = apply_homography(video_H_seg @ seg_H_small @ frame_to_small, corners)
                cv2.polylines(out, [np.round(quad * 4).astype(np.int32)], True, (255, 40, 40), 2, cv2.LINE_AA,
                              shift=2)
                yield out

        return write_video(path, frames(), fps=fps, gop=int(max(1, fps)))
