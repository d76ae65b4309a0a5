"""A segment's first frames held until the poses settle (and the canvas's sampling is decided), and the pose checks made then.

Settling (mosaic.settle_s, mosaic.settle_max_frames): the first frame of a segment is placed by its
pose when the filter knows least, and drift control then pulls the next frames toward better poses;
painted at once, the first frames would not line up with the later ones. So a segment's first
frames are held, unpainted, until settle_s seconds of them (or settle_max_frames frames) have been
placed; then they are placed back from the newest one through their own registrations,
H_k = H_(k+1) inv(prev_H_cur_(k+1)) (the chain (4.6) run backwards), and painted. Their records are
decided then; their poses are ready at once (Pipeline.take_fused).

Sampling (mosaic.resolution 'finest', canvas_resolution.py): every segment's first frames are held
so, georeferenced or not; when they settle, their scales on the segment's plane decide how finely
its canvas samples it, and their placements are refined by that zoom (with the raster's gsd and
the drift controller, for the georeferenced canvas) before the first of them is painted.

Pose check (poses without a measured attitude: the filter's camera is only the configured mount,
nadir by default): when the first georeferenced segment settles, its drift-control innovations say
whether that assumption fits the footage (core/georef/pose_check.py). When it does not (an oblique
or forward-looking camera), the held frames are placed back in the first frame's pixel plane through
their registrations, no later segment is placed by its pose, and the mosaic is chained as without
intrinsics (georeferenced afterwards by its geotags where they can place it). With a measured
attitude nothing is decided: the elevation the frames show is compared with it (attitude_check).
"""
from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..config import PipelineConfig
from ..core.georef.chain_mount import MountEstimate, horizon_words, mount_from_chain
from ..core.georef.pose_check import PoseCheck, check_measured_attitude, check_pose_placement
from ..core.mosaic.canvas import CanvasError
from ..core.mosaic.resolution import zoom_homography
from ..core.mosaic.segments import Segment
from .canvas_resolution import decided_at_settle, settled_zoom, start_zoom
from .checkpointed import Checkpointed
from .painter import Painter
from .records import Held
from .segment_book import SegmentBook, first_frame_plane
from .telemetry_sync import TelemetrySync

__all__ = ['Settler']

_LOG = logging.getLogger('srmosaic_ros.pipeline')


