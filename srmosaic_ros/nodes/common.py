"""What the nodes share: topic names, the /srmosaic/registration layout, pose messages, diagnostics,
once-per-kind warnings, QoS."""
from __future__ import annotations

import collections
import copy
import math
import threading
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import NavSatFix
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ..errors import SrMosaicError

__all__ = ['TOPICS', 'SERVICES', 'DIAGNOSTICS_TOPICS', 'REGISTRATION_LAYOUT', 'DiagnosticsPublisher', 'diagnostic_array', 'RegistrationMsg',
           'decode_registration', 'encode_registration', 'pose_messages', 'PosePublisher', 'frame_ids', 'WarnOnce', 'camera_image',
           'subscribe_input', 'input_qos', 'IMAGE_QOS_DEPTH', 'TELEMETRY_QOS_DEPTH', 'check_range']

IMAGE_QOS_DEPTH = 20
TELEMETRY_QOS_DEPTH = 500

#: Topic names of the graph, relative: they resolve under the node's namespace (`-r __ns:=/uav1`
#: gives /uav1/camera/image_raw, /uav1/srmosaic/mosaic_preview, ...), and in the root namespace to
#: the names of the topic contract (/camera/image_raw, /srmosaic/...). Remap them as usual.
TOPICS = {
    'image': 'camera/image_raw',
    'image_compressed': 'camera/image_raw/compressed',
    'camera_info': 'camera/camera_info',
    'fix': 'fix',
    'imu': 'imu/data',
    'preview': 'srmosaic/mosaic_preview',
    'preview_compressed': 'srmosaic/mosaic_preview/compressed',
    'registration': 'srmosaic/registration',
    'raster': 'srmosaic/raster',
    'pose': 'srmosaic/pose',
    'fused_fix': 'srmosaic/fix',
    'odom': 'srmosaic/odom',
    'sr_tile': 'srmosaic/sr_tile',
    'map_tile': 'srmosaic/map_tile',
    'map_tiles': 'srmosaic/map_tiles',
    'footprint': 'srmosaic/footprint',
    'sr_map_tile': 'srmosaic/sr_map_tile',
    'sr_map_tiles': 'srmosaic/sr_map_tiles',
}
#: Services, relative as TOPICS: the whole live map so far, and all the SR tiles sent so far
#: (std_srvs/Trigger; live/map_tiles.py, live/sr_tile_stream.py).
SERVICES = {'get_map': 'srmosaic/get_map', 'get_sr_map': 'srmosaic/get_sr_map'}
#: Diagnostics go to /diagnostics, where diagnostic_aggregator and rqt_robot_monitor listen (absolute,
#: as diagnostic_updater publishes), and to srmosaic/diagnostics under the namespace (the contract's
#: /srmosaic/diagnostics in the root namespace).
DIAGNOSTICS_TOPICS = ('/diagnostics', 'srmosaic/diagnostics')

#: Float64MultiArray layout of /srmosaic/registration (one message per processed frame, in
#: processing order): stamp_sec, stamp_nanosec, ok (1: painted into the mosaic), inliers, rms_px,
#: segment (-1: not painted), then seg_H_frame (9, row-major: frame pixels -> the segment's plane,
#: NaN when not painted), then prev_H_cur (9: frame pixels -> pixels of the frame it was registered
#: to, which is the previous painted frame of the stream; NaN for the first frame of a segment),
#: then reg_ok (1 when that registration passed its checks), then the (8, 8) covariance of
#: prev_H_cur's h00..h21 (64, row-major; NaN when unknown). Fields are only ever appended.
REGISTRATION_LAYOUT = ['stamp_sec', 'stamp_nanosec', 'ok', 'inliers', 'rms_px', 'segment',
                       *[f'seg_H_frame{r}{c}' for r in range(3) for c in range(3)],
                       *[f'prev_H_cur{r}{c}' for r in range(3) for c in range(3)],
                       'reg_ok', *[f'cov{r}{c}' for r in range(8) for c in range(8)]]
_BASE_FIELDS = 24  # the fields up to prev_H_cur: the least a message must carry
#: layout.dim[0].label of /srmosaic/registration: the layout's version (1: REGISTRATION_LAYOUT above).
REGISTRATION_LABEL = 'fields v1'


class RegistrationMsg:
    """A decoded /srmosaic/registration message (see REGISTRATION_LAYOUT)."""

    __slots__ = ('stamp_ns', 'ok', 'inliers', 'rms_px', 'segment', 'seg_H_frame', 'prev_H_cur', 'reg_ok',
                 'covariance')

    def __init__(self, stamp_ns: int, ok: bool, inliers: int, rms_px: float, segment: int,
                 seg_H_frame: np.ndarray | None, prev_H_cur: np.ndarray | None, reg_ok: bool,
                 covariance: np.ndarray | None) -> None:
        self.stamp_ns, self.ok, self.inliers, self.rms_px, self.segment = stamp_ns, ok, inliers, rms_px, segment
        self.seg_H_frame, self.prev_H_cur, self.reg_ok, self.covariance = seg_H_frame, prev_H_cur, reg_ok, covariance


