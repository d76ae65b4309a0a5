"""A PNG written strip by strip, its deflate stream compressed on several threads (pigz's way).

Pillow, OpenCV and GDAL's PNG driver encode a PNG from a whole image (GDAL: a CreateCopy from a
dataset, on one thread), so a mosaic of a hundred megapixels is either held whole or encoded
after the fact, on one core. ``StreamingPngWriter`` takes the rows as they are rendered:

- each strip's scanlines are filtered ("Up" for the strip's rows, against the last row of the
  previous strip: one numpy subtraction, wrapping modulo 256) and compressed as raw deflate ending
  on a byte boundary (``Z_SYNC_FLUSH``), by a pool of ``threads`` threads (zlib releases the GIL);
- the pieces are written in order as IDAT chunks of one zlib stream (header, the pieces, an empty
  final block, the Adler-32 of every filtered byte), which any PNG decoder reads as one stream.

Convention: 8-bit samples; ``channels`` 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA), rows
top to bottom. The file is written under a temporary name and renamed into place on ``close()``
(``with StreamingPngWriter(...) as png:``); an exception inside the block leaves no file.
"""
from __future__ import annotations

import collections
import os
import struct
import zlib
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FULL_DISK_ERRNOS, OutputError
from .mosaic_files import atomic_path

__all__ = ['PNG_COLOUR_TYPES', 'StreamingPngWriter']

#: PNG colour type of each channel count.
PNG_COLOUR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}
_SIGNATURE = b'\x89PNG\r\n\x1a\n'
_UP = 2  # PNG filter type "Up"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack('>I', len(data)) + kind + data + struct.pack('>I', zlib.crc32(data, zlib.crc32(kind)))


def _deflate(raw: np.ndarray, level: int) -> bytes:
    """Raw deflate of ``raw``'s bytes, ending on a byte boundary with no final block (a piece of a longer stream)."""
    c = zlib.compressobj(level, zlib.DEFLATED, -15, 9)
    return c.compress(raw) + c.flush(zlib.Z_SYNC_FLUSH)


