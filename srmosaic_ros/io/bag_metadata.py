"""metadata.yaml of a rosbag2 folder: read, checked, as a plain record (or one-line BagError)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import PurePath
from typing import TYPE_CHECKING, Any

from srmosaic_ros.errors import BagError

from .bag_problems import _describe, _listing
from .bag_types import _NEWEST_READABLE_VERSION, STORAGES

if TYPE_CHECKING:
    from pathlib import Path

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in


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
