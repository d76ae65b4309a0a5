"""The real-video SR protocol: halve a video, super-resolve it back, score every tile against the original frames.

A real video has no ground truth but its own frames at full size. The protocol (DESIGN.md, "Real-video
SR scoring"; bench/sr_video.py and `srmosaic evaluate DIR --original VIDEO`):

1. :func:`halve_video`: every frame of the video (read as `process` reads it: interlaced frames keep
   their top field) halved by an area filter and re-encoded with H.264 at CRF ``HALVED_CRF`` (high
   quality), frame k of the halved video being frame k of the original;
2. `srmosaic process HALVED --out DIR --sr --sr-factor 2` (no metadata: the chain alone);
3. :func:`score_sr_run`: every SR tile of DIR/sr/tiles.json is compared with the original frame that
   holds the whole tile and whose centre lands nearest the tile's (the truth frame k: the frame the
   best-view mosaic shows there and SR anchors to), sampled at the tile's pixels through the run's
   registered homography (original pixel = 2 * halved pixel + 0.5, pixel centres at integers):

   - (a) ``mosaic``: SR against mosaic.png sampled bicubically (what the product shows without SR);
   - (b) ``frame``: SR against frame k's own halved image sampled bicubically (single-frame upsampling);
   - (c) ``loo`` (leave-one-out): the tile reconstructed again **without frame k** (from the frames the
     scheduler would choose among the others, with the run's settings and its fallback rule,
     core/sr/fallback.py) against the bicubic of the nearest other frame in time j (k +- 1 where it
     holds the tile; the leave-one-out solve is anchored to it, so both show the same instant).
     Neither side has seen frame k's noise or compression: the baseline that counts.

   Luma (Rec. 601) PSNR and SSIM on static pixels only: the original frames that hold the tile (up to
   ``MEDIAN_FRAMES``, spread over the run) are sampled onto the tile's grid and their per-pixel
   median taken; a pixel where the truth frame or the nearest other frame (Gaussian-smoothed by ``MOVING_SMOOTH_PX`` against
   registration's sub-pixel error at edges) departs from the smoothed median by more than
   ``MOVING_THRESHOLD`` grey levels saw something move, and is masked with ``MOVING_GROW_PX`` around
   it; the fraction masked is reported. Per tile also the sub-pixel shift of the SR tile against the
   truth (phase correlation, HR pixels): a registration or grid-convention error shows there before
   it shows as lost dB.

Methods beside SR (the peer, bench/peer_sr.py) are scored on the same tiles and both ways: from the
tile's frames against (b), and without the truth frame against (c).
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..core.homography import translation
from ..core.sr.fallback import super_resolve_or_fallback
from ..core.sr.quality import side_by_side
from ..core.sr.reconstruct import SRConfig, SRError, reconstruct_tile
from ..core.sr.scheduler import SRTileConfig, choose_frames, frame_centres, frame_holds_rect
from ..errors import InputError
from ..io.mosaic_files import read_frames_csv, write_png
from ..io.video import VideoReader, write_video
from .evaluate import tile_grid_H
from .evaluate_real import load_report

__all__ = ['HALVED_CRF', 'MEDIAN_FRAMES', 'MOVING_THRESHOLD', 'TileMethod', 'halve_video', 'luma255', 'masked_ssim',
           'moving_mask', 'score_sr_run', 'format_protocol', 'subpixel_shift']

#: H.264 CRF of the halved video: visually lossless, so the halving, not the re-encode, sets what SR gets.
HALVED_CRF = 10
#: Most original frames whose median says what is static on a tile.
MEDIAN_FRAMES = 15
#: Grey levels (0..255, luma) by which a smoothed truth pixel departs from the median where something moved.
MOVING_THRESHOLD = 20.0
#: Gaussian sigma (HR px) of the smoothing before that test, and the growth (HR px) of the moving mask.
MOVING_SMOOTH_PX = 1.5
MOVING_GROW_PX = 4
#: Gaussian sigma (HR px) both images are smoothed by before their sub-pixel shift is read.
SHIFT_SMOOTH_PX = 1.0
#: Tiles drawn in the compare image.
COMPARE_TILES = 4
#: A method beside SR: (LR frames (h, w, 3) uint8 RGB, tile_H_frames, tile_shape (H, W), factor, psf sigma LR px)
#: -> (H s, W s, 3) float in [0, 1].
TileMethod = Callable[[Sequence[np.ndarray], Sequence[np.ndarray], tuple[int, int], int, float], np.ndarray]
_HR_H_LR = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])
_LUMA_BGR = np.array([0.114, 0.587, 0.299])


def _halved(rgb: np.ndarray) -> np.ndarray:
    """(h, w, 3) -> (h', w', 3) area-halved, h' and w' even (yuv420p): the original cropped to multiples of 4
    from its top-left corner, so original pixel = 2 * halved pixel + 0.5 holds."""
    h, w = rgb.shape[0] // 4 * 4, rgb.shape[1] // 4 * 4
    return cv2.resize(np.ascontiguousarray(rgb[:h, :w]), (w // 2, h // 2), interpolation=cv2.INTER_AREA)


def halve_video(src: Path, dst: Path, *, frames: int | None = None, crf: int = HALVED_CRF) -> int:
    """Write ``src`` halved (area filter) to the H.264 video ``dst`` at ``crf``, its first ``frames``
    frames (None: all), at the source's frame rate; returns the number of frames written."""
    reader = VideoReader(src)
    fps = reader.fps if math.isfinite(reader.fps) and reader.fps > 0 else 25.0

    def halves() -> Iterator[np.ndarray]:
        for k, frame in enumerate(reader):
            if frames is not None and k >= frames:
                return
            yield _halved(frame.image)

    n = write_video(dst, halves(), fps=fps, crf=crf)
    if n == 0:
        msg = f'{src} holds no frame to halve; check the video.'
        raise InputError(msg)
    return n


