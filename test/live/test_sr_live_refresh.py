"""Live SR planning over a growing store (ROS-free side of the SR node): tiles are refreshed when
many more frames cover them, the refreshed tile is closer to the ground truth, and tiles published
long ago never crowd new ones out of the plan."""
from __future__ import annotations

import numpy as np

from srmosaic_ros.core.sr import SRConfig
from srmosaic_ros.core.sr.scheduler import SRTileConfig
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile
from srmosaic_ros.live.sr import LiveFrameStore, plan_live_tiles, reconstruct_live_tile

from imagery import translation, world_rgb

T = 32   # tile side (LR plane pixels); the synthetic tile is the plane's tile (0, 0)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((a.astype(np.float64) - b) ** 2)))


def test_a_tile_is_refreshed_from_more_frames_and_gets_closer_to_the_truth():
    world = world_rgb().astype(np.float32) / 255.0
    st = make_synthetic_tile(world, (120, 440), (T, T), 2, 8, noise_sigma=2.0, seed=5)
    size = (st.frames[0].shape[1], st.frames[0].shape[0])
    cfg = SRTileConfig(factor=2, tile_size=T, min_frames=3, max_frames=8)
    store = LiveFrameStore(pending=20, kept=20)
    published: dict[tuple[int, int, int], int] = {}
    sizes: dict[int, tuple[int, int]] = {}
    results = []
    for k, (frame, tile_H_frame) in enumerate(zip(st.frames, st.tile_H_frames, strict=True)):
        store.add_image(k, frame)
        store.add_registration(k, 0, tile_H_frame)   # the plane of the tile: tile (0, 0) is the truth's
        sizes[k] = size
        plans = plan_live_tiles(store.registered(), sizes, cfg, published, refresh_growth=2.0)
        plans = [(p, used) for p, used in plans if (p.x0, p.y0) == (0, 0)]
        if not plans:
            continue
        plan, used = plans[0]
        image, placement, _ = reconstruct_live_tile(plan, [f.payload for f in used], [f.seg_H_frame for f in used],
                                                    2, SRConfig(iterations=10, device='cpu'), 0)
        assert (placement.x0, placement.y0, placement.width) == (0, 0, T)
        published[0, 0, 0] = len(used)
        results.append((k + 1, len(used), psnr(image.astype(np.float32) / 255.0, st.truth)))
    # published at 3 frames, refreshed once 6 cover it (growth 2), and not again (8 < 2 x 6)
    assert [r[:2] for r in results] == [(3, 3), (6, 6)], results
    assert results[1][2] > results[0][2] + 0.3, results
    # with refreshes off (a set, or growth 0) the tile is never planned again
    assert not [p for p, _ in plan_live_tiles(store.registered(), sizes, cfg, set(published)) if (p.x0, p.y0) == (0, 0)]
    assert not [p for p, _ in plan_live_tiles(store.registered(), sizes, cfg, published) if (p.x0, p.y0) == (0, 0)]


def test_published_tiles_do_not_crowd_new_ones_out_and_new_ones_come_first():
    # a long strip of frames over a blank plane: many tiles, more than max_tiles
    store = LiveFrameStore(pending=100, kept=100)
    sizes = {}
    for k in range(60):
        store.add_image(k, f'frame {k}')
        store.add_registration(k, 3, translation(8.0 * k, 0.0))
        sizes[k] = (128, 64)
    cfg = SRTileConfig(tile_size=32, min_frames=3, max_frames=4, max_tiles=5)
    first = plan_live_tiles(store.registered(), sizes, cfg)
    assert len(first) == 5
    done = {(3, p.x0, p.y0): len(used) for p, used in first}
    second = plan_live_tiles(store.registered(), sizes, cfg, done, refresh_growth=2.0)
    assert len(second) == 5 and not {(3, p.x0, p.y0) for p, _ in second} & set(done)
    # once the new ones are published too, a published tile comes back only as a refresh
    few = {key: 1 for key in done}               # published from a single frame each: 4 >= 2 x 1
    third = plan_live_tiles(store.registered(), sizes, cfg, few, refresh_growth=2.0)
    keys = [(3, p.x0, p.y0) for p, _ in third]
    fresh = [k for k in keys if k not in few]
    assert keys[:len(fresh)] == fresh and len(fresh) == 5  # new tiles first; refreshes fill what is left
