"""Writing rosbag2 bags (sqlite3 or mcap) message by message (io/bags.py re-exports BagWriter)."""
from __future__ import annotations

import contextlib
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

from srmosaic_ros.errors import BagError

if TYPE_CHECKING:
    from types import TracebackType

    from rosbags.interfaces import Connection

from .bag_problems import _describe
from .bag_types import _ROSBAG2_VERSION, STORAGES

__all__ = ['BagWriter']

# --------------------------------------------------------------------------------------------
# Writing


def _rclpy_msgtype(msg: Any) -> str | None:
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
        from rosbags.rosbag2 import StoragePlugin

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
        from rosbags.rosbag2 import Writer

        from msg_adapters._flavor import rosbags_typestore

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

    def _serialize(self, topic: str, msg: Any) -> tuple[str, bytes]:
        msgtype = getattr(msg, '__msgtype__', None)
        try:
            if isinstance(msgtype, str):
                return msgtype, bytes(self._typestore.serialize_cdr(msg, msgtype))
            msgtype = _rclpy_msgtype(msg)
            if msgtype is not None:
                from rclpy.serialization import serialize_message

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

    def write(self, topic: str, msg: Any, stamp_ns: int) -> None:
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
