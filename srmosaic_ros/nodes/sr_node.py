"""SRNode: super-resolved mosaic tiles, reconstructed in the background and published periodically.

Subscribes to /camera/image_raw (sensor_msgs/Image) and /camera/image_raw/compressed
(CompressedImage), the same frames the mosaic node registers, and to /srmosaic/registration
(std_msgs/Float64MultiArray, REGISTRATION_LAYOUT in nodes/common.py), which carries each processed
frame's stamp and its homography into the segment plane, and to /camera/camera_info only to
remove lens distortion from the images as the mosaic node does (``undistort``, core/undistort.py).
It needs nothing else, so it runs in the mosaic node's process or in its own (ground-station SR,
behind a radio link that carries the frames and the registrations).

Publishes /srmosaic/sr_tile (sensor_msgs/Image, rgb8 or mono8) and /srmosaic/diagnostics (also on
/diagnostics). Names in the root namespace; the node's are relative (nodes.common.TOPICS).

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
"""
from __future__ import annotations

import collections
import multiprocessing
import os
import threading
import time
import traceback
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from msg_adapters import (SUPPORTED_ENCODINGS, camera_info_to_intrinsics, header_to_ns_frame,
                          numpy_to_image)

from ..core.sr.reconstruct import SRFramesDisagree
from ..core.sr.self_check import SRNotBetterThanMosaic
from ..core.types import CameraIntrinsics
from ..core.undistort import Undistorter
from ..errors import SrMosaicError
from ..live.sr import (
    LiveFrame,
    LiveFrameStore,
    SRError,
    init_sr_worker_process,
    plan_live_tiles,
    reconstruct_live_tile,
    reconstruct_live_tile_image,
    sr_worker_ready,
)
from .common import (IMAGE_QOS_DEPTH, TOPICS, DiagnosticsPublisher, StreamOrder, WarnOnce, camera_image, check_range,
                     input_qos, subscribe_input)
from .messages import Messages, message_kind
from .node_checks import check_sr_frames_kept, refresh_growth_problem
from .parameters import SR_PARAMETERS, declare_pipeline_parameters, on_parameter_change, read_pipeline_config

#: Parameters `ros2 param set` changes while the node runs (the others are read-only).
CHANGEABLE = ('live.sr_period_s', 'live.sr_tiles_per_round', 'live.sr_refresh_growth')


__all__ = ['SRNode', 'main']


