"""Painting placed frames into their segments' canvases: at once, on a painter thread, thinned
(mosaic.paint_stride, core/mosaic/thinning.py), or mosaic.revisit_spread_frames frames later.

Revisit spreading (mosaic.revisit_spread_frames N > 0): every frame is placed at once but painted
N frames later, so that a keyframe's correction can still move it (RevisitCorrector); its record is
decided when it is painted.
"""
from __future__ import annotations

import collections
from typing import Any

import numpy as np

from ..config import PipelineConfig
from ..core.homography import corner_depth_ratio, project_points
from ..core.mosaic.best_view import clip_depth, clipped_polygon
from ..core.mosaic.canvas import CanvasError
from ..core.mosaic.minify import area_reduce
from ..core.mosaic.segments import Segment
from ..core.mosaic.thinning import PaintThinning
from ..core.serial_worker import SerialWorker
from ..core.stage_clock import StageClock
from .checkpointed import Checkpointed
from .paint_input import PaintInput
from .records import FrameRecord, Held

__all__ = ['THIN_MAX_DEPTH_RATIO', 'Painter']

#: A frame is left to its painted neighbours (mosaic.paint_stride) only when the depths of its
#: corners differ by at most this ratio: a view within about 7 deg of nadir for a 60 deg lens.
THIN_MAX_DEPTH_RATIO = 1.15

#: (segment, frame, frame_H_image): a frame placed and not painted yet, its image reduced to the
#: mosaic's sampling (raw is then that image; frame_H_image (3, 3) the reduction, painted at
#: seg_H_frame @ frame_H_image)
Unpainted = tuple[Segment, Held, np.ndarray]


