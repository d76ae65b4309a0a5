"""Which frames a tile takes (core/sr/scheduler.py ``frame_choice``): frames spread in time average away
more of the compression error that consecutive H.264 frames share."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from srmosaic_ros.core.homography import translation
from srmosaic_ros.core.sr import reconstruct_tile
from srmosaic_ros.core.sr.scheduler import SRTileConfig, choose_frames, plan_tiles
from srmosaic_ros.io.video import VideoReader, write_video

from sr_tiles import hwc, psnr, world01

N_FRAMES = 40
HR_SIZE = (192, 144)               # (width, height) of the "original" frames
STEP_HR = (0.61, 0.37)             # camera motion per frame, HR px: every sub-pixel phase is visited
ORIGIN = (300, 200)                # world px of the first frame's corner
TILE = (32, 32)                    # LR tile, inside every frame
TILE_AT = (32, 20)                 # its corner in the reference frame's LR pixels
USE = 6


def test_choose_frames_nearest_and_spread() -> None:
    order = [20, 21, 19, 22, 18, 23, 17, 24, 16, 0, 39, 5, 30]     # nearest the tile first
    assert choose_frames(order, 4, 'nearest') == [20, 21, 19, 22]
    spread = choose_frames(order, 4, 'spread')
    assert spread[0] == 20 and len(set(spread)) == 4
    assert min(spread) == 0 and max(spread) == 39                    # the whole time span
    assert choose_frames(order, 20, 'spread') == order               # fewer frames than asked: all of them
    with pytest.raises(ValueError, match='frame choice'):
        choose_frames(order, 4, 'random')


def test_plan_tiles_spreads_the_frames_in_time() -> None:
    h = {k: translation(0.2 * k, 0.0) for k in range(30)}
    sizes = dict.fromkeys(h, (100, 80))
    coverage = np.ones((80, 110), bool)
    near = plan_tiles(h, sizes, coverage, SRTileConfig(tile_size=32, max_frames=5))
    spread = plan_tiles(h, sizes, coverage, SRTileConfig(tile_size=32, max_frames=5, frame_choice='spread'))
    assert [p.frames_covering for p in near] == [p.frames_covering for p in spread]
    for a, b in zip(near, spread, strict=True):
        assert len(b.frames) == 5
        assert max(b.frames) - min(b.frames) > max(a.frames) - min(a.frames)
        assert set(a.frames) & set(b.frames)                         # the reference is in both


@pytest.fixture(scope='module')
def flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """A slow pan over the synthetic ground: HR frames (blurred, noisy), the same through H.264 CRF 28,
    both halved (area); the truth of the reference frame's tile (the ground, no blur)."""
    world = world01()
    blurred = cv2.GaussianBlur(world, (0, 0), 0.7)
    w, h = HR_SIZE
    rng = np.random.default_rng(0)

    def grab(img: np.ndarray, k: int) -> np.ndarray:
        m = np.float32([[1, 0, ORIGIN[0] + STEP_HR[0] * k], [0, 1, ORIGIN[1] + STEP_HR[1] * k]])
        return cv2.warpAffine(img, m, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)

    raw = [np.clip(grab(blurred, k) * 255.0 + rng.normal(0, 2.0, (h, w, 3)) + 0.5, 0, 255).astype(np.uint8)
           for k in range(N_FRAMES)]
    path = Path(tmp_path_factory.mktemp('frame_choice')) / 'pan.mp4'
    write_video(path, iter(raw), fps=25.0, crf=28)
    decoded = [f.image for f in VideoReader(path)]
    ref = N_FRAMES // 2
    x, y = TILE_AT
    # HR tile pixel u is the reference's HR pixel u + 2 x (the LR grid's pixel u / 2 - 1/4 + x)
    truth = grab(world, ref)[2 * y:2 * (y + TILE[0]), 2 * x:2 * (x + TILE[1])]
    return {'raw': [cv2.resize(f, (w // 2, h // 2), interpolation=cv2.INTER_AREA) for f in raw],
            'h264': [cv2.resize(f, (w // 2, h // 2), interpolation=cv2.INTER_AREA) for f in decoded],
            'truth': truth, 'ref': ref}


def _sr_psnr(flight: dict[str, object], data: str, choice: str) -> float:
    ref = flight['ref']
    order = sorted(range(N_FRAMES), key=lambda k: (abs(k - ref), k))   # the frames nearest the tile first
    use = choose_frames(order, USE, choice)

    def tile_H_frame(k: int) -> np.ndarray:  # LR frame px -> LR tile px: the true motion, halved
        return translation(-TILE_AT[0] + STEP_HR[0] * (k - ref) / 2, -TILE_AT[1] + STEP_HR[1] * (k - ref) / 2)

    res = reconstruct_tile([flight[data][k] for k in use], [tile_H_frame(k) for k in use], TILE, 2, reference=0,
                           device='cpu')
    return psnr(hwc(res.image), flight['truth'])


def test_spread_frames_beat_consecutive_ones_through_h264_only(flight: dict[str, object]) -> None:
    gain_h264 = _sr_psnr(flight, 'h264', 'spread') - _sr_psnr(flight, 'h264', 'nearest')
    gain_raw = _sr_psnr(flight, 'raw', 'spread') - _sr_psnr(flight, 'raw', 'nearest')
    # consecutive frames share their compression error, frames far apart do not; raw frames' noise is
    # independent in every frame, so there the choice matters little
    assert gain_h264 > 0.25
    assert abs(gain_raw) < 0.15
    assert gain_h264 > gain_raw + 0.2
