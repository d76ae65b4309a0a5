"""Reading flights from bags and writing bags, through rosbags.

Reads rosbag2 (sqlite3 and mcap, a bag folder or a bare ``.db3``/``.mcap`` file) and ROS 1
``.bag`` files; writes rosbag2 (sqlite3 or mcap). Every failure of the underlying readers
(rosbags, SQLite, struct, YAML, OS) leaves this module as a :class:`BagError` that names the
path and says what to try.
"""
from __future__ import annotations

import contextlib
import dataclasses
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from msg_adapters import (
    camera_info_to_intrinsics,
    header_to_ns_frame,
    image_to_rgb_or_mono,
    imu_to_sample,
    navsat_to_fix,
)
from srmosaic_ros.core.types import CameraIntrinsics, Frame, GeoFix, ImuSample
from srmosaic_ros.errors import BagError, MessageError

if TYPE_CHECKING:
    from collections.abc import Generator, Iterable, Iterator, Mapping
    from types import TracebackType

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

__all__ = [
    'iter_raw',
    'IMAGE_MSGTYPE',
    'COMPRESSED_IMAGE_MSGTYPE',
    'CAMERA_INFO_MSGTYPE',
    'NAVSAT_MSGTYPE',
    'IMU_MSGTYPE',
    'STORAGES',
    'TopicConfig',
    'TopicSummary',
    'BagInfo',
    'FlightReader',
    'BagWriter',
    'inspect_bag',
    'read_flight',
]

IMAGE_MSGTYPE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE_MSGTYPE = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO_MSGTYPE = 'sensor_msgs/msg/CameraInfo'
NAVSAT_MSGTYPE = 'sensor_msgs/msg/NavSatFix'
IMU_MSGTYPE = 'sensor_msgs/msg/Imu'
STORAGES: tuple[str, ...] = ('sqlite3', 'mcap')

_SUFFIX_STORAGE = {'.bag': 'rosbag1', '.db3': 'sqlite3', '.mcap': 'mcap'}
_ROSBAG2_VERSION = 9  # what ROS 2 Jazzy writes
_EXPECTED = {
    'image': (IMAGE_MSGTYPE, COMPRESSED_IMAGE_MSGTYPE),
    'camera_info': (CAMERA_INFO_MSGTYPE,),
    'fix': (NAVSAT_MSGTYPE,),
    'imu': (IMU_MSGTYPE,),
}
_OPTION = {
    'image': '--image-topic',
    'camera_info': '--camera-info-topic',
    'fix': '--fix-topic',
    'imu': '--imu-topic',
}


