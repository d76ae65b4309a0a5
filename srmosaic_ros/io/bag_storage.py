"""The storage layer of io/bags.py: metadata.yaml, the storage files of rosbag2 (sqlite3, mcap;
split, zstd-compressed) and ROS 1 bags, read by topic name with rosbags' own readers, and every
failure as a one-line BagError. io/bags.py is the way in.
"""
from __future__ import annotations

import contextlib
import dataclasses
import heapq
import re
import shlex
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any

from srmosaic_ros.errors import BagError

if TYPE_CHECKING:
    from collections.abc import Generator, Iterable, Mapping
    from types import TracebackType

    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

from .bag_types import (
    _CDR,
    _MAX_LISTED,
    _NEWEST_READABLE_VERSION,
    _ROS1,
    _SUFFIX_STORAGE,
    _ZSTD_MAGIC,
    STORAGES,
    BagInfo,
    TopicSummary,
)

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in

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
        import yaml

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
    listing = sorted(p.name for p in path.iterdir())
    what = 'it is empty' if not listing else f'it holds no images either ({_listing(listing)})'
    return (f'{head}, nor a folder of stills: {what}; give a rosbag2 folder, a .db3/.mcap file, a ROS 1 '
            '.bag file, a video file, or a folder of .jpg/.jpeg/.png/.tif stills.')


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
    import yaml

    where = f'Cannot open bag {str(path)!r}'
    loader = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)  # libyaml's parser where built in
    try:
        doc = yaml.load((path / 'metadata.yaml').read_text(), Loader=loader)  # a safe loader
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


def _zstd() -> Any:  # the module itself
    try:
        from compression import zstd  # type: ignore[import-not-found]
    except ImportError:
        from backports import zstd  # type: ignore[no-redef]
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
        from rosbags.rosbag1 import Reader as Reader1
        from rosbags.rosbag2 import Reader as Reader2

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
        from rosbags.interfaces import ConnectionExtRosbag2
        from rosbags.rosbag2.metadata import parse_qos

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
        from rosbags.typesys import Stores, get_typestore

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
        from rosbags.interfaces import MessageDefinitionFormat

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
        from rosbags.typesys import Stores, get_typestore

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

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
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
        from rosbags.typesys import Stores, get_typestore

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
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

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
