"""The bag layer's one-line messages: exception text, listings, repair hints, and the refusal of paths
that cannot be bags (before rosbags sees them)."""
from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import TYPE_CHECKING

from srmosaic_ros.errors import BagError

from .bag_types import _MAX_LISTED, _SUFFIX_STORAGE

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in


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