@dataclass(frozen=True)
class TopicConfig:
    """Topics of a flight. An empty string switches a topic off.

    If ``image`` is absent but ``<image>/compressed`` carries sensor_msgs/CompressedImage, that is
    used. ``camera_info``, ``fix`` and ``imu`` are optional in the bag.
    """

    image: str = '/camera/image_raw'
    camera_info: str = '/camera/camera_info'
    fix: str = '/fix'
    imu: str = '/imu/data'


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: its message type (None if several) and message count."""

    msgtype: str | None
    count: int


@dataclass(frozen=True)
class BagInfo:
    """What :func:`inspect_bag` finds: storage ('sqlite3', 'mcap', 'rosbag1' or None), times, topics."""

    path: Path
    storage: str | None
    start_ns: int
    end_ns: int
    message_count: int
    topics: Mapping[str, TopicSummary] = field(default_factory=dict)

    @property
    def duration_ns(self) -> int:
        """Nanoseconds from the first to the last message (0 for an empty bag)."""
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0

    @property
    def duration_s(self) -> float:
        return self.duration_ns * 1e-9


# --------------------------------------------------------------------------------------------
# Opening


def _repair_hint(path: Path) -> str:
    storage = _storage_id(path)
    if storage == 'rosbag1':
        return 'if the recording was cut short, try `rosbag reindex` on a copy'
    if storage == 'mcap':
        return 'if the recording was cut short, try `mcap recover` on a copy'
    return 'if the recording was cut short, try `ros2 bag reindex` on a copy'


def _storage_id(path: Path) -> str | None:
    if path.is_file():
        return _SUFFIX_STORAGE.get(path.suffix)
    try:
        import yaml  # noqa: PLC0415

        meta = yaml.safe_load((path / 'metadata.yaml').read_text())
        storage = meta['rosbag2_bagfile_information']['storage_identifier']
    except Exception:  # noqa: BLE001 - the storage id is informative only
        return None
    return str(storage) if storage else None


def _check_path(path: Path) -> None:
    """Refuse paths that cannot be bags before rosbags sees them."""
    if not path.exists():
        msg = (
            f'Bag {str(path)!r} does not exist; check the path. Give a rosbag2 folder (with '
            'metadata.yaml), a bare .db3/.mcap file, or a ROS 1 .bag file.'
        )
        raise BagError(msg)
    if path.is_dir():
        if not (path / 'metadata.yaml').is_file():
            inside = sorted(p.name for p in path.iterdir() if p.suffix in {'.db3', '.mcap'})
            if inside:
                hint = (
                    f'it holds {inside[0]!r}: pass that file itself, or regenerate metadata.yaml '
                    'with `ros2 bag reindex`'
                )
            else:
                hint = 'give a rosbag2 folder, a .db3/.mcap file or a ROS 1 .bag file'
            msg = f'{str(path)!r} is a folder without metadata.yaml, so not a rosbag2 bag; {hint}.'
            raise BagError(msg)
    elif path.suffix not in _SUFFIX_STORAGE:
        msg = (
            f'{str(path)!r} is not a bag: expected a rosbag2 folder, a .db3 or .mcap file, or a '
            f'ROS 1 .bag file (got suffix {path.suffix!r}). For video files use the video input.'
        )
        raise BagError(msg)


def _open_reader(path: Path) -> AnyReader:
    """An open AnyReader on ``path``, or BagError."""
    from rosbags.highlevel import AnyReader  # noqa: PLC0415
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    _check_path(path)
    store = Stores.ROS1_NOETIC if path.suffix == '.bag' else Stores.ROS2_JAZZY
    try:
        reader = AnyReader([path], default_typestore=get_typestore(store))
        reader.open()
    except Exception as exc:
        msg = (
            f'Cannot open bag {str(path)!r}: {_describe(exc)}. The bag is truncated, corrupt, '
            f'or not a bag; {_repair_hint(path)}.'
        )
        raise BagError(msg) from exc
    return reader


def _describe(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.rstrip('.')


# --------------------------------------------------------------------------------------------
# Inspecting


def _summaries(reader: AnyReader) -> dict[str, TopicSummary]:
    return {
        name: TopicSummary(info.msgtype, int(info.msgcount))
        for name, info in sorted(reader.topics.items())
    }


def _bag_info(path: Path, reader: AnyReader) -> BagInfo:
    count = int(reader.message_count)
    return BagInfo(
        path=path,
        storage=_storage_id(path),
        start_ns=int(reader.start_time) if count else 0,
        end_ns=int(reader.end_time) - 1 if count else 0,
        message_count=count,
        topics=_summaries(reader),
    )


def inspect_bag(path: str | Path) -> BagInfo:
    """Storage, time span and topics (message type and count) of a bag.

    Raises:
        BagError: path missing, not a bag, or the bag cannot be opened.

    """
    path = Path(path)
    reader = _open_reader(path)
    try:
        return _bag_info(path, reader)
    except Exception as exc:
        msg = f'Cannot read the index of bag {str(path)!r}: {_describe(exc)}; {_repair_hint(path)}.'
        raise BagError(msg) from exc
    finally:
        reader.close()


# --------------------------------------------------------------------------------------------
# Reading a flight


def _topic_listing(topics: Mapping[str, TopicSummary]) -> str:
    if not topics:
        return 'the bag has no topics'
    return 'topics in the bag: ' + ', '.join(
        f'{name} ({info.msgtype or "several types"}, {info.count} msgs)'
        for name, info in topics.items()
    )


class FlightReader:
    """Iterable over the Frame, GeoFix and ImuSample items of a bag, in bag log-time order.

    Attributes:
        path: the bag.
        info: :class:`BagInfo` of the bag.
        topics: the topics asked for.
        image_topic: the image topic actually read ('' if none), maybe ``<image>/compressed``.
        image_msgtype: its message type (Image or CompressedImage), '' if none.
        frame_count: number of image messages in the bag, known before iterating.
        skipped: messages skipped by the current (or last) iteration, counted per reason
            ('<topic>: <what was wrong>'); reset when a new iteration starts.
        messages_read: image, fix and imu messages taken from the bag by that iteration.

    Each Frame's ``camera`` is the latest CameraInfo logged at or before it, or the first one of
    the bag if all came later, or None if the bag has none. ``stamp_ns`` of every item is its
    header stamp, or the log time when the header stamp is zero.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        topics: TopicConfig = TopicConfig(),  # noqa: B008 - frozen, hence safe
        require_image: bool = True,
    ) -> None:
        self.path = Path(path)
        self.topics = topics
        self.skipped: dict[str, int] = {}
        self.messages_read = 0
        reader = _open_reader(self.path)
        try:
            self.info = _bag_info(self.path, reader)
        except Exception as exc:
            msg = (
                f'Cannot read the index of bag {str(self.path)!r}: {_describe(exc)}; '
                f'{_repair_hint(self.path)}.'
            )
            raise BagError(msg) from exc
        finally:
            reader.close()
        self._roles: dict[str, str] = {}
        self.image_topic = self._resolve_image(require_image)
        image_summary = self.info.topics.get(self.image_topic)
        self.image_msgtype = (image_summary.msgtype or '') if image_summary else ''
        self.frame_count = self.info.topics[self.image_topic].count if self.image_topic else 0
        for role in ('camera_info', 'fix', 'imu'):
            topic = getattr(topics, role)
            if topic and topic in self.info.topics:
                self._check_type(role, topic)
                self._roles[topic] = role

    # -- topic resolution ---------------------------------------------------------------------

    def _check_type(self, role: str, topic: str) -> None:
        expected = _EXPECTED[role]
        found = self.info.topics[topic].msgtype
        if found not in expected:
            what = 'several message types' if found is None else f'type {found!r}'
            msg = (
                f'Topic {topic!r} in bag {str(self.path)!r} has {what}, but the {role} topic must '
                f'be {" or ".join(expected)}. Choose another topic with {_OPTION[role]} '
                f'({_topic_listing(self.info.topics)}).'
            )
            raise BagError(msg)

    def _resolve_image(self, require_image: bool) -> str:
        wanted = self.topics.image
        if not wanted:
            return ''
        compressed = wanted.rstrip('/') + '/compressed'
        available = self.info.topics
        if wanted in available:
            topic = wanted
        elif available.get(compressed, TopicSummary(None, 0)).msgtype == COMPRESSED_IMAGE_MSGTYPE:
            topic = compressed
        elif require_image:
            images = [n for n, i in available.items() if i.msgtype in _EXPECTED['image']]
            suggestion = f'; image topics present: {", ".join(images)}' if images else ''
            msg = (
                f'Bag {str(self.path)!r} has no image topic {wanted!r} (nor {compressed!r}){suggestion}. '
                f'Choose the image topic with --image-topic TOPIC ({_topic_listing(available)}).'
            )
            raise BagError(msg)
        else:
            return ''
        self._check_type('image', topic)
        self._roles[topic] = 'image'
        return topic

    # -- iteration ----------------------------------------------------------------------------

    def _skip(self, topic: str, reason: str) -> None:
        key = f'{topic}: {reason}'
        self.skipped[key] = self.skipped.get(key, 0) + 1

    def _guarded(
        self, reader: AnyReader, connections: list[Connection], phase: str
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        """reader.messages(connections), turning storage damage into BagError."""
        if not connections:
            return
        stream = reader.messages(connections=connections)
        count = 0
        while True:
            try:
                item = next(stream)
            except StopIteration:
                return
            except Exception as exc:
                msg = (
                    f'Bag {str(self.path)!r} is damaged: reading {phase} stopped after {count} '
                    f'messages ({_describe(exc)}). The file is truncated or corrupt; '
                    f'{_repair_hint(self.path)}.'
                )
                raise BagError(msg) from exc
            count += 1
            yield item

    def _deserialize(
        self, reader: AnyReader, connection: Connection, raw: bytes
    ) -> Any | None:  # noqa: ANN401
        try:
            return reader.deserialize(raw, connection.msgtype)
        except Exception as exc:  # noqa: BLE001 - one bad message must not stop the flight
            reason = f'cannot deserialise {connection.msgtype}: {_describe(exc)}'
            self._skip(connection.topic, reason)
            return None

    def _camera_infos(self, reader: AnyReader) -> list[tuple[int, CameraIntrinsics]]:
        connections = [c for c in reader.connections if self._roles.get(c.topic) == 'camera_info']
        infos: list[tuple[int, CameraIntrinsics]] = []
        for connection, log_ns, raw in self._guarded(reader, connections, 'camera infos'):
            msg = self._deserialize(reader, connection, raw)
            if msg is None:
                continue
            try:
                infos.append((log_ns, camera_info_to_intrinsics(msg)))
            except MessageError as exc:
                self._skip(connection.topic, str(exc))
        return infos

    def __iter__(self) -> Iterator[Frame | GeoFix | ImuSample]:
        return self._items()

    def _items(self) -> Generator[Frame | GeoFix | ImuSample, None, None]:
        self.skipped = {}
        self.messages_read = 0
        reader = _open_reader(self.path)
        try:
            yield from self._read(reader)
        finally:
            reader.close()

    def _read(self, reader: AnyReader) -> Generator[Frame | GeoFix | ImuSample, None, None]:
        infos = self._camera_infos(reader)
        next_info = 0
        camera: CameraIntrinsics | None = infos[0][1] if infos else None
        connections = [
            c for c in reader.connections if self._roles.get(c.topic) in {'image', 'fix', 'imu'}
        ]
        for connection, log_ns, raw in self._guarded(reader, connections, 'the flight'):
            self.messages_read += 1
            msg = self._deserialize(reader, connection, raw)
            if msg is None:
                continue
            role = self._roles[connection.topic]
            try:
                if role == 'image':
                    while next_info < len(infos) and infos[next_info][0] <= log_ns:
                        camera = infos[next_info][1]
                        next_info += 1
                    stamp_ns, frame_id = header_to_ns_frame(msg)
                    item: Frame | GeoFix | ImuSample = Frame(
                        stamp_ns=stamp_ns or log_ns,
                        image=image_to_rgb_or_mono(msg),
                        camera=camera,
                        frame_id=frame_id,
                    )
                elif role == 'fix':
                    item = navsat_to_fix(msg)
                else:
                    item = imu_to_sample(msg)
            except MessageError as exc:
                self._skip(connection.topic, str(exc))
                continue
            if not isinstance(item, Frame) and item.stamp_ns == 0:
                item = dataclasses.replace(item, stamp_ns=log_ns)
            yield item


def read_flight(
    path: str | Path,
    *,
    topics: TopicConfig = TopicConfig(),  # noqa: B008 - frozen, hence safe
    require_image: bool = True,
) -> FlightReader:
    """Frames, fixes and IMU samples of a bag in log-time order (see :class:`FlightReader`).

    The bag is opened and its topics checked now; messages are read when iterating. A message
    that cannot be converted is skipped and counted in ``.skipped``.

    Raises:
        BagError: path missing, not a bag, corrupt or truncated (also while iterating), no image
            topic (when ``require_image``), or a topic of the wrong message type.

    """
    return FlightReader(path, topics=topics, require_image=require_image)


def iter_raw(
    path: str | Path, *, topics: Iterable[str] | None = None
) -> Generator[tuple[str, str, int, bytes], None, None]:
    """(topic, msgtype, log_time_ns, CDR bytes) of a bag in log-time order, for republishing.

    rosbag2 messages are already CDR; ROS 1 messages are converted to CDR, so the bytes can be
    published as they are (rclpy ``Publisher.publish(bytes)``). ``topics`` limits the topics read.

    Raises:
        BagError: as :func:`read_flight`, including damage found while iterating.
    """
    path = Path(path)
    reader = _open_reader(path)
    try:
        wanted = set(topics) if topics is not None else None
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        ros1 = path.suffix == '.bag'
        store = reader.typestore if hasattr(reader, 'typestore') else None
        stream = reader.messages(connections=connections)
        count = 0
        while True:
            try:
                connection, log_ns, raw = next(stream)
                if ros1 and store is not None:
                    raw = bytes(store.ros1_to_cdr(raw, connection.msgtype))
            except StopIteration:
                return
            except Exception as exc:
                msg = (
                    f'Bag {str(path)!r} is damaged: reading stopped after {count} messages '
                    f'({_describe(exc)}); {_repair_hint(path)}.'
                )
                raise BagError(msg) from exc
            count += 1
            yield connection.topic, connection.msgtype, log_ns, bytes(raw)
    finally:
        reader.close()


# --------------------------------------------------------------------------------------------
# Writing


def _rclpy_msgtype(msg: Any) -> str | None:  # noqa: ANN401
    """'pkg/msg/Name' of an rclpy message instance, else None."""
    cls = type(msg)
    parts = cls.__module__.split('.')
    if len(parts) >= 2 and parts[1] == 'msg' and hasattr(cls, '_TYPE_SUPPORT'):
        return f'{parts[0]}/msg/{cls.__name__}'
    return None


class BagWriter:
    """Writes a rosbag2 bag (sqlite3 or mcap) message by message; a context manager.

    Connections are added on first use of a topic. Messages are rosbags message instances (their
    type from ``__msgtype__``, as built by msg_adapters with ``flavor='rosbags'``); rclpy messages
    are accepted too.

    Raises:
        BagError: unknown storage, ``path`` exists (without ``overwrite``), unknown message type,
            a topic written with two types, or a failing write.

    """

    def __init__(
        self, path: str | Path, *, storage: str = 'sqlite3', overwrite: bool = False
    ) -> None:
        from rosbags.rosbag2 import StoragePlugin  # noqa: PLC0415

        self.path = Path(path)
        plugins = {'sqlite3': StoragePlugin.SQLITE3, 'mcap': StoragePlugin.MCAP}
        if storage not in plugins:
            msg = f'storage {storage!r} is not supported for writing; use one of {STORAGES}.'
            raise BagError(msg)
        if self.path.exists() and not overwrite:
            msg = (
                f'{str(self.path)!r} exists already; choose another output path or allow '
                'overwriting (overwrite=True / --overwrite).'
            )
            raise BagError(msg)
        self.storage = storage
        self.overwrite = overwrite
        self._plugin = plugins[storage]
        self._writer: Any = None
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    def open(self) -> None:
        from rosbags.rosbag2 import Writer  # noqa: PLC0415

        from msg_adapters._flavor import rosbags_typestore  # noqa: PLC0415

        if self._writer is not None:
            msg = f'BagWriter on {str(self.path)!r} is already open.'
            raise BagError(msg)
        try:
            if self.path.exists():
                if not self.overwrite:
                    msg = (
                        f'{str(self.path)!r} exists already; choose another output path or '
                        'pass overwrite=True.'
                    )
                    raise BagError(msg)
                if self.path.is_dir() and not self.path.is_symlink():
                    shutil.rmtree(self.path)
                else:
                    self.path.unlink()
            writer = Writer(self.path, version=_ROSBAG2_VERSION, storage_plugin=self._plugin)
            writer.open()
        except BagError:
            raise
        except Exception as exc:
            msg = (
                f'Cannot create bag {str(self.path)!r}: {_describe(exc)}. '
                'Check the path and its permissions.'
            )
            raise BagError(msg) from exc
        self._typestore = rosbags_typestore()
        self._writer = writer

    def _serialize(self, topic: str, msg: Any) -> tuple[str, bytes]:  # noqa: ANN401
        msgtype = getattr(msg, '__msgtype__', None)
        try:
            if isinstance(msgtype, str):
                return msgtype, bytes(self._typestore.serialize_cdr(msg, msgtype))
            msgtype = _rclpy_msgtype(msg)
            if msgtype is not None:
                from rclpy.serialization import serialize_message  # noqa: PLC0415

                return msgtype, serialize_message(msg)
        except Exception as exc:
            text = (
                f'Cannot serialise a {msgtype} for topic {topic!r} into {str(self.path)!r}: '
                f'{_describe(exc)}. Build the message with msg_adapters (flavor=\'rosbags\').'
            )
            raise BagError(text) from exc
        text = (
            f'Cannot write a {type(msg).__name__} to topic {topic!r}: it is neither a rosbags '
            'message (no __msgtype__) nor an rclpy message. Build it with msg_adapters.'
        )
        raise BagError(text)

    def write(self, topic: str, msg: Any, stamp_ns: int) -> None:  # noqa: ANN401
        """Append ``msg`` to ``topic`` with log time ``stamp_ns`` (integer nanoseconds)."""
        if self._writer is None:
            text = f'BagWriter on {str(self.path)!r} is not open; use it as a context manager.'
            raise BagError(text)
        msgtype, raw = self._serialize(topic, msg)
        connection = self._connections.get(topic)
        if connection is None:
            try:
                connection = self._writer.add_connection(topic, msgtype, typestore=self._typestore)
            except Exception as exc:
                text = (
                    f'Cannot add topic {topic!r} of type {msgtype!r} to bag {str(self.path)!r}: '
                    f'{_describe(exc)}. Is {msgtype!r} a message type known to ROS 2 Jazzy?'
                )
                raise BagError(text) from exc
            self._connections[topic] = connection
        elif connection.msgtype != msgtype:
            text = (
                f'Topic {topic!r} of bag {str(self.path)!r} already carries {connection.msgtype!r}; '
                f'cannot write a {msgtype!r} to it. Use another topic.'
            )
            raise BagError(text)
        if int(stamp_ns) < 0:
            text = f'stamp_ns {stamp_ns} for topic {topic!r} is negative; bags store log times >= 0.'
            raise BagError(text)
        try:
            self._writer.write(connection, int(stamp_ns), raw)
        except Exception as exc:
            text = f'Cannot write to bag {str(self.path)!r}: {_describe(exc)}. Is the disk full?'
            raise BagError(text) from exc
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> None:
        """Finish the bag (index, metadata.yaml). Closing twice is harmless."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            writer.close()
        except Exception as exc:
            text = f'Cannot finish bag {str(self.path)!r}: {_describe(exc)}. Is the disk full?'
            raise BagError(text) from exc

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_val: BaseException | None,
        exc_tb: TracebackType | None,
    ) -> None:
        # Finish the bag even after an error, so that what was written stays readable; a failure
        # to finish must not hide the error that got us here.
        if exc_type is None:
            self.close()
        else:
            with contextlib.suppress(Exception):
                self.close()