class Settler(Checkpointed):
    """settling: the first frames of ``settling_seg``, placed, not painted yet; settling_nis: their
    drift-control NIS (evidence for the pose check); pose_check / attitude_check: decided when the
    first georeferenced segment settles (module docstring)."""

    STATE = (('_settling', 'settling'), ('_settling_seg', 'settling_seg'), ('pose_check', 'pose_check'),
             ('_settling_nis', 'settling_nis'), ('attitude_check', 'attitude_check'))
    NEWER = frozenset({'attitude_check'})

    def __init__(self, config: PipelineConfig, telemetry: TelemetrySync, book: SegmentBook, painter: Painter) -> None:
        self.config = config
        self.telemetry = telemetry
        self.book = book
        self.painter = painter
        self.settling: list[Held] = []
        self.settling_seg: Segment | None = None
        self.settling_nis: list[float] = []
        self.pose_check: PoseCheck | None = None
        self.attitude_check: dict[str, Any] | None = None

    @property
    def poses_refused(self) -> bool:
        """Whether the pose check refused the assumed attitude: no segment is placed by its pose."""
        return self.pose_check is not None and not self.pose_check.used

    def begin(self, seg: Segment) -> None:
        """Hold the first frames of ``seg``, georeferenced and new."""
        self.settling_seg = seg

    def note_drift_nis(self, seg: Segment, nis: float) -> None:
        """Keep the drift-control NIS of a frame of the first georeferenced segment while it settles."""
        if seg is self.settling_seg and seg is self.book.geo_canvas and self.pose_check is None:
            self.settling_nis.append(nis)

    def place(self, seg: Segment, held: Held, seg_H_frame: np.ndarray) -> bool:
        """Paint the frame now (Painter.place), or hold it while its segment settles."""
        if seg is not self.settling_seg:
            return self.painter.place(seg, held, seg_H_frame)
        try:  # refused now, as painting it would be: an absurd placement must not become the chain's base
            seg.canvas.check_placement(seg_H_frame, *held.record.size)
        except CanvasError as exc:
            held.record.reason = f'not painted: {exc}'
            return False
        held.record.seg_H_frame = seg_H_frame  # provisional: drift control chains the next frame from it
        self.settling.append(held)
        cfg = self.config.mosaic
        span_s = (held.record.stamp_ns - self.settling[0].record.stamp_ns) * 1e-9
        if span_s >= cfg.settle_s or len(self.settling) >= cfg.settle_max_frames:
            self.settle()
        return True

    def settle(self) -> None:
        """Place the held frames back from the newest through their registrations, and paint them."""
        held, seg = self.settling, self.settling_seg
        self.settling, self.settling_seg = [], None
        if not held or seg is None:
            return
        chained = self._chained_from_first(held)  # the frames' mount shows in it; their placement if refused
        if self._refuse_poses(seg, held, chained) or not seg.georeferenced:
            placed = chained
        else:
            placed = [held[-1].record.seg_H_frame]
            for k in range(len(held) - 2, -1, -1):
                rel = held[k + 1].record.registration.prev_H_cur  # frame k+1 -> frame k (its last good frame)
                h = placed[-1] @ np.linalg.inv(rel)
                placed.append(h / h[2, 2])
            placed.reverse()
        placed = self._refined(seg, held, placed)
        for h_k, frame in zip(placed, held, strict=True):
            if not self.painter.place(seg, frame, h_k):
                frame.record.seg_H_frame = None
            if not self.painter.holds(frame):  # else decided when painted
                self.painter.decided.append(frame.record)

    def _refined(self, seg: Segment, held: list[Held], placed: list[np.ndarray]) -> list[np.ndarray]:
        """The held frames' placements on ``seg``'s canvas sampled as mosaic.resolution 'finest' says
        (canvas_resolution.py): refined by the zoom their scales decide, with the raster's gsd when the
        canvas is the georeferenced one; as they are when the canvas is painted already or its sampling was
        decided with its first frame."""
        cfg = self.config.mosaic
        if not decided_at_settle(cfg) or not seg.canvas.is_empty or (seg.georeferenced and seg is not self.book.geo_canvas):
            return placed
        zoom = settled_zoom(cfg, placed, [frame.record.size for frame in held])
        if seg.georeferenced and zoom > 1.0:
            zoom = self.telemetry.georef.refine_raster(zoom)
        if not zoom > 1.0:
            return placed
        canvas_H_plane = zoom_homography(zoom)
        return [canvas_H_plane @ h for h in placed]

    def _refuse_poses(self, seg: Segment, held: list[Held], chained: list[np.ndarray]) -> bool:
        """Decide pose_check when ``seg``, the first georeferenced segment, settles with ``held`` its
        frames, ``chained`` their _chained_from_first (module docstring); True when its frames must not
        be placed by their poses: then the segment, not painted yet, becomes an ordinary one in its
        first frame's plane and no later one is georeferenced. With a measured attitude nothing is
        decided; it is compared with the frames' instead (_check_attitude)."""
        nis, self.settling_nis = self.settling_nis, []
        if seg is not self.book.geo_canvas or self.pose_check is not None or self.attitude_check is not None:
            return False
        if self.telemetry.attitude_measured():
            self._check_attitude(held, chained)
            return False
        g = self.config.georef
        self.pose_check = check_pose_placement(nis, g.gate_probability, (g.gimbal_azimuth_deg, g.gimbal_elevation_deg),
                                               self._mount_shown(held, chained), len(self.telemetry.attitudes))
        if self.pose_check is None or self.pose_check.used:
            return False
        if held[0].camera is not None:
            self.pose_check = self.pose_check.with_mount_to_try(held[0].camera.K)
        self._warn_refused(self.pose_check)
        seg.georeferenced = False
        self.book.geo_canvas = None
        self.telemetry.georef.drop_raster()
        return True

    @staticmethod
    def _warn_refused(check: PoseCheck) -> None:
        mount = check.mount_to_try
        _LOG.warning('the frames are not placed by the filter\'s poses: %s. They are chained in the first frame\'s plane '
                     'as without intrinsics, and the mosaic is georeferenced afterwards by its geotags if they can place '
                     'it (not when its frames look obliquely). To place them '
                     'on the map through the filter, give the camera attitude (an Imu orientation, gimbal angles) or '
                     'the mount it is fixed at (%s).', check.reason,
                     f'the frames\' own: georef.gimbal_elevation_deg: {mount[1]:g}, georef.gimbal_azimuth_deg: {mount[0]:g}'
                     if mount is not None else 'georef.gimbal_elevation_deg, georef.gimbal_azimuth_deg')

    @staticmethod
    def _mount_shown(held: list[Held], chained: list[np.ndarray]) -> MountEstimate | None:
        """The camera mount the held frames' chain (``chained``, in the first one's plane) shows
        (chain_mount.py), None when it cannot tell."""
        if any(frame.camera is None for frame in held):
            return None
        first_from_plane = np.linalg.inv(chained[0])
        return mount_from_chain([first_from_plane @ h for h in chained], [frame.camera.K for frame in held])

    def _check_attitude(self, held: list[Held], chained: list[np.ndarray]) -> None:
        """Compare the camera elevation the held frames show with the measured camera attitudes of
        their time, from 1 s before the first to 1 s after the last (pose_check.check_measured_attitude);
        warn when they disagree. The poses still place the frames: the measurement is not overruled by
        the frames' estimate."""
        t0, t1 = held[0].record.stamp_ns - 1_000_000_000, held[-1].record.stamp_ns + 1_000_000_000
        self.attitude_check = check_measured_attitude(self._mount_shown(held, chained),
                                                      self.telemetry.measured_elevations_deg(t0, t1))
        check = self.attitude_check
        if check is not None and not check['agrees']:
            _LOG.warning('the frames show the camera looking %s where its measured attitude says %s (%g deg apart, '
                         'report.json attitude_check): check the attitude source and its convention (angles relative to '
                         'the body, not to the horizon; a sign; another axis order); the frames are placed by the '
                         'measured attitude.', horizon_words(check['frames_elevation_deg']),
                         horizon_words(check['measured_elevation_deg']), check['difference_deg'])

    def _chained_from_first(self, held: list[Held]) -> list[np.ndarray]:
        """seg_H_frame (3, 3) of each held frame in the first one's pixel plane (scaled to
        mosaic.max_width and mosaic.oversample), through their registrations (4.6): what a segment without
        georeferencing gives."""
        cfg = self.config.mosaic
        start = first_frame_plane(cfg.max_width, held[0].record.size[0])
        if not decided_at_settle(cfg):  # refined as a chained segment's first frame is (placer.py); else by _refined
            start = zoom_homography(start_zoom(cfg, start, *held[0].record.size)) @ start
        placed = [start]
        for frame in held[1:]:
            placed.append(placed[-1] @ frame.record.registration.prev_H_cur)  # frame k -> frame k-1
        return placed
