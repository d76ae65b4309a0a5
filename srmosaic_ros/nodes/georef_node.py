"""GeorefNode: the georeferencing UKF in a process of its own, from /fix, /imu/data and the registrations.

Where the georeferencing runs, and why:

The georeferencing filter stays *inside* the mosaic node by default (`live.georef_standalone:
false`): the mosaic is drawn on the georeferenced raster, so every frame is placed by its fused
pose before it is painted, and chained homographies are pulled toward the pose-predicted placement
(drift control, pipeline.py). That needs the pose of frame k synchronously, between its
registration and its painting; a round trip through another process for every frame would add the
DDS latency to every frame and reorder telemetry against frames differently from `srmosaic
process`, so the live mosaic would no longer match the offline one. The mosaic node then publishes
/srmosaic/pose and /srmosaic/fix itself, and this node, when started, stays idle (it says so once).

The split is still possible: with `live.georef_standalone: true` (set it for the whole graph) the
mosaic node does not fuse telemetry (its mosaic lies in the first frame's pixel plane: registration
and mosaicking only, the cheapest onboard configuration) and this node runs the same Georeferencer
(core/georef) from /fix (NavSatFix), /imu/data (Imu), /camera/camera_info and
/srmosaic/registration (REGISTRATION_LAYOUT: each frame's stamp, its homography to the previous
painted frame, the homography's covariance), and publishes /srmosaic/pose
(PoseWithCovarianceStamped, ENU plane tangent at the first fix, frame_id live.map_frame) and
/srmosaic/fix (NavSatFix) and /srmosaic/odom (nav_msgs/Odometry), one per registered frame, plus /srmosaic/diagnostics. Exactly one node of
a graph publishes the poses in either mode.

Synchronisation: the inputs are merged by stamp, as `srmosaic process` reads a bag. Telemetry waits
in the node until a registration at or after its stamp is fused (registrations come
mosaic.revisit_spread_frames frames late by design, 7.5 s at 4 fps with the defaults: fed at once,
the telemetry would run past the filter's telemetry_buffer_s and the filter would bridge a camera
dropout that is not one), or until it is TELEMETRY_HOLD_S older than the newest. A registration
waits until every telemetry stream still coming has delivered what it stamps up to the
registration's (core/time_sync.TelemetryStreams: under load a fast Imu backlog
drains behind a slow fix stream, and a frame fused early misses its gyro samples), or until it waited
SYNC_TIMEOUT_S of the node's own running time (a node stopped by the scheduler does not time out the
telemetry waiting in its queues), or REGISTRATION_HOLD registrations wait. Bad input (NaN fix, time
going backwards, malformed registration) is logged once per kind and skipped.

The node owns its subscriptions, timers and lifecycle; live.georef_sync.GeorefSync does the merging
and fusing.
"""
from __future__ import annotations

import time
from typing import Any

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from sensor_msgs.msg import CameraInfo, Imu, NavSatFix

from msg_adapters import camera_info_to_intrinsics, imu_to_sample, navsat_to_fix

from ..core.undistort import Undistorter
from ..errors import SrMosaicError
from ..live.georef_sync import REGISTRATION_HOLD, SYNC_TIMEOUT_S, TELEMETRY_HOLD_S, TICK_S, GeorefSync
from .common import TELEMETRY_QOS_DEPTH, DiagnosticsPublisher, PosePublisher, StreamOrder, WarnOnce, input_qos, subscribe_input
from .lifecycle import ManagedNode, autostart, release
from .messages import Messages, message_kind
from .node_checks import check_georef_standalone
from .parameters import GEOREF_PARAMETERS, declare_pipeline_parameters, on_parameter_change, read_pipeline_config

__all__ = ['REGISTRATION_HOLD', 'SYNC_TIMEOUT_S', 'TELEMETRY_HOLD_S', 'TICK_S', 'GeorefNode', 'main']