def encode_registration(stamp_ns: int, painted: bool, inliers: int, rms_px: float, segment: int,
                        seg_H_frame: np.ndarray | None, prev_H_cur: np.ndarray | None, reg_ok: bool,
                        covariance: np.ndarray | None) -> Float64MultiArray:
    nan9, nan64 = np.full(9, np.nan), np.full(64, np.nan)
    cov = np.asarray(covariance, dtype=float).ravel() if covariance is not None else nan64
    values = np.concatenate([
        [stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000, float(painted), inliers, rms_px, segment],
        np.asarray(seg_H_frame, dtype=float).ravel() if seg_H_frame is not None else nan9,
        np.asarray(prev_H_cur, dtype=float).ravel() if prev_H_cur is not None else nan9,
        [float(reg_ok)], cov if cov.size == 64 else nan64]).astype(float)
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=REGISTRATION_LABEL, size=values.size, stride=values.size)]
    msg.data = values.tolist()
    return msg


def decode_registration(msg: Float64MultiArray) -> RegistrationMsg:
    """Parse a /srmosaic/registration message; raises SrMosaicError when it is malformed."""
    d = np.asarray(msg.data, dtype=float)
    if d.size < _BASE_FIELDS or not (math.isfinite(d[0]) and math.isfinite(d[1])):
        msg_ = (f'/srmosaic/registration message with {d.size} fields (expected >= {_BASE_FIELDS}, see '
                'REGISTRATION_LAYOUT); publisher and subscriber versions differ?')
        raise SrMosaicError(msg_)
    seg_H = d[6:15].reshape(3, 3)
    prev_H = d[15:24].reshape(3, 3)
    has_ext = d.size >= len(REGISTRATION_LAYOUT)
    reg_ok = bool(d[24] > 0.5) if has_ext else bool(d[2] > 0.5 and np.all(np.isfinite(prev_H)))
    cov = d[25:89].reshape(8, 8) if has_ext else None
    return RegistrationMsg(
        stamp_ns=int(d[0]) * 1_000_000_000 + int(d[1]), ok=bool(d[2] > 0.5),
        inliers=int(d[3]) if math.isfinite(d[3]) else 0, rms_px=float(d[4]),
        segment=int(d[5]) if math.isfinite(d[5]) else -1,
        seg_H_frame=seg_H if np.all(np.isfinite(seg_H)) else None,
        prev_H_cur=prev_H if np.all(np.isfinite(prev_H)) else None, reg_ok=reg_ok,
        covariance=cov if cov is not None and np.all(np.isfinite(cov)) else None)


def pose_messages(stamp_ns: int, pose: Any, map_frame: str = 'srmosaic_enu',
                  body_frame: str = 'srmosaic') -> tuple[PoseWithCovarianceStamped, NavSatFix, Odometry] | None:
    """(srmosaic/pose, srmosaic/fix, srmosaic/odom) messages of a fused FramePose, or None when it is not valid.

    Pose: body position in the local ENU plane tangent at the first fix (m), frame_id `map_frame`
    (live.map_frame), orientation body in ENU (REP 103), covariance of (east, north, up, roll,
    pitch, yaw). Fix: WGS84 of the same pose, frame_id `body_frame` (live.body_frame), covariance
    ENU (m^2). Odometry: the same pose from `map_frame` to child_frame_id `body_frame`; the filter
    does not estimate the body's velocity, so the twist is zero with covariance[0] = -1 ("not
    provided", as sensor_msgs marks a missing field).
    """
    if pose is None or not pose.valid:
        return None
    from ..core.georef.frames import R_enu_from_body, quat_xyzw_from_matrix

    msg = PoseWithCovarianceStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.frame_id = map_frame
    e, n, u = (float(v) for v in pose.position_enu_m)
    msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z = e, n, u
    q = quat_xyzw_from_matrix(R_enu_from_body(*pose.rpy_rad))
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in q)
    cov = np.asarray(pose.covariance, dtype=np.float64)
    msg.pose.covariance = [float(v) for v in cov.ravel()]
    fix = NavSatFix()
    fix.header.stamp = msg.header.stamp
    fix.header.frame_id = body_frame
    fix.status.status = 0
    fix.latitude, fix.longitude, fix.altitude = (float(pose.latitude_deg), float(pose.longitude_deg),
                                                 float(pose.altitude_m))
    fix.position_covariance = [float(v) for v in cov[:3, :3].ravel()]
    fix.position_covariance_type = NavSatFix.COVARIANCE_TYPE_KNOWN
    odom = Odometry()
    odom.header = msg.header
    odom.child_frame_id = body_frame
    odom.pose = msg.pose
    odom.twist.covariance[0] = -1.0
    return msg, fix, odom


