"""rosbag2 bags: a folder with metadata.yaml (sqlite3 or mcap storage files; split; zstd-compressed per
file or per message), or one bare .db3/.mcap file, read with rosbags' rosbag2 storage reader."""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any

from srmosaic_ros.errors import BagError

from .bag_metadata import _read_metadata
from .bag_problems import _check_path, _describe, _listing
from .bag_reader import _BagReader
from .bag_types import _CDR, _SUFFIX_STORAGE, _ZSTD_MAGIC

if TYPE_CHECKING:
    from collections.abc import Callable

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in


def _zstd() -> Any:  # the module itself
    try:
        from compression import zstd  # type: ignore[import-not-found]
    except ImportError:
        from backports import zstd  # type: ignore[no-redef]
    return zstd


class _Rosbag2(_BagReader):
    """A rosbag2 bag (folder or bare storage file); messages in CDR."""

    def __init__(self, path: Path) -> None:
        super().__init__(path, ros1=False)
        self._zstd_messages = False

    def _reader_class(self) -> type[Any]:
        from rosbags.rosbag2 import Reader

        return Reader

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

    def declared_format(self, topic: str) -> str:
        if self.meta is not None and topic in self.meta.topics:
            return self.meta.topics[topic].serialization_format
        formats = self.stored_formats(topic)
        return formats[0] if len(formats) == 1 else ','.join(formats)

    def format_problem(self, topic: str) -> str:
        """'' if the topic's messages are CDR , else why not, in a few words."""
        stored = self.stored_formats(topic)
        declared = self.declared_format(topic)
        bad = [f for f in (declared, *stored) if f != _CDR]
        if not bad:
            return ''
        text = f'serialisation format {bad[0]!r} is not CDR'
        if self.meta is not None and stored and stored != [declared]:
            text += f" (metadata.yaml declares {declared!r}, the storage file {', '.join(map(repr, stored))})"
        return text

    def _decompressor(self) -> Callable[[bytes], bytes] | None:
        if self._zstd_messages or (self.meta is not None and self.meta.compression_mode == 'message'):
            return _zstd().decompress
        return None
