"""Reading flights from bags and writing bags, through rosbags.

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

import contextlib
import dataclasses
import heapq
import logging
import re
import shlex
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path, PurePath
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

    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

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

IMAGE_MSGTYPE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE_MSGTYPE = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO_MSGTYPE = 'sensor_msgs/msg/CameraInfo'
NAVSAT_MSGTYPE = 'sensor_msgs/msg/NavSatFix'
IMU_MSGTYPE = 'sensor_msgs/msg/Imu'
STORAGES: tuple[str, ...] = ('sqlite3', 'mcap')

_LOG = logging.getLogger(__name__)

_SUFFIX_STORAGE = {'.bag': 'rosbag1', '.db3': 'sqlite3', '.mcap': 'mcap'}
_ROSBAG2_VERSION = 9  # what ROS 2 Jazzy writes
_NEWEST_READABLE_VERSION = 9  # metadata.yaml versions 1..9 share the fields read here
_CDR = 'cdr'
_ROS1 = 'ros1'
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
_ROLES = ('image', 'camera_info', 'fix', 'imu')
_MAX_LISTED = 4  # topics or files named in one message before '...'
_ZSTD_MAGIC = b'\x28\xb5\x2f\xfd'  # a zstd frame; CDR starts with its 0x00 encapsulation byte


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
    """One topic of a bag: its message type (None if several) and message count in the storage files."""

    msgtype: str | None
    count: int


@dataclass(frozen=True)
class BagInfo:
    """What :func:`inspect_bag` finds: storage ('sqlite3', 'mcap', 'rosbag1' or None), times, topics.

    Times and counts are those of the storage files (their index), which are what a reader yields.
    ``warnings`` are one-line notes on the bag as a whole (metadata.yaml disagreeing with the files,
    messages missing); ``missing`` maps a topic to the messages metadata.yaml counts on it that the
    storage files do not hold.
    """

    path: Path
    storage: str | None
    start_ns: int
    end_ns: int
    message_count: int
    topics: Mapping[str, TopicSummary] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    missing: Mapping[str, int] = field(default_factory=dict)

    @property
    def duration_ns(self) -> int:
        """Nanoseconds from the first to the last message (0 for an empty bag)."""
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0

    @property
    def duration_s(self) -> float:
        return self.duration_ns * 1e-9


@dataclass(frozen=True)
class TopicCount:
    """One topic of a :class:`BagSummary`.

    Attributes:
        msgtype: message type in the storage files (metadata.yaml's when the files lack the topic;
            None if several).
        serialization_format: as declared: metadata.yaml's for a rosbag2 folder, else the storage
            file's ('cdr'); 'ros1' for a ROS 1 bag.
        count_metadata: messages metadata.yaml counts on it; for a bare storage file or a ROS 1 bag,
            the file's own index. None when metadata.yaml does not list the topic.
        count_read: messages actually read from the storage files (None if the summary was made
            without reading messages).
        note: why the package cannot deserialise the topic or how it worked around the bag ('' when
            all is well).
    """

    msgtype: str | None
    serialization_format: str
    count_metadata: int | None
    count_read: int | None
    note: str = ''


@dataclass(frozen=True)
class BagSummary:
    """What :func:`bag_summary` finds in a bag, for ``srmosaic inspect`` and tests.

    Attributes:
        path: the bag.
        storage: 'sqlite3', 'mcap' or 'rosbag1'.
        metadata_version: metadata.yaml's ``version`` (1..9); None for a bare storage file or a ROS 1
            bag.
        files: names of the storage files (as metadata.yaml lists them, or the file itself).
        compression: rosbag2 compression as '<format> <mode>' ('zstd file', 'zstd message'), ''
            when none (ROS 1 chunk compression is handled but not reported).
        start_ns: first message, nanoseconds since the epoch, as metadata.yaml (or the index) says;
            0 for an empty bag.
        duration_ns: nanoseconds from the first to the last message, as metadata.yaml (or the
            index) says; 0 for an empty bag.
        message_count: messages as metadata.yaml (or the index) counts.
        messages_read: messages actually read (None if not read).
        topics: per topic, sorted by name.
        warnings: one-line warnings on the bag as a whole.
        missing: per topic, messages metadata.yaml counts that the storage files do not hold.
        flight_topics: role ('image', 'camera_info', 'fix', 'imu') -> the topic :func:`read_flight`
            reads for it with the given TopicConfig (roles it would not read are absent).
        refusal: the one-line BagError message of :func:`read_flight` on this bag with that
            TopicConfig, '' when it reads the bag.
    """

    path: Path
    storage: str
    metadata_version: int | None
    files: tuple[str, ...]
    compression: str
    start_ns: int
    duration_ns: int
    message_count: int
    messages_read: int | None
    topics: Mapping[str, TopicCount]
    warnings: tuple[str, ...]
    missing: Mapping[str, int]
    flight_topics: Mapping[str, str]
    refusal: str


# --------------------------------------------------------------------------------------------
# Messages


def _describe(exc: BaseException) -> str:
    """One line of at most 160 characters: messages of this module never carry a dump."""
    text = ' '.join(str(exc).split()) or type(exc).__name__
    if len(text) > 160:
        text = text[:157] + '...'
    return text.rstrip('.')


def _listing(names: Iterable[str]) -> str:
    names = list(names)
    shown = ', '.join(names[:_MAX_LISTED])
    return shown + (f' and {len(names) - _MAX_LISTED} more' if len(names) > _MAX_LISTED else '')


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


# --------------------------------------------------------------------------------------------
# Opening


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
            raise BagError(_no_metadata_message(path))
    elif path.suffix == '.zstd' and Path(path.stem).suffix in {'.db3', '.mcap'}:
        msg = (
            f'{str(path)!r} is a zstd-compressed storage file: read its bag folder (with '
            f'metadata.yaml), or decompress it (`zstd -d`) and pass the {Path(path.stem).suffix} file.'
        )
        raise BagError(msg)
    elif path.suffix not in _SUFFIX_STORAGE:
        msg = (
            f'{str(path)!r} is not a bag: expected a rosbag2 folder, a .db3 or .mcap file, or a '
            f'ROS 1 .bag file (got suffix {path.suffix!r}). For video files use the video input.'
        )
        raise BagError(msg)


def _no_metadata_message(path: Path) -> str:
    inside = sorted(p.name for p in path.iterdir() if p.suffix in {'.db3', '.mcap'})
    packed = sorted(
        p.name for p in path.iterdir() if p.suffix == '.zstd' and Path(p.stem).suffix in {'.db3', '.mcap'}
    )
    head = f'{str(path)!r} is a folder without metadata.yaml, so not a readable rosbag2 bag'
    if packed:
        return (
            f'{head}: it holds {len(packed)} zstd-compressed storage files ({_listing(packed)}) whose '
            'compression only metadata.yaml records; reindex it with `ros2 bag reindex`, or '
            'decompress one (`zstd -d`) and pass that file.'
        )
    if len(inside) == 1:
        return (
            f'{head}; it holds {inside[0]!r}: pass that file itself, or regenerate metadata.yaml '
            'with `ros2 bag reindex`.'
        )
    # rosbag2 names the parts of a split bag <name>_<index>.<db3|mcap>
    parts = [re.fullmatch(r'(.+)_\d+(\.db3|\.mcap)', name) for name in inside]
    if inside and all(parts) and len({(m.group(1), m.group(2)) for m in parts if m}) == 1:
        storage = _SUFFIX_STORAGE[Path(inside[0]).suffix]
        return (
            f'{head}: it holds the {len(inside)} files of a split bag ({_listing(inside)}); reindex '
            f'it with `ros2 bag reindex {shlex.quote(str(path))} -s {storage}` (or pass one file to '
            'read only its part).'
        )
    if inside:
        return (
            f'{head}: it holds {len(inside)} storage files that are not the parts of one split bag '
            f'({_listing(inside)}); pass one of them, or if they are one bag regenerate its '
            'metadata.yaml with `ros2 bag reindex`.'
        )
    return f'{head}; give a rosbag2 folder, a .db3/.mcap file or a ROS 1 .bag file.'


@dataclass(frozen=True)
class _MetaTopic:
    """A topic as metadata.yaml lists it."""

    msgtype: str
    serialization_format: str
    count: int
    qos: Any
    digest: str


@dataclass(frozen=True)
class _Metadata:
    """The fields of metadata.yaml this module reads; ``compression_mode`` is '', 'file' or 'message'."""

    version: int
    storage: str
    files: tuple[str, ...]
    compression_format: str
    compression_mode: str
    message_count: int
    start_ns: int
    duration_ns: int
    topics: dict[str, _MetaTopic]


def _read_metadata(path: Path) -> _Metadata:
    """metadata.yaml of the bag folder ``path``, checked, or BagError."""
    import yaml  # noqa: PLC0415

    where = f'Cannot open bag {str(path)!r}'
    loader = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)  # libyaml's parser where built in
    try:
        doc = yaml.load((path / 'metadata.yaml').read_text(), Loader=loader)  # noqa: S506 - a safe loader
    except OSError as exc:
        msg = f'{where}: cannot read its metadata.yaml ({_describe(exc)}); check its permissions.'
        raise BagError(msg) from exc
    except yaml.YAMLError as exc:
        msg = (
            f'{where}: its metadata.yaml is not valid YAML ({_describe(exc)}); regenerate it with '
            '`ros2 bag reindex`.'
        )
        raise BagError(msg) from exc
    try:
        info = doc['rosbag2_bagfile_information']
        topics: dict[str, _MetaTopic] = {}
        for entry in info['topics_with_message_count'] or []:
            meta = entry['topic_metadata']
            name = str(meta['name'])
            count = int(entry['message_count'])
            if name in topics:  # one topic with two types: keep the first type, count all
                count += topics[name].count
            topics.setdefault(name, _MetaTopic(
                str(meta['type']), str(meta['serialization_format']), 0,
                meta.get('offered_qos_profiles') or '', str(meta.get('type_description_hash') or '')))
            topics[name] = dataclasses.replace(topics[name], count=count)
        mode = str(info.get('compression_mode') or '').lower()
        metadata = _Metadata(
            version=int(info['version']),
            storage=str(info['storage_identifier']),
            files=tuple(PurePath(str(x)).name for x in info['relative_file_paths']),
            compression_format=str(info.get('compression_format') or ''),
            compression_mode='' if mode == 'none' else mode,
            message_count=int(info['message_count']),
            start_ns=int(info['starting_time']['nanoseconds_since_epoch']),
            duration_ns=int(info['duration']['nanoseconds']),
            topics=topics,
        )
    except KeyError as exc:
        msg = (
            f'{where}: a metadata key is missing from its metadata.yaml ({exc}); regenerate it with '
            '`ros2 bag reindex`.'
        )
        raise BagError(msg) from exc
    except (TypeError, ValueError, AttributeError) as exc:
        msg = (
            f'{where}: its metadata.yaml is malformed ({_describe(exc)}); regenerate it with '
            '`ros2 bag reindex`.'
        )
        raise BagError(msg) from exc
    _check_metadata(path, metadata)
    return metadata


def _check_metadata(path: Path, meta: _Metadata) -> None:
    where = f'Cannot open bag {str(path)!r}'
    if meta.version > _NEWEST_READABLE_VERSION:
        msg = (
            f'{where}: metadata.yaml version {meta.version} is newer than the versions 1 to '
            f'{_NEWEST_READABLE_VERSION} this reader knows; convert it with `ros2 bag convert` '
            'where it was recorded, or update rosbags and srmosaic_ros.'
        )
        raise BagError(msg)
    if meta.storage not in STORAGES:
        msg = (
            f'{where}: storage {meta.storage!r} is not supported (only sqlite3 and mcap); convert '
            'the bag with `ros2 bag convert` to sqlite3 or mcap.'
        )
        raise BagError(msg)
    if meta.compression_mode not in {'', 'file', 'message'}:
        msg = (
            f'{where}: compression mode {meta.compression_mode!r} in metadata.yaml is unknown '
            "(expected 'file' or 'message'); regenerate metadata.yaml with `ros2 bag reindex`."
        )
        raise BagError(msg)
    if meta.compression_mode and meta.compression_format != 'zstd':
        msg = (
            f'{where}: compressed with {meta.compression_format!r} in {meta.compression_mode} mode; '
            'only zstd is supported: decompress it with `ros2 bag convert` where it was recorded.'
        )
        raise BagError(msg)
    if not meta.files:
        msg = (
            f'{where}: its metadata.yaml lists no storage files; regenerate it with `ros2 bag '
            'reindex`.'
        )
        raise BagError(msg)
    missing = [name for name in meta.files if not (path / name).is_file()]
    if missing:
        msg = (
            f'{where}: storage files listed in its metadata.yaml are not in the folder '
            f'({_listing(missing)}); copy the whole bag folder, or if the files were renamed '
            'regenerate metadata.yaml with `ros2 bag reindex`.'
        )
        raise BagError(msg)


def _zstd() -> Any:  # noqa: ANN401 - the module itself
    try:
        from compression import zstd  # type: ignore[import-not-found]  # noqa: PLC0415
    except ImportError:
        from backports import zstd  # type: ignore[no-redef]  # noqa: PLC0415
    return zstd


class _Bag:
    """An open bag: its storage files through rosbags' storage readers, read by topic name.

    ``connections`` are the storage files' own (a topic split over files has one per file);
    ``messages`` merges them in log-time order. Types are registered per message type on demand
    (:meth:`prepare_types`), from the bag's own definition, else from ROS 2 Jazzy's (ROS 1 Noetic's
    for a ROS 1 bag) types.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.meta: _Metadata | None = None
        self.files: tuple[str, ...] = (path.name,)
        self.storage = ''
        self.connections: list[Connection] = []
        self.warnings: list[str] = []
        self.missing: dict[str, int] = {}
        self.type_notes: dict[str, str] = {}
        self._note_of_type: dict[str, str] = {}
        self._readers: list[Any] = []
        self._reader_of: dict[int, Any] = {}
        self._stack = contextlib.ExitStack()
        self._stores: dict[str, Typestore] = {}
        self._default: Typestore | None = None
        self._shared: Typestore | None = None
        self._cdr_stores: dict[str, Typestore] = {}
        self._cdr_of_store: dict[int, Typestore] = {}
        self._zstd_messages = False

    # -- opening ------------------------------------------------------------------------------

    def open(self) -> None:
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        _check_path(self.path)
        if self.path.is_dir():
            self.meta = _read_metadata(self.path)
            self.storage = self.meta.storage
            self.files = self.meta.files
            for name in self.meta.files:
                self._open_file(self._storage_path(name), name)
            self._compare_with_metadata()
        else:
            self.storage = _SUFFIX_STORAGE[self.path.suffix]
            self._open_file(self.path, self.path.name)
            if self.storage != 'rosbag1':
                self._sniff_message_compression()

    def _sniff_message_compression(self) -> None:
        """Note zstd frames in a bare storage file: one file of a bag compressed per message."""
        stream = self.messages(self.connections)
        try:
            first = next(stream, None)
        except Exception:  # noqa: BLE001 - damage is reported where messages are read
            return
        finally:
            stream.close()
        if first is not None and bytes(first[2][:4]) == _ZSTD_MAGIC:
            self._zstd_messages = True
            self.warnings.append(
                f'Bag {str(self.path)!r}: its messages are zstd frames, so it is one file of a bag '
                'compressed in zstd message mode whose metadata.yaml is not with it; they are '
                'decompressed as they are read.')

    def _storage_path(self, name: str) -> Path:
        """The storage file ``name`` of the folder, decompressed first in zstd file mode."""
        source = self.path / name
        if self.meta is None or self.meta.compression_mode != 'file':
            return source
        tmp = Path(self._stack.enter_context(tempfile.TemporaryDirectory(prefix='srmosaic_bag_')))
        target = tmp / PurePath(name).stem
        try:
            zstd = _zstd()
            with source.open('rb') as packed, zstd.open(packed, 'rb') as infile, target.open('wb') as out:
                shutil.copyfileobj(infile, out)
        except Exception as exc:
            msg = (
                f'Cannot open bag {str(self.path)!r}: {name!r} does not decompress as zstd '
                f'({_describe(exc)}), though metadata.yaml says the bag is compressed in zstd file '
                'mode; the file is truncated or corrupt, or metadata.yaml is wrong (`ros2 bag reindex`).'
            )
            raise BagError(msg) from exc
        return target

    def _open_file(self, path: Path, name: str) -> None:
        from rosbags.rosbag1 import Reader as Reader1  # noqa: PLC0415
        from rosbags.rosbag2 import Reader as Reader2  # noqa: PLC0415

        expected = {'sqlite3': '.db3', 'mcap': '.mcap', 'rosbag1': '.bag'}[self.storage]
        if path.suffix != expected:
            msg = (
                f'Cannot open bag {str(self.path)!r}: its metadata.yaml says storage {self.storage!r} '
                f'but lists {name!r}, not a {expected} file; regenerate metadata.yaml with `ros2 bag '
                'reindex`.'
            )
            raise BagError(msg)
        try:
            reader = (Reader1 if self.storage == 'rosbag1' else Reader2)(path)
            reader.open()
        except Exception as exc:
            where = f' ({name})' if self.path.is_dir() else ''
            msg = (
                f'Cannot open bag {str(self.path)!r}{where}: {_describe(exc)}. The bag is truncated, '
                f'corrupt, or not a bag; {_repair_hint(self.path)}.'
            )
            raise BagError(msg) from exc
        self._stack.callback(reader.close)
        self._readers.append(reader)
        for connection in reader.connections:
            self._reader_of[id(connection.owner)] = reader
            self.connections.append(connection)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._stack.close()

    def __enter__(self) -> _Bag:
        return self  # opened by _open_bag; the context closes it

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_val: BaseException | None,
        exc_tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- what the files hold ------------------------------------------------------------------

    def storage_counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for connection in self.connections:
            counts[connection.topic] = counts.get(connection.topic, 0) + int(connection.msgcount)
        return counts

    def msgtypes(self) -> dict[str, str | None]:
        """Topic -> message type (None if several): the files', else metadata.yaml's."""
        seen: dict[str, set[str]] = {}
        for connection in self.connections:
            seen.setdefault(connection.topic, set()).add(connection.msgtype)
        types: dict[str, str | None] = {
            topic: next(iter(kinds)) if len(kinds) == 1 else None for topic, kinds in seen.items()
        }
        for topic, meta in (self.meta.topics if self.meta else {}).items():
            types.setdefault(topic, meta.msgtype)
        return types

    def declared_format(self, topic: str) -> str:
        if self.storage == 'rosbag1':
            return _ROS1
        if self.meta is not None and topic in self.meta.topics:
            return self.meta.topics[topic].serialization_format
        formats = self.stored_formats(topic)
        return formats[0] if len(formats) == 1 else ','.join(formats)

    def stored_formats(self, topic: str) -> list[str]:
        """Serialisation formats the storage files give the topic (mcap: the channel's encoding)."""
        return sorted({
            str(getattr(c.ext, 'serialization_format', '')) for c in self.connections if c.topic == topic})

    def format_problem(self, topic: str) -> str:
        """'' if the topic's messages are CDR (or ROS 1), else why not, in a few words."""
        if self.storage == 'rosbag1':
            return ''
        stored = self.stored_formats(topic)
        declared = self.declared_format(topic)
        bad = [f for f in (declared, *stored) if f != _CDR]
        if not bad:
            return ''
        text = f'serialisation format {bad[0]!r} is not CDR'
        if self.meta is not None and stored and stored != [declared]:
            text += f" (metadata.yaml declares {declared!r}, the storage file {', '.join(map(repr, stored))})"
        return text

    def _compare_with_metadata(self) -> None:
        """Warnings where metadata.yaml and the storage files disagree, and ``missing``."""
        from rosbags.interfaces import ConnectionExtRosbag2  # noqa: PLC0415
        from rosbags.rosbag2.metadata import parse_qos  # noqa: PLC0415

        assert self.meta is not None
        where = f'Bag {str(self.path)!r}'
        retyped: list[str] = []
        dropped: dict[str, int] = {}
        for connection in self.connections:
            meta = self.meta.topics.get(connection.topic)
            if meta is None:
                continue
            if meta.msgtype != connection.msgtype:
                retyped.append(
                    f'{connection.topic} ({meta.msgtype} in metadata.yaml, {connection.msgtype} in '
                    f'{PurePath(str(getattr(connection.owner, "path", ""))).name or "the file"})')
                continue
            # rosbags' own directory reader pairs metadata.yaml's topics with the files' by type,
            # QoS profiles and type hash too, and yields nothing for a topic where they differ.
            try:
                ext = ConnectionExtRosbag2(meta.serialization_format, parse_qos(meta.qos))
            except Exception:  # noqa: BLE001 - unparsable QoS strings are a mismatch as well
                ext = None
            digests_agree = not meta.digest or not connection.digest or meta.digest == connection.digest
            if connection.msgcount and (ext != connection.ext or not digests_agree):
                if meta.serialization_format == getattr(connection.ext, 'serialization_format', None):
                    dropped[connection.topic] = dropped.get(connection.topic, 0) + connection.msgcount
        if retyped:
            self.warnings.append(
                f'{where}: metadata.yaml and the storage files disagree on the message type of '
                f'{_listing(sorted(set(retyped)))}; the storage files\' types are used.')
        if dropped:
            self.warnings.append(
                f"{where}: metadata.yaml's QoS profiles (or type hashes) of {_listing(sorted(dropped))} "
                f'differ from those in {_listing(self.files)}, so the rosbags reader would yield none '
                f'of their {sum(dropped.values())} messages; they are read by topic name from the '
                'storage files instead.')
        stored = self.storage_counts()
        for topic, meta in self.meta.topics.items():
            if meta.count > stored.get(topic, 0):
                self.missing[topic] = meta.count - stored.get(topic, 0)
        if self.missing:
            shortfall = ', '.join(
                f'{t} {self.meta.topics[t].count} -> {stored.get(t, 0)}' for t in sorted(self.missing))
            self.warnings.append(
                f'{where}: the storage files hold {sum(self.missing.values())} messages fewer than '
                f'metadata.yaml counts ({shortfall}); the recording was cut short or metadata.yaml is '
                'wrong (`ros2 bag reindex` rewrites it from the files).')
        listed = {t: m.count for t, m in self.meta.topics.items()}
        extra = {t: n for t, n in stored.items() if n > listed.get(t, 0)}
        if extra:
            self.warnings.append(
                f'{where}: the storage files hold more messages than metadata.yaml counts on '
                f'{_listing(f"{t} ({n})" for t, n in sorted(extra.items()))}; all of them are read.')

    # -- types --------------------------------------------------------------------------------

    def _default_store(self) -> Typestore:
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

        if self._default is None:
            self._default = get_typestore(
                Stores.ROS1_NOETIC if self.storage == 'rosbag1' else Stores.ROS2_JAZZY)
        return self._default

    def prepare_types(self, connections: Iterable[Connection]) -> dict[str, str]:
        """Make the types of ``connections`` deserialisable; topic -> why not, for those that fail.

        Each connection's own definition is parsed and registered on its own, so that one
        unparsable definition touches no other type (a definition conflicting with an earlier
        one gets a typestore of its own); without a usable definition, ROS 2 Jazzy's (ROS 1
        Noetic's) type is used, and where a definition failed that is noted in ``type_notes``.
        """
        from rosbags.interfaces import MessageDefinitionFormat  # noqa: PLC0415

        problems: dict[str, str] = {}
        failed: dict[str, str] = {}
        for connection in connections:
            msgtype = connection.msgtype
            if msgtype in self._stores:
                if msgtype in self._note_of_type:
                    self.type_notes[connection.topic] = self._note_of_type[msgtype]
                continue
            if msgtype in failed:
                problems[connection.topic] = failed[msgtype]
                continue
            reason = ''
            if connection.msgdef.format != MessageDefinitionFormat.NONE:
                try:
                    store = self._register(_parse_definition(connection), msgtype)
                except Exception as exc:  # noqa: BLE001 - contained: this type only
                    reason = _definition_problem(connection, exc)
                else:
                    self._stores[msgtype] = store
                    continue
            default = self._default_store()
            if msgtype in default.fielddefs:
                self._stores[msgtype] = default
                release = 'ROS 1 Noetic' if self.storage == 'rosbag1' else 'ROS 2 Jazzy'
                if reason:
                    self._note_of_type[msgtype] = f'{reason}; {release}\'s {msgtype} is used instead'
                    self.type_notes[connection.topic] = self._note_of_type[msgtype]
                continue
            if not reason:
                reason = (
                    f'the bag carries no definition of {msgtype} and '
                    f'{"ROS 1 Noetic" if self.storage == "rosbag1" else "ROS 2 Jazzy"} has no such type')
            failed[msgtype] = reason
            problems[connection.topic] = reason
        return problems

    def _register(self, types: dict[str, Any], msgtype: str) -> Typestore:
        """A store holding ``types``: the bag's shared one, or a store of their own on a conflict."""
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

        if msgtype not in types:
            msg = f'the definition does not define {msgtype}'
            raise KeyError(msg)
        if self._shared is None:
            self._shared = get_typestore(Stores.EMPTY)
        try:
            self._shared.register(types)  # checks every type before adding any
        except Exception:  # noqa: BLE001 - two topics defining a type differently
            own = get_typestore(Stores.EMPTY)
            own.register(types)
            return own
        return self._shared

    def deserialize(self, raw: bytes, msgtype: str) -> Any:  # noqa: ANN401
        store = self._stores[msgtype]
        if self.storage == 'rosbag1':
            return store.deserialize_ros1(raw, msgtype)
        return store.deserialize_cdr(raw, msgtype)

    def prepare_ros1_to_cdr(self, connections: Iterable[Connection]) -> dict[str, str]:
        """Like :meth:`prepare_types`, for converting ROS 1 messages to CDR (:meth:`ros1_to_cdr`).

        rosbags converts a ROS 1 std_msgs/Header (seq, stamp, frame_id) to ROS 2's (stamp,
        frame_id) only when its typestore holds ROS 2's Header, so the conversion types are the
        bag's with ROS 2 Jazzy's Header (and builtin_interfaces/Time) in its place.
        """
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

        connections = list(connections)
        problems = self.prepare_types(connections)
        jazzy: Typestore | None = None
        for connection in connections:
            msgtype = connection.msgtype
            if connection.topic in problems or msgtype in self._cdr_stores:
                continue
            store = self._stores[msgtype]
            cdr = self._cdr_of_store.setdefault(id(store), get_typestore(Stores.EMPTY))
            if msgtype not in cdr.fielddefs:
                types = dict(store.fielddefs)
                if 'std_msgs/msg/Header' in types:
                    jazzy = jazzy or get_typestore(Stores.ROS2_JAZZY)
                    for name in ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time'):
                        types[name] = jazzy.fielddefs[name]
                try:
                    cdr.register(types)
                except Exception as exc:  # noqa: BLE001 - contained: this type only
                    problems[connection.topic] = (
                        f'its type {msgtype} cannot be prepared for conversion to CDR ({_describe(exc)})')
                    continue
            self._cdr_stores[msgtype] = cdr
        return problems

    def ros1_to_cdr(self, raw: bytes, msgtype: str) -> bytes:
        return bytes(self._cdr_stores[msgtype].ros1_to_cdr(raw, msgtype))

    # -- messages -----------------------------------------------------------------------------

    def messages(
        self, connections: Iterable[Connection]
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        """(connection, log time ns, raw bytes) of ``connections``, in log-time order."""
        groups: dict[int, list[Connection]] = {}
        for connection in connections:
            groups.setdefault(id(connection.owner), []).append(connection)
        streams = [
            self._reader_of[owner].messages(connections=conns) for owner, conns in groups.items()
        ]
        if not streams:
            return
        stream = streams[0] if len(streams) == 1 else heapq.merge(*streams, key=lambda x: x[1])
        if self._zstd_messages or (self.meta is not None and self.meta.compression_mode == 'message'):
            decompress = _zstd().decompress
            for connection, log_ns, raw in stream:
                yield connection, log_ns, decompress(raw)
        else:
            yield from stream

    # -- summaries ----------------------------------------------------------------------------

    def info(self) -> BagInfo:
        counts = self.storage_counts()
        types = self.msgtypes()
        total = sum(counts.values())
        starts = [int(r.start_time) for r in self._readers if int(r.message_count)]
        ends = [int(r.end_time) for r in self._readers if int(r.message_count)]
        return BagInfo(
            path=self.path,
            storage=self.storage,
            start_ns=min(starts) if total and starts else 0,
            end_ns=max(ends) - 1 if total and ends else 0,
            message_count=total,
            topics={name: TopicSummary(types[name], counts.get(name, 0)) for name in sorted(types)},
            warnings=tuple(self.warnings),
            missing=dict(self.missing),
        )


def _parse_definition(connection: Connection) -> dict[str, Any]:
    """Types of a connection's own message definition (as rosbags' AnyReader parses them)."""
    from rosbags.interfaces import MessageDefinitionFormat  # noqa: PLC0415
    from rosbags.typesys import get_types_from_idl, get_types_from_msg  # noqa: PLC0415

    data = connection.msgdef.data
    if connection.msgdef.format == MessageDefinitionFormat.MSG:
        return dict(get_types_from_msg(data, connection.msgtype))
    sep = '=' * 80 + '\n'
    if data.startswith(f'{sep}IDL: '):
        types: dict[str, Any] = {}
        for part in data.split(sep)[1:]:
            _, idl = part.split('\n', 1)
            types.update(get_types_from_idl(idl))
        return types
    return dict(get_types_from_idl(data))


def _definition_problem(connection: Connection, exc: BaseException) -> str:
    if any(line.strip() == '---' for line in connection.msgdef.data.splitlines()):
        # rosbag2 (Jazzy) writes a service event topic's schema as the .srv text, request and
        # response parts split by '---', which is no message definition (ros2/rosbag2#2365).
        return (
            f'its definition of {connection.msgtype} in the bag is a service/action text with '
            "'---', not a message definition")
    return f'its definition of {connection.msgtype} in the bag cannot be parsed ({_describe(exc)})'


def _open_bag(path: Path) -> _Bag:
    """An open :class:`_Bag` on ``path``, or BagError."""
    bag = _Bag(path)
    try:
        bag.open()
    except BagError:
        raise
    except Exception as exc:  # a reader failing outside the guarded calls
        msg = f'Cannot open bag {str(path)!r}: {_describe(exc)}; {_repair_hint(path)}.'
        raise BagError(msg) from exc
    return bag


def _bag_info(path: Path, bag: _Bag) -> BagInfo:
    try:
        return bag.info()
    except Exception as exc:
        msg = f'Cannot read the index of bag {str(path)!r}: {_describe(exc)}; {_repair_hint(path)}.'
        raise BagError(msg) from exc


def _format_refusal(path: Path, bag: _Bag, topics: Iterable[str]) -> str | None:
    """The one-line refusal for topics that are not CDR, or None if all are."""
    bad = {t: p for t in sorted(set(topics)) if (p := bag.format_problem(t))}
    if not bad:
        return None
    first = next(iter(bad.values()))
    stored_cdr = all(bag.stored_formats(t) == [_CDR] for t in bad)
    if bag.meta is not None and stored_cdr:
        todo = ('the storage files say cdr: if they are right, regenerate metadata.yaml with `ros2 bag '
                'reindex`')
    else:
        todo = 're-record or convert those topics to CDR, or leave them out'
    return (
        f'Bag {str(path)!r} cannot be read: {_listing(bad)}: {first}; only CDR (and ROS 1) '
        f'messages are read; {todo}.'
    )


def _types_refusal(path: Path, problems: Mapping[str, str]) -> str | None:
    if not problems:
        return None
    topic, reason = next(iter(sorted(problems.items())))
    more = f' (and {len(problems) - 1} more topics)' if len(problems) > 1 else ''
    return (
        f'Bag {str(path)!r} cannot be read: topic {topic!r}{more}: {reason}; leave the topic out or '
        're-record it with a complete message definition.'
    )


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
        unreadable = bag.prepare_types(bag.connections)
        if bag.meta is not None:
            meta_counts: dict[str, int] = {t: m.count for t, m in bag.meta.topics.items()}
        else:
            meta_counts = {t: s.count for t, s in info.topics.items()}
        entries: dict[str, TopicCount] = {}
        for name, summary in info.topics.items():
            notes = [n for n in (bag.format_problem(name), unreadable.get(name, ''),
                                 bag.type_notes.get(name, '')) if n]
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
    refusal = _types_refusal(path, bag.prepare_types(c for c in bag.connections if c.topic in roles))
    if refusal:
        raise BagError(refusal)
    notes = tuple(
        f'Bag {str(path)!r}: topic {t!r}: {bag.type_notes[t]}.' for t in roles if t in bag.type_notes)
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
        key = f'{topic}: {reason}'
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

    def _deserialize(
        self, bag: _Bag, connection: Connection, raw: bytes
    ) -> Any | None:  # noqa: ANN401
        try:
            return bag.deserialize(raw, connection.msgtype)
        except Exception as exc:  # noqa: BLE001 - one bad message must not stop the flight
            reason = f'cannot deserialise {connection.msgtype}: {_describe(exc)}'
            self._skip(connection.topic, reason)
            return None

    def _camera_infos(self, bag: _Bag) -> list[tuple[int, CameraIntrinsics]]:
        connections = [c for c in bag.connections if self._roles.get(c.topic) == 'camera_info']
        infos: list[tuple[int, CameraIntrinsics]] = []
        for connection, log_ns, raw in self._guarded(bag, connections, 'camera infos'):
            msg = self._deserialize(bag, connection, raw)
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
        with _open_bag(self.path) as bag:
            refusal = _types_refusal(
                self.path, bag.prepare_types(c for c in bag.connections if c.topic in self._roles))
            if refusal:  # the bag changed since it was opened
                raise BagError(refusal)
            yield from self._read(bag)

    def _read(self, bag: _Bag) -> Generator[Frame | GeoFix | ImuSample, None, None]:
        infos = self._camera_infos(bag)
        next_info = 0
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
    that cannot be converted is skipped and counted in ``.skipped``; messages metadata.yaml counts
    but the storage files lack are counted in ``.missing`` and said in ``.warnings``. Topics other
    than the flight's are never deserialised, so their definitions and formats do not matter.

    Raises:
        BagError: path missing, not a bag, corrupt or truncated (also while iterating), no image
            topic (when ``require_image``), a topic of the wrong message type, or a flight topic
            that is not CDR or whose type cannot be built.

    """
    return FlightReader(path, topics=topics, require_image=require_image)


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
            refusal = _types_refusal(path, bag.prepare_ros1_to_cdr(connections))
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
                    raw = bag.ros1_to_cdr(raw, connection.msgtype)
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
