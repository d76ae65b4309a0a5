"""Building messages of either flavour: rclpy classes or rosbags dataclasses.

rclpy message modules are imported lazily, so msg_adapters works where only rosbags is installed.
Readers never need this module: they only read the fields that both flavours share.
"""
from __future__ import annotations

import array
import importlib
from functools import cache
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from srmosaic_ros.errors import ConfigError, MessageError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from rosbags.typesys.store import Typestore

__all__ = [
    'FLAVORS',
    'Flavor',
    'as_u8',
    'check_flavor',
    'float_field',
    'new_message',
    'rosbags_typestore',
    'u8_field',
]

Flavor = Literal['rclpy', 'rosbags']
FLAVORS: tuple[str, ...] = ('rclpy', 'rosbags')

_NUMPY_DTYPES = {
    'bool': np.bool_,
    'byte': np.uint8,
    'char': np.uint8,
    'int8': np.int8,
    'uint8': np.uint8,
    'int16': np.int16,
    'uint16': np.uint16,
    'int32': np.int32,
    'uint32': np.uint32,
    'int64': np.int64,
    'uint64': np.uint64,
    'float32': np.float32,
    'float64': np.float64,
}


def check_flavor(flavor: str) -> Flavor:
    """Return ``flavor`` if it is known, else raise ConfigError."""
    if flavor not in FLAVORS:
        msg = f'flavor {flavor!r} is not known; use one of {FLAVORS}.'
        raise ConfigError(msg)
    return flavor  # type: ignore[return-value]


@cache
def rosbags_typestore() -> Typestore:
    """The ROS 2 Jazzy typestore that rosbags-flavoured messages are built from."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _rclpy_class(msgtype: str) -> Any:
    package, _, name = msgtype.split('/')
    try:
        module = importlib.import_module(f'{package}.msg')
        return getattr(module, name)
    except (ImportError, AttributeError) as exc:
        msg = (
            f'flavor=\'rclpy\' needs the ROS 2 Python message {msgtype!r}, which cannot be imported '
            f'({exc}); source a ROS 2 Jazzy setup or install ros-jazzy-common-interfaces, '
            'or build with flavor=\'rosbags\'.'
        )
        raise MessageError(msg) from None


def _rosbags_default(typestore: Typestore, fielddef: tuple[Any, Any]) -> Any:
    """Default value of one rosbags field definition (zeros, empty strings, empty sequences)."""
    from rosbags.typesys.base import Nodetype

    kind, detail = fielddef
    if kind == Nodetype.BASE:
        typ = detail[0]
        if typ == 'string' or typ == 'wstring':
            return ''
        if typ == 'bool':
            return False
        if typ.startswith('float'):
            return 0.0
        return 0
    if kind == Nodetype.NAME:
        return _rosbags_new(typestore, detail, {})
    sub, length = detail
    sub_kind, sub_detail = sub
    if sub_kind == Nodetype.BASE and sub_detail[0] in _NUMPY_DTYPES:
        size = length if kind == Nodetype.ARRAY else 0
        return np.zeros(size, dtype=_NUMPY_DTYPES[sub_detail[0]])
    if kind == Nodetype.ARRAY:
        return [_rosbags_default(typestore, sub) for _ in range(length)]
    return []


def _rosbags_new(typestore: Typestore, msgtype: str, fields: dict[str, Any]) -> Any:
    cls = typestore.types[msgtype]
    _, fielddefs = typestore.fielddefs[msgtype]
    values = {
        name: fields[name] if name in fields else _rosbags_default(typestore, fielddef)
        for name, fielddef in fielddefs
    }
    if unknown := set(fields) - set(values):
        msg = f'{msgtype} has no field(s) {sorted(unknown)}.'
        raise MessageError(msg)
    return cls(**values)


def new_message(flavor: str, msgtype: str, **fields: Any) -> Any:
    """Build a message ``msgtype`` (e.g. 'sensor_msgs/msg/Image') of ``flavor``.

    Fields not given take their defaults (zeros, empty). Values must already be in the
    flavour's representation: see :func:`u8_field` and :func:`float_field`.
    """
    if check_flavor(flavor) == 'rclpy':
        return _rclpy_class(msgtype)(**fields)
    return _rosbags_new(rosbags_typestore(), msgtype, fields)


def as_u8(data: Any) -> np.ndarray:
    """1-D uint8 view (no copy where possible) of a ``data`` field of either flavour.

    rosbags gives numpy uint8 arrays, rclpy ``array.array('B')``; bytes and lists work too.
    """
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            data = np.ascontiguousarray(data).view(np.uint8)
        return data.reshape(-1)
    if isinstance(data, (bytes, bytearray, memoryview, array.array)):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8).reshape(-1)


def u8_field(buffer: np.ndarray, flavor: str) -> Any:
    """A uint8 buffer as the ``data`` field of ``flavor`` (a fresh array, never a view)."""
    flat = np.ascontiguousarray(buffer, dtype=np.uint8).reshape(-1)
    if flavor == 'rclpy':
        return array.array('B', flat.tobytes())
    return flat.copy()


def float_field(values: Sequence[float] | np.ndarray, flavor: str) -> Any:
    """A float64 array/sequence field (CameraInfo.k, covariances...) for ``flavor``."""
    flat = np.asarray(values, dtype=np.float64).reshape(-1)
    if flavor == 'rclpy':
        return [float(x) for x in flat]
    return flat.copy()