def _read_frames(path: Path, wanted: set[int]) -> dict[int, np.ndarray]:
    """Frames ``wanted`` (indices in decoding order) of a video, RGB uint8, read as `process` reads them."""
    out: dict[int, np.ndarray] = {}
    if not wanted:
        return out
    for k, frame in enumerate(VideoReader(path)):
        if k in wanted:
            out[k] = frame.image
        if k >= max(wanted):
            break
    return out


def luma255(bgr_or_rgb: np.ndarray, *, bgr: bool = False) -> np.ndarray:
    """(H, W, 3) or (H, W) image in 0..255 -> (H, W) float64 luma (Rec. 601)."""
    a = np.asarray(bgr_or_rgb, dtype=np.float64)
    if a.ndim == 2:
        return a
    w = _LUMA_BGR if bgr else _LUMA_BGR[::-1]
    return a[:, :, :3] @ w


def _sample(img: np.ndarray, img_H_tile: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    out = cv2.warpPerspective(np.asarray(img, dtype=np.float32), img_H_tile, (shape[1], shape[0]),
                              flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    return np.clip(out, 0, 255).astype(np.float64)


def moving_mask(truth: np.ndarray, others: Sequence[np.ndarray]) -> np.ndarray:
    """(H, W) bool: pixels of the luma ``truth`` where something moved against the per-pixel median of
    ``others`` (luma on the same grid, the truth among them or not; module docstring)."""
    if len(others) < 3:
        return np.zeros(truth.shape, bool)
    med = np.median(np.stack(others), axis=0).astype(np.float32)
    a = cv2.GaussianBlur(truth.astype(np.float32), (0, 0), MOVING_SMOOTH_PX)
    b = cv2.GaussianBlur(med, (0, 0), MOVING_SMOOTH_PX)
    moved = (np.abs(a - b) > MOVING_THRESHOLD).astype(np.uint8)
    k = 2 * MOVING_GROW_PX + 1
    return cv2.dilate(moved, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0


def masked_ssim(a: np.ndarray, b: np.ndarray, keep: np.ndarray, *, border: int = 5) -> float:
    """SSIM (Wang et al. 2004; Gaussian window sigma 1.5, K1 0.01, K2 0.03, range 255) of two luma
    images, averaged over ``keep`` less ``border`` pixels at each side; NaN when nothing is kept."""
    x, y = a.astype(np.float64), b.astype(np.float64)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def f(z: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(z, (11, 11), 1.5, borderType=cv2.BORDER_REFLECT)

    mx, my = f(x), f(y)
    sxx, syy, sxy = f(x * x) - mx * mx, f(y * y) - my * my, f(x * y) - mx * my
    m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    inner = np.zeros(keep.shape, bool)
    inner[border:keep.shape[0] - border, border:keep.shape[1] - border] = True
    use = keep & inner
    return float(m[use].mean()) if use.any() else float('nan')


def subpixel_shift(image: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(dx, dy) HR pixels by which luma ``image`` is displaced against ``truth``: phase correlation (Hann
    window) of both smoothed by ``SHIFT_SMOOTH_PX`` (the whitened correlation would otherwise weigh the
    band near Nyquist, where an interpolated image, a bob-deinterlaced one above all, holds only
    replicas, as much as the rest), less what it reads for the truth against itself (OpenCV's
    phaseCorrelate reads half a pixel on sizes it pads)."""
    a, b = (cv2.GaussianBlur(x.astype(np.float32), (0, 0), SHIFT_SMOOTH_PX) for x in (image, truth))
    win = cv2.createHanningWindow(a.shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(b, a, win)
    (bx, by), _ = cv2.phaseCorrelate(b, b, win)
    return float(dx - bx), float(dy - by)


def _sse(x: np.ndarray, truth: np.ndarray, keep: np.ndarray) -> float:
    return float(((x - truth)[keep] ** 2).sum())


def _psnr(sse: float, n: int) -> float:
    return float(10 * np.log10(255.0**2 / max(sse / max(n, 1), 1e-12)))


def _config_of(report: dict[str, Any], tiles: list[dict[str, Any]]) -> tuple[SRConfig, SRTileConfig]:
    """The run's SR and tile settings (report.json sr.settings, sr.tile_settings; older runs: defaults
    with the run's PSF and tile size)."""
    sr = report.get('sr') or {}
    known = {f.name for f in fields(SRConfig)}
    given = {k: tuple(v) if isinstance(v, list) else v for k, v in (sr.get('settings') or {}).items() if k in known}
    if 'psf_sigma' not in given and sr.get('psf_sigma_px') is not None:
        given['psf_sigma'] = float(sr['psf_sigma_px'])
    config = SRConfig(**given)
    tile_known = {f.name for f in fields(SRTileConfig)}
    tile_given = {k: v for k, v in (sr.get('tile_settings') or {}).items() if k in tile_known}
    if 'tile_size' not in tile_given and tiles:
        tile_given['tile_size'] = int(tiles[0]['width'])
    tile_given['factor'] = int(tiles[0]['factor']) if tiles else 2
    return config, SRTileConfig(**tile_given)


def _nearest(covering: list[int], centres: np.ndarray, c: np.ndarray, count: int) -> list[int]:
    """Of ``covering`` (indices into ``centres``), the ``count`` whose centres lie nearest ``c``, nearest first."""
    return sorted(covering, key=lambda k: float(np.hypot(*(centres[k] - c))))[:count]


def score_sr_run(out: Path, original: Path, *, methods: dict[str, TileMethod] | None = None,
                 loo: bool = True, compare: bool = True, max_tiles: int | None = None,
                 images_out: dict[str, dict[str, np.ndarray]] | None = None,
                 input_path: Path | None = None) -> dict[str, Any]:
    """Score the SR tiles of the run ``out`` (made by `process --sr` from a video halved from
    ``original`` by :func:`halve_video`) against the original frames (module docstring).

    methods: name -> :data:`TileMethod` scored beside SR on the same tiles (protocol b and c).
    input_path: the halved video the run was made from, when it moved (default: report.json "input").
    loo: reconstruct each tile without its truth frame (protocol c; one more solve per tile).
    images_out: when given, filled with each tile's luma images (HR grid, 0..255) by tile file and
    name ('truth', 'sr', 'sr_only', 'mosaic_bicubic', 'frame_bicubic', 'other_bicubic', 'loo_sr', ...).
    compare: write DIR/sr/protocol_compare.png (the first COMPARE_TILES tiles: truth | mosaic
    bicubic | frame bicubic | SR | other frame bicubic | SR without the truth frame | moving mask).

    Returns a JSON-serialisable dict: ``tiles`` (scored), ``summary`` ({comparison: {psnr_sr,
    psnr_baseline, gain_db (pooled), mean_gain_db, min_gain_db, fraction_gaining, ssim_sr,
    ssim_baseline}} for 'mosaic', 'frame', 'loo' and, per method, 'frame:NAME' and 'loo:NAME';
    'originals_apart_psnr': the truth frame's original against the nearest other frame's, registered),
    ``masked_fraction`` (static-pixel mask), ``per_tile``; written also to DIR/sr/protocol.json.
    Raises InputError when the run is not one of a halved video (another input kind, another
    --select, a camera calibration) or its files are missing.
    """
    out, original = Path(out), Path(original)
    for name in ('frames.csv', 'report.json', 'mosaic.png', 'sr/tiles.json'):
        if not (out / name).is_file():
            msg = f'{out / name} not found; run `srmosaic process HALVED_VIDEO --out {out} --sr` first.'
            raise InputError(msg)
    if not original.is_file():
        msg = f'original video {original} not found; pass the full-size video the run\'s input was halved from.'
        raise InputError(msg)
    report = load_report(out / 'report.json')
    video = report.get('video') or {}
    if report.get('input_kind') != 'video' or str(video.get('select', 'all')) != 'all' or video.get('camera'):
        msg = (f'{out} is not a run of a halved video processed frame by frame (input_kind video, --select all, no '
               '--camera); make one with `srmosaic halve VIDEO HALVED.mp4` and `srmosaic process HALVED.mp4 --sr`.')
        raise InputError(msg)
    halved = Path(input_path) if input_path is not None else Path(report.get('input', ''))
    if not halved.is_file():
        msg = (f'the run\'s input {halved} (report.json "input", or --input) does not exist; the protocol reads its frames '
               'again: pass the halved video (--input).')
        raise InputError(msg)
    tiles = json.loads((out / 'sr' / 'tiles.json').read_text())
    if max_tiles is not None:
        tiles = tiles[:max_tiles]
    rows = read_frames_csv(out / 'frames.csv')
    ok = [i for i, r in enumerate(rows) if r['ok']]
    mosaic_H = {i: rows[i]['mosaic_H_frame'] for i in ok}
    probe = VideoReader(halved)
    size = (probe.width, probe.height)
    orig_probe = VideoReader(original)
    if (orig_probe.width // 4 * 2, orig_probe.height // 4 * 2) != size:
        msg = (f'{original} is {orig_probe.width}x{orig_probe.height}, the run\'s input {halved} is {size[0]}x{size[1]}: '
               'not its halved copy; pass the video the input was halved from.')
        raise InputError(msg)
    sr_config, tile_config = _config_of(report, tiles)
    centres_list = frame_centres([mosaic_H[i] for i in ok], [size] * len(ok))
    centres = {i: centres_list[n] for n, i in enumerate(ok)}

    # which frames each tile needs: its truth frame, the others of the leave-one-out, the median's
    plans = []
    for entry in tiles:
        rect = (entry['x0'], entry['y0'], entry['width'], entry['height'])
        covering = [i for i in ok if frame_holds_rect(np.linalg.inv(mosaic_H[i]), size, rect)]
        if not covering:
            continue
        c = np.array([entry['x0'] + (entry['width'] - 1) / 2, entry['y0'] + (entry['height'] - 1) / 2])
        order = sorted(covering, key=lambda i: float(np.hypot(*(centres[i] - c))))
        truth = order[0]
        chosen = sorted(choose_frames(order, tile_config.max_frames, tile_config.frame_choice))
        # the nearest other frame in time (k +- 1 where it holds the tile): it never saw frame k's noise or
        # compression; the leave-one-out solve anchors to it, among the frames the scheduler would take
        other = min((i for i in covering if i != truth), key=lambda i: (abs(i - truth), i), default=None)
        if other is None:
            without = []
        else:
            without = choose_frames([other] + [i for i in order[1:] if i != other], tile_config.max_frames,
                                    tile_config.frame_choice)
        spread = [covering[int(v)] for v in np.unique(np.round(np.linspace(0, len(covering) - 1,
                                                                            min(MEDIAN_FRAMES, len(covering)))))]
        plans.append((entry, truth, chosen, without, spread))
    need_lr = {i for _, _, chosen, without, _ in plans for i in (*chosen, *without)}
    need_hr = {i for _, truth, _, without, spread in plans for i in (truth, *without[:1], *spread)}
    lr = _read_frames(halved, need_lr)
    hr = _read_frames(original, need_hr)
    mosaic = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)[:, :, :3]
    methods = methods or {}
    per_tile, panels = [], []
    for entry, truth_k, chosen, without, spread in plans:
        s = int(entry['factor'])
        if s != 2:
            msg = f'the protocol scores factor-2 SR of a video halved once; {entry["file"]} is factor {s}.'
            raise InputError(msg)
        grid_H = tile_grid_H(entry)
        shape = (entry['height'] * s, entry['width'] * s)
        tile_shape = (entry['height'], entry['width'])

        def frame_H_grid(i: int) -> np.ndarray:
            return np.linalg.inv(mosaic_H[i]) @ grid_H  # noqa: B023 - used within this tile's iteration

        truth = luma255(_sample(hr[truth_k], _HR_H_LR @ frame_H_grid(truth_k), shape))
        others_hr = [luma255(_sample(hr[i], _HR_H_LR @ frame_H_grid(i), shape)) for i in spread]
        moved = moving_mask(truth, others_hr)
        other_hr = None
        if loo and without:  # and where the nearest other frame, the leave-one-out's baseline, saw something move
            other_hr = luma255(_sample(hr[without[0]], _HR_H_LR @ frame_H_grid(without[0]), shape))
            moved |= moving_mask(other_hr, others_hr)
        keep = ~moved
        n = int(keep.sum())
        sr_bgr = cv2.imread(str(out / 'sr' / entry['file']), cv2.IMREAD_COLOR).astype(np.float64)
        images: dict[str, np.ndarray] = {
            'sr': luma255(sr_bgr, bgr=True),
            'mosaic_bicubic': luma255(_sample(mosaic, grid_H, shape), bgr=True),
            'frame_bicubic': luma255(_sample(lr[truth_k], frame_H_grid(truth_k), shape)),
        }
        tile_H = {i: translation(-entry['x0'], -entry['y0']) @ mosaic_H[i] for i in need_lr if i in lr}
        images['sr_only'] = images['sr']
        if entry.get('fallback') == 'held_out_worse_than_frame':
            try:  # what SR alone would have shown on a tile that fell back
                res = reconstruct_tile([lr[i] for i in chosen], [tile_H[i] for i in chosen], tile_shape, s, config=sr_config)
                images['sr_only'] = luma255(255.0 * res.image.detach().cpu().numpy().transpose(1, 2, 0))
            except SRError:
                pass
        for name, method in methods.items():
            images[f'{name}'] = luma255(255.0 * np.asarray(method([lr[i] for i in chosen], [tile_H[i] for i in chosen],
                                                                    tile_shape, s, sr_config.psf_sigma)))
        record: dict[str, Any] = {'file': entry['file'], 'truth_frame': truth_k, 'frames': chosen,
                                  'source': entry.get('source', 'sr'), 'fallback': entry.get('fallback'),
                                  'masked_fraction': round(1.0 - n / truth.size, 4), 'pixels': n}
        if loo and without:
            other = without[0]
            images['other_bicubic'] = luma255(_sample(lr[other], frame_H_grid(other), shape))
            frames_wo = [lr[i] for i in without]
            mats_wo = [tile_H[i] for i in without]
            outcome = super_resolve_or_fallback(frames_wo, mats_wo, tile_shape, s, sr_config, holdouts=sr_config.fallback,
                                                reference=0)
            images['loo_sr'] = luma255(255.0 * outcome.image)
            if outcome.fallback == 'held_out_worse_than_frame':
                try:  # what SR alone would have shown
                    res = reconstruct_tile(frames_wo, mats_wo, tile_shape, s, config=sr_config, reference=0)
                    images['loo_sr_only'] = luma255(255.0 * res.image.detach().cpu().numpy().transpose(1, 2, 0))
                except SRError:
                    images['loo_sr_only'] = images['loo_sr']
            else:
                images['loo_sr_only'] = images['loo_sr']
            for name, method in methods.items():
                images[f'loo_{name}'] = luma255(255.0 * np.asarray(method(frames_wo, mats_wo, tile_shape, s,
                                                                           sr_config.psf_sigma)))
            record.update({'other_frame': other, 'frames_without_truth': without, 'loo_fallback': outcome.fallback or None})
        for key, img in images.items():
            record[f'sse_{key}'] = _sse(img, truth, keep)
            record[f'ssim_{key}'] = masked_ssim(img, truth, keep)
        if other_hr is not None:  # how far two full-size originals a frame apart are: what no method removes
            record['sse_other_original'] = _sse(other_hr, truth, keep)
        if images_out is not None:
            images_out[entry['file']] = {'truth': truth, 'moving': moved, **images,
                                         **({'other_original': other_hr} if other_hr is not None else {})}
        dx, dy = subpixel_shift(images['sr'], truth)
        record['sr_shift_px'] = [round(dx, 3), round(dy, 3)]
        dx, dy = subpixel_shift(images['frame_bicubic'], truth)
        record['frame_shift_px'] = [round(dx, 3), round(dy, 3)]  # the truth frame's own: the protocol's sampling
        per_tile.append(record)
        if compare and len(panels) < COMPARE_TILES:
            row = [truth, images['mosaic_bicubic'], images['frame_bicubic'], images['sr']]
            labels = ['original', 'mosaic bicubic', 'frame bicubic', 'SR']
            if 'loo_sr' in images:
                row += [images['other_bicubic'], images['loo_sr']]
                labels += ['other frame bicubic', 'SR without it']
            for name in methods:
                row.append(images[name])
                labels.append(name)
            row.append(np.where(moved, 255.0, truth * 0.5))
            labels.append('moving (white)')
            panels.append(side_by_side([np.clip(r / 255.0, 0, 1) for r in row], labels, zoom=2 if shape[0] <= 160 else 1))
    summary = _summary(per_tile, list(methods))
    use = [t for t in per_tile if 'sse_other_original' in t and t['pixels'] > 0]
    if use:  # the originals of the truth frame and of the nearest other frame, against each other
        summary['originals_apart_psnr'] = round(_psnr(sum(t['sse_other_original'] for t in use),
                                                      sum(t['pixels'] for t in use)), 3)
    masked = [t['masked_fraction'] for t in per_tile]
    result = {'original': str(original), 'halved': str(halved), 'tiles': len(per_tile),
              'psf_sigma_px': sr_config.psf_sigma,
              'masked_fraction': round(float(np.mean(masked)), 4) if masked else None,
              'summary': summary,
              'per_tile': [{k: (round(v, 4) if isinstance(v, float) and math.isfinite(v) else
                                (None if isinstance(v, float) else v)) for k, v in t.items()} for t in per_tile]}
    if panels:
        width = max(p.shape[1] for p in panels)
        sheet = np.full((sum(p.shape[0] + 8 for p in panels), width, 3), 255, np.uint8)
        y = 0
        for p in panels:
            sheet[y:y + p.shape[0], :p.shape[1]] = p
            y += p.shape[0] + 8
        write_png(out / 'sr' / 'protocol_compare.png', sheet / 255.0)
        result['compare'] = 'sr/protocol_compare.png'
    (out / 'sr' / 'protocol.json').write_text(json.dumps(result, indent=1))
    return result


#: (comparison, the estimate's key, the baseline's key) in the per-tile records.
def _comparisons(methods: list[str]) -> list[tuple[str, str, str]]:
    pairs = [('mosaic', 'sr', 'mosaic_bicubic'), ('frame', 'sr', 'frame_bicubic'), ('loo', 'loo_sr', 'other_bicubic'),
             ('mosaic_sr_only', 'sr_only', 'mosaic_bicubic'), ('frame_sr_only', 'sr_only', 'frame_bicubic'),
             ('loo_sr_only', 'loo_sr_only', 'other_bicubic')]
    for m in methods:
        pairs += [(f'frame:{m}', m, 'frame_bicubic'), (f'loo:{m}', f'loo_{m}', 'other_bicubic'),
                  (f'{m}:mosaic', m, 'mosaic_bicubic')]
    return pairs


def _summary(per_tile: list[dict[str, Any]], methods: list[str]) -> dict[str, Any]:
    summary: dict[str, Any] = {}
    for name, est, base in _comparisons(methods):
        use = [t for t in per_tile if f'sse_{est}' in t and f'sse_{base}' in t and t['pixels'] > 0]
        if not use:
            continue
        n = sum(t['pixels'] for t in use)
        p_est = _psnr(sum(t[f'sse_{est}'] for t in use), n)
        p_base = _psnr(sum(t[f'sse_{base}'] for t in use), n)
        gains = np.array([_psnr(t[f'sse_{est}'], t['pixels']) - _psnr(t[f'sse_{base}'], t['pixels']) for t in use])
        ssim_e = [t[f'ssim_{est}'] for t in use if math.isfinite(t[f'ssim_{est}'])]
        ssim_b = [t[f'ssim_{base}'] for t in use if math.isfinite(t[f'ssim_{base}'])]
        summary[name] = {'tiles': len(use), 'psnr': round(p_est, 3), 'psnr_baseline': round(p_base, 3),
                         'gain_db': round(p_est - p_base, 3), 'mean_gain_db': round(float(gains.mean()), 3),
                         'min_gain_db': round(float(gains.min()), 3), 'fraction_gaining': round(float(np.mean(gains > 0)), 3),
                         'ssim': round(float(np.mean(ssim_e)), 4) if ssim_e else None,
                         'ssim_baseline': round(float(np.mean(ssim_b)), 4) if ssim_b else None}
    return summary


_LABELS = {'mosaic': '(a) SR against the bicubic of mosaic.png',
           'frame': "(b) SR against the reference frame's own bicubic",
           'loo': '(c) leave-one-out: SR without the truth frame against the nearest other frame\'s bicubic',
           'mosaic_sr_only': '    (a) without the fallback to the best frame',
           'frame_sr_only': '    (b) without the fallback to the best frame',
           'loo_sr_only': '    (c) without the fallback to the best frame'}


def format_protocol(result: dict[str, Any]) -> list[str]:
    """The lines `srmosaic evaluate DIR --original VIDEO` prints for :func:`score_sr_run`'s result."""
    lines = [f'SR protocol: {result["tiles"]} tiles against the original frames of {result["original"]} (luma, static '
             f'pixels; {100 * (result["masked_fraction"] or 0):.1f} % masked as moving)']
    for key, s in result['summary'].items():
        if not isinstance(s, dict):
            continue
        label = _LABELS.get(key, f'{key.replace(":", " ")} against its baseline')
        lines.append(f'{label}: PSNR {s["psnr"]:.2f} vs {s["psnr_baseline"]:.2f} dB, gain {s["gain_db"]:+.2f} dB '
                     f'(per tile mean {s["mean_gain_db"]:+.2f}, worst {s["min_gain_db"]:+.2f}, '
                     f'{100 * s["fraction_gaining"]:.0f} % gaining); SSIM {s["ssim"]:.3f} vs {s["ssim_baseline"]:.3f}')
    if result['summary'].get('originals_apart_psnr') is not None:
        lines.append(f'the truth frame\'s original against the nearest other frame\'s (registered, full size): PSNR '
                     f'{result["summary"]["originals_apart_psnr"]:.2f} dB (what two recordings of the same ground differ by)')
    if result.get('compare'):
        lines.append(f'original | mosaic bicubic | frame bicubic | SR | ...: {result["compare"]}')
    return lines
