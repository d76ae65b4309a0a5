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

The node owns its subscriptions, timer and lifecycle; named collaborators do the work:
live.frame_intake.FrameIntake (the queues, the stamp order, the rate limiter),
live.mosaic_worker.MosaicWorker (the thread that drives the Pipeline under its lock),
nodes.mosaic_outputs.MosaicOutputs (registration, poses, footprint), nodes.mosaic_periodic.MosaicPeriodic
(preview, raster, map tiles through a nodes.tile_stream_publisher.TileStreamPublisher, diagnostics
by nodes.mosaic_diagnostics.MosaicDiagnostics).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import torch
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu, NavSatFix

from msg_adapters import camera_info_to_intrinsics, header_to_ns_frame, imu_to_sample, navsat_to_fix

from ..app.process import write_outputs
from ..core.types import Frame
from ..errors import SrMosaicError
from ..io.mosaic_files import write_json
from ..io.outputs import peak_rss_mb
from ..live.frame_intake import FrameIntake
from ..live.map_tiles import MapTileStream
from ..live.mosaic_worker import IDLE_PAINT_S, MosaicWorker
from ..pipeline import Pipeline
from .common import (IMAGE_QOS_DEPTH, REGISTRATION_LAYOUT, TELEMETRY_QOS_DEPTH, DiagnosticsPublisher, StreamOrder, WarnOnce,
                     camera_image, frame_ids, input_qos, subscribe_input)
from .lifecycle import ManagedNode, autostart, release
from .messages import Messages, message_kind
from .mosaic_diagnostics import MosaicDiagnostics
from .mosaic_outputs import MosaicOutputs
from .mosaic_periodic import MosaicPeriodic
from .parameters import MOSAIC_PARAMETERS, declare_pipeline_parameters, on_parameter_change, read_pipeline_config
from .tile_stream_publisher import TileStreamPublisher

__all__ = ['IDLE_PAINT_S', 'MosaicNode', 'REGISTRATION_LAYOUT', 'main']


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
        self.map_stream: MapTileStream | None = None  # live.map_tiles: the changed tiles on /srmosaic/map_tile
        on_parameter_change(self, {'live.preview_period_s': self._set_period,
                                   'live.map_bytes_per_s': self._set_map_budget})
        autostart(self)

    def _configure(self) -> None:
        config = read_pipeline_config(self, self._defaults)  # ConfigError refuses bad values at start
        queue_size = int(self.get_parameter('live.queue_size').value)
        period = float(self.get_parameter('live.preview_period_s').value)
        max_rate = float(self.get_parameter('live.max_rate_hz').value)  # 0..1000: the declared range
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
        standalone = bool(self.get_parameter('live.georef_standalone').value)
        if standalone:  # the georef node fuses telemetry; the mosaic stays in the frame plane
            config = dataclasses.replace(config, georef_enabled=False)
        self.config = config
        self.messages = Messages(message_kind(self))  # portable or typed registration and raster
        self.output_dir = str(self.get_parameter('live.output_dir').value)
        frame_ids(self)  # refused at start when not frame ids (PosePublisher uses them)
        if self.output_dir:
            from ..io.output_dir import check_output_dir

            check_output_dir(Path(self.output_dir), 'live.output_dir')  # at start, not at shutdown with the mosaic in hand
        self.intake = FrameIntake(queue_size, max_rate, StreamOrder(self, self.warn, config.stamp_tolerance_s), self.warn)
        self._subscribe()
        map_tiles = bool(self.get_parameter('live.map_tiles').value)
        tiles = None
        if map_tiles:
            self.map_stream = MapTileStream(int(self.get_parameter('live.map_level').value),
                                            float(self.get_parameter('live.map_bytes_per_s').value))
            tiles = TileStreamPublisher(self, self.map_stream, 'map_tile', 'map_tiles', 'get_map')
        # not with the georef node standalone: it publishes the poses (one publisher per graph)
        outputs = MosaicOutputs(self, self.messages, poses=not standalone, footprints=map_tiles)
        # frames painted on a thread of their own while the next ones register (the preview syncs first)
        self.worker = MosaicWorker(Pipeline(config, paint_thread=True), self.intake, self.warn, outputs,
                                   footprints=map_tiles, log_error=self.get_logger().error)
        diagnostics = MosaicDiagnostics(self.warn, DiagnosticsPublisher(self, 'srmosaic: registration and mosaic'))
        self.periodic = MosaicPeriodic(self, self.worker, diagnostics, tiles, config.mosaic.preview_max_side_px)
        self._periodic = self.create_timer(period, self.periodic.tick, callback_group=MutuallyExclusiveCallbackGroup())
        self.worker.start()
        self.configured = True

    def _subscribe(self) -> None:
        """The inputs. Sensor-data QoS (best effort, volatile) as camera and GNSS drivers publish it,
        with room for bursts: the callbacks only enqueue, but they share the interpreter with the
        worker. live.reliable_inputs: reliable delivery and a deeper history when every frame
        matters (bag playback, tests; still bounded)."""
        reliable = bool(self.get_parameter('live.reliable_inputs').value)
        depth = IMAGE_QOS_DEPTH * 5 if reliable else IMAGE_QOS_DEPTH
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

    # -- input callbacks: convert, check, enqueue; never raise ------------------------------
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
        decoded = camera_image(msg, self.intake.camera, self.warn)
        if decoded is None:
            return
        image, camera = decoded
        if not self.intake.in_order('image', stamp_ns):
            return
        if not self.intake.rate.due(stamp_ns):
            self.warn.count('frames_skipped_by_rate')
            return
        self.intake.put_frame(Frame(stamp_ns, image, camera, frame_id))

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self.intake.set_camera(camera_info_to_intrinsics(msg))
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
        if self.intake.in_order(kind, item.stamp_ns):
            self.intake.put_telemetry(item)

    def _on_fix(self, msg: NavSatFix) -> None:
        self._on_telemetry('fix', navsat_to_fix, msg)

    def _on_imu(self, msg: Imu) -> None:
        self._on_telemetry('imu', imu_to_sample, msg)

    def _set_map_budget(self, value: float) -> None:
        if self.map_stream is not None:
            self.map_stream.set_budget(float(value))

    # -- shutdown -------------------------------------------------------------------------------
    def finish(self) -> None:
        """Drain the queue, stop the worker, write the outputs when `output_dir` is set, and free what
        configure made (cleanup, shutdown, or the end of the process); nothing when not configured."""
        if not self.configured:
            return
        self.active = False
        self.configured = False
        self.worker.stop(timeout_s=60)
        self.periodic.join(timeout_s=60)
        pipeline = self.worker.pipeline
        if self.output_dir:
            with self.worker.lock:
                result = pipeline.finish()
                report = write_outputs(result, Path(self.output_dir), self.config,
                                       {'input': 'live', 'node_stats': self.warn.snapshot()})
            report['wall_s'] = round(sum(r.time_s for r in result.records), 3)  # processing time
            report['stage_times'] = pipeline.clock.summary()
            report['peak_rss_mb'] = round(peak_rss_mb(), 1)
            write_json(Path(self.output_dir) / 'report.json', report)
            self.get_logger().info(f"wrote {report['frames_registered']}/{report['frames_in']} frames to "
                                   f'{self.output_dir}')
        pipeline.close()
        release(self._entities)
        self._entities, self._periodic, self.worker.pipeline, self.map_stream = [], None, None, None


def main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros mosaic_node [--ros-args ...]`."""
    from .executables import node_main

    return node_main('mosaic_node', MosaicNode, argv)
