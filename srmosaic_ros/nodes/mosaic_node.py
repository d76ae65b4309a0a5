"""MosaicNode: registration and the growing mosaic, live.

Subscribes (sensor-data QoS) to /camera/image_raw (sensor_msgs/Image) and
/camera/image_raw/compressed (CompressedImage), /camera/camera_info, /fix, /imu/data. Publishes
/srmosaic/mosaic_preview (Image, downscaled) and /srmosaic/mosaic_preview/compressed (JPEG),
/srmosaic/registration (std_msgs/Float64MultiArray, layout in REGISTRATION_LAYOUT),
/srmosaic/pose (geometry_msgs/PoseWithCovarianceStamped: the fused body pose per frame, position
in the local ENU plane tangent at the first fix, frame_id live.map_frame; covariance of
(east, north, up, roll, pitch, yaw)), /srmosaic/fix (NavSatFix of the same pose, covariance ENU),
/srmosaic/odom (nav_msgs/Odometry of the same pose, child_frame_id live.body_frame)
and /srmosaic/diagnostics (diagnostic_msgs/DiagnosticArray, also on /diagnostics). With
`live.map_tiles` (default) and while something subscribes to it, /srmosaic/map_tile
(sensor_msgs/CompressedImage, format png, reliable) carries the canvas tiles painted since the last
round (the preview's period), reduced by 2^`live.map_level`, RGBA (transparent where nothing is
painted), header.frame_id their region of the live plane (live.raster.ImagePlacement), within
`live.map_bytes_per_s` (oldest change first; the rest wait, none is lost); /srmosaic/map_tiles
(std_msgs/String JSON, transient local) lists the tiles sent, and the service /srmosaic/get_map
(std_srvs/Trigger) answers the whole map sent so far, PNGs in base64 (live/map_tiles.py);
/srmosaic/footprint (geometry_msgs/PolygonStamped) is the ground the newest fused frame sees by its
pose, in pixels of the /srmosaic/raster grid (frame_id srmosaic_raster). These are the
names in the root namespace: the node uses relative names (nodes.common.TOPICS), so under
`-r __ns:=/uav1` they are /uav1/camera/image_raw, /uav1/srmosaic/..., and all are remappable.
The georeferencing filter runs inside this node (each frame is placed on the georeferenced raster
by its fused pose before it is painted; see nodes/georef_node.py for the reasons); with
`live.georef_standalone: true` it does not, the mosaic lies in the first frame's pixel plane, and
the georef node publishes /srmosaic/pose, /srmosaic/fix and /srmosaic/odom instead. /srmosaic/registration is what
the SR and georef nodes need from this one, so they can run in other processes. With
georeferencing, /srmosaic/raster (std_msgs/String, transient local; live/raster.py) says where the
plane of seg_H_frame (and of the SR tiles' placements) lies on the map.

Back-pressure: image callbacks only convert and enqueue into a bounded queue (parameter
`live.queue_size`); when it is full the oldest frame is dropped and counted (`dropped_frames` in the
diagnostics). One worker thread runs the pipeline; the queue never grows without bound.
`live.max_rate_hz` takes at most that many frames per second by their stamps (the rest skipped
evenly and counted), for a camera faster than the node: a steady rate instead of random drops.
Bad input (wrong encoding, empty image, NaN fix, time going backwards) is logged once per kind
and skipped; the node keeps spinning.
"""
from __future__ import annotations

import collections
import dataclasses
import threading
import traceback
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Point32, PolygonStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu, NavSatFix
from std_msgs.msg import String
from std_srvs.srv import Trigger

from msg_adapters import (
    camera_info_to_intrinsics,
    header_to_ns_frame,
    imu_to_sample,
    navsat_to_fix,
    numpy_to_compressed,
    numpy_to_image,
)

