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
"""
from __future__ import annotations

import collections
import time
from typing import Any

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from sensor_msgs.msg import CameraInfo, Imu, NavSatFix

from msg_adapters import camera_info_to_intrinsics, imu_to_sample, navsat_to_fix

from ..core.georef.georeferencer import Georeferencer
from ..core.undistort import Undistorter
from ..errors import SrMosaicError
from ..core.time_sync import TelemetryStreams
from .common import (TELEMETRY_QOS_DEPTH, DiagnosticsPublisher, PosePublisher, RegistrationMsg, StreamOrder, WarnOnce,
                     input_qos, subscribe_input)
from .messages import Messages, message_kind
from .lifecycle import ManagedNode, autostart, release
from .node_checks import check_georef_standalone
from .parameters import GEOREF_PARAMETERS, declare_pipeline_parameters, on_parameter_change, read_pipeline_config

__all__ = ['GeorefNode', 'main']

#: Seconds (of the node running) a registration waits for its telemetry before it is fused without.
SYNC_TIMEOUT_S = 1.0
#: Registrations that may wait; one more and the oldest is fused without its telemetry (memory bound:
#: they come in bursts, up to mosaic.revisit_spread_frames at once, so the offline SYNC_HOLD_FRAMES is too few).
REGISTRATION_HOLD = 200
#: Seconds of telemetry (by stamp) the node holds for registrations still to come; older telemetry
#: goes to the filter (which bridges frames that never came). Above revisit_spread_frames frame periods.
TELEMETRY_HOLD_S = 60.0
#: Period of the timer that applies the timeout (s); a longer gap between its calls is time the
#: process did not run.
TICK_S = 0.2


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
        self.georef: Georeferencer | None = None
        self._camera = None
        self._pending: list[tuple[float, RegistrationMsg]] = []  # (arrival on the running clock s, registration)
        self._streams = TelemetryStreams(quiet_s=SYNC_TIMEOUT_S)
        self._held: dict[str, collections.deque[Any]] = {}  # kind -> telemetry not fed yet, by stamp
        self._running_s = 0.0  # seconds this node has been running (stalls of the process left out)
        self._last_tick = time.monotonic()
        self._order = StreamOrder(self, self.warn, self.config.stamp_tolerance_s)  # stamps off the clock or backwards
        self._ref_stamp: int | None = None  # the last painted frame fed: what prev_H_cur maps into
        self._last_pose = None
        if not self.standalone:
            self.get_logger().info('georeferencing runs inside the mosaic node (live.georef_standalone is false); '
                                   'this node stays idle. Set live.georef_standalone:=true for the whole graph to '
                                   'run the filter here.')
            self.configured = True
            return
        check_georef_standalone(self.standalone, self.config.georef_enabled)
        self.pub_diag = DiagnosticsPublisher(self, 'srmosaic: georeferencing')
        reliable = bool(self.get_parameter('live.reliable_inputs').value)
        qos = input_qos(reliable, TELEMETRY_QOS_DEPTH)
        group = MutuallyExclusiveCallbackGroup()  # one group: the filter sees its inputs one at a time, in order
        subscribe_input(self, NavSatFix, 'fix', self._on_fix, qos, group)
        subscribe_input(self, Imu, 'imu', self._on_imu, qos, group)
        subscribe_input(self, CameraInfo, 'camera_info', self._on_camera_info, qos, group)
        subscribe_input(self, self.messages.registration_type, 'registration', self._on_registration, input_qos(True, 200), group)
        self.pub_poses = PosePublisher(self)
        period = float(self.get_parameter('live.preview_period_s').value)
        self.create_timer(TICK_S, self._on_tick, callback_group=group)
        self._periodic = self.create_timer(period, self._publish_diagnostics,
                                                    callback_group=MutuallyExclusiveCallbackGroup())
        self.configured = True

    # -- inputs ---------------------------------------------------------------------------------
    def _in_order(self, stream: str, stamp_ns: int) -> bool:
        return self._order.accept(stream, stamp_ns)

    def _telemetry(self, kind: str, convert: Any, msg: Any) -> None:
        if not self.active:
            self.warn.count('inputs_while_inactive')
            return
        try:
            item = convert(msg)
        except SrMosaicError as exc:
            self.warn(kind, f'{kind} skipped: {exc}')
            return
        if not self._in_order(kind, item.stamp_ns):
            return
        self._held.setdefault(kind, collections.deque()).append(item)
        self._streams.seen(kind, item.stamp_ns, time.monotonic())
        self._drain()

    def _feed_telemetry(self, through_ns: int) -> None:
        """Feed the filter the held telemetry stamped up to ``through_ns``, in stamp order."""
        items = []
        for kind, held in self._held.items():
            while held and held[0].stamp_ns <= through_ns:
                items.append((kind, held.popleft()))
        for kind, item in sorted(items, key=lambda ki: ki[1].stamp_ns):
            georef = self._filter()
            (georef.feed_fix if kind == 'fix' else georef.feed_imu)(item)

    def _filter(self) -> Georeferencer:
        """The filter, made at its first input (with the camera known by then)."""
        if self.georef is None:
            self.georef = Georeferencer(self.config.georef, self._camera)
        return self.georef

    def _on_fix(self, msg: NavSatFix) -> None:
        self._telemetry('fix', navsat_to_fix, msg)

    def _on_imu(self, msg: Imu) -> None:
        self._telemetry('imu', imu_to_sample, msg)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            # registrations are of undistorted frames: their camera is the pinhole one (core/undistort.py)
            self._camera = self._undistorter.camera(camera_info_to_intrinsics(msg))
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
        if not self._in_order('registration', reg.stamp_ns):
            return
        self._pending.append((self._running_s, reg))
        self._drain()

    def _on_tick(self) -> None:
        now = time.monotonic()
        # A tick much later than due: the process was not scheduled (a loaded machine) and its
        # queues filled meanwhile; that time is not waiting for telemetry.
        self._running_s += min(now - self._last_tick, 2 * TICK_S)
        self._last_tick = now
        self._drain(timeout=True)

    # -- fusion -----------------------------------------------------------------------------------
    def _drain(self, *, timeout: bool = False) -> None:
        """Fuse the waiting registrations whose telemetry has arrived (approximate-time association)."""
        while self._pending:
            arrived, reg = self._pending[0]
            late = timeout and self._running_s - arrived > SYNC_TIMEOUT_S
            if not (self._streams.covers(reg.stamp_ns) or late or len(self._pending) > REGISTRATION_HOLD):
                break
            self._pending.pop(0)
            self._feed_telemetry(reg.stamp_ns)
            self._fuse(reg)
        newest = max((held[-1].stamp_ns for held in self._held.values() if held), default=None)
        if newest is not None:
            self._feed_telemetry(newest - int(TELEMETRY_HOLD_S * 1e9))

    def _fuse(self, reg: RegistrationMsg) -> None:
        georef = self._filter()
        use = reg.ok and reg.reg_ok and reg.prev_H_cur is not None and self._ref_stamp is not None
        try:
            pose = georef.feed_frame(
                reg.stamp_ns, reg.prev_H_cur if use else None, reg.covariance if use else None,
                rms_px=reg.rms_px if use else float('nan'), inliers=reg.inliers if use else 0, camera=self._camera,
                ref_stamp_ns=self._ref_stamp if use else None)
        except Exception as exc:  # noqa: BLE001 - a bad frame must not stop the filter node
            self.warn(f'georef: {type(exc).__name__}', f'frame at {reg.stamp_ns} not fused: {exc!r}')
            return
        if reg.ok:
            self._ref_stamp = reg.stamp_ns
        self.warn.count('frames_fused')
        if self.pub_poses.publish(reg.stamp_ns, pose):
            self.warn.count('poses_published')
            self._last_pose = pose

    def _publish_diagnostics(self) -> None:
        stats = self.warn.snapshot()
        pose = self._last_pose
        values = {
            'frames_fused': stats.get('frames_fused', 0),
            'poses_published': stats.get('poses_published', 0),
            'registrations_waiting': len(self._pending),
            'last_std_east_m': f'{pose.std_enu_m[0]:.2f}' if pose is not None else 'nan',
            'last_std_north_m': f'{pose.std_enu_m[1]:.2f}' if pose is not None else 'nan',
        }
        if self.georef is not None:
            values.update({f'filter skipped: {k}': v for k, v in self.georef.skipped.items()})
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
        if self.standalone:
            while self._pending:
                reg = self._pending.pop(0)[1]
                self._feed_telemetry(reg.stamp_ns)
                self._fuse(reg)
        release(self._entities)
        self._entities, self._periodic, self.georef = [], None, None


def main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros georef_node [--ros-args ...]`."""
    from .executables import node_main

    return node_main('georef_node', GeorefNode, argv)
