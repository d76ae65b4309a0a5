"""Reading flights from bags and writing bags, through rosbags: the way in to the bag layer
(bag_types.py: the records; bag_storage.py: a bag opened with the reader of its kind,
bag_rosbag2.py or bag_rosbag1.py; bag_writer.py).

Reads rosbag2 (sqlite3 and mcap, a bag folder or a bare ``.db3``/``.mcap`` file; split bags; zstd
file or message compression; metadata.yaml versions 1 to 9) and ROS 1 ``.bag`` files; writes
rosbag2 (sqlite3 or mcap). Every failure of the underlying readers (rosbags, SQLite, struct, YAML,
OS) leaves this module as a :class:`BagError` of one line that names the path, the reason and what
to try.

Reading convention: the storage files are the truth. metadata.yaml says which files make the bag,
their compression and the declared serialisation format of each topic; messages are then taken from
every storage file by topic name, so a metadata.yaml whose QoS strings or type names differ from the
database's (as rosbag2's own test bags and hand-edited bags have) loses nothing. Where metadata.yaml
and the files disagree, a one-line warning says so, and messages that metadata.yaml counts but the
files lack are counted per topic (``missing``). Message definitions are parsed only for the topics
that are read and deserialised, each on its own, so the definition of a topic the package does not
need (a service event topic, a custom type) never stops it.
"""
from __future__ import annotations

import dataclasses
import logging
import re
from dataclasses import dataclass
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
from srmosaic_ros.core.stamp_gate import StampGate
from srmosaic_ros.errors import BagError, MessageError

if TYPE_CHECKING:
    from collections.abc import Generator, Iterable, Iterator, Mapping

    from rosbags.interfaces import Connection

from .bag_storage import _Bag, _bag_info, _describe, _format_refusal, _open_bag, _repair_hint, _types_refusal
from .bag_types import (
    _EXPECTED,
    _OPTION,
    _ROLES,
    CAMERA_INFO_MSGTYPE,
    COMPRESSED_IMAGE_MSGTYPE,
    IMAGE_MSGTYPE,
    IMU_MSGTYPE,
    NAVSAT_MSGTYPE,
    STORAGES,
    BagInfo,
    BagSummary,
    TopicConfig,
    TopicCount,
    TopicSummary,
)
from .bag_writer import BagWriter

_LOG = logging.getLogger(__name__)
#: Image messages with a problem named one by one in the log (by topic and stamp); the rest are counted.
FRAMES_NAMED = 10
_NUMBER = re.compile(r'(?<![\w.])[-+]?\d+(\.\d+)?([eE][-+]?\d+)?(?![\w.])')  # not inside a word (mono16)

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
    'TopicCount',
    'BagSummary',
    'FlightReader',
    'BagWriter',
    'bag_summary',
    'inspect_bag',
    'read_flight',
]

# --------------------------------------------------------------------------------------------
# Inspecting


def inspect_bag(path: str | Path) -> BagInfo:
    """Storage, time span and topics (message type and count) of a bag.

    Raises:
        BagError: path missing, not a bag, or the bag cannot be opened.

    """
    path = Path(path)
    with _open_bag(path) as bag:
        return _bag_info(path, bag)