class PosePublisher:
    """A node's srmosaic/pose, srmosaic/fix and srmosaic/odom (frame ids: live.map_frame, live.body_frame)."""

    def __init__(self, node: Node) -> None:
        self.frames = frame_ids(node)
        self._publishers = [node.create_publisher(PoseWithCovarianceStamped, TOPICS['pose'], 50),
                            node.create_publisher(NavSatFix, TOPICS['fused_fix'], 50),
                            node.create_publisher(Odometry, TOPICS['odom'], 50)]

    def publish(self, stamp_ns: int, pose: Any) -> bool:
        """Publish the pose of the frame at `stamp_ns`; False (nothing sent) when it is not valid."""
        msgs = pose_messages(stamp_ns, pose, *self.frames)
        if msgs is None:
            return False
        for pub, msg in zip(self._publishers, msgs):
            pub.publish(msg)
        return True


class WarnOnce:
    """Counts rejected inputs per kind (for diagnostics) and logs the first of each kind."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self._warned: set[str] = set()
        self._lock = threading.Lock()
        self.stats: collections.Counter[str] = collections.Counter()
        self._reported = 0  # rejections said by the last status()

    def __call__(self, kind: str, text: str) -> None:
        with self._lock:
            self.stats[f'rejected: {kind}'] += 1
            first = kind not in self._warned
            self._warned.add(kind)
        if first:
            self._node.get_logger().warning(f'{text} (logged once; further cases are counted in diagnostics)')

    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self.stats[key] += n

    def snapshot(self) -> dict[str, int]:
        """A copy of the counters, taken under the lock (callbacks and workers count concurrently)."""
        with self._lock:
            return dict(self.stats)

    def note(self, key: str, text: str) -> None:
        """Count ``key`` (an input adjusted, not rejected) and log ``text`` the first time."""
        with self._lock:
            self.stats[key] += 1
            first = self.stats[key] == 1
        if first:
            self._node.get_logger().warning(f'{text} (logged once; counted in diagnostics as {key})')

    def status(self, message: str) -> tuple[bytes, str]:
        """(diagnostic level, message): WARN, naming the kinds, when inputs were rejected since the
        last call (so diagnostics are true while messages are being refused), else OK."""
        with self._lock:
            level, message, self._reported = rejection_status(self.stats, self._reported, message)
        return level, message


def rejection_status(stats: dict[str, int], reported: int, message: str) -> tuple[bytes, str, int]:
    """(level, message, rejections now) of a node's diagnostics: WARN, naming the kinds, when the
    'rejected: <kind>' counts of ``stats`` grew past ``reported`` (those said last time), else OK."""
    rejected = {k: v for k, v in stats.items() if k.startswith('rejected') and v}
    total = sum(rejected.values())
    if total <= reported:
        return DiagnosticStatus.OK, message, total
    kinds = ', '.join(k.removeprefix('rejected: ') for k in rejected)
    return DiagnosticStatus.WARN, f'{message}; {total - reported} messages rejected since the last report ({kinds})', total


class StreamOrder:
    """The live nodes' check of each input stream's header stamps: first against the stream's
    receive times (core/stamp_gate.py: a stamp far off them is refused, ``'<stream> stamp off the
    clock'``), then against the stream's previous stamp (``'<stream> time going backwards'``); a
    refusal is counted in ``warn`` and logged once per kind. Not thread-safe: callers hold the
    lock of their stream's state."""

    def __init__(self, node: Node, warn: WarnOnce, tolerance_s: float) -> None:
        from ..core.stamp_gate import StampGate

        self._node, self._warn, self._tolerance_s = node, warn, tolerance_s
        self._gate = StampGate(tolerance_s)
        self._last: dict[str, int] = {}

    def accept(self, stream: str, stamp_ns: int) -> bool:
        off_s = self._gate.check(stream, stamp_ns, self._node.get_clock().now().nanoseconds)
        if off_s is not None:  # before the order check: one future stamp must not make every later one 'older'
            self._warn(f'{stream} stamp off the clock', f'{stream} stamp {stamp_ns} is {off_s:+.3g} s off the receive '
                       f'times of the stream (stamp_tolerance_s {self._tolerance_s:g}); message skipped')
            return False
        last = self._last.get(stream)
        if last is not None and stamp_ns < last:
            self._warn(f'{stream} time going backwards', f'{stream} stamp {stamp_ns} is older than the previous '
                       f'{last}; message skipped')
            return False
        self._last[stream] = stamp_ns
        return True


def subscribe_input(node: Node, msg_type: type, key: str, callback: Any, qos: QoSProfile,
                    group: Any) -> Any:
    """A subscription to TOPICS[key] whose history, depth and reliability the standard parameters
    qos_overrides.<resolved topic>.subscription.{history,depth,reliability} override (given at start:
    `-p qos_overrides./uav1/camera/image_raw.subscription.reliability:=reliable`); `qos` is the default."""
    # a copy: rclpy writes the overrides into the profile it is given, which may be shared
    return node.create_subscription(msg_type, TOPICS[key], callback, copy.copy(qos), callback_group=group,
                                    qos_overriding_options=QoSOverridingOptions.with_default_policies())


def camera_image(msg: Any, camera: Any, warn: WarnOnce) -> tuple[np.ndarray, Any] | None:
    """A camera Image / CompressedImage as an (H, W, 3) RGB or (H, W) mono uint8/uint16 array, with the
    camera's intrinsics at its size; None (warned once per kind, counted) when it cannot be used.

    A CameraInfo of another size with the same aspect ratio is scaled to the image (a driver's
    binning or a resized stream; io/bags.py does the same offline), counted as camera_info_scaled;
    another aspect ratio refuses the image. `camera` None (no CameraInfo yet) stays None.
    """
    from msg_adapters import image_to_rgb_or_mono

    try:
        image = image_to_rgb_or_mono(msg)
    except SrMosaicError as exc:
        warn(f'image: {type(exc).__name__}', f'image skipped: {exc}')
        return None
    if image.size == 0:
        warn('image: empty', 'empty image skipped')
        return None
    if camera is None:
        return image, None
    h, w = image.shape[:2]
    scaled = camera.scaled_to(w, h)
    if scaled is None:
        warn('image: size unlike the camera info',
             f'image of {w}x{h} px but the camera info is of {camera.width}x{camera.height} (another aspect '
             'ratio); publish the camera info of this camera mode; image skipped')
        return None
    if scaled is not camera:
        warn.note('camera_info_scaled', f'camera info of {camera.width}x{camera.height} px scaled to the images '
                  f'of {w}x{h} (the aspect ratio holds)')
    return image, scaled


def input_qos(reliable: bool, depth: int) -> QoSProfile:
    """Sensor-data QoS (best effort, volatile) as drivers publish, or reliable (bag playback, tests)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def check_range(node: Node, name: str, lo: float, hi: float) -> Any:
    """The value of parameter `name`, refused (SrMosaicError) outside lo..hi."""
    value = node.get_parameter(name).value
    if isinstance(value, bool) or not isinstance(value, int | float) or not lo <= value <= hi:
        msg = f'{name} must be a number in {lo}..{hi}, got {value!r}; fix it in your params file or -p {name}:=...'
        raise SrMosaicError(msg)
    return value


def frame_ids(node: Node) -> tuple[str, str]:
    """(map frame, body frame) of the pose messages: parameters live.map_frame and live.body_frame."""
    from .node_checks import check_frame_id

    return (check_frame_id('live.map_frame', node.get_parameter('live.map_frame').value),
            check_frame_id('live.body_frame', node.get_parameter('live.body_frame').value))


def diagnostic_array(node: Node, name: str, message: str, values: dict[str, Any], *,
                     level: bytes = DiagnosticStatus.OK, hardware_id: str = 'srmosaic') -> DiagnosticArray:
    """One DiagnosticStatus (values as strings) stamped with the node's clock."""
    status = DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    out = DiagnosticArray()
    out.header.stamp = node.get_clock().now().to_msg()
    out.status = [status]
    return out


class DiagnosticsPublisher:
    """A node's status on every topic of DIAGNOSTICS_TOPICS.

    The status is named `task` in the root namespace ('srmosaic: registration and mosaic') and
    '<namespace>/<task>' under one ('uav1/srmosaic: registration and mosaic'), so that the statuses
    of two aircraft in one graph stay apart on /diagnostics; hardware_id is the resolved name of
    the camera's image topic ('/uav1/camera/image_raw'), which names the camera the node serves.
    """

    def __init__(self, node: Node, task: str) -> None:
        namespace = node.get_namespace().strip('/')
        self.name = f'{namespace}/{task}' if namespace else task
        self.hardware_id = node.resolve_topic_name(TOPICS['image'])
        self._node = node
        self._publishers = [node.create_publisher(DiagnosticArray, topic, 10) for topic in DIAGNOSTICS_TOPICS]

    def array(self, message: str, values: dict[str, Any], level: bytes = DiagnosticStatus.OK) -> DiagnosticArray:
        return diagnostic_array(self._node, self.name, message, values, level=level, hardware_id=self.hardware_id)

    def publish(self, msg: DiagnosticArray) -> None:
        for pub in self._publishers:
            pub.publish(msg)
