"""The storage layer of io/bags.py: a bag opened with the reader of its kind (bag_rosbag2.py: metadata.yaml,
sqlite3 and mcap files, split, zstd-compressed; bag_rosbag1.py: ROS 1 bags), each behind the
protocol of bag_reader.py, and the one-line refusals built from them. io/bags.py is the way in.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from srmosaic_ros.errors import BagError

from .bag_problems import _check_path, _describe, _listing, _repair_hint
from .bag_reader import _BagReader as _Bag
from .bag_rosbag1 import _Rosbag1
from .bag_rosbag2 import _Rosbag2
from .bag_types import _CDR, _SUFFIX_STORAGE, BagInfo

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping
    from pathlib import Path

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in


def _open_bag(path: Path) -> _Bag:
    """An open reader of the bag ``path`` (ROS 1 or rosbag2, by what it is), or BagError."""
    _check_path(path)
    bag: _Bag = _Rosbag1(path) if path.is_file() and _SUFFIX_STORAGE.get(path.suffix) == 'rosbag1' else _Rosbag2(path)
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
