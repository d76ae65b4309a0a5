"""What every storage reader of the bag layer gives (rosbag2 in bag_rosbag2.py, ROS 1 in bag_rosbag1.py),
and the parts they share: the storage files opened through rosbags' own readers, read by topic name,
and merged in log-time order.
"""
from __future__ import annotations

import contextlib
import heapq
from typing import TYPE_CHECKING, Any

from srmosaic_ros.errors import BagError

from .bag_problems import _describe, _repair_hint
from .bag_types import BagInfo, TopicSummary
from .bag_typestore import BagTypes

if TYPE_CHECKING:
    from collections.abc import Callable, Generator, Iterable
    from pathlib import Path
    from types import TracebackType

    from rosbags.interfaces import Connection

    from .bag_metadata import _Metadata

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in


class _BagReader:
    """An open bag: its storage files through rosbags' storage readers, read by topic name.

    ``connections`` are the storage files' own (a topic split over files has one per file);
    ``messages`` merges them in log-time order. ``types`` makes their messages deserialisable
    (:class:`~.bag_typestore.BagTypes`). ``meta`` is metadata.yaml's record (rosbag2 folders only),
    ``warnings`` what the reader noticed, ``missing`` topic -> messages metadata.yaml counts that the
    files do not hold. Subclasses give :meth:`_open`, :meth:`_reader_class`, :meth:`declared_format`
    and :meth:`format_problem`.
    """

    storage = ''  # 'sqlite3', 'mcap' or 'rosbag1'

    def __init__(self, path: Path, *, ros1: bool) -> None:
        self.path = path
        self.meta: _Metadata | None = None
        self.files: tuple[str, ...] = (path.name,)
        self.connections: list[Connection] = []
        self.warnings: list[str] = []
        self.missing: dict[str, int] = {}
        self.types = BagTypes(ros1=ros1)
        self._readers: list[Any] = []
        self._reader_of: dict[int, Any] = {}
        self._stack = contextlib.ExitStack()

    # -- opening ------------------------------------------------------------------------------

    def open(self) -> None:
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        raise NotImplementedError

    def _reader_class(self) -> type[Any]:
        """rosbags' reader of one storage file of this kind."""
        raise NotImplementedError

    def _open_file(self, path: Path, name: str) -> None:
        expected = {'sqlite3': '.db3', 'mcap': '.mcap', 'rosbag1': '.bag'}[self.storage]
        if path.suffix != expected:
            msg = (
                f'Cannot open bag {str(self.path)!r}: its metadata.yaml says storage {self.storage!r} '
                f'but lists {name!r}, not a {expected} file; regenerate metadata.yaml with `ros2 bag '
                'reindex`.'
            )
            raise BagError(msg)
        try:
            reader = self._reader_class()(path)
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

    def __enter__(self) -> _BagReader:
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
        """The topic's serialisation format as the bag declares it."""
        raise NotImplementedError

    def stored_formats(self, topic: str) -> list[str]:
        """Serialisation formats the storage files give the topic (mcap: the channel's encoding)."""
        return sorted({
            str(getattr(c.ext, 'serialization_format', '')) for c in self.connections if c.topic == topic})

    def format_problem(self, topic: str) -> str:
        """'' if the topic's messages are CDR (or ROS 1), else why not, in a few words."""
        raise NotImplementedError

    # -- messages -----------------------------------------------------------------------------

    def _decompressor(self) -> Callable[[bytes], bytes] | None:
        """What turns a stored message into its serialised bytes (None: stored as they are)."""
        return None

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
        decompress = self._decompressor()
        if decompress is not None:
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
