"""io/png_stream.py: a PNG written strip by strip and compressed on threads decodes to the rows
given (OpenCV and Pillow), for every channel count, strip height and thread count; a PNG not
finished (too few rows, an exception) leaves no file; bad rows are refused."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from srmosaic_ros.io.png_stream import StreamingPngWriter


def _image(h: int, w: int, c: int, seed: int) -> np.ndarray:
    """Smooth texture with noise and a flat band (what filters and deflate see in a mosaic)."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.random((h, w, c), dtype=np.float32), (0, 0), 3.0).reshape(h, w, c)
    img = np.clip(base * 600.0 - 150.0 + rng.normal(0, 4, (h, w, c)), 0, 255).astype(np.uint8)
    img[:, : w // 5] = 0  # uncovered
    return img


def _write(path: Path, img: np.ndarray, rows: list[int], threads: int) -> None:
    with StreamingPngWriter(path, img.shape[1], img.shape[0], img.shape[2], threads=threads) as png:
        r = 0
        for n in rows:
            png.write(img[r:r + n] if img.shape[2] > 1 or n % 2 else img[r:r + n, :, 0])  # (n, W) for grey too
            r += n
        assert r == img.shape[0]


@pytest.mark.parametrize('channels', [1, 2, 3, 4])
@pytest.mark.parametrize('threads', [1, 2, 3])
def test_strips_decode_to_the_rows_written(channels: int, threads: int, tmp_path: Path) -> None:
    img = _image(203, 157, channels, seed=channels)
    path = tmp_path / 'm.png'
    _write(path, img, [1, 64, 0, 37, 100, 1], threads)
    with Image.open(path) as im:
        assert im.mode == {1: 'L', 2: 'LA', 3: 'RGB', 4: 'RGBA'}[channels]
        pillow = np.asarray(im)
    assert np.array_equal(pillow.reshape(img.shape), img)
    opencv = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if channels >= 3:
        opencv = cv2.cvtColor(opencv, cv2.COLOR_BGRA2RGBA if channels == 4 else cv2.COLOR_BGR2RGB)
    if channels != 2:  # OpenCV reads grey + alpha as BGRA
        assert np.array_equal(opencv.reshape(img.shape), img)
    assert not [p.name for p in tmp_path.iterdir() if p.name != 'm.png']  # no temporary left


def test_the_strip_split_does_not_change_the_pixels(tmp_path: Path) -> None:
    img = _image(300, 200, 4, seed=7)
    _write(tmp_path / 'a.png', img, [300], 1)
    _write(tmp_path / 'b.png', img, [7] * 42 + [6], 2)
    a, b = (np.asarray(Image.open(tmp_path / f)) for f in ('a.png', 'b.png'))
    assert np.array_equal(a, b) and np.array_equal(a, img)


def test_an_unfinished_png_leaves_no_file(tmp_path: Path) -> None:
    img = _image(64, 32, 3, seed=1)
    with pytest.raises(ValueError, match='32 of its 64 rows'):
        with StreamingPngWriter(tmp_path / 'short.png', 32, 64, 3, threads=2) as png:
            png.write(img[:32])
    with pytest.raises(RuntimeError, match='render failed'), \
            StreamingPngWriter(tmp_path / 'failed.png', 32, 64, 3, threads=2) as png:
        png.write(img[:16])
        raise RuntimeError('render failed')
    assert list(tmp_path.iterdir()) == []


def test_bad_rows_are_refused(tmp_path: Path) -> None:
    with StreamingPngWriter(tmp_path / 'm.png', 8, 4, 3) as png:
        with pytest.raises(ValueError, match='uint8'):
            png.write(np.zeros((4, 8, 3), np.float32))
        with pytest.raises(ValueError, match=r'\(n, 8, 3\)'):
            png.write(np.zeros((4, 9, 3), np.uint8))
        with pytest.raises(ValueError, match='5 rows written to a PNG of 4'):
            png.write(np.zeros((5, 8, 3), np.uint8))
        png.write(np.zeros((4, 8, 3), np.uint8))
    with pytest.raises(ValueError, match='1 to 4 channels'):
        StreamingPngWriter(tmp_path / 'x.png', 8, 4, 5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['m.png']


@pytest.mark.parametrize('limit', [20_000, 200_000])
def test_a_full_disk_is_an_output_error_naming_the_file_and_leaves_none(limit: int, tmp_path: Path) -> None:
    """A file size limit (as a full disk: EFBIG) met early or late in the stream (the 360 kB of
    noise do not compress) is an OutputError that names the file and says what to do; no file and
    no temporary file is left."""
    import subprocess
    import sys

    script = f'''
import resource, signal
import numpy as np
from srmosaic_ros.errors import OutputError
from srmosaic_ros.io.png_stream import StreamingPngWriter
img = (np.random.default_rng(0).random((400, 300, 3)) * 255).astype(np.uint8)
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
try:
    with StreamingPngWriter({str(tmp_path / 'm.png')!r}, 300, 400, 3, threads=2) as png:
        for r in range(0, 400, 50):
            png.write(img[r:r + 50])
except OutputError as exc:
    print('OutputError:', exc)
'''
    run = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith('OutputError: m.png could not be written (File too large)'), run.stdout
    assert 'free space' in run.stdout
    assert list(tmp_path.iterdir()) == []