from ..errors import SrMosaicError
from ..live.map_tiles import FOOTPRINT_FRAME, MAP_TILE_FORMAT, MapTileStream
from ..live.raster import ImagePlacement, LiveRaster
from ..core.types import Frame
from ..io.mosaic_files import write_json
from ..io.outputs import peak_rss_mb, preview_image
from ..app.process import write_outputs
from ..pipeline import FrameRecord, Pipeline
from .common import (IMAGE_QOS_DEPTH, REGISTRATION_LAYOUT, SERVICES, TELEMETRY_QOS_DEPTH, TOPICS, DiagnosticsPublisher,
                     PosePublisher, StreamOrder, WarnOnce, camera_image, frame_ids, input_qos,
                     subscribe_input)
from .messages import Messages, message_kind
from .lifecycle import ManagedNode, autostart, release
from .parameters import MOSAIC_PARAMETERS, declare_pipeline_parameters, on_parameter_change, read_pipeline_config

__all__ = ['MosaicNode', 'REGISTRATION_LAYOUT', 'main']

#: The input paused this long (s): the frames held for revisit corrections (mosaic.revisit_spread_frames)
#: are painted too; shorter pauses (frames a second apart) only end the waits for telemetry and settling.
IDLE_PAINT_S = 5.0

#: live.max_rate_hz: a frame this fraction of the interval before it is due is taken as on time
RATE_SLACK = 0.25

#: said once when the queue first drops a frame (then counted; diagnostics WARN while it goes on)
FALLING_BEHIND = ('frames arrive faster than this node processes them: the oldest queued frame is dropped '
                  '(live.queue_size). Register and paint fewer pixels (params/live_hd.yaml: registration.max_width, '
                  'mosaic.max_width), take fewer frames (live.max_rate_hz), or give the node more CPU; a larger live.queue_size '
                  'only rides out bursts, at the cost of latency')


