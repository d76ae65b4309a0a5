"""Each frame aligned to the reference on the tile (core/sr/local_align.py)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from srmosaic_ros.core.sr import SRFramesDisagree, reconstruct_tile
from srmosaic_ros.core.sr.local_align import align_to_reference
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile, perturb_homography

from sr_tiles import hwc, psnr, world01

TILE = (32, 32)


@pytest.fixture(scope='module')
def world() -> np.ndarray:
    return world01()


def _shifted(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    import cv2
    m = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    return cv2.warpAffine(img, m, img.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def test_a_shifted_frame_is_moved_back_onto_the_reference(world) -> None:
    ref = np.ascontiguousarray(world[100:172, 400:472].mean(axis=2))
    moved = _shifted(ref, 0.6, -0.4)           # the frame shows the reference's content 0.6 px right, 0.4 px up
    warped = torch.from_numpy(np.stack([ref, moved]))[:, None]
    covered = torch.ones_like(warped)
    for mode in ('translation', 'affine'):
        corr = align_to_reference(warped, covered, 0, mode=mode)
        np.testing.assert_allclose(corr[0], np.eye(3))
        # the correction maps the frame's tile point onto the reference's: (x + 0.6, y - 0.4) -> (x, y)
        p = corr[1] @ np.array([30.6, 19.6, 1.0])
        np.testing.assert_allclose(p[:2] / p[2], [30.0, 20.0], atol=0.1)


def test_a_mismatch_or_a_large_correction_is_not_applied(world) -> None:
    ref = np.ascontiguousarray(world[100:172, 400:472].mean(axis=2))
    other = np.ascontiguousarray(world[300:372, 40:112].mean(axis=2))   # another place
    far = _shifted(ref, 4.0, 0.0)                                          # beyond max_shift
    warped = torch.from_numpy(np.stack([ref, other, far]))[:, None]
    corr = align_to_reference(warped, torch.ones_like(warped), 0, mode='affine', max_shift=1.5)
    np.testing.assert_allclose(corr, np.tile(np.eye(3), (3, 1, 1)))
    with pytest.raises(ValueError, match='local alignment mode'):
        align_to_reference(warped, torch.ones_like(warped), 0, mode='projective')


def test_local_alignment_recovers_what_misregistration_costs(world) -> None:
    st = make_synthetic_tile(world, (120, 440), TILE, 2, 6, noise_sigma=1.0, seed=3)
    rng = np.random.default_rng(1)
    kw = {'device': 'cpu', 'anchor': False, 'consistency': 0}
    exact_res = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, local_align='off', **kw)
    exact = psnr(hwc(exact_res.image), st.truth)
    # every frame but the reference misregistered: the tile is drawn where the reference is
    bad = [h if i == exact_res.reference else perturb_homography(h, f.shape[:2], 0.7, rng)
           for i, (h, f) in enumerate(zip(st.tile_H_frames, st.frames, strict=True))]
    off = psnr(hwc(reconstruct_tile(st.frames, bad, TILE, 2, local_align='off', **kw).image), st.truth)
    on = psnr(hwc(reconstruct_tile(st.frames, bad, TILE, 2, local_align='affine', **kw).image), st.truth)
    assert on > off + 1.0 and on > exact - 0.3, (exact, off, on)


def test_an_anchored_tile_takes_the_reference_frames_colour_where_it_departs(world) -> None:
    st = make_synthetic_tile(world, (120, 440), TILE, 2, 6, noise_sigma=1.0, seed=3)
    first = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, device='cpu')
    frames = [f.copy() for f in st.frames]
    ref = frames[first.reference].astype(np.float64)
    # the reference frame alone shows the whole tile bluer and less red (white balance): same luma
    ref[..., 0] -= 12
    ref[..., 2] += 12 * 0.299 / 0.114
    frames[first.reference] = np.clip(ref + 0.5, 0, 255).astype(np.uint8)
    anchored = hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, device='cpu').image)
    free = hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, device='cpu', anchor=False, photometric=False).image)
    shift_anchored = (anchored - hwc(first.image)).reshape(-1, 3).mean(axis=0) * 255
    shift_free = (free - hwc(first.image)).reshape(-1, 3).mean(axis=0) * 255
    assert shift_anchored[0] < -8 and shift_anchored[2] > 20, shift_anchored     # the reference's colour
    assert abs(shift_free[0]) < 4 and abs(shift_free[2]) < 8, shift_free        # the average's


def test_frames_exposed_otherwise_are_matched_to_the_reference(world) -> None:
    from srmosaic_ros.core.sr.local_align import photometric_to_reference

    st = make_synthetic_tile(world, (120, 440), TILE, 2, 6, noise_sigma=1.0, seed=3)
    ref = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, device='cpu').reference
    frames = [f.copy() for f in st.frames]
    for i in range(len(frames)):   # the other frames brighter and warmer (auto exposure, white balance)
        if i != ref:
            frames[i] = np.clip(frames[i].astype(np.float64) * [1.25, 1.15, 1.0] + 8, 0, 255).astype(np.uint8)
    on = psnr(hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, device='cpu').image), st.truth)
    # unmatched, the reference is the odd one out: the tile is refused, or fused at the others' exposure
    with pytest.raises(SRFramesDisagree):
        reconstruct_tile(frames, st.tile_H_frames, TILE, 2, device='cpu', photometric=False)
    off = psnr(hwc(reconstruct_tile(frames, st.tile_H_frames, TILE, 2, device='cpu', photometric=False,
                                    anchor=False).image), st.truth)
    exact = psnr(hwc(reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, device='cpu').image), st.truth)
    assert on > off + 3.0 and on > exact - 0.5, (on, off, exact)
    # the fit itself: a known gain and offset are recovered, the reference keeps its own
    base = torch.from_numpy(world[100:172, 400:472].transpose(2, 0, 1).copy())
    warped = torch.stack([base, base * 0.8 + 0.05])
    a, b = photometric_to_reference(warped, torch.ones(2, 1, 72, 72), 0)
    torch.testing.assert_close(a[1, :, 0, 0], torch.full((3,), 1.25), atol=1e-3, rtol=0)
    torch.testing.assert_close(b[1, :, 0, 0], torch.full((3,), -0.0625), atol=1e-3, rtol=0)
    assert float(a[0].min()) == 1.0 and float(b[0].abs().max()) == 0.0