def bag_summary(
    path: str | Path,
    *,
    topics: TopicConfig = TopicConfig(),  # noqa: B008 - frozen, hence safe
    read_messages: bool = True,
) -> BagSummary:
    """What a bag holds, what its metadata says, and what :func:`read_flight` would make of it.

    With ``read_messages`` every message is read (not deserialised) and counted per topic.

    Raises:
        BagError: the bag cannot be opened at all (missing, not a bag, no or unusable
            metadata.yaml, storage files missing or corrupt), or it is damaged while reading.

    """
    path = Path(path)
    with _open_bag(path) as bag:
        info = _bag_info(path, bag)
        read: dict[str, int] | None = None
        if read_messages:
            read = dict.fromkeys(info.topics, 0)
            try:
                for connection, _log_ns, _raw in bag.messages(bag.connections):
                    read[connection.topic] += 1
            except Exception as exc:
                msg = (
                    f'Bag {str(path)!r} is damaged: reading stopped after {sum(read.values())} '
                    f'messages ({_describe(exc)}); {_repair_hint(path)}.'
                )
                raise BagError(msg) from exc
        unreadable = bag.types.prepare_types(bag.connections)
        if bag.meta is not None:
            meta_counts: dict[str, int] = {t: m.count for t, m in bag.meta.topics.items()}
        else:
            meta_counts = {t: s.count for t, s in info.topics.items()}
        entries: dict[str, TopicCount] = {}
        for name, summary in info.topics.items():
            notes = [n for n in (bag.format_problem(name), unreadable.get(name, ''),
                                 bag.types.type_notes.get(name, '')) if n]
            if name in bag.missing:
                notes.append(f'{bag.missing[name]} messages counted in metadata.yaml are not in the files')
            entries[name] = TopicCount(
                msgtype=summary.msgtype,
                serialization_format=bag.declared_format(name),
                count_metadata=meta_counts.get(name),
                count_read=None if read is None else read.get(name, 0),
                note='; '.join(notes),
            )
        try:
            flight = _resolve_flight(path, info, bag, topics, require_image=True)
        except BagError as exc:
            refusal, flight_topics = str(exc), {}
        else:
            refusal, flight_topics = '', {role: t for t, role in flight.roles.items()}
        meta = bag.meta
        if meta is not None:  # as metadata.yaml says; an empty bag's start is INT64_MAX there
            count = meta.message_count
            start_ns, duration_ns = (meta.start_ns, meta.duration_ns) if count else (0, 0)
            compression = f'{meta.compression_format} {meta.compression_mode}' if meta.compression_mode else ''
        else:
            count, start_ns, duration_ns = info.message_count, info.start_ns, info.duration_ns
            compression = ''
        return BagSummary(
            path=path,
            storage=bag.storage,
            metadata_version=meta.version if meta is not None else None,
            files=bag.files,
            compression=compression,
            start_ns=start_ns,
            duration_ns=duration_ns,
            message_count=count,
            messages_read=None if read is None else sum(read.values()),
            topics=entries,
            warnings=info.warnings,
            missing=info.missing,
            flight_topics=dict(sorted(flight_topics.items(), key=lambda kv: _ROLES.index(kv[0]))),
            refusal=refusal,
        )


# --------------------------------------------------------------------------------------------
# Reading a flight


def _topic_listing(topics: Mapping[str, TopicSummary]) -> str:
    if not topics:
        return 'the bag has no topics'
    return 'topics in the bag: ' + ', '.join(
        f'{name} ({info.msgtype or "several types"}, {info.count} msgs)'
        for name, info in topics.items()
    )


@dataclass(frozen=True)
class _Flight:
    """The topics of a flight in a bag: the image topic read (maybe '') and topic -> role."""

    image_topic: str
    image_msgtype: str
    roles: dict[str, str]
    notes: tuple[str, ...]


def _resolve_flight(
    path: Path, info: BagInfo, bag: _Bag, topics: TopicConfig, *, require_image: bool
) -> _Flight:
    """Which topics of the bag a FlightReader reads, checked (type, CDR, definition), or BagError."""
    roles: dict[str, str] = {}

    def check_type(role: str, topic: str) -> None:
        expected = _EXPECTED[role]
        found = info.topics[topic].msgtype
        if found not in expected:
            what = 'several message types' if found is None else f'type {found!r}'
            msg = (
                f'Topic {topic!r} in bag {str(path)!r} has {what}, but the {role} topic must '
                f'be {" or ".join(expected)}. Choose another topic with {_OPTION[role]} '
                f'({_topic_listing(info.topics)}).'
            )
            raise BagError(msg)

    image_topic = ''
    wanted = topics.image
    if wanted:
        compressed = wanted.rstrip('/') + '/compressed'
        available = info.topics
        if wanted in available:
            image_topic = wanted
        elif available.get(compressed, TopicSummary(None, 0)).msgtype == COMPRESSED_IMAGE_MSGTYPE:
            image_topic = compressed
        elif require_image:
            images = [n for n, i in available.items() if i.msgtype in _EXPECTED['image']]
            suggestion = f'; image topics present: {", ".join(images)}' if images else ''
            msg = (
                f'Bag {str(path)!r} has no image topic {wanted!r} (nor {compressed!r}){suggestion}. '
                f'Choose the image topic with --image-topic TOPIC ({_topic_listing(available)}).'
            )
            raise BagError(msg)
        if image_topic:
            check_type('image', image_topic)
            roles[image_topic] = 'image'
    for role in ('camera_info', 'fix', 'imu'):
        topic = getattr(topics, role)
        if topic and topic in info.topics:
            check_type(role, topic)
            roles[topic] = role
    refusal = _format_refusal(path, bag, roles)
    if refusal:
        raise BagError(refusal)
    refusal = _types_refusal(path, bag.types.prepare_types(c for c in bag.connections if c.topic in roles))
    if refusal:
        raise BagError(refusal)
    notes = tuple(
        f'Bag {str(path)!r}: topic {t!r}: {bag.types.type_notes[t]}.' for t in roles if t in bag.types.type_notes)
    image_summary = info.topics.get(image_topic)
    return _Flight(
        image_topic=image_topic,
        image_msgtype=(image_summary.msgtype or '') if image_summary else '',
        roles=roles,
        notes=notes,
    )


