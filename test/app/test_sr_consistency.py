"""The consistency gate of SR (core/sr/consistency.py): frames that do not see the same picture are left out."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.sr import SRFramesDisagree, reconstruct_tile
from srmosaic_ros.core.sr.consistency import consistent_frames, noise_sigma
from srmosaic_ros.core.sr.synthetic import make_synthetic_tile
from srmosaic_ros.app.evaluate_stills import halve_stills, pooled_gain_db, sr_errors_against_originals, tile_comparisons
from srmosaic_ros.app.process import process_input

from imagery import world_rgb
from repo_paths import REPO

TILE = (32, 32)
SEQUENCES = REPO / 'data' / 'sequences'


@pytest.fixture(scope='module')
def world() -> np.ndarray:
    return world_rgb().astype(np.float32) / 255.0


def _stack(frames: list[np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    x = torch.as_tensor(np.stack([f.astype(np.float32) for f in frames]))[:, None]
    return x, torch.ones_like(x)


def test_noise_estimate_on_a_smooth_ramp() -> None:
    rng = np.random.default_rng(0)
    ramp = np.add.outer(np.linspace(0.2, 0.6, 96), np.linspace(0.0, 0.2, 128))
    imgs = [ramp + rng.normal(0, 0.02, ramp.shape) for _ in range(3)]
    assert noise_sigma(_stack(imgs)[0]) == pytest.approx(0.02, rel=0.1)


def test_aligned_frames_are_all_kept(world) -> None:
    st = make_synthetic_tile(world, (120, 440), TILE, 2, 6, noise_sigma=2.0, seed=3)
    res = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, iterations=5, device='cpu')
    assert res.frame_consistent.all()
    assert res.consistency['ncc_median'] > 0.95 and res.consistency['kept'] == 6


def test_flat_noisy_tile_is_not_mistaken_for_disagreement(world) -> None:
    """Low contrast against strong noise correlates poorly, and the noise bound says so."""
    flat = cv2.GaussianBlur(world, (0, 0), 6) * 0.15 + 0.4
    st = make_synthetic_tile(flat, (120, 440), TILE, 2, 6, noise_sigma=5.0, seed=3)
    res = reconstruct_tile(st.frames, st.tile_H_frames, TILE, 2, iterations=5, device='cpu')
    assert res.consistency['ncc_median'] < 0.9  # the raw correlation is low ...
    assert res.frame_consistent.all()           # ... as low as the noise makes it


def test_frames_of_different_ground_refuse_the_tile(world) -> None:
    """Every frame shows another place (3-D scene, lost registration): SR would average pictures."""
    frames, mats = [], []
    for k, origin in enumerate([(120, 440), (400, 100), (700, 300)]):
        st = make_synthetic_tile(world, origin, TILE, 2, 1, noise_sigma=1.0, seed=k)
        frames += st.frames
        mats += st.tile_H_frames
    with pytest.raises(SRFramesDisagree, match='disagree with each other.*left to the mosaic'):
        reconstruct_tile(frames, mats, TILE, 2, iterations=5, device='cpu')
    res = reconstruct_tile(frames, mats, TILE, 2, iterations=5, device='cpu', consistency=0)  # the test off
    assert res.frame_consistent.all()


def test_reference_seeds_the_set_when_it_has_a_partner(world) -> None:
    """Two pairs that agree within but not across: the set holds the reference's pair."""
    a = make_synthetic_tile(world, (120, 440), TILE, 2, 2, noise_sigma=1.0, seed=1)
    b = make_synthetic_tile(world, (400, 100), TILE, 2, 2, noise_sigma=1.0, seed=2)
    warped = []
    for st in (a, b):
        for f, h in zip(st.frames, st.tile_H_frames, strict=True):
            g = cv2.cvtColor(f, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255
            warped.append(cv2.warpPerspective(g, h, TILE[::-1], flags=cv2.INTER_LINEAR))
    x, cov = _stack(warped)
    for ref, expect in ((0, [True, True, False, False]), (3, [False, False, True, True])):
        keep, fig = consistent_frames(x, cov, reference=ref)
        assert keep.tolist() == expect and fig['reference_kept'] == 1.0
    # a reference that agrees with nobody is the odd one out: the others' set is used
    keep, fig = consistent_frames(x[[0, 2, 3]], cov[[0, 2, 3]], reference=0)
    assert keep.tolist() == [False, True, True] and fig['reference_kept'] == 0.0


def test_brighton_stills_tree_tiles_are_left_to_the_mosaic(tmp_path) -> None:
    """Stills 7 s apart at 40 m over tree canopy: the frames disagree on most tiles, and those are
    not super-resolved (before the gate they came out blurrier than the mosaic); where two frames
    agree, the tile is."""
    out = tmp_path / 'out'
    process_input(SEQUENCES / 'brighton_beach', out, pipeline_config(), sr_factor=2, progress=False)
    report = json.loads((out / 'report.json').read_text())['sr']
    # a refused tile shows its best still upsampled (core/sr/fallback.py), named in tiles.json
    refused = [t for t in report['per_tile'] if t.get('fallback') == 'frames_disagree']
    made = [t for t in report['per_tile'] if not t.get('fallback')]
    assert report['tiles_refused'] == len(refused) >= report['tiles_planned'] // 3
    assert all('disagree' in t['error'] and t['frames_disagree'] for t in refused)
    assert report['tiles_frames_disagree'] == len(refused)
    assert report['tiles_fallback'] == sum(1 for t in report['per_tile'] if t.get('fallback')) >= len(refused)
    assert made and all(t['frames_consistent'] >= 2 for t in made)
    tiles = json.loads((out / 'sr' / 'tiles.json').read_text())
    assert sorted(t['file'] for t in tiles if t['source'] == 'sr') == sorted(t['file'] for t in made)
    assert {t['file']: t['fallback'] for t in tiles if t['source'] == 'frame'} == {
        t['file']: t['fallback'] for t in report['per_tile'] if t.get('fallback')}


def _super_resolved(out, errors: dict) -> dict:
    """The tiles of ``errors`` that show SR (not their best frame upsampled: tiles.json "source")."""
    sr = {t['file'] for t in json.loads((out / 'sr' / 'tiles.json').read_text()) if t['source'] == 'sr'}
    return {k: v for k, v in errors.items() if k in sr}


def test_real_stills_super_resolved_against_their_originals(tmp_path) -> None:
    """No simulation: the brighton stills halved and super-resolved back (bench/sr_real.py), each tile
    scored against the original of the nearest still that holds all of it. Tree canopy seen from
    stills 7 s apart at 40 m differs between them: anchored to the still the mosaic shows there
    (sr.anchor), the tiles come out closer to its original; chained, the gate leaves the tiles
    whose stills disagree to the mosaic."""
    hr = halve_stills(SEQUENCES / 'brighton_beach', tmp_path / 'lr')
    runs = {}
    for label, overrides in (('global', {}), ('global unanchored', {'sr.anchor': False}),
                             ('chain', {'survey.mode': 'chain', 'mosaic.blend': 'feather'})):
        out = tmp_path / label.replace(' ', '_')
        report = process_input(tmp_path / 'lr', out, pipeline_config({'sr_tiles.tile_size': 64, **overrides}),
                               sr_factor=2, progress=False)
        runs[label] = (report['sr'], _super_resolved(out, sr_errors_against_originals(out, hr)))
    report, errors = runs['global']
    _, unanchored = runs['global unanchored']
    # anchored, a tile whose reference (the still the mosaic shows) disagrees with the others is
    # left to the mosaic too: the anchored run's tiles are the unanchored run's less those (none since
    # each frame's exposure is matched to the reference's, sr.photometric: 8 of 8; 7 before)
    # (tiles that fall back to their best still, core/sr/fallback.py, are left out of both: the runs'
    # fallbacks differ, so the gains are compared over the tiles both super-resolved)
    common = sorted(set(errors) & set(unanchored))
    assert len(errors) >= 7 and len(common) >= 5
    assert sum(1 for t in report['per_tile'] if t.get('anchored')) == len(errors)
    # pooled over the same tiles against bicubic of mosaic.png: measured +5.13 dB anchored, +3.11 not
    gain, gain_unanchored = pooled_gain_db(errors, common)[2], pooled_gain_db(unanchored, common)[2]
    assert gain > 2.0 and gain > gain_unanchored + 0.5, (gain, gain_unanchored)
    # scored against other images than the originals (a simulated flight's true ground): the tiles'
    # baselines are still made from the originals halved, only what all are compared with changes
    other = {k: cv2.GaussianBlur(v, (0, 0), 2.0) for k, v in hr.items()}
    for plain, against_other in zip(tile_comparisons(tmp_path / 'global', hr),
                                    tile_comparisons(tmp_path / 'global', hr, other), strict=True):
        assert plain.reference == against_other.reference
        assert np.array_equal(plain.frame_bicubic, against_other.frame_bicubic)
        assert np.array_equal(plain.sr, against_other.sr)
        assert np.abs(plain.truth - against_other.truth).mean() > 1.0
    chain_report, chain_errors = runs['chain']
    refused = [t for t in chain_report['per_tile'] if 'error' in t and t.get('fallback') != 'held_out_worse_than_frame']
    assert refused and len(chain_errors) >= 8 and all(t['frames_disagree'] for t in refused)