class StreamingPngWriter:
    """PNG of ``height`` x ``width`` x ``channels`` uint8 written by ``write(rows)`` calls, top to bottom.

    Args:
        path: the .png file (appears on ``close()``).
        width, height: pixels.
        channels: 1, 2, 3 or 4 (grey, grey + alpha, RGB, RGBA).
        level: zlib level (1: fastest, as mosaic.png has always been written).
        threads: compressing threads (1: compressed on the caller's thread).

    Memory: the strips in flight, at most ``threads + 1`` of them with their compressed bytes.
    """

    def __init__(self, path: str | os.PathLike[str], width: int, height: int, channels: int, *, level: int = 1,
                 threads: int = 2) -> None:
        if channels not in PNG_COLOUR_TYPES:
            msg = f'a PNG has 1 to 4 channels (grey, grey + alpha, RGB, RGBA), not {channels}.'
            raise ValueError(msg)
        if width < 1 or height < 1 or width * channels + 1 >= 2**31:
            msg = f'a PNG of {width}x{height} px with {channels} channels cannot be written.'
            raise ValueError(msg)
        self.width, self.height, self.channels, self.level = int(width), int(height), int(channels), int(level)
        self._name = Path(path).name
        self._stack = ExitStack()
        self._tmp = self._stack.enter_context(atomic_path(path))
        self._file = self._stack.enter_context(open(self._tmp, 'wb'))
        self._pool = self._stack.enter_context(ThreadPoolExecutor(max(1, int(threads)))) if threads > 1 else None
        self._threads = max(1, int(threads))
        self._pending: collections.deque[Future[bytes] | bytes] = collections.deque()
        self._prev: np.ndarray | None = None  # the last row written (the "Up" filter's previous row)
        self._adler = 1
        self.rows_written = 0
        ihdr = struct.pack('>IIBBBBB', self.width, self.height, 8, PNG_COLOUR_TYPES[self.channels], 0, 0, 0)
        self._put(_SIGNATURE + _chunk(b'IHDR', ihdr) + _chunk(b'IDAT', b'\x78\x01'))  # the zlib header (deflate, 32 KiB window)

    def __enter__(self) -> StreamingPngWriter:
        return self

    def __exit__(self, exc_type: Any, *rest: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self._abort()

    def write(self, rows: np.ndarray) -> None:
        """Append rows: uint8 (n, width, channels), or (n, width) for one channel."""
        img = np.asarray(rows)
        if img.ndim == 2:
            img = img[:, :, None]
        if img.dtype != np.uint8 or img.shape[1:] != (self.width, self.channels):
            msg = (f'rows must be uint8 (n, {self.width}, {self.channels}), got {img.dtype} {img.shape}; '
                   'convert the strip first.')
            raise ValueError(msg)
        n = img.shape[0]
        if self.rows_written + n > self.height:
            msg = f'{self.rows_written + n} rows written to a PNG of {self.height}.'
            raise ValueError(msg)
        if n == 0:
            return
        flat = img.reshape(n, self.width * self.channels)
        raw = np.empty((n, flat.shape[1] + 1), np.uint8)
        raw[:, 0] = _UP
        np.subtract(flat[1:], flat[:-1], out=raw[1:, 1:])  # uint8: modulo 256, as the filter is defined
        if self._prev is None:
            raw[0, 1:] = flat[0]  # "Up" against the row above the image: zeros
        else:
            np.subtract(flat[0], self._prev, out=raw[0, 1:])
        self._prev = flat[-1].copy()
        self._adler = zlib.adler32(raw, self._adler)
        self.rows_written += n
        if self._pool is None:
            self._pending.append(_deflate(raw, self.level))
        else:
            self._pending.append(self._pool.submit(_deflate, raw, self.level))
        self._drain(self._threads)

    def _drain(self, keep: int) -> None:
        while len(self._pending) > keep:
            item = self._pending.popleft()
            data = item if isinstance(item, bytes) else item.result()
            if data:
                self._put(_chunk(b'IDAT', data))

    def _put(self, data: bytes | None) -> None:
        """Write ``data`` to the file (None: close it, flushing its buffer); a full disk or a file size
        limit is an OutputError naming the file."""
        try:
            if data is None:
                self._file.close()
            else:
                self._file.write(data)
        except OSError as exc:
            if exc.errno not in FULL_DISK_ERRNOS:
                raise
            msg = (f'{self._name} could not be written ({exc.strerror}): the disk is full or a file size limit was '
                   'reached; free space, or give --out elsewhere.')
            raise OutputError(msg) from None

    def close(self) -> None:
        """Finish the stream and move the file into place; every row must have been written."""
        if self._file.closed:
            return
        if self.rows_written != self.height:
            self._abort()
            msg = f'the PNG got {self.rows_written} of its {self.height} rows; it is not written.'
            raise ValueError(msg)
        try:
            self._drain(0)
            tail = zlib.compressobj(self.level, zlib.DEFLATED, -15, 9).flush(zlib.Z_FINISH)  # an empty final block
            self._put(_chunk(b'IDAT', tail + struct.pack('>I', self._adler)) + _chunk(b'IEND', b''))
            self._put(None)
        except BaseException:
            self._abort()
            raise
        self._stack.close()  # the pool, then the rename

    def _abort(self) -> None:
        """Drop the file (an exception, or too few rows)."""
        for item in self._pending:
            if isinstance(item, Future):
                item.cancel()
        self._pending.clear()
        try:
            self._file.close()
        except OSError:  # its buffer could not be flushed: the file is dropped all the same
            pass
        try:
            self._stack.__exit__(RuntimeError, RuntimeError('aborted'), None)  # atomic_path: no rename
        except RuntimeError:
            pass