class SRNode(Node):
    """Live SR stage (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('srmosaic_sr', **kwargs)
        defaults = declare_pipeline_parameters(self, SR_PARAMETERS, changeable=CHANGEABLE)
        self.config = read_pipeline_config(self, defaults)  # ConfigError refuses bad sr / sr_tiles values
        self.period_s = float(check_range(self, 'live.sr_period_s', 0.1, 3600.0))
        self.tiles_per_round = int(check_range(self, 'live.sr_tiles_per_round', 1, 100))
        self.refresh_growth = float(check_range(self, 'live.sr_refresh_growth', 0.0, 100.0))
        if problem := refresh_growth_problem(self.refresh_growth):
            raise SrMosaicError(problem)
        kept = int(check_range(self, 'live.sr_frames_kept', 1, 1000))
        pending = int(check_range(self, 'live.sr_images_pending', 1, 1000))
        check_sr_frames_kept(kept, self.config.sr_tiles.min_frames)
        self.factor = int(self.config.sr_tiles.factor)
        self.messages = Messages(message_kind(self))  # portable or typed registrations
        self.worker_kind = str(self.get_parameter('live.sr_worker').value)
        if self.worker_kind not in ('process', 'thread'):
            msg = f"live.sr_worker must be 'process' or 'thread', got {self.worker_kind!r}."
            raise SrMosaicError(msg)
        self._torch_threads = int(self.get_parameter('live.torch_threads').value)
        self._pool: ProcessPoolExecutor | None = None
        if self.worker_kind == 'process':
            self._pool = self._start_pool()
        self.warn = WarnOnce(self)
        self._store = LiveFrameStore(pending=pending, kept=kept)
        self._store_lock = threading.Lock()
        self._sizes: dict[int, tuple[int, int]] = {}
        # (segment, x0, y0) of each published tile -> frames its last publication was made from
        self._done: dict[tuple[int, int, int], int] = {}
        self._order = StreamOrder(self, self.warn, self.config.stamp_tolerance_s)  # stamps off the clock or backwards
        self._planned_at = -1  # store.added at the last round that found nothing to do
        self._times_s: collections.deque[float] = collections.deque(maxlen=200)
        self._wake = threading.Condition()
        self._round_requested = False
        self._busy = False
        self._stop = False

        reliable = bool(self.get_parameter('live.reliable_inputs').value)
        depth = IMAGE_QOS_DEPTH * 5 if reliable else IMAGE_QOS_DEPTH
        images = MutuallyExclusiveCallbackGroup()
        subscribe_input(self, Image, 'image', self._on_image, input_qos(reliable, depth), images)
        subscribe_input(self, CompressedImage, 'image_compressed', self._on_image, input_qos(reliable, depth), images)
        # the registrations are of undistorted frames: the images must be undistorted alike
        self._camera: CameraIntrinsics | None = None
        self._undistorter = Undistorter(self.config.undistort)
        subscribe_input(self, CameraInfo, 'camera_info', self._on_camera_info, input_qos(False, 5), images)
        # Registrations are few and each matters: reliable, deep.
        subscribe_input(self, self.messages.registration_type, 'registration', self._on_registration, input_qos(True, 200),
                        MutuallyExclusiveCallbackGroup())
        self.pub_tile = self.create_publisher(Image, TOPICS['sr_tile'], 10)
        self.pub_diag = DiagnosticsPublisher(self, 'srmosaic: super-resolution')
        timer = self.create_timer(self.period_s, self._on_timer, callback_group=MutuallyExclusiveCallbackGroup())
        on_parameter_change(self, {
            'live.sr_period_s': lambda v: setattr(timer, 'timer_period_ns', int(v * 1e9)),
            'live.sr_tiles_per_round': lambda v: setattr(self, 'tiles_per_round', int(v)),
            'live.sr_refresh_growth': lambda v: setattr(self, 'refresh_growth', float(v)),
        }, check={'live.sr_refresh_growth': refresh_growth_problem})
        self._worker = threading.Thread(target=self._work, name='srmosaic-sr-worker', daemon=True)
        self._worker.start()

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
        with self._store_lock:
            if not self._order.accept('image', stamp_ns):
                return
            self._store.add_image(stamp_ns, msg)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self._camera = camera_info_to_intrinsics(msg)
        except SrMosaicError as exc:
            self.warn('camera_info', f'camera info skipped: {exc}')

    def _on_registration(self, msg: Any) -> None:
        try:
            reg = self.messages.read_registration(msg)
        except SrMosaicError as exc:
            self.warn('registration', f'registration skipped: {exc}')
            return
        with self._store_lock:
            before = self._store.missed_dropped
            self._store.add_registration(reg.stamp_ns, reg.segment if reg.ok else -1, reg.seg_H_frame)
            dropped = self._store.missed_dropped > before
        if dropped:  # counted as a rejection: WARN while it goes on, the way out logged once
            self.warn('registration after its image was dropped',
                      'a registration came after its image had been dropped from the images waiting for theirs '
                      '(live.sr_images_pending): raise it to the camera frames of (mosaic.revisit_spread_frames + '
                      'live.queue_size) registered frames, times camera rate / live.max_rate_hz when that is set')

    def _on_timer(self) -> None:
        with self._wake:
            if self._busy:
                self.warn.count('rounds_skipped_busy')
            else:
                self._round_requested = True
                self._wake.notify()
        self.pub_diag.publish(self._diagnostics())

    # -- worker -----------------------------------------------------------------------------------
    def _start_pool(self) -> ProcessPoolExecutor:
        # spawn, not fork: this process runs DDS threads, which a fork would copy half-alive.
        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                   initializer=init_sr_worker_process, initargs=(self._torch_threads, 10, os.getpid()))
        pool.submit(sr_worker_ready)  # start it now, not at the first tile
        return pool

    def _reconstruct(self, plan, images, seg_H_frames, segment) -> tuple[np.ndarray, Any, str]:
        """(tile, placement, stop reason) in the worker process or, with live.sr_worker thread, here."""
        if self._pool is None:
            image, placement, res = reconstruct_live_tile(plan, images, seg_H_frames, self.factor, self.config.sr,
                                                          segment)
            return image, placement, str(res.stop_reason)
        try:
            return self._pool.submit(reconstruct_live_tile_image, plan, images, seg_H_frames, self.factor,
                                     self.config.sr, segment).result()
        except BrokenProcessPool:
            if self._stop:  # finish() ended the worker process
                raise SRError('the node is stopping: the tile in progress was abandoned') from None
            self.warn('sr worker died', 'the SR worker process died (out of memory or killed); it is restarted '
                      'and the tile skipped')
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None if self._stop else self._start_pool()
            raise SRError('the SR worker process died') from None

    def _image(self, frame: LiveFrame) -> np.ndarray | None:
        """The frame's pixels (H, W[, 3]) uint8/uint16, decoded on first use and kept decoded."""
        if isinstance(frame.payload, np.ndarray):
            return frame.payload
        decoded = camera_image(frame.payload, self._camera, self.warn)
        if decoded is None:
            return None
        image, camera = decoded
        try:
            image = self._undistorter.image(image, camera)
        except SrMosaicError as exc:
            self.warn(f'image: {type(exc).__name__}', f'image skipped: {exc}')
            return None
        frame.payload = image
        return image

    def _work(self) -> None:
        # SR is background work: in the mosaic node's process it must not take the CPU from
        # registration. Linux applies a niceness to the calling thread only (best effort).
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
        except (AttributeError, OSError):
            pass
        while True:
            with self._wake:
                while not self._round_requested and not self._stop:
                    self._wake.wait(0.5)
                if self._stop:
                    return
                self._round_requested = False
                self._busy = True
            try:
                self._round()
            except Exception as exc:  # noqa: BLE001 - the worker must outlive any one tile
                self.warn(f'sr bug: {type(exc).__name__}', f'SR round failed (please report): {exc!r}')
                self.get_logger().error(traceback.format_exc())
            finally:
                with self._wake:
                    self._busy = False

    def _round(self) -> None:
        """Plan, reconstruct and publish up to tiles_per_round tiles."""
        with self._store_lock:
            if self._store.added == self._planned_at:
                return  # nothing new since a round found no tile
            frames = self._store.registered()
            added = self._store.added
        # Frame sizes: from the Image header; a compressed stream is decoded once per round (its
        # newest frame) and its size taken for the others (the frames of one stream share it).
        stream_size = None
        for f in reversed(frames):
            if f.stamp_ns in self._sizes:
                continue
            if isinstance(f.payload, Image):
                self._sizes[f.stamp_ns] = (int(f.payload.width), int(f.payload.height))
                continue
            if stream_size is None:
                image = self._image(f)
                if image is None:
                    continue
                stream_size = (image.shape[1], image.shape[0])
            self._sizes[f.stamp_ns] = stream_size
        frames = [f for f in frames if f.stamp_ns in self._sizes]
        live = {f.stamp_ns for f in frames}
        self._sizes = {k: v for k, v in self._sizes.items() if k in live}
        if frames and any(key[0] != frames[-1].segment for key in self._done):
            # the store keeps the newest segment only: older segments' tiles can never come again
            self._done = {key: n for key, n in self._done.items() if key[0] == frames[-1].segment}
        plans = plan_live_tiles(frames, self._sizes, self.config.sr_tiles, self._done,
                                refresh_growth=self.refresh_growth)
        if not plans:
            self._planned_at = added
            return
        for plan, used in plans[:self.tiles_per_round]:
            if self._stop:
                return
            t0 = time.perf_counter()
            segment = used[-1].segment
            refresh = (segment, plan.x0, plan.y0) in self._done
            self._done[segment, plan.x0, plan.y0] = len(used)
            decoded = [(self._image(f), f) for f in used]
            decoded = [(im, f) for im, f in decoded if im is not None]
            if not decoded:
                continue
            try:
                image, placement, stop_reason = self._reconstruct(
                    plan, [im for im, _ in decoded], [f.seg_H_frame for _, f in decoded], segment)
            except SRFramesDisagree as exc:  # 3-D ground or motion: expected, counted apart
                self.warn('sr tile frames disagree', f'SR tile at ({plan.x0}, {plan.y0}) left to the mosaic: {exc}')
                continue
            except SRNotBetterThanMosaic as exc:  # the leave-one-out check: expected, counted apart
                self.warn('sr tile not better than mosaic', f'SR tile at ({plan.x0}, {plan.y0}) left to the mosaic: {exc}')
                continue
            except SRError as exc:
                self.warn('sr tile', f'SR tile at ({plan.x0}, {plan.y0}) skipped: {exc}')
                continue
            stamp = max(f.stamp_ns for f in used)
            encoding = 'mono8' if image.ndim == 2 else 'rgb8'
            self.pub_tile.publish(numpy_to_image(image, encoding, stamp_ns=stamp, frame_id=placement.frame_id()))
            dt = time.perf_counter() - t0
            self._times_s.append(dt)
            self.warn.count('tiles_published')
            if refresh:
                self.warn.count('tiles_refreshed')
            self.get_logger().debug(f'SR tile {placement.frame_id()} from {len(used)} frames in {dt:.2f} s '
                                    f'({stop_reason})')

    # -- diagnostics, shutdown ------------------------------------------------------------------
    def _diagnostics(self) -> DiagnosticArray:
        stats = self.warn.snapshot()
        times = np.array(self._times_s) if self._times_s else np.array([np.nan])
        with self._store_lock:
            kept, pending, missed = len(self._store.registered()), self._store.pending, self._store.missed
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
            'worker': self.worker_kind,
        }
        values.update({k: v for k, v in stats.items() if k.startswith(('rejected', 'camera_info_scaled'))})
        level, message = self.warn.status(f"{values['tiles_published']} tiles published")
        return self.pub_diag.array(message, values, level)

    def finish(self) -> None:
        """Stop the worker. A tile in progress in the worker process is abandoned (the process is
        ended: a tile takes seconds, a minute on a loaded machine, and once the graph stops it reaches
        nobody; Ctrl-C must not wait for it); with `live.sr_worker: thread` it completes first (up to
        60 s)."""
        with self._wake:
            self._stop = True
            self._wake.notify()
        if self._pool is not None:
            # ProcessPoolExecutor has no way to stop a running call before Python 3.14's
            # terminate_workers(); its worker processes are in _processes (pid -> Process).
            processes = getattr(self._pool, '_processes', None) or {}
            for proc in list(processes.values()):
                proc.terminate()
        self._worker.join(timeout=60)
        if self._pool is not None:
            self._pool.shutdown(wait=not self._worker.is_alive(), cancel_futures=True)


def main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros sr_node [--ros-args ...]`."""
    from .executables import node_main

    return node_main('sr_node', SRNode, argv)
