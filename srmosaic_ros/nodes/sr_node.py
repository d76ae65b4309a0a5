"""SRNode: super-resolved mosaic tiles, reconstructed in the background and published periodically.

Subscribes to /camera/image_raw (sensor_msgs/Image) and /camera/image_raw/compressed
(CompressedImage), the same frames the mosaic node registers, and to /srmosaic/registration
(std_msgs/Float64MultiArray, REGISTRATION_LAYOUT in nodes/common.py), which carries each processed
frame's stamp and its homography into the segment plane, and to /camera/camera_info only to
remove lens distortion from the images as the mosaic node does (``undistort``, core/undistort.py).
It needs nothing else, so it runs in the mosaic node's process or in its own (ground-station SR,
behind a radio link that carries the frames and the registrations).

Publishes /srmosaic/sr_tile (sensor_msgs/Image, rgb8 or mono8) and /srmosaic/diagnostics (also on
/diagnostics). With `live.map_tiles` (default) each tile also goes on /srmosaic/sr_map_tile
(sensor_msgs/CompressedImage, format png, reliable, the same header.frame_id) within
`live.sr_map_bytes_per_s` (oldest first; the rest wait, none is lost), with the latched summary
/srmosaic/sr_map_tiles (std_msgs/String JSON, transient local) and the service /srmosaic/get_sr_map
(std_srvs/Trigger: every SR tile sent so far, PNGs in base64) for late joiners such as the map server
(nodes/sr_publisher.py). Names in the root namespace; the node's are relative (nodes.common.TOPICS).

Tile placement, carried in every tile: header.stamp is the stamp of the newest frame used;
header.frame_id is ``srmosaic_segment_<k>;x0=<int>;y0=<int>;width=<int>;height=<int>;factor=<int>``
(parse it with :meth:`srmosaic_ros.live.sr.SRTilePlacement.parse`). (x0, y0, width, height) is
the tile's region in pixels of segment k's plane, the plane of seg_H_frame in
/srmosaic/registration (with georeferencing: the north-up UTM raster shared by all georeferenced
segments); the image has height * factor rows and width * factor columns, and tile pixel (u, v)
shows plane point (x0 + (u + 0.5) / factor - 0.5, y0 + (v + 0.5) / factor - 0.5), the convention of
sr/tiles.json of `srmosaic process --sr`.

How it works: image callbacks only keep the message (decoded later, and only for the frames a tile
uses) in a bounded store keyed by stamp (`live.sr_images_pending`); a registration moves the
frame into the store of registered frames (`live.sr_frames_kept`, newest segment only). Every
`live.sr_period_s` a timer asks the worker thread for a round when it is idle: the SR scheduler
(core/sr/scheduler.plan_tiles, settings `sr_tiles.*`) picks the tiles that at least
`sr_tiles.min_frames` registered frames cover entirely and that were not published yet; the worker
reconstructs up to `live.sr_tiles_per_round` of them (core/sr/reconstruct_tile, settings `sr.*`) and
publishes them. A published tile is reconstructed and published again (same placement: a consumer
keeps the latest it received) once it can be made from `live.sr_refresh_growth` times as many
frames as its last publication (frames that arrived later, a revisit), counted as
`tiles_refreshed`; tiles never published go first. The node remembers the published tiles of the
newest segment only. The executor never waits for a reconstruction; a round that is still running
when the timer fires is skipped (counted as `rounds_skipped_busy`).

Where the reconstruction runs (`live.sr_worker`): `process` (default) hands each tile to a worker
process (spawned at start, niceness 10, `live.torch_threads` threads), so that SR in the mosaic
node's process (`srmosaic launch` runs the graph in one process) takes neither the interpreter
lock nor the CPU from registration; `thread` reconstructs in the worker thread itself (no extra
process; it competes with registration for the interpreter). A worker process that dies (out of
memory, killed) is counted and replaced at the next tile.

The node owns its subscriptions and timers; named collaborators do the work:
live.sr_scheduler.SRTileScheduler (the frame store and which tiles each round makes),
live.sr_rounds.RoundThread (the worker thread), live.sr_reconstructor.SRReconstructor (the worker
process), nodes.sr_frames.SRFrameDecoder (decoding and undistortion), nodes.sr_publisher.SRPublisher.
"""
from __future__ import annotations

import time
import traceback
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from msg_adapters import SUPPORTED_ENCODINGS, camera_info_to_intrinsics, header_to_ns_frame

from ..core.sr.reconstruct import SRFramesDisagree
from ..core.sr.self_check import SRNotBetterThanMosaic
from ..errors import SrMosaicError
from ..live.sr import SRError
from ..live.sr_reconstructor import SRReconstructor
from ..live.sr_rounds import RoundThread
from ..live.sr_scheduler import SRJob, SRTileScheduler
from .common import IMAGE_QOS_DEPTH, DiagnosticsPublisher, StreamOrder, WarnOnce, check_range, input_qos, subscribe_input
from .messages import Messages, message_kind
from .node_checks import check_sr_frames_kept, refresh_growth_problem
from .parameters import SR_PARAMETERS, declare_pipeline_parameters, on_parameter_change, read_pipeline_config
from .sr_frames import SRFrameDecoder, header_size
from .sr_publisher import SRPublisher

