"""Interlaced video: frames the stream flags as interlaced keep their top field (io/deinterlace.py), so
that a frame whose two fields saw the ground at two instants becomes one instant."""
from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from srmosaic_ros.errors import InputError
from srmosaic_ros.io.deinterlace import top_field
from srmosaic_ros.io.video import VideoReader

W, H, N = 320, 240, 6


def _scene(shift_px: float) -> np.ndarray:
    """A textured ground (uint8 RGB, H x W) seen shifted right by ``shift_px``."""
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.integers(0, 255, (H, W + 40, 3), dtype=np.uint8), (0, 0), 6.0)
    base = cv2.normalize(base, None, 0, 255, cv2.NORM_MINMAX)
    M = np.float32([[1, 0, shift_px - 20.0], [0, 1, 0]])  # dst(x) = base(x + 20 - shift)
    return cv2.warpAffine(base, M, (W, H), flags=cv2.INTER_LINEAR)


def _write(path: Path, *, interlaced: bool) -> list[np.ndarray]:
    """N frames panning 12 px per frame; interlaced: the odd rows (bottom field) exposed half a frame
    later, 6 px further on (the combing a moving interlaced camera records). Returns the true
    top-field instants."""
    truths = []
    with av.open(str(path), 'w') as c:
        s = c.add_stream('libx264', rate=25)
        s.width, s.height, s.pix_fmt = W, H, 'yuv420p'
        s.codec_context.options = {'crf': '10', **({'x264-params': 'interlaced=1:tff=1'} if interlaced else {})}
        for k in range(N):
            top = _scene(12.0 * k)
            frame = top.copy()
            if interlaced:
                frame[1::2] = _scene(12.0 * k + 6.0)[1::2]
            truths.append(top)
            for p in s.encode(av.VideoFrame.from_ndarray(frame, format='rgb24')):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return truths


def test_top_field_keeps_even_rows_and_fills_odd_ones_between() -> None:
    img = np.arange(5 * 3, dtype=np.uint8).reshape(5, 3) * 10
    out = top_field(img)
    assert np.array_equal(out[0::2], img[0::2])
    assert np.array_equal(out[1], (img[0].astype(int) + img[2] + 1) // 2)
    even = np.zeros((4, 2, 3), np.uint8)
    even[2] = 200
    assert np.array_equal(top_field(even)[3], even[2])  # the last odd row copies the one above
    assert top_field(np.zeros((1, 4), np.uint8)).shape == (1, 4)


def test_interlaced_video_keeps_one_instant_per_frame(tmp_path: Path) -> None:
    truths = _write(tmp_path / 'combed.mp4', interlaced=True)
    auto = VideoReader(tmp_path / 'combed.mp4')
    frames = [f.image for f in auto]
    assert auto.deinterlaced == N
    raw = VideoReader(tmp_path / 'combed.mp4', deinterlace='off')
    combed = [f.image for f in raw]
    assert raw.deinterlaced == 0

    def err(img: np.ndarray, k: int) -> float:  # on luma: 4:2:0 chroma blurs colour either way
        grey = [cv2.cvtColor(i, cv2.COLOR_RGB2GRAY)[4:-4, 8:-8].astype(float) for i in (img, truths[k])]
        return float(np.abs(grey[0] - grey[1]).mean())
    for k in range(N):
        # the comb (every odd row 2 px off) is gone: the frame is the top field's instant
        assert err(frames[k], k) < 0.5 * err(combed[k], k), (k, err(frames[k], k), err(combed[k], k))


def test_progressive_video_is_left_alone(tmp_path: Path) -> None:
    _write(tmp_path / 'progressive.mp4', interlaced=False)
    auto = VideoReader(tmp_path / 'progressive.mp4')
    off = VideoReader(tmp_path / 'progressive.mp4', deinterlace='off')
    assert all(np.array_equal(a.image, b.image) for a, b in zip(auto, off, strict=True))
    assert auto.deinterlaced == 0
    forced = VideoReader(tmp_path / 'progressive.mp4', deinterlace='on')
    assert len(list(forced)) == N and forced.deinterlaced == N
    with pytest.raises(InputError, match="deinterlace 'yes'"):
        VideoReader(tmp_path / 'progressive.mp4', deinterlace='yes')