class MosaicNode(ManagedNode):
    """Registration + mosaic stage (see module docstring), a managed (lifecycle) node.

    configure reads the parameters and builds the pipeline, subscriptions, publishers and worker;
    activate starts processing the inputs; deactivate pauses (inputs are counted and ignored, the
    mosaic is kept); cleanup writes the outputs (live.output_dir) and frees the pipeline; shutdown
    does the same from any state. With live.autostart (default) the node configures and activates
    itself at start, a refused configure raising its error (as a plain node would).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('srmosaic_mosaic', **kwargs)
        self._defaults = declare_pipeline_parameters(self, MOSAIC_PARAMETERS,
                                                     changeable=('live.preview_period_s', 'live.map_bytes_per_s'))
        self.warn = WarnOnce(self)  # the counters of the diagnostics; rejected inputs logged once per kind
        on_parameter_change(self, {'live.preview_period_s': self._set_period,
                                   'live.map_bytes_per_s': self._set_map_budget})
        autostart(self)

    def _configure(self) -> None:
        config = read_pipeline_config(self, self._defaults)  # ConfigError refuses bad values at start
        queue_size = int(self.get_parameter('live.queue_size').value)
        period = float(self.get_parameter('live.preview_period_s').value)
        max_rate = float(self.get_parameter('live.max_rate_hz').value)  # 0..1000: the declared range
        self._rate_interval_ns = int(1e9 / max_rate) if max_rate > 0 else 0
        self._next_due_ns: int | None = None  # stamp from which the next frame is due (live.max_rate_hz)
        if not 1 <= queue_size <= 100 or not 0.05 <= period <= 3600:
            msg = f'live.queue_size must be in 1..100 and live.preview_period_s in 0.05..3600 (got {queue_size}, {period}).'
            raise SrMosaicError(msg)
        threads = int(self.get_parameter('live.torch_threads').value)
        if not 0 <= threads <= 256:
            msg = f'live.torch_threads must be in 0..256 (0: one per core), got {threads}.'
            raise SrMosaicError(msg)
        if threads:
            # Process-wide: intra-op threads beyond the cores left free by DDS and the executor
            # only contend with them (bench/live.py).
            torch.set_num_threads(threads)
        self.georef_standalone = bool(self.get_parameter('live.georef_standalone').value)
        if self.georef_standalone:  # the georef node fuses telemetry; the mosaic stays in the frame plane
            config = dataclasses.replace(config, georef_enabled=False)
        self.config = config
        self.messages = Messages(message_kind(self))  # portable or typed registration and raster
        self.output_dir = str(self.get_parameter('live.output_dir').value)
        frame_ids(self)  # refused at start when not frame ids (PosePublisher uses them)
        if self.output_dir:
            from ..io.output_dir import check_output_dir

            check_output_dir(Path(self.output_dir), 'live.output_dir')  # at start, not at shutdown with the mosaic in hand
        # frames painted on a thread of their own while the next ones register (the preview syncs first)
        self.pipeline = Pipeline(config, paint_thread=True)
        self._lock = threading.Lock()  # guards the pipeline (worker vs preview/diagnostics timer)
        self._queue: collections.deque[Frame] = collections.deque(maxlen=queue_size)
        self._telemetry: collections.deque[Any] = collections.deque(maxlen=10000)
        self._wake = threading.Condition()
        self._stop = False
        self._camera = None
        self._order = StreamOrder(self, self.warn, config.stamp_tolerance_s)  # stamps off the clock or backwards
        self._latency_ms: collections.deque[float] = collections.deque(maxlen=500)
        self._dropped_reported = self.warn.snapshot().get('dropped_frames', 0)  # as the last diagnostics said it
        self._last_record: FrameRecord | None = None

        # Sensor-data QoS (best effort, volatile) as camera and GNSS drivers publish it, with room for
        # bursts: the callbacks only enqueue, but they share the interpreter with the worker.
        # live.reliable_inputs: reliable delivery when every frame matters (bag playback, tests).
        reliability = (ReliabilityPolicy.RELIABLE if self.get_parameter('live.reliable_inputs').value
                       else ReliabilityPolicy.BEST_EFFORT)
        # Reliable inputs (bag playback) keep a deeper DDS history: every frame matters there, and
        # the node's executor shares the interpreter with the worker (still bounded).
        depth = IMAGE_QOS_DEPTH * 5 if reliability == ReliabilityPolicy.RELIABLE else IMAGE_QOS_DEPTH
        reliable = reliability == ReliabilityPolicy.RELIABLE
        images_qos = input_qos(reliable, depth)
        telemetry_qos = input_qos(reliable, TELEMETRY_QOS_DEPTH)
        # Input callbacks only convert and enqueue; they get their own callback groups so that the
        # periodic preview (which waits for the pipeline lock) never blocks them. Each group is
        # mutually exclusive, so every stream stays in order.
        inputs = MutuallyExclusiveCallbackGroup()
        images = MutuallyExclusiveCallbackGroup()
        subscribe_input(self, Image, 'image', self._on_image, images_qos, images)
        subscribe_input(self, CompressedImage, 'image_compressed', self._on_image, images_qos, images)
        subscribe_input(self, CameraInfo, 'camera_info', self._on_camera_info, telemetry_qos, inputs)
        subscribe_input(self, NavSatFix, 'fix', self._on_fix, telemetry_qos, inputs)
        subscribe_input(self, Imu, 'imu', self._on_imu, telemetry_qos, inputs)
        self._input_lock = threading.Lock()  # input callbacks run concurrently: guard their shared state
        self.pub_preview = self.create_publisher(Image, TOPICS['preview'], 1)
        self.pub_preview_c = self.create_publisher(CompressedImage, TOPICS['preview_compressed'], 1)
        self.pub_registration = self.create_publisher(self.messages.registration_type, TOPICS['registration'], 50)
        self.pub_diag = DiagnosticsPublisher(self, 'srmosaic: registration and mosaic')
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             history=HistoryPolicy.KEEP_LAST)
        self.pub_raster = self.create_publisher(self.messages.raster_type, TOPICS['raster'], latched)
        self._raster_sent: LiveRaster | None = None
        self._map: MapTileStream | None = None  # live.map_tiles: the changed tiles on /srmosaic/map_tile
        if self.get_parameter('live.map_tiles').value:
            self._map = MapTileStream(int(self.get_parameter('live.map_level').value),
                                      float(self.get_parameter('live.map_bytes_per_s').value))
            # reliable and deep enough for a round's tiles: a tile sent is not lost on the way
            tiles_qos = QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
            self.pub_map_tile = self.create_publisher(CompressedImage, TOPICS['map_tile'], tiles_qos)
            self.pub_map_summary = self.create_publisher(String, TOPICS['map_tiles'], latched)
            self.pub_footprint = self.create_publisher(PolygonStamped, TOPICS['footprint'], 10)
            self._map_summary_sent = ''
            self.create_service(Trigger, SERVICES['get_map'], self._get_map,
                                callback_group=MutuallyExclusiveCallbackGroup())
        if not self.georef_standalone:  # else the georef node publishes them (one publisher per graph)
            self.pub_poses = PosePublisher(self)
        self._preview_thread: threading.Thread | None = None
        self._periodic = self.create_timer(period, self._publish_periodic, callback_group=MutuallyExclusiveCallbackGroup())
        self._worker = threading.Thread(target=self._work, name='srmosaic-mosaic-worker', daemon=True)
        self._worker.start()

        self.configured = True

    # -- input callbacks: convert, check, enqueue; never raise ------------------------------
    def _monotonic(self, stream: str, stamp_ns: int) -> bool:
        with self._input_lock:
            return self._monotonic_locked(stream, stamp_ns)

    def _monotonic_locked(self, stream: str, stamp_ns: int) -> bool:
        return self._order.accept(stream, stamp_ns)

    def _due(self, stamp_ns: int) -> bool:
        """live.max_rate_hz: whether the frame of this stamp is taken. Frames are due one interval
        apart on the stamps' clock (30 fps at 20 Hz: two of three), a frame within RATE_SLACK of
        an interval early counting as on time (stamp jitter must not skip it); after a gap in the
        input the schedule starts again. Called by the image callback only."""
        interval, due = self._rate_interval_ns, self._next_due_ns
        if due is not None and stamp_ns < due - RATE_SLACK * interval:
            return False
        restart = due is None or stamp_ns - due >= interval
        self._next_due_ns = (stamp_ns if restart else due) + interval
        return True

    def _on_image(self, msg: Image | CompressedImage) -> None:
        self.warn.count('frames_received')
        if not self.active:  # inactive (lifecycle): paused, before the stamp order so a replay is taken later
            self.warn.count('frames_while_inactive')
            return
        try:
            stamp_ns, frame_id = header_to_ns_frame(msg)
        except SrMosaicError as exc:
            self.warn(f'image: {type(exc).__name__}', f'image skipped: {exc}')
            return
        decoded = camera_image(msg, self._camera, self.warn)
        if decoded is None:
            return
        image, camera = decoded
        if not self._monotonic('image', stamp_ns):
            return
        if self._rate_interval_ns and not self._due(stamp_ns):
            self.warn.count('frames_skipped_by_rate')
            return
        with self._wake:
            if len(self._queue) == self._queue.maxlen:
                self.warn.note('dropped_frames', FALLING_BEHIND)
            self._queue.append(Frame(stamp_ns, image, camera, frame_id))
            self._wake.notify()

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            camera = camera_info_to_intrinsics(msg)
            if camera != self._camera:
                self._camera = camera
                self._telemetry.append(camera)  # in order with the telemetry: frames without one get it
        except SrMosaicError as exc:
            self.warn('camera_info', f'camera info skipped: {exc}')

    def _on_telemetry(self, kind: str, convert: Any, msg: Any) -> None:
        """Convert a fix or IMU message, check its time order, queue it for the worker."""
        if not self.active:
            return
        try:
            item = convert(msg)
        except SrMosaicError as exc:
            self.warn(kind, f'{kind} skipped: {exc}')
            return
        if self._monotonic(kind, item.stamp_ns):
            self._telemetry.append(item)

    def _on_fix(self, msg: NavSatFix) -> None:
        self._on_telemetry('fix', navsat_to_fix, msg)

    def _on_imu(self, msg: Imu) -> None:
        self._on_telemetry('imu', imu_to_sample, msg)

    # -- worker ---------------------------------------------------------------------------------
    def _work(self) -> None:
        idle_since = time.monotonic()
        while True:
            with self._wake:
                idle = False
                while not self._queue and not self._stop:
                    if not self._wake.wait(0.5):
                        idle = True
                        break
                if self._stop and not self._queue:
                    return
                frame = self._queue.popleft() if self._queue else None
            if frame is not None or not idle:
                idle_since = time.monotonic()
            t0 = time.perf_counter()
            with self._lock:
                records = []
                while self._telemetry:
                    records += self.pipeline.feed(self._telemetry.popleft())
                try:
                    if frame is not None:
                        records += self.pipeline.feed(frame)
                        self.pipeline.clock.end_frame()
                    elif idle and self.pipeline.held_back:  # input paused: do not hold frames forever; those
                        # held for revisit corrections wait IDLE_PAINT_S (frames a second apart keep them)
                        records += self.pipeline.flush(paint_held=time.monotonic() - idle_since >= IDLE_PAINT_S)
                except SrMosaicError as exc:
                    self.warn(f'pipeline: {type(exc).__name__}', f'frame skipped: {exc}')
                    continue
                except Exception as exc:  # noqa: BLE001 - the worker must outlive any one frame
                    self.warn(f'pipeline bug: {type(exc).__name__}',
                                    f'frame skipped after an internal error (please report): {exc!r}')
                    self.get_logger().error(traceback.format_exc())
                    continue
                fused = self.pipeline.take_fused()
                footprint = self._footprint(fused[-1]) if fused and self._map is not None else None
            if footprint is not None:
                self._publish_footprint(*footprint)
            if records:
                self._latency_ms.append((time.perf_counter() - t0) * 1e3)
            self.warn.count('frames_processed', len(records))
            for record in fused:  # poses at once, also of frames held while their segment settles
                self._publish_pose(record)
            for record in records:
                self._publish_registration(record)
                self._last_record = record

    def _publish_registration(self, record: FrameRecord) -> None:
        reg = record.registration
        self.pub_registration.publish(self.messages.registration(
            record.stamp_ns, record.painted, reg.inliers if reg else 0, reg.rms_px if reg else float('nan'),
            record.segment, record.seg_H_frame, reg.prev_H_cur if reg is not None else None,
            bool(reg is not None and reg.ok), getattr(reg, 'covariance', None)))

    def _publish_pose(self, record: FrameRecord) -> None:
        if not self.georef_standalone:
            self.pub_poses.publish(record.stamp_ns, record.pose)

    # -- periodic output ------------------------------------------------------------------------
    def _publish_periodic(self) -> None:
        """Timer: render and publish the preview in a thread of its own (the executor is single-
        threaded, and rendering a large mosaic takes longer than an image callback may wait); a
        round still rendering when the next is due is skipped (diagnostics still go out)."""
        if self._preview_thread is not None and self._preview_thread.is_alive():
            self.warn.count('preview_rounds_skipped')
            self.pub_diag.publish(self._diagnostics())
            return
        self._preview_thread = threading.Thread(target=self._render_and_publish, name='srmosaic-preview', daemon=True)
        self._preview_thread.start()

    def _render_and_publish(self) -> None:
        image = coverage = raster = None
        tiles: list = []
        region = 'srmosaic_mosaic'
        if self._lock.acquire(timeout=2.0):  # the worker holds it per frame; skip a round when busy
            try:
                try:
                    self.pipeline.sync()  # the frames still being painted
                except Exception as exc:  # noqa: BLE001 - a paint that failed skips its frame, not the node
                    self.warn(f'paint: {type(exc).__name__}', f'a frame was not painted: {exc!r}')
                raster = self._live_raster()
                seg = self.pipeline.segments[-1] if self.pipeline.segments else None
                if seg is not None and not seg.canvas.is_empty:
                    # Incremental and reduced: the worker waits for this lock, so its cost must not
                    # grow with the mosaic (a full render of a long flight takes seconds).
                    image, coverage = seg.canvas.render_preview(self.config.mosaic.preview_max_side_px)
                    region = ImagePlacement(seg.index, *seg.canvas.last_preview_region).frame_id()
                if self._map is not None:  # the changed tiles: marked always, read only for a subscriber
                    send = self.pub_map_tile.get_subscription_count() > 0
                    tiles = self._map.collect(self.pipeline.segments, time.monotonic(), send=send)
            finally:
                self._lock.release()
        if raster is not None:
            self.pub_raster.publish(self.messages.raster(raster, self.get_clock().now().nanoseconds))
        if image is not None:
            preview = preview_image(image, coverage, self.config.mosaic.preview_max_side_px)
            stamp = self.get_clock().now().nanoseconds
            u8 = np.clip(preview * 255.0 + 0.5, 0, 255).astype(np.uint8)
            encoding = 'mono8' if u8.ndim == 2 else 'rgb8'
            # header.frame_id: the plane region the preview shows (live.raster.ImagePlacement)
            self.pub_preview.publish(numpy_to_image(u8, encoding, stamp_ns=stamp, frame_id=region))
            self.pub_preview_c.publish(numpy_to_compressed(u8, stamp_ns=stamp, frame_id=region))
        if self._map is not None:
            self._publish_map_tiles(tiles)
        self.pub_diag.publish(self._diagnostics())

    def _footprint(self, record: FrameRecord) -> tuple[int, np.ndarray] | None:
        """(stamp, (4, 2) raster pixels) of the ground a fused frame sees, by its pose (the filter's
        best estimate now, whether or not the frame is painted yet); None without one. Under the lock."""
        georef = self.pipeline.georef
        if georef is None or georef.raster is None or record.pose is None or not record.pose.valid:
            return None
        w, h = record.size
        corners = np.array([[-0.5, w - 0.5, w - 0.5, -0.5], [-0.5, -0.5, h - 0.5, h - 0.5], [1.0, 1.0, 1.0, 1.0]])
        try:
            p = georef.raster_H_frame(record.pose, record.camera) @ corners
        except (SrMosaicError, ValueError, np.linalg.LinAlgError):
            return None
        if not np.all(np.isfinite(p)) or np.any(p[2] <= 0):  # a corner above the horizon
            return None
        return record.stamp_ns, (p[:2] / p[2]).T

    def _publish_footprint(self, stamp_ns: int, corners: np.ndarray) -> None:
        msg = PolygonStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
        msg.header.frame_id = FOOTPRINT_FRAME
        msg.polygon.points = [Point32(x=float(x), y=float(y), z=0.0) for x, y in corners]
        self.pub_footprint.publish(msg)

    def _publish_map_tiles(self, batch: list) -> None:
        """Encode and publish the round's changed tiles within the budget, then the summary when it
        changed (its bytes count against the budget too). Outside the pipeline lock."""
        stamp_ns = self.get_clock().now().nanoseconds  # the tiles' stamp, as the summary lists it
        for frame_id, data in self._map.encode(batch, stamp_ns):
            msg = CompressedImage(format=MAP_TILE_FORMAT, data=data)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            msg.header.frame_id = frame_id
            self.pub_map_tile.publish(msg)
        summary = self._map.summary()
        if summary != self._map_summary_sent:
            self.pub_map_summary.publish(String(data=summary))
            self._map.spend(len(summary))
            self._map_summary_sent = summary

    def _get_map(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """srmosaic/get_map: every map tile sent so far (live/map_tiles.whole_map_text)."""
        response.success, response.message = True, self._map.whole_map()
        return response

    def _set_map_budget(self, value: float) -> None:
        if self._map is not None:
            self._map.set_budget(float(value))

    def _live_raster(self) -> LiveRaster | None:
        """The raster to publish on /srmosaic/raster: when it is new, or drift control's canvas
        similarity moved the plane by more than 2 mm (else None). Called under the pipeline lock."""
        georef = self.pipeline.georef
        if georef is None or georef.raster is None:
            return None
        new = LiveRaster.from_georaster(georef.raster, georef.canvas_similarity)
        if new.moved_m(self._raster_sent) <= 0.002:
            return None
        self._raster_sent = new
        return new

    def _diagnostics(self) -> DiagnosticArray:
        stats = self.warn.snapshot()
        rec = self._last_record
        reg = rec.registration if rec is not None else None
        lat = np.array(self._latency_ms) if self._latency_ms else np.array([np.nan])
        values = {
            'frames_received': stats.get('frames_received', 0),
            'frames_processed': stats.get('frames_processed', 0),
            'dropped_frames': stats.get('dropped_frames', 0),
            'frames_skipped_by_rate': stats.get('frames_skipped_by_rate', 0),
            'frames_in_mosaic': sum(len(s.frames) for s in self.pipeline.segments),
            'segments': len(self.pipeline.segments),
            'last_ok': int(rec.painted) if rec else 0,
            'last_inliers': reg.inliers if reg else 0,
            'last_rms_px': f'{reg.rms_px:.3f}' if reg else 'nan',
            'last_reason': rec.reason if rec else '',
            'processing_ms_median': f'{np.median(lat):.1f}',
            'processing_ms_p95': f'{np.percentile(lat, 95):.1f}',
        }
        values.update({k: v for k, v in stats.items() if k.startswith(('rejected', 'preview_', 'camera_info_scaled'))})
        georef = self.pipeline.georef
        if georef is not None:  # as the standalone georef node says them (a copy: the worker fuses meanwhile)
            values.update({f'filter skipped: {k}': v for k, v in dict(georef.skipped).items()})
        level = DiagnosticStatus.OK
        message = 'registering'
        if rec is not None and not rec.painted:
            level, message = DiagnosticStatus.WARN, f'last frame not registered: {rec.reason}'
        dropped = stats.get('dropped_frames', 0)
        if dropped > self._dropped_reported:  # WARN while frames are being dropped, not for ever after
            level = DiagnosticStatus.WARN
            message += (f'; falling behind: {dropped - self._dropped_reported} frames dropped since the last report '
                        f'({dropped} in all; processing median {values["processing_ms_median"]} ms a frame)')
        elif dropped:
            message += f'; {dropped} frames dropped (falling behind) earlier'
        self._dropped_reported = dropped
        check = self.pipeline.pose_check
        if check is not None and not check.used:  # off the map for the rest of the run: WARN until restarted
            level = max(level, DiagnosticStatus.WARN)
            message += f'; {check.operator_note()}'
            values['pose_placement'] = 'refused'
            if check.mount_to_try is not None:
                values['frames_mount_azimuth_deg'], values['frames_mount_elevation_deg'] = check.mount_to_try
        if not self.active:
            message = 'inactive (lifecycle): inputs ignored, the mosaic kept'
            values['frames_while_inactive'] = stats.get('frames_while_inactive', 0)
        rejecting, message = self.warn.status(message)
        level = max(level, rejecting)  # WARN while messages are being rejected, not for ever after
        return self.pub_diag.array(message, values, level)

    # -- shutdown -------------------------------------------------------------------------------
    def finish(self) -> None:
        """Drain the queue, stop the worker, write the outputs when `output_dir` is set, and free what
        configure made (cleanup, shutdown, or the end of the process); nothing when not configured."""
        if not self.configured:
            return
        self.active = False
        self.configured = False
        with self._wake:
            self._stop = True
            self._wake.notify()
        self._worker.join(timeout=60)
        if self._preview_thread is not None:
            self._preview_thread.join(timeout=60)
        if self.output_dir:
            with self._lock:
                result = self.pipeline.finish()
                report = write_outputs(result, Path(self.output_dir), self.config,
                                       {'input': 'live', 'node_stats': self.warn.snapshot()})
            report['wall_s'] = round(sum(r.time_s for r in result.records), 3)  # processing time
            report['stage_times'] = self.pipeline.clock.summary()
            report['peak_rss_mb'] = round(peak_rss_mb(), 1)
            write_json(Path(self.output_dir) / 'report.json', report)
            self.get_logger().info(f"wrote {report['frames_registered']}/{report['frames_in']} frames to "
                                   f'{self.output_dir}')
        self.pipeline.close()
        release(self._entities)
        self._entities, self._periodic, self.pipeline = [], None, None


def main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros mosaic_node [--ros-args ...]`."""
    from .executables import node_main

    return node_main('mosaic_node', MosaicNode, argv)