class Painter(Checkpointed):
    """Paints placed frames; keeps the records decided by a later paint until they are taken."""

    STATE = (('_unpainted', 'unpainted'), ('_thin', 'thin'), ('_settled', 'decided'))
    NEWER = frozenset({'_thin'})

    def __init__(self, config: PipelineConfig, clock: StageClock, *, paint_thread: bool = False) -> None:
        self.config = config
        self.clock = clock
        self.worker: SerialWorker | None = SerialWorker(name='srmosaic-paint') if paint_thread else None
        self.input = PaintInput(config)
        self.unpainted: collections.deque[Unpainted] = collections.deque()
        # the moving-object vote needs every frame's colours: no thinning with it
        cfg = config.mosaic
        self.thin = PaintThinning(cfg.paint_stride if not cfg.moving > 0 else 1, cfg.paint_shift_px, cfg.tile_size)
        self.decided: list[FrameRecord] = []  # records decided by a settle or a late paint, not taken yet

    def state(self) -> dict[str, Any]:
        """Checkpointed.state, with the paint input's channel count."""
        return {**super().state(), **self.input.state()}

    def restore(self, state: dict[str, Any]) -> None:
        super().restore(state)
        self.input.restore(state)

    def place(self, seg: Segment, held: Held, seg_H_frame: np.ndarray) -> bool:
        """Place the frame in ``seg`` at seg_H_frame and paint it: now, on the painter thread, or
        mosaic.revisit_spread_frames frames later. False when the placement is refused (the record says why)."""
        record = held.record
        if self.worker is None and self.config.mosaic.revisit_spread_frames == 0 and self.thin.stride == 1:
            return self._paint_in_place(seg, held, seg_H_frame)
        try:  # placed now, painted later: the placement is checked and recorded now
            seg.canvas.check_placement(seg_H_frame, *record.size)
        except CanvasError as exc:
            record.reason = f'not painted: {exc}'
            return False
        seg.place(record.index, seg_H_frame)
        record.segment = seg.index
        record.seg_H_frame = seg_H_frame
        if self.config.mosaic.revisit_spread_frames == 0:
            self._paint_pixels(seg, held)
        else:  # held at the mosaic's sampling: N frames of a 4K stream would take gigabytes as they came
            frame_H_image = np.eye(3)
            k = self.input.area_factor(held.raw, seg_H_frame) if held.raw.dtype == np.uint8 else 1
            if k > 1:
                held.raw, frame_H_image = area_reduce(held.raw, frame_H_image, k)
            self.unpainted.append((seg, held, frame_H_image))
            self.paint_unpainted(keep=self.config.mosaic.revisit_spread_frames)
        return True

    def _paint_in_place(self, seg: Segment, held: Held, seg_H_frame: np.ndarray) -> bool:
        """Check, paint and place the frame in this thread (no painter thread, thinning or spreading)."""
        record = held.record
        with self.clock.stage('paint'):
            try:
                seg.canvas.check_placement(seg_H_frame, *record.size)
                seg.canvas.paint(*self.input.prepare(held.raw, seg_H_frame), finite=held.raw.dtype == np.uint8)
            except CanvasError as exc:  # absurd footprint: refuse, never allocate a giant canvas
                record.reason = f'not painted: {exc}'
                return False
            seg.place(record.index, seg_H_frame)
        record.segment = seg.index
        record.seg_H_frame = seg_H_frame
        return True

    def paint_unpainted(self, keep: int = 0) -> None:
        """Paint the oldest frames held by revisit spreading until ``keep`` remain; their records are decided."""
        while len(self.unpainted) > keep:
            seg, held, frame_H_image = self.unpainted.popleft()
            if held.record.seg_H_frame is not None:
                self._paint_pixels(seg, held, frame_H_image)
            self.decided.append(held.record)

    def holds(self, held: Held) -> bool:
        """Whether ``held`` waits for its paint (revisit spreading): its record is decided then."""
        return any(h is held for _, h, _ in self.unpainted)

    def _paint_pixels(self, seg: Segment, held: Held, frame_H_image: np.ndarray | None = None) -> None:
        """Paint a placed frame (its raw image, at its record's seg_H_frame @ frame_H_image), on the
        painter thread when there is one, unless the paint thinning holds it back (core/mosaic/thinning.py:
        then it is painted later where it sees what its painted neighbours do not, or whole at the end
        of its segment). A paint refused after all (the canvas grew meanwhile) unplaces it, as if never
        placed."""
        if self.thin.stride == 1:
            self._paint_now(seg, held, frame_H_image)
            return
        m, (w, h) = held.record.seg_H_frame, held.record.size
        u = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
        corners, _ = project_points(m, u)
        footprint, _ = project_points(m, clipped_polygon(m, u, clip_depth(m, w, h, self.config.mosaic.max_stretch)))
        # only a near-nadir view is left to its neighbours: an oblique one sees relief and the far
        # field from its own angle, which its neighbours' pixels do not show
        oblique = corner_depth_ratio(m, w, h) > THIN_MAX_DEPTH_RATIO
        for (s, hd, f_H_i), tiles in self.thin.offer(seg.index, (seg, held, frame_H_image), corners, footprint,
                                                     force=oblique):
            self._paint_now(s, hd, f_H_i, tiles)

    def paint_held_back(self) -> None:
        """Paint the frames the paint thinning holds back (the last of each segment)."""
        for (seg, held, frame_H_image), tiles in self.thin.release():
            self._paint_now(seg, held, frame_H_image, tiles)

    def _paint_now(self, seg: Segment, held: Held, frame_H_image: np.ndarray | None = None,
                   tiles: dict[tuple[int, int], tuple[int, int, int, int]] | None = None) -> None:
        record, raw = held.record, held.raw
        seg_H_frame = record.seg_H_frame if frame_H_image is None else record.seg_H_frame @ frame_H_image

        def paint() -> None:
            with self.clock.stage('paint'):
                try:
                    seg.canvas.paint(*self.input.prepare(raw, seg_H_frame), finite=raw.dtype == np.uint8,  # from uint8: finite
                                     tiles=tiles)
                except CanvasError as exc:
                    seg.unplace(record.index)
                    record.segment, record.seg_H_frame = -1, None
                    record.reason = f'not painted: {exc}'

        if self.worker is not None:
            self.worker.submit(paint)
        else:
            paint()

    def take_decided(self) -> list[FrameRecord]:
        """The records decided since the last call (by a settle or a late paint), in order."""
        out = self.decided
        self.decided = []
        return out

    def sync(self) -> None:
        """Wait for the frames being painted on the painter thread: the canvases are complete after
        this. Raises the error of a paint that failed."""
        if self.worker is not None:
            self.worker.wait()  # (the painter counts its own time)

    def close(self) -> None:
        """Finish the paints in flight and stop the painter thread (painting goes on in the caller's thread)."""
        if self.worker is not None:
            worker, self.worker = self.worker, None
            worker.close()
