"""Input images decoded under one guard that knows their name (survey stills, CompressedImage payloads).

What the decoder finds wrong with an image becomes that image's problem, said with its name, instead
of a line on stderr that names nothing (libjpeg's "Premature end of JPEG file", "Corrupt JPEG data"):

- empty bytes, or bytes OpenCV cannot decode at all: refused (``kind`` 'image_empty', 'image_undecodable');
- a JPEG without its end-of-image marker after the image data is truncated: libjpeg would fill the
  rest of the picture with grey, which would be painted. It is refused before decoding
  ('image_truncated'; the markers are walked by length up to the first scan, so the EXIF
  thumbnail's own end marker does not count, and bytes after the end marker are allowed);
- libjpeg's warnings are read off the decoder's stderr while it decodes (OpenCV leaves them to
  libjpeg, which prints them there; any other output caught meanwhile is passed on). A warning that
  the decoder filled or guessed pixels (a premature end of the data, a bad Huffman code) refuses
  the image ('image_corrupt'); others (extraneous bytes between segments: every pixel was read)
  keep it and come back in ``Decoded.warnings``.

With ``check_content`` the picture itself is judged too (stills; a CompressedImage of a live camera
is not, since tests and cameras send small or flat frames on purpose):

- a side below MIN_IMAGE_SIDE_PX at full size ('image_too_small');
- no content: every channel's standard deviation below UNIFORM_MAX_STD grey levels over a sample of
  the pixels (all black, one flat colour: an image that would paint a blank over good ones;
  'image_uniform').

Refusals raise :class:`ImageRefused` (an InputError) with the image's name, its kind and what to do.
"""
from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError

__all__ = ['MIN_IMAGE_SIDE_PX', 'UNIFORM_MAX_STD', 'Decoded', 'ImageRefused', 'check_content', 'decode_bytes',
           'decode_file', 'jpeg_is_truncated']

#: An image with a side shorter than this (pixels at full size) is refused as degenerate.
MIN_IMAGE_SIDE_PX = 32
#: An image whose every channel varies less than this (standard deviation, 8-bit grey levels) has no content.
UNIFORM_MAX_STD = 1.0
#: Pixels sampled for the content check (a strided grid).
_CONTENT_SAMPLES = 65536

# What libjpeg (and libpng, libtiff, OpenCV's logger) print while decoding; other lines are passed on.
_DECODER_LINE = re.compile(r'^\s*(Premature end of JPEG file|Corrupt JPEG data|Invalid |Bogus |Inconsistent |'
                           r'Huffman |Unsupported |Warning|libpng|libtiff|TIFF|\[ ?(WARN|ERROR))')
# ... and those saying that the decoder filled or guessed pixels (the rest are notes)
_FILLED = re.compile(r'premature end|bad huffman|bad arithmetic|found marker', re.IGNORECASE)
_CAPTURE_LOCK = threading.Lock()


class ImageRefused(InputError):
    """An input image refused by the guard: ``name`` (file or frame), ``kind`` (counted in report.json),
    ``what`` is wrong with it, and ``hint``, what to try; ``why`` is the message without the name."""

    def __init__(self, name: str, kind: str, what: str, hint: str = 'Copy it again, or remove it.') -> None:
        self.name, self.kind, self.what, self.hint = name, kind, what, hint
        self.why = f'{what}; left out. {hint}'
        super().__init__(f'{name}: {self.why}')


@dataclass(frozen=True)
class Decoded:
    """Pixels as OpenCV decodes them ((H, W) or (H, W, C) BGR[A], uint8 or uint16) and the decoder's
    warnings that did not refuse the image."""

    pixels: np.ndarray
    warnings: tuple[str, ...] = ()


