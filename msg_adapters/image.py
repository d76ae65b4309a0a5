"""sensor_msgs/Image and sensor_msgs/CompressedImage <-> numpy arrays.

Like cv_bridge, the readers honour ``encoding``, ``step`` row padding and ``is_bigendian``; they
read only the fields that rclpy and rosbags messages share, so one function serves both.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from srmosaic_ros.core.image_decode import ImageRefused, decode_bytes
from srmosaic_ros.errors import MessageError

from ._flavor import as_u8, check_flavor, new_message, u8_field
from .stamps import make_header

__all__ = [
    'SUPPORTED_ENCODINGS',
    'COMPRESSED_FORMATS',
    'image_to_numpy',
    'image_to_rgb_or_mono',
    'numpy_to_image',
    'numpy_to_compressed',
    'is_compressed_image',
]


@dataclass(frozen=True)
class _Encoding:
    channels: int
    itemsize: int  # bytes per channel value
    order: str  # 'mono', 'rgb', 'bgr', 'rgba' or 'bgra'


# OpenCV's conventions decide the order of the generic 8UCn encodings: 8UC3 is BGR, 8UC4 BGRA.
_ENCODINGS: dict[str, _Encoding] = {
    'mono8': _Encoding(1, 1, 'mono'),
    'mono16': _Encoding(1, 2, 'mono'),
    'rgb8': _Encoding(3, 1, 'rgb'),
    'bgr8': _Encoding(3, 1, 'bgr'),
    'rgba8': _Encoding(4, 1, 'rgba'),
    'bgra8': _Encoding(4, 1, 'bgra'),
    'rgb16': _Encoding(3, 2, 'rgb'),
    'bgr16': _Encoding(3, 2, 'bgr'),
    'rgba16': _Encoding(4, 2, 'rgba'),
    'bgra16': _Encoding(4, 2, 'bgra'),
    '8UC1': _Encoding(1, 1, 'mono'),
    '8UC3': _Encoding(3, 1, 'bgr'),
    '8UC4': _Encoding(4, 1, 'bgra'),
    '16UC1': _Encoding(1, 2, 'mono'),
}
SUPPORTED_ENCODINGS: tuple[str, ...] = tuple(_ENCODINGS)
COMPRESSED_FORMATS: tuple[str, ...] = ('jpeg', 'png')


def _encoding(name: str, field: str) -> _Encoding:
    enc = _ENCODINGS.get(str(name).strip())
    if enc is None:
        msg = (
            f'{field} {name!r} is not supported; supported: {", ".join(SUPPORTED_ENCODINGS)}. '
            'Convert upstream (e.g. debayer with image_proc, or republish as rgb8/mono8).'
        )
        raise MessageError(msg)
    return enc


def is_compressed_image(msg: Any) -> bool:
    """True for a sensor_msgs/CompressedImage (has ``format``), False for an Image."""
    return hasattr(msg, 'format') and not hasattr(msg, 'encoding')


def image_to_numpy(msg: Any) -> np.ndarray:
    """Pixels of a sensor_msgs/Image (rclpy or rosbags) as a new numpy array.

    Returns:
        (H, W) for one channel, else (H, W, C) in the message's own channel order
        (bgr8 stays BGR); dtype uint8 or uint16 in native byte order. Always a copy.

    Raises:
        MessageError: unsupported encoding, zero size, ``step`` too small, or a ``data`` length
            other than height * step; the message names the field.

    """
    enc = _encoding(msg.encoding, 'Image.encoding')
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    for name, value in (('height', height), ('width', width)):
        if value <= 0:
            msg_ = (
                f'Image.{name} is {value}; an image needs at least one row and column. '
                'The publisher sent an empty image.'
            )
            raise MessageError(msg_)
    row_bytes = width * enc.channels * enc.itemsize
    if step < row_bytes:
        msg_ = (
            f'Image.step {step} is smaller than width*channels*bytes = {width}*{enc.channels}*'
            f'{enc.itemsize} = {row_bytes} for encoding {msg.encoding!r}; the publisher filled '
            'step wrongly (step is the row length in bytes, padding included).'
        )
        raise MessageError(msg_)
    buf = as_u8(msg.data)
    if buf.size != height * step:
        msg_ = (
            f'Image.data has {buf.size} bytes but height*step = {height}*{step} = {height * step}; '
            'the message is truncated or its height/step are wrong. Check the publisher.'
        )
        raise MessageError(msg_)
    rows = buf.reshape(height, step)[:, :row_bytes]
    if enc.itemsize == 1:
        pixels = rows.copy()
    else:
        wire = np.dtype('>u2' if msg.is_bigendian else '<u2')
        pixels = np.ascontiguousarray(rows).view(wire).astype(np.uint16, copy=True)
    shape = (height, width) if enc.channels == 1 else (height, width, enc.channels)
    return pixels.reshape(shape)


def _to_rgb(pixels: np.ndarray, order: str) -> np.ndarray:
    if order in {'mono', 'rgb'}:
        return pixels
    if order == 'rgba':
        return np.ascontiguousarray(pixels[..., :3])
    return np.ascontiguousarray(pixels[..., 2::-1])  # bgr, bgra


def _decode_compressed(msg: Any, warnings: list[str] | None = None) -> np.ndarray:
    fmt = str(msg.format)
    if 'compresseddepth' in fmt.lower():
        msg_ = (
            f'CompressedImage.format {fmt!r} (compressedDepth) is not supported; '
            'subscribe to the colour or mono stream instead.'
        )
        raise MessageError(msg_)
    buf = as_u8(msg.data)
    if buf.size == 0:
        msg_ = 'CompressedImage.data is empty; the publisher sent no payload.'
        raise MessageError(msg_)
    try:
        guarded = decode_bytes(buf, cv2.IMREAD_UNCHANGED, name='CompressedImage.data')
    except ImageRefused as exc:
        msg_ = (
            f'CompressedImage.data ({buf.size} bytes, format {fmt!r}) cannot be decoded: {exc.what}. '
            'Check the image_transport plugin of the publisher, or the recording.'
        )
        raise MessageError(msg_) from None
    if warnings is not None:
        warnings.extend(guarded.warnings)
    decoded = guarded.pixels
    if decoded.dtype not in (np.uint8, np.uint16):
        msg_ = (
            f'CompressedImage.data decodes to dtype {decoded.dtype}; '
            'only 8 and 16 bit images are supported.'
        )
        raise MessageError(msg_)
    if decoded.ndim == 3 and decoded.shape[2] == 1:
        decoded = decoded[..., 0]
    if decoded.ndim == 2:
        return np.ascontiguousarray(decoded)
    order = {3: 'bgr', 4: 'bgra'}.get(decoded.shape[2])
    if order is None:
        msg_ = f'CompressedImage.data decodes to {decoded.shape[2]} channels; expected 1, 3 or 4.'
        raise MessageError(msg_)
    return _to_rgb(decoded, order)


def image_to_rgb_or_mono(msg: Any, warnings: list[str] | None = None) -> np.ndarray:
    """Pixels of an Image or CompressedImage normalised for the core.

    A CompressedImage is decoded under the guard of srmosaic_ros/core/image_decode.py: truncated or
    damaged data (the decoder would fill pixels) is refused; the decoder's other warnings are
    appended to ``warnings`` when given.

    Returns:
        (H, W) for mono, (H, W, 3) RGB for colour (alpha dropped, BGR swapped); uint8 or uint16.
        Always a new array.

    Raises:
        MessageError: as :func:`image_to_numpy`, or an undecodable CompressedImage payload.

    """
    if is_compressed_image(msg):
        return _decode_compressed(msg, warnings)
    enc = _encoding(msg.encoding, 'Image.encoding')
    return _to_rgb(image_to_numpy(msg), enc.order)


def numpy_to_image(
    array: np.ndarray,
    encoding: str,
    *,
    stamp_ns: int = 0,
    frame_id: str = '',
    flavor: str = 'rclpy',
    is_bigendian: bool = False,
    step: int | None = None,
) -> Any:
    """Build a sensor_msgs/Image of ``flavor`` from pixels already in ``encoding``'s order.

    Args:
        array: (H, W) or (H, W, C) uint8 or uint16 (as the encoding requires).
        encoding: one of :data:`SUPPORTED_ENCODINGS`; channels are not reordered.
        stamp_ns: header stamp, integer nanoseconds.
        frame_id: header frame.
        flavor: 'rclpy' or 'rosbags'.
        is_bigendian: byte order of 16-bit data on the wire.
        step: row length in bytes; larger than the packed row to add (zero) padding.

    Raises:
        MessageError: the array does not fit the encoding, or step is too small.

    """
    flavor = check_flavor(flavor)
    enc = _encoding(encoding, 'encoding')
    pixels = np.asarray(array)
    want_dtype = np.uint8 if enc.itemsize == 1 else np.uint16
    if pixels.dtype != want_dtype:
        msg = (
            f'encoding {encoding!r} needs a {np.dtype(want_dtype)} array, got {pixels.dtype}; '
            'convert it first.'
        )
        raise MessageError(msg)
    if pixels.ndim == 3 and enc.channels == 1 and pixels.shape[2] == 1:
        pixels = pixels[..., 0]
    want_ndim = 2 if enc.channels == 1 else 3
    if pixels.ndim != want_ndim or (want_ndim == 3 and pixels.shape[2] != enc.channels):
        want = '(H, W)' if enc.channels == 1 else f'(H, W, {enc.channels})'
        msg = f'encoding {encoding!r} needs an array of shape {want}, got {pixels.shape}.'
        raise MessageError(msg)
    height, width = int(pixels.shape[0]), int(pixels.shape[1])
    if height == 0 or width == 0:
        msg = f'array of shape {pixels.shape} is empty; an Image needs at least one pixel.'
        raise MessageError(msg)
    row_bytes = width * enc.channels * enc.itemsize
    step = row_bytes if step is None else int(step)
    if step < row_bytes:
        msg = (
            f'step {step} is smaller than the packed row of {row_bytes} bytes; '
            f'pass step >= {row_bytes}.'
        )
        raise MessageError(msg)
    if enc.itemsize == 2:
        pixels = pixels.astype('>u2' if is_bigendian else '<u2')
    packed = np.ascontiguousarray(pixels).view(np.uint8).reshape(height, row_bytes)
    if step == row_bytes:
        buffer = packed
    else:
        buffer = np.zeros((height, step), dtype=np.uint8)
        buffer[:, :row_bytes] = packed
    return new_message(
        flavor,
        'sensor_msgs/msg/Image',
        header=make_header(stamp_ns, frame_id, flavor),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=int(bool(is_bigendian)),
        step=step,
        data=u8_field(buffer, flavor),
    )


def numpy_to_compressed(
    array_rgb_or_mono: np.ndarray,
    *,
    fmt: str = 'jpeg',
    quality: int = 90,
    stamp_ns: int = 0,
    frame_id: str = '',
    flavor: str = 'rclpy',
) -> Any:
    """Build a sensor_msgs/CompressedImage of ``flavor`` as image_transport's plugin would.

    Args:
        array_rgb_or_mono: (H, W) mono or (H, W, 3) RGB; uint8, or uint16 for PNG.
        fmt: 'jpeg' (alias 'jpg') or 'png'.
        quality: JPEG quality 1..100 (ignored for PNG).

    The ``format`` field reads like image_transport's, e.g. 'rgb8; jpeg compressed bgr8'.

    Raises:
        MessageError: unsupported fmt, shape or dtype, or the encoder failed.

    """
    flavor = check_flavor(flavor)
    kind = {'jpeg': 'jpeg', 'jpg': 'jpeg', 'png': 'png'}.get(str(fmt).lower())
    if kind is None:
        msg = f'fmt {fmt!r} is not supported; use one of {COMPRESSED_FORMATS}.'
        raise MessageError(msg)
    pixels = np.asarray(array_rgb_or_mono)
    if pixels.dtype not in (np.uint8, np.uint16) or (kind == 'jpeg' and pixels.dtype != np.uint8):
        msg = f'{kind} cannot hold a {pixels.dtype} image; use uint8 (or uint16 with fmt=\'png\').'
        raise MessageError(msg)
    bits = 8 if pixels.dtype == np.uint8 else 16
    if pixels.ndim == 2:
        encoding = target = f'mono{bits}'
        bgr = pixels
    elif pixels.ndim == 3 and pixels.shape[2] == 3:
        encoding, target = f'rgb{bits}', f'bgr{bits}'
        bgr = np.ascontiguousarray(pixels[..., ::-1])
    else:
        msg = f'array of shape {pixels.shape} is neither (H, W) mono nor (H, W, 3) RGB.'
        raise MessageError(msg)
    if kind == 'jpeg':
        if not 1 <= int(quality) <= 100:
            msg = f'quality {quality} is outside 1..100.'
            raise MessageError(msg)
        params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    else:
        params = [cv2.IMWRITE_PNG_COMPRESSION, 3]
    ok, encoded = cv2.imencode('.jpg' if kind == 'jpeg' else '.png', bgr, params)
    if not ok:
        msg = f'OpenCV could not encode a {pixels.shape} {pixels.dtype} image as {kind}.'
        raise MessageError(msg)
    return new_message(
        flavor,
        'sensor_msgs/msg/CompressedImage',
        header=make_header(stamp_ns, frame_id, flavor),
        format=f'{encoding}; {kind} compressed {target}',
        data=u8_field(encoded, flavor),
    )