#: Parameters `ros2 param set` changes while the node runs (the others are read-only).
CHANGEABLE = ('live.sr_period_s', 'live.sr_tiles_per_round', 'live.sr_refresh_growth', 'live.sr_map_bytes_per_s')


__all__ = ['SRNode', 'main']


class SRNode(Node):
    """Live SR stage (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('srmosaic_sr', **kwargs)
        defaults = declare_pipeline_parameters(self, SR_PARAMETERS, changeable=CHANGEABLE)
        self.config = read_pipeline_config(self, defaults)  # ConfigError refuses bad sr / sr_tiles values
        period_s = float(check_range(self, 'live.sr_period_s', 0.1, 3600.0))
        self.tiles_per_round = int(check_range(self, 'live.sr_tiles_per_round', 1, 100))
        refresh_growth = float(check_range(self, 'live.sr_refresh_growth', 0.0, 100.0))
        if problem := refresh_growth_problem(refresh_growth):
            raise SrMosaicError(problem)
        kept = int(check_range(self, 'live.sr_frames_kept', 1, 1000))
        pending = int(check_range(self, 'live.sr_images_pending', 1, 1000))
        check_sr_frames_kept(kept, self.config.sr_tiles.min_frames)
        self.messages = Messages(message_kind(self))  # portable or typed registrations
        self.warn = WarnOnce(self)
        self.reconstructor = SRReconstructor(str(self.get_parameter('live.sr_worker').value), int(self.config.sr_tiles.factor),
                                             self.config.sr, int(self.get_parameter('live.torch_threads').value), self.warn)
        self.scheduler = SRTileScheduler(self.config.sr_tiles, pending=pending, kept=kept, refresh_growth=refresh_growth,
                                         order=StreamOrder(self, self.warn, self.config.stamp_tolerance_s))
        # the registrations are of undistorted frames: the images must be undistorted alike
        self.decode = SRFrameDecoder(self.config.undistort, self.warn)

        reliable = bool(self.get_parameter('live.reliable_inputs').value)
        depth = IMAGE_QOS_DEPTH * 5 if reliable else IMAGE_QOS_DEPTH
        images = MutuallyExclusiveCallbackGroup()
        subscribe_input(self, Image, 'image', self._on_image, input_qos(reliable, depth), images)
        subscribe_input(self, CompressedImage, 'image_compressed', self._on_image, input_qos(reliable, depth), images)
        subscribe_input(self, CameraInfo, 'camera_info', self._on_camera_info, input_qos(False, 5), images)
        # Registrations are few and each matters: reliable, deep.
        subscribe_input(self, self.messages.registration_type, 'registration', self._on_registration, input_qos(True, 200),
                        MutuallyExclusiveCallbackGroup())
        budget = float(self.get_parameter('live.sr_map_bytes_per_s').value)
        self.publisher = SRPublisher(self, budget if self.get_parameter('live.map_tiles').value else None)
        self.pub_diag = DiagnosticsPublisher(self, 'srmosaic: super-resolution')
        timer = self.create_timer(period_s, self._on_timer, callback_group=MutuallyExclusiveCallbackGroup())
        on_parameter_change(self, {
            'live.sr_period_s': lambda v: setattr(timer, 'timer_period_ns', int(v * 1e9)),
            'live.sr_tiles_per_round': lambda v: setattr(self, 'tiles_per_round', int(v)),
            'live.sr_refresh_growth': lambda v: setattr(self.scheduler, 'refresh_growth', float(v)),
            'live.sr_map_bytes_per_s': self.publisher.set_budget,
        }, check={'live.sr_refresh_growth': refresh_growth_problem})
        self.rounds = RoundThread(self._round, name='srmosaic-sr-worker', niceness=10, on_error=self._round_failed)
        self.rounds.start()

    @property
    def factor(self) -> int:
        return self.reconstructor.factor

    # -- inputs: keep the message, never decode here ------------------------------------------
    def _on_image(self, msg: Image | CompressedImage) -> None:
        self.warn.count('frames_received')
        try:
            stamp_ns, _ = header_to_ns_frame(msg)
        except SrMosaicError as exc:
            self.warn(f'image: {type(exc).__name__}', f'image skipped: {exc}')
            return
        if isinstance(msg, Image):
            if msg.width == 0 or msg.height == 0:
                self.warn('image: empty', 'empty image skipped')
                return
            if msg.encoding not in SUPPORTED_ENCODINGS or len(msg.data) < msg.height * msg.step:
                self.warn('image: MessageError', f'image with encoding {msg.encoding!r} and {len(msg.data)} bytes '
                          f'skipped; supported: {", ".join(SUPPORTED_ENCODINGS)}')
                return
        elif len(msg.data) == 0:
            self.warn('image: empty', 'empty compressed image skipped')
            return
        self.scheduler.add_image(stamp_ns, msg)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self.decode.camera = camera_info_to_intrinsics(msg)
        except SrMosaicError as exc:
            self.warn('camera_info', f'camera info skipped: {exc}')

    def _on_registration(self, msg: Any) -> None:
        try:
            reg = self.messages.read_registration(msg)
        except SrMosaicError as exc:
            self.warn('registration', f'registration skipped: {exc}')
            return
        if self.scheduler.add_registration(reg.stamp_ns, reg.segment if reg.ok else -1, reg.seg_H_frame):
            # counted as a rejection: WARN while it goes on, the way out logged once
            self.warn('registration after its image was dropped',
                      'a registration came after its image had been dropped from the images waiting for theirs '
                      '(live.sr_images_pending): raise it to the camera frames of (mosaic.revisit_spread_frames + '
                      'live.queue_size) registered frames, times camera rate / live.max_rate_hz when that is set')

    def _on_timer(self) -> None:
        if not self.rounds.request():
            self.warn.count('rounds_skipped_busy')
        self.pub_diag.publish(self._diagnostics())

    # -- worker -----------------------------------------------------------------------------------
    def _round_failed(self, exc: BaseException) -> None:
        self.warn(f'sr bug: {type(exc).__name__}', f'SR round failed (please report): {exc!r}')
        self.get_logger().error(''.join(traceback.format_exception(exc)))

    def _round(self) -> None:
        """Plan, reconstruct and publish up to tiles_per_round tiles."""
        for job in self.scheduler.plan(self.decode, self.tiles_per_round, header_size=header_size):
            if self.rounds.stopping:
                return
            self._make(job)

    def _make(self, job: SRJob) -> None:
        t0 = time.perf_counter()
        plan = job.plan
        decoded = [(self.decode(f), f) for f in job.frames]
        decoded = [(im, f) for im, f in decoded if im is not None]
        if not decoded:
            return
        try:
            image, placement, stop_reason = self.reconstructor.reconstruct(
                plan, [im for im, _ in decoded], [f.seg_H_frame for _, f in decoded], job.segment)
        except SRFramesDisagree as exc:  # 3-D ground or motion: expected, counted apart
            self.warn('sr tile frames disagree', f'SR tile at ({plan.x0}, {plan.y0}) left to the mosaic: {exc}')
            return
        except SRNotBetterThanMosaic as exc:  # the leave-one-out check: expected, counted apart
            self.warn('sr tile not better than mosaic', f'SR tile at ({plan.x0}, {plan.y0}) left to the mosaic: {exc}')
            return
        except SRError as exc:
            self.warn('sr tile', f'SR tile at ({plan.x0}, {plan.y0}) skipped: {exc}')
            return
        dt = time.perf_counter() - t0
        self.publisher.publish(image, placement.frame_id(), max(f.stamp_ns for f in job.frames), dt)
        self.warn.count('tiles_published')
        if job.refresh:
            self.warn.count('tiles_refreshed')
        self.get_logger().debug(f'SR tile {placement.frame_id()} from {len(job.frames)} frames in {dt:.2f} s '
                                f'({stop_reason})')

    # -- diagnostics, shutdown ------------------------------------------------------------------
    def _diagnostics(self) -> DiagnosticArray:
        stats = self.warn.snapshot()
        times = np.array(self.publisher.times_s) if self.publisher.times_s else np.array([np.nan])
        kept, pending, missed = self.scheduler.counts()
        values = {
            'frames_received': stats.get('frames_received', 0),
            'frames_kept': kept,
            'images_waiting_for_registration': pending,
            'registrations_without_image': missed,
            'tiles_published': stats.get('tiles_published', 0),
            'tiles_refreshed': stats.get('tiles_refreshed', 0),
            'rounds_skipped_busy': stats.get('rounds_skipped_busy', 0),
            'tile_s_median': f'{np.median(times):.2f}',
            'tile_s_p95': f'{np.percentile(times, 95):.2f}',
            'factor': self.factor,
            'worker': self.reconstructor.worker,
        }
        if self.publisher.stream is not None:
            values['sr_map_tiles_waiting'] = self.publisher.stream.pending
        values.update({k: v for k, v in stats.items() if k.startswith(('rejected', 'camera_info_scaled'))})
        level, message = self.warn.status(f"{values['tiles_published']} tiles published")
        return self.pub_diag.array(message, values, level)

    def finish(self) -> None:
        """Stop the worker. A tile in progress in the worker process is abandoned (the process is
        ended: a tile takes seconds, a minute on a loaded machine, and once the graph stops it reaches
        nobody; Ctrl-C must not wait for it); with `live.sr_worker: thread` it completes first (up to
        60 s)."""
        self.rounds.stop()
        self.reconstructor.abandon()
        self.rounds.join(timeout_s=60)
        self.reconstructor.close(wait=not self.rounds.is_alive())


def main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros sr_node [--ros-args ...]`."""
    from .executables import node_main

    return node_main('sr_node', SRNode, argv)