def jpeg_is_truncated(data: bytes | memoryview) -> bool:
    """Whether JPEG bytes end before their end-of-image marker (FF D9) after the first scan.

    The segments before the scan are skipped by their lengths (an EXIF thumbnail holds an FF D9 of its
    own); inside the scan data a real FF is always followed by 00 or a restart marker, so the first
    FF D9 after the scan header is the image's end. Bytes that are not JPEG are not called truncated.
    """
    view = memoryview(data)
    n = len(view)
    if n < 4 or view[0] != 0xFF or view[1] != 0xD8:
        return False
    i = 2
    while i + 1 < n:
        if view[i] != 0xFF:
            return False  # not a marker where one belongs: the decoder will say what is wrong
        marker = view[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0xD9:
            return False
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        if i + 3 >= n:
            return True
        length = (view[i + 2] << 8) | view[i + 3]
        if marker == 0xDA:
            return bytes(view[i + 2 + length:]).find(b'\xff\xd9') < 0
        i += 2 + length
    return True  # the headers run past the end of the bytes


@contextmanager
def _decoder_messages() -> Iterator[list[str]]:
    """Collect what the C decoders print on stderr (file descriptor 2) inside the block; lines that are
    not theirs (another thread's) are written to stderr afterwards. One block at a time."""
    lines: list[str] = []
    with _CAPTURE_LOCK:
        try:
            saved = os.dup(2)
        except OSError:  # no stderr to take over: the decoder's words are lost, the guard's checks stay
            yield lines
            return
        try:
            sys.stderr.flush()
        except (AttributeError, OSError, ValueError):
            pass
        with tempfile.TemporaryFile() as tmp:
            os.dup2(tmp.fileno(), 2)
            try:
                yield lines
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                tmp.seek(0)
                caught = tmp.read().decode('utf-8', errors='replace')
        for line in caught.splitlines(keepends=True):
            if _DECODER_LINE.match(line):
                lines.append(line.strip())
            else:
                os.write(2, line.encode())


def check_content(pixels: np.ndarray, *, name: str, reduction: int = 1) -> None:
    """Refuse a degenerate picture (module docstring): a side below MIN_IMAGE_SIDE_PX at full size
    (``reduction``: how much the decoder shrank it), or no content."""
    h, w = pixels.shape[:2]
    if min(h, w) * reduction < MIN_IMAGE_SIDE_PX:
        what = (f'the image is {w * reduction}x{h * reduction} px, below the {MIN_IMAGE_SIDE_PX} px a side that '
                'registration needs')
        raise ImageRefused(name, 'image_too_small', what, 'Remove it from the input.')
    step = max(1, int(np.sqrt(h * w / _CONTENT_SAMPLES)))
    sample = pixels[::step, ::step].reshape(-1, pixels.shape[2] if pixels.ndim == 3 else 1).astype(np.float32)
    scale = 257.0 if pixels.dtype == np.uint16 else 1.0
    spread = float(sample.std(axis=0).max()) / scale
    if spread < UNIFORM_MAX_STD:
        level = ', '.join(f'{v / scale:.0f}' for v in sample.mean(axis=0))
        what = (f'the image has no content (every pixel about ({level}), standard deviation {spread:.2f} grey '
                'levels): it would paint a blank over the others')
        raise ImageRefused(name, 'image_uniform', what, 'Remove it from the input, or check the camera.')


def decode_bytes(data: bytes | np.ndarray, flags: int = cv2.IMREAD_COLOR, *, name: str,
                 content: bool = False, reduction: int = 1, listen: bool = True) -> Decoded:
    """Decode an encoded image (JPEG, PNG, TIFF, ...) with cv2.imdecode under the guard (module
    docstring). ``reduction``: the factor the flags shrink the image by (IMREAD_REDUCED_*), for the
    size check. ``listen=False`` skips reading the decoder's stderr (which admits one decode at a
    time): for bytes heard decoding cleanly before, decoded again in parallel. Raises ImageRefused."""
    buf = np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1).view(np.uint8)
    if buf.size == 0:
        raise ImageRefused(name, 'image_empty', 'the image is empty (0 bytes)')
    if jpeg_is_truncated(buf.data):
        what = (f'the JPEG is truncated ({buf.size} bytes, no end-of-image marker after its image data): the '
                'decoder would fill the rest with grey')
        raise ImageRefused(name, 'image_truncated', what, 'Copy the file again from the camera.')
    with _decoder_messages() if listen else nullcontext([]) as messages:
        try:
            pixels = cv2.imdecode(buf, flags)
        except cv2.error:
            pixels = None
    if pixels is None:
        said = f' (the decoder: {messages[0]})' if messages else ''
        what = f'the image cannot be decoded ({buf.size} bytes){said}: it is damaged or not an image'
        raise ImageRefused(name, 'image_undecodable', what)
    filled = [m for m in messages if _FILLED.search(m) and 'extraneous bytes' not in m]
    if filled:
        what = (f'the image data is damaged (the decoder: "{filled[0]}"): part of the picture would be the '
                "decoder's fill")
        raise ImageRefused(name, 'image_corrupt', what, 'Copy the file again.')
    if content:
        check_content(pixels, name=name, reduction=reduction)
    return Decoded(pixels, tuple(messages))


def decode_file(path: str | os.PathLike[str], flags: int = cv2.IMREAD_COLOR, *, content: bool = True,
                reduction: int = 1, listen: bool = True) -> Decoded:
    """Read and decode an image file under the guard (decode_bytes), named by its file name."""
    path = Path(path)
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise ImageRefused(path.name, 'image_unreadable', f'the file cannot be read ({exc.strerror or exc})',
                           'Check its permissions.') from None
    return decode_bytes(data, flags, name=path.name, content=content, reduction=reduction, listen=listen)
