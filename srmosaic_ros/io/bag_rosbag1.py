"""ROS 1 bags (one .bag file, ROS 1 serialisation), read with rosbags' rosbag1 reader; their types are
ROS 1 Noetic's unless the bag defines its own."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .bag_problems import _check_path
from .bag_reader import _BagReader
from .bag_types import _ROS1

if TYPE_CHECKING:
    from pathlib import Path

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in


class _Rosbag1(_BagReader):
    """A ROS 1 .bag file."""

    storage = 'rosbag1'

    def __init__(self, path: Path) -> None:
        super().__init__(path, ros1=True)

    def _reader_class(self) -> type[Any]:
        from rosbags.rosbag1 import Reader

        return Reader

    def _open(self) -> None:
        _check_path(self.path)
        self._open_file(self.path, self.path.name)

    def declared_format(self, topic: str) -> str:
        return _ROS1

    def format_problem(self, topic: str) -> str:
        return ''