class FlightReader:
    """Iterable over the Frame, GeoFix and ImuSample items of a bag, in bag log-time order.

    Attributes:
        path: the bag.
        info: :class:`BagInfo` of the bag.
        topics: the topics asked for.
        image_topic: the image topic actually read ('' if none), maybe ``<image>/compressed``.
        image_msgtype: its message type (Image or CompressedImage), '' if none.
        frame_count: number of image messages in the bag's storage files, known before iterating.
        warnings: one-line warnings on the bag, logged when it is opened: metadata.yaml
            disagreeing with the storage files (and how that was worked around), messages missing,
            a definition replaced by ROS 2 Jazzy's.
        missing: per topic, messages that metadata.yaml counts but the storage files do not hold
            (so no iteration can yield them); empty for a complete bag.
        skipped: messages skipped by the current (or last) iteration, counted per reason
            ('<topic>: <what was wrong>'); reset when a new iteration starts. A message whose
            header stamp is more than ``stamp_tolerance_s`` from its topic's log-time offset is
            one of them (core/stamp_gate.py); a topic whose header clock jumped for good is
            followed after three messages and counted as '<topic>: header clock jumped'.
        messages_read: image, fix and imu messages taken from the bag by that iteration.
        adjusted: images whose CameraInfo was of another size of the same aspect ratio, and was
            scaled to them, counted per pair of sizes (logged once each); an image of another aspect
            ratio than its CameraInfo is skipped (counted in ``skipped``).

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
        stamp_tolerance_s: float = 10.0,
    ) -> None:
        self.path = Path(path)
        self.topics = topics
        self.stamp_tolerance_s = stamp_tolerance_s
        StampGate(stamp_tolerance_s)  # a bad tolerance is refused now, not when iterating
        self.skipped: dict[str, int] = {}
        self.adjusted: dict[str, int] = {}
        self.warned: dict[str, int] = {}  # images used although their decoder warned, per kind
        self._frames_named = 0
        self.messages_read = 0
        with _open_bag(self.path) as bag:
            self.info = _bag_info(self.path, bag)
            flight = _resolve_flight(self.path, self.info, bag, topics, require_image=require_image)
        self._roles = flight.roles
        self.image_topic = flight.image_topic
        self.image_msgtype = flight.image_msgtype
        self.frame_count = self.info.topics[self.image_topic].count if self.image_topic else 0
        self.warnings: tuple[str, ...] = (*self.info.warnings, *flight.notes)
        self.missing: dict[str, int] = dict(self.info.missing)
        for warning in self.warnings:
            _LOG.warning('%s', warning)

    # -- iteration ----------------------------------------------------------------------------

    def _skip(self, topic: str, reason: str) -> None:
        # counted per kind: the values in a reason (a stamp, a size, a NaN's field) go, so that 5 s
        # of bad Imu make one key with its count, not one key per message
        key = f'{topic}: {_NUMBER.sub("#", reason)}'
        self.skipped[key] = self.skipped.get(key, 0) + 1

    def _guarded(
        self, bag: _Bag, connections: list[Connection], phase: str
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        """bag.messages(connections), turning storage damage into BagError."""
        if not connections:
            return
        stream = bag.messages(connections)
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

    def _say_frame(self, topic: str, stamp_ns: int, text: str) -> None:
        """Log a problem of one image message, naming it by topic and stamp: the first FRAMES_NAMED of
        the bag, then once that the rest are counted in report.json skipped_messages."""
        self._frames_named += 1
        if self._frames_named <= FRAMES_NAMED:
            _LOG.warning('%s: image at stamp %d ns (%s UTC) on %s: %s', self.path.name, stamp_ns,
                         _utc(stamp_ns), topic, text)
        elif self._frames_named == FRAMES_NAMED + 1:
            _LOG.warning('%s: more images with problems on %s; they are counted in report.json skipped_messages.',
                         self.path.name, topic)

    def _deserialize(
        self, bag: _Bag, connection: Connection, raw: bytes
    ) -> Any | None:
        try:
            return bag.types.deserialize(raw, connection.msgtype)
        except Exception as exc:  # noqa: BLE001 - one bad message must not stop the flight
            reason = f'cannot deserialise {connection.msgtype}: {_describe(exc)}'
            self._skip(connection.topic, reason)
            return None

    def _camera_for(self, topic: str, camera: CameraIntrinsics | None, image: Any) -> CameraIntrinsics | None:
        """``camera`` for ``image`` (H, W[, C]): scaled when the CameraInfo is of another size of the
        same aspect ratio (said once per pair of sizes); MessageError when the aspect differs."""
        if camera is None or image.size == 0:
            return camera
        h, w = image.shape[:2]
        scaled = camera.scaled_to(w, h)
        if scaled is None:
            msg = (f'image of {w}x{h} px but the CameraInfo before it is of {camera.width}x{camera.height} '
                   '(another aspect ratio): record the CameraInfo of this camera mode')
            raise MessageError(msg)
        if scaled is not camera:
            key = f'{topic}: CameraInfo of {camera.width}x{camera.height} px scaled to the images of {w}x{h}'
            if key not in self.adjusted:
                _LOG.warning('%s (the aspect ratio holds)', key)
            self.adjusted[key] = self.adjusted.get(key, 0) + 1
        return scaled

    def _camera_infos(self, bag: _Bag) -> list[tuple[int, CameraIntrinsics]]:
        connections = [c for c in bag.connections if self._roles.get(c.topic) == 'camera_info']
        infos: list[tuple[int, CameraIntrinsics]] = []
        try:
            for connection, log_ns, raw in self._guarded(bag, connections, 'camera infos'):
                msg = self._deserialize(bag, connection, raw)
                if msg is None:
                    continue
                try:
                    infos.append((log_ns, camera_info_to_intrinsics(msg)))
                except MessageError as exc:
                    self._skip(connection.topic, str(exc))
        except BagError as exc:
            # damage in the tail must not cost the flight before it: the images up to the damage are
            # read with the camera infos before it, and the main pass stops there with its own error
            _LOG.warning('%s The images before the damage are processed.', exc)
        return infos

    def __iter__(self) -> Iterator[Frame | GeoFix | ImuSample]:
        return self._items()

    def _items(self) -> Generator[Frame | GeoFix | ImuSample, None, None]:
        self.skipped = {}
        self.adjusted = {}
        self.warned = {}
        self._frames_named = 0
        self.messages_read = 0
        with _open_bag(self.path) as bag:
            refusal = _types_refusal(
                self.path, bag.types.prepare_types(c for c in bag.connections if c.topic in self._roles))
            if refusal:  # the bag changed since it was opened
                raise BagError(refusal)
            yield from self._read(bag)

    def _read(self, bag: _Bag) -> Generator[Frame | GeoFix | ImuSample, None, None]:
        infos = self._camera_infos(bag)
        next_info = 0
        gate = StampGate(self.stamp_tolerance_s)
        camera: CameraIntrinsics | None = infos[0][1] if infos else None
        connections = [
            c for c in bag.connections if self._roles.get(c.topic) in {'image', 'fix', 'imu'}
        ]
        for connection, log_ns, raw in self._guarded(bag, connections, 'the flight'):
            self.messages_read += 1
            msg = self._deserialize(bag, connection, raw)
            if msg is None:
                continue
            role = self._roles[connection.topic]
            try:
                if role == 'image':
                    while next_info < len(infos) and infos[next_info][0] <= log_ns:
                        camera = infos[next_info][1]
                        next_info += 1
                    stamp_ns, frame_id = header_to_ns_frame(msg)
                    try:
                        image = image_to_rgb_or_mono(msg, decoder_said := [])
                    except MessageError as exc:
                        self._say_frame(connection.topic, stamp_ns or log_ns, f'{exc} The frame is left out.')
                        raise
                    for said in decoder_said:
                        key = f'{connection.topic}: {_NUMBER.sub("#", said)}'
                        self.warned[key] = self.warned.get(key, 0) + 1
                        self._say_frame(connection.topic, stamp_ns or log_ns, f'the decoder says "{said}" (the '
                                        'frame is used: every pixel was read).')
                    item: Frame | GeoFix | ImuSample = Frame(
                        stamp_ns=stamp_ns or log_ns,
                        image=image,
                        camera=self._camera_for(connection.topic, camera, image),
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
            jumps = gate.rebased.get(connection.topic, 0)
            off_s = gate.check(connection.topic, item.stamp_ns, log_ns)
            if gate.rebased.get(connection.topic, 0) > jumps:
                self._skip(connection.topic, 'header clock jumped for good: followed after three messages')
            if off_s is not None:
                self._skip(connection.topic, f'{gate.REASON} (its log times)')
                continue
            yield item


def read_flight(
    path: str | Path,
    *,
    topics: TopicConfig = TopicConfig(),  # noqa: B008 - frozen, hence safe
    require_image: bool = True,
    stamp_tolerance_s: float = 10.0,
) -> FlightReader:
    """Frames, fixes and IMU samples of a bag in log-time order (see :class:`FlightReader`).

    The bag is opened and its topics checked now; messages are read when iterating. A message
    that cannot be converted, or whose header stamp is more than ``stamp_tolerance_s`` seconds off
    its topic's clock (core/stamp_gate.py; 0: no check), is skipped and counted in ``.skipped``; messages metadata.yaml counts
    but the storage files lack are counted in ``.missing`` and said in ``.warnings``. Topics other
    than the flight's are never deserialised, so their definitions and formats do not matter.

    Raises:
        BagError: path missing, not a bag, corrupt or truncated (also while iterating), no image
            topic (when ``require_image``), a topic of the wrong message type, or a flight topic
            that is not CDR or whose type cannot be built.

    """
    return FlightReader(path, topics=topics, require_image=require_image, stamp_tolerance_s=stamp_tolerance_s)


def iter_raw(
    path: str | Path, *, topics: Iterable[str] | None = None
) -> Generator[tuple[str, str, int, bytes], None, None]:
    """(topic, msgtype, log_time_ns, CDR bytes) of a bag in log-time order, for republishing.

    rosbag2 messages are already CDR (decompressed if the bag compresses messages); ROS 1 messages
    are converted to CDR, so the bytes can be published as they are (rclpy
    ``Publisher.publish(bytes)``). ``topics`` limits the topics read; the bag's warnings are logged.

    Raises:
        BagError: as :func:`read_flight`, including damage found while iterating, and a topic read
            that is not CDR (or, for ROS 1, whose type cannot be built for the conversion).
    """
    path = Path(path)
    with _open_bag(path) as bag:
        wanted = set(topics) if topics is not None else None
        connections = [c for c in bag.connections if wanted is None or c.topic in wanted]
        refusal = _format_refusal(path, bag, {c.topic for c in connections})
        ros1 = bag.storage == 'rosbag1'
        if refusal is None and ros1:
            refusal = _types_refusal(path, bag.types.prepare_ros1_to_cdr(connections))
        if refusal:
            raise BagError(refusal)
        for warning in bag.warnings:
            _LOG.warning('%s', warning)
        stream = bag.messages(connections) if connections else iter(())
        count = 0
        while True:
            try:
                connection, log_ns, raw = next(stream)
                if ros1:
                    raw = bag.types.ros1_to_cdr(raw, connection.msgtype)
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


def _utc(stamp_ns: int) -> str:
    """A stamp as an ISO 8601 UTC time (for naming a message in the log)."""
    import datetime as dt

    try:
        return dt.datetime.fromtimestamp(stamp_ns / 1e9, dt.timezone.utc).isoformat(timespec='milliseconds')
    except (OverflowError, OSError, ValueError):
        return '?'
