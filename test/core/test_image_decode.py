"""The decoding guard (srmosaic_ros/core/image_decode.py): what it refuses, what it keeps, what it says."""
from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.image_decode import ImageRefused, decode_bytes, decode_file, jpeg_is_truncated


@pytest.fixture(scope='module')
def jpeg() -> bytes:
    rng = np.random.default_rng(1)
    pixels = cv2.GaussianBlur(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8), (0, 0), 2.0)
    ok, data = cv2.imencode('.jpg', pixels, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return data.tobytes()


def test_a_good_jpeg_is_decoded_without_warnings(jpeg: bytes) -> None:
    decoded = decode_bytes(jpeg, name='good.jpg', content=True)
    assert decoded.pixels.shape == (240, 320, 3) and decoded.warnings == ()
    assert decoded_same(decode_bytes(jpeg + b'trailer after the end marker', name='t.jpg'), decoded)


def decoded_same(a, b) -> bool:
    return np.array_equal(a.pixels, b.pixels)


@pytest.mark.parametrize('keep', [0.2, 0.5, 0.9])
def test_a_truncated_jpeg_is_refused_before_decoding(jpeg: bytes, keep: float) -> None:
    cut = jpeg[:int(len(jpeg) * keep)]
    assert jpeg_is_truncated(cut) and not jpeg_is_truncated(jpeg)
    with pytest.raises(ImageRefused, match=r'cut\.jpg: the JPEG is truncated .* left out') as info:
        decode_bytes(cut, name='cut.jpg')
    assert info.value.kind == 'image_truncated'


def test_damaged_data_that_the_decoder_fills_is_refused(jpeg: bytes) -> None:
    """A marker in the middle of the scan data (bytes lost or inserted): libjpeg fills the rest of the
    segment and says so. (Damage it resynchronises after without a word stays unseen.)"""
    middle = len(jpeg) // 2
    data = jpeg[:middle] + b'\xff\xd0' * 3 + jpeg[middle:]
    with pytest.raises(ImageRefused, match='damaged') as info:
        decode_bytes(bytes(data), name='bad.jpg')
    assert info.value.kind == 'image_corrupt' and 'Corrupt JPEG data' in info.value.what


def test_extraneous_bytes_are_a_warning_and_the_image_is_kept(jpeg: bytes, capfd: pytest.CaptureFixture[str]) -> None:
    data = jpeg[:-2] + b'abc' + jpeg[-2:]
    decoded = decode_bytes(data, name='x.jpg')
    assert decoded.pixels.shape == (240, 320, 3)
    assert len(decoded.warnings) == 1 and 'extraneous bytes' in decoded.warnings[0]
    assert 'extraneous' not in capfd.readouterr().err  # said by the caller, with the name, not raw


def test_other_output_on_stderr_meanwhile_is_passed_on(jpeg: bytes, capfd: pytest.CaptureFixture[str]) -> None:
    from srmosaic_ros.core import image_decode

    with image_decode._decoder_messages() as lines:
        os.write(2, b'a progress bar\n')
        os.write(2, b'Premature end of JPEG file\n')
    assert lines == ['Premature end of JPEG file']
    assert capfd.readouterr().err == 'a progress bar\n'


@pytest.mark.parametrize(('data', 'kind'), [(b'', 'image_empty'), (b'not an image at all', 'image_undecodable')])
def test_empty_and_undecodable_bytes_are_refused(data: bytes, kind: str) -> None:
    with pytest.raises(ImageRefused) as info:
        decode_bytes(data, name='f.jpg')
    assert info.value.kind == kind and str(info.value).startswith('f.jpg: ')


@pytest.mark.parametrize(('pixels', 'kind'), [
    (np.zeros((900, 1200, 3), np.uint8), 'image_uniform'),
    (np.full((300, 400), 77, np.uint8), 'image_uniform'),
    (np.full((1, 1, 3), 200, np.uint8), 'image_too_small'),
])
def test_degenerate_pictures_are_refused_with_content_checks(tmp_path, pixels: np.ndarray, kind: str) -> None:
    path = tmp_path / 'p.png'
    cv2.imwrite(str(path), pixels)
    with pytest.raises(ImageRefused) as info:
        decode_file(path)
    assert info.value.kind == kind and info.value.name == 'p.png'
    decode_file(path, content=False)  # without them, the same picture is decoded


def test_a_reduced_decode_is_judged_at_full_size(jpeg: bytes) -> None:
    decoded = decode_bytes(jpeg, cv2.IMREAD_REDUCED_COLOR_8, name='r.jpg', content=True, reduction=8)
    assert decoded.pixels.shape == (30, 40, 3)  # 30 px at 1/8: 240 px, large enough