class GeorefNode(ManagedNode):
    """Georeferencing stage (see module docstring), a managed (lifecycle) node as the mosaic node is.

    configure reads the parameters and, in standalone mode, builds the subscriptions, publishers and
    timers; activate starts fusing; deactivate pauses (inputs are counted and ignored, the filter is
    kept); cleanup fuses the registrations still waiting and frees what configure made (the filter
    with it); shutdown does the same from any state. With live.autostart (default) the node
    configures and activates itself at start.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('srmosaic_georef', **kwargs)
        self._defaults = declare_pipeline_parameters(self, GEOREF_PARAMETERS,
                                                     changeable=('live.preview_period_s',))
        self.warn = WarnOnce(self)
        self.standalone = False
        on_parameter_change(self, {'live.preview_period_s': self._set_period})
        autostart(self)

    def _configure(self) -> None:
        self.config = read_pipeline_config(self, self._defaults)  # ConfigError refuses bad georef.* values
        self._undistorter = Undistorter(self.config.undistort)
        self.standalone = bool(self.get_parameter('live.georef_standalone').value)
        self.messages = Messages(message_kind(self))  # portable or typed registrations
        self._order = StreamOrder(self, self.warn, self.config.stamp_tolerance_s)  # stamps off the clock or backwards
        self.sync: GeorefSync | None = None
        if not self.standalone:
            self.get_logger().info('georeferencing runs inside the mosaic node (live.georef_standalone is false); '
                                   'this node stays idle. Set live.georef_standalone:=true for the whole graph to '
                                   'run the filter here.')
            self.configured = True
            return
        check_georef_standalone(self.standalone, self.config.georef_enabled)
        self.pub_diag = DiagnosticsPublisher(self, 'srmosaic: georeferencing')
        self.sync = GeorefSync(self.config.georef, self.warn, PosePublisher(self).publish, time.monotonic())
        reliable = bool(self.get_parameter('live.reliable_inputs').value)
        qos = input_qos(reliable, TELEMETRY_QOS_DEPTH)
        group = MutuallyExclusiveCallbackGroup()  # one group: the filter sees its inputs one at a time, in order
        subscribe_input(self, NavSatFix, 'fix', self._on_fix, qos, group)
        subscribe_input(self, Imu, 'imu', self._on_imu, qos, group)
        subscribe_input(self, CameraInfo, 'camera_info', self._on_camera_info, qos, group)
        subscribe_input(self, self.messages.registration_type, 'registration', self._on_registration, input_qos(True, 200), group)
        period = float(self.get_parameter('live.preview_period_s').value)
        self.create_timer(TICK_S, lambda: self.sync.tick(time.monotonic()), callback_group=group)
        self._periodic = self.create_timer(period, self._publish_diagnostics,
                                           callback_group=MutuallyExclusiveCallbackGroup())
        self.configured = True

    # -- inputs ---------------------------------------------------------------------------------
    def _telemetry(self, kind: str, convert: Any, msg: Any) -> None:
        if not self.active:
            self.warn.count('inputs_while_inactive')
            return
        try:
            item = convert(msg)
        except SrMosaicError as exc:
            self.warn(kind, f'{kind} skipped: {exc}')
            return
        if self._order.accept(kind, item.stamp_ns):
            self.sync.telemetry(kind, item, time.monotonic())

    def _on_fix(self, msg: NavSatFix) -> None:
        self._telemetry('fix', navsat_to_fix, msg)

    def _on_imu(self, msg: Imu) -> None:
        self._telemetry('imu', imu_to_sample, msg)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            # registrations are of undistorted frames: their camera is the pinhole one (core/undistort.py)
            self.sync.camera = self._undistorter.camera(camera_info_to_intrinsics(msg))
        except SrMosaicError as exc:
            self.warn('camera_info', f'camera info skipped: {exc}')

    def _on_registration(self, msg: Any) -> None:
        if not self.active:  # paused (lifecycle): before the stamp order, so a replay is taken later
            self.warn.count('inputs_while_inactive')
            return
        try:
            reg = self.messages.read_registration(msg)
        except SrMosaicError as exc:
            self.warn('registration', f'registration skipped: {exc}')
            return
        if self._order.accept('registration', reg.stamp_ns):
            self.sync.registration(reg)

    def _publish_diagnostics(self) -> None:
        stats = self.warn.snapshot()
        pose = self.sync.last_pose
        values = {
            'frames_fused': stats.get('frames_fused', 0),
            'poses_published': stats.get('poses_published', 0),
            'registrations_waiting': len(self.sync.pending),
            'last_std_east_m': f'{pose.std_enu_m[0]:.2f}' if pose is not None else 'nan',
            'last_std_north_m': f'{pose.std_enu_m[1]:.2f}' if pose is not None else 'nan',
        }
        if self.sync.georef is not None:
            values.update({f'filter skipped: {k}': v for k, v in self.sync.georef.skipped.items()})
        values.update({k: v for k, v in stats.items() if k.startswith('rejected')})
        message = f"{values['poses_published']} poses"
        if not self.active:
            message = 'inactive (lifecycle): inputs ignored, the filter kept'
            values['inputs_while_inactive'] = stats.get('inputs_while_inactive', 0)
        level, message = self.warn.status(message)
        self.pub_diag.publish(self.pub_diag.array(message, values, level))

    def finish(self) -> None:
        """Fuse the registrations still waiting for telemetry and free what configure made (cleanup,
        shutdown, or the end of the process); nothing when not configured."""
        if not self.configured:
            return
        self.active = False
        self.configured = False
        if self.sync is not None:
            self.sync.flush()
        release(self._entities)
        self._entities, self._periodic, self.sync = [], None, None


def main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros georef_node [--ros-args ...]`."""
    from .executables import node_main

    return node_main('georef_node', GeorefNode, argv)
