"""SR on real stills, evaluated against their own originals (no simulation anywhere).

A folder of stills (`data/sequences` layout: images/ and telemetry_from_exif.csv) is halved (area
average, JPEG quality 98) into an LR folder for `srmosaic process --sr`; each SR tile is then
compared with the HR original of its reference frame (of the frames that hold the whole tile, the
one whose centre is nearest the tile's: the frame SR anchors to), sampled at the tile's pixels through that frame's registered
homography: HR pixel = 2 * LR pixel + 0.5 (pixel centres at integers). Two baselines, both sampled
bicubically at the same points: mosaic.png (what the product shows without SR) and the reference
frame's own LR image (the HR original halved by area average: single-frame bicubic upsampling, the
usual baseline of SR). They differ where the mosaic shows another frame than the reference (best
view: exposure, parallax, waves and traffic differ between frames), which the mosaic baseline
charges to bicubic. Used by bench/sr_real.py, bench/sr_video.py and test/test_sr_consistency.py.
"""
from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..core.sr.scheduler import frame_centres, frame_holds_rect
from .evaluate import tile_grid_H
from ..io.mosaic_files import read_frames_csv

__all__ = ['TileComparison', 'TileErrors', 'gains_db', 'halve_stills', 'pooled_gain_db', 'psnr_from_sse',
           'sr_errors_against_originals', 'tile_comparisons']

#: Per SR tile file: (sum of squared errors of SR, of the mosaic sampled bicubically, number of
#: values, of the reference frame's LR image sampled bicubically), 0..255 units.
TileErrors = dict[str, tuple[float, float, int, float]]
_HR_H_LR = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])


def halve_stills(src: Path, dst: Path, *, jpeg_quality: int = 98) -> dict[str, np.ndarray]:
    """Write the LR copy of the stills folder ``src`` into ``dst``; returns the HR images (BGR) by name."""
    (dst / 'images').mkdir(parents=True, exist_ok=True)
    shutil.copy(src / 'telemetry_from_exif.csv', dst / 'telemetry_from_exif.csv')
    hr = {}
    for f in sorted((src / 'images').iterdir()):
        img = cv2.imread(str(f))
        if img is None:
            continue
        hr[f.name] = img
        h, w = img.shape[:2]
        cv2.imwrite(str(dst / 'images' / f.name), cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA),
                    [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    return hr


def _sample(img: np.ndarray, img_H_tile: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    out = cv2.warpPerspective(img.astype(np.float32), img_H_tile, (shape[1], shape[0]),
                              flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    return np.clip(out, 0, 255).astype(np.float64)


def sr_errors_against_originals(out: Path, hr: dict[str, np.ndarray],
                                truth: dict[str, np.ndarray] | None = None) -> TileErrors:
    """Errors of every tile of ``out``/sr/tiles.json against the HR originals ``hr`` (name -> BGR
    image, in the folder's frame order = sorted names, one per frames.csv row), or against
    ``truth`` (the same names) where the originals are not the ground (:func:`tile_comparisons`)."""
    result: TileErrors = {}
    for t in tile_comparisons(out, hr, truth):
        result[t.file] = (float(((t.sr - t.truth) ** 2).sum()), float(((t.mosaic_bicubic - t.truth) ** 2).sum()),
                          t.truth.size, float(((t.frame_bicubic - t.truth) ** 2).sum()))
    return result


@dataclass(frozen=True)
class TileComparison:
    """One SR tile and what it is scored against, all (H s, W s, 3) float64 BGR 0..255 on the tile's
    grid: the HR original of its reference frame ``reference`` (truth), the SR tile, mosaic.png and
    the reference's LR image sampled bicubically."""

    file: str
    reference: str
    truth: np.ndarray
    sr: np.ndarray
    mosaic_bicubic: np.ndarray
    frame_bicubic: np.ndarray


def tile_comparisons(out: Path, hr: dict[str, np.ndarray],
                     truth: dict[str, np.ndarray] | None = None) -> Iterator[TileComparison]:
    """Every tile of ``out``/sr/tiles.json beside its truth and baselines (module docstring); ``hr``
    as :func:`sr_errors_against_originals` takes it. Tiles no frame holds whole are skipped.
    ``truth``: what each frame should have shown, by the same names and size as ``hr``, when that is
    known and differs from the originals (a simulated flight: the ground without the camera's blur,
    noise and compression); the LR frames stay ``hr`` halved."""
    names = sorted(hr)
    rows = read_frames_csv(out / 'frames.csv')
    ok = [(names[i], r['mosaic_H_frame']) for i, r in enumerate(rows) if r['ok']]
    mosaic = cv2.imread(str(out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)[:, :, :3]
    h_hr, w_hr = next(iter(hr.values())).shape[:2]
    size = (w_hr // 2, h_hr // 2)
    centres = frame_centres([h for _, h in ok], [size] * len(ok))
    lr: dict[str, np.ndarray] = {}  # the reference frames halved, as the LR input was made
    for entry in json.loads((out / 'sr' / 'tiles.json').read_text()):
        sr = cv2.imread(str(out / 'sr' / entry['file']))[:, :, :3].astype(np.float64)
        grid_H = tile_grid_H(entry)
        c = np.array([entry['x0'] + (entry['width'] - 1) / 2, entry['y0'] + (entry['height'] - 1) / 2])
        # the reference is the nearest frame that holds the whole tile, as the SR scheduler picks
        # them: a nearer frame that holds only part of it would be compared outside its own pixels
        rect = (entry['x0'], entry['y0'], entry['width'], entry['height'])
        covers = np.array([frame_holds_rect(np.linalg.inv(h), size, rect) for _, h in ok])
        if not covers.any():
            continue
        dist = np.where(covers, np.hypot(*(centres - c).T), np.inf)
        name, mosaic_H_frame = ok[int(np.argmin(dist))]
        frame_H_grid = np.linalg.inv(mosaic_H_frame) @ grid_H
        if name not in lr:
            lr[name] = cv2.resize(hr[name], size, interpolation=cv2.INTER_AREA)
        yield TileComparison(entry['file'], name, _sample((hr if truth is None else truth)[name], _HR_H_LR @ frame_H_grid,
                                                          sr.shape[:2]), sr,
                             _sample(mosaic, grid_H, sr.shape[:2]), _sample(lr[name], frame_H_grid, sr.shape[:2]))


#: Where each baseline's sum of squared errors sits in a TileErrors tuple.
_BASELINE_FIELD = {'mosaic': 1, 'frame': 3}


def _baseline_field(baseline: str) -> int:
    if baseline not in _BASELINE_FIELD:
        msg = f"baseline must be 'mosaic' or 'frame', got {baseline!r}."
        raise ValueError(msg)
    return _BASELINE_FIELD[baseline]


def gains_db(errors: TileErrors, baseline: str = 'mosaic') -> np.ndarray:
    """Per-tile PSNR gain (dB) of SR over the ``baseline`` ('mosaic' or 'frame', module docstring)."""
    k = _baseline_field(baseline)
    return np.array([psnr_from_sse(e[0], e[2]) - psnr_from_sse(e[k], e[2]) for e in errors.values()])


def psnr_from_sse(sse: float, n: int) -> float:
    return float(10 * np.log10(255.0**2 / max(sse / max(n, 1), 1e-12)))


def pooled_gain_db(errors: TileErrors, files: list[str] | None = None, baseline: str = 'mosaic') -> tuple[float, float, float]:
    """(PSNR of SR, PSNR of bicubic, gain dB) pooled over ``files`` (default all), bicubic of the
    ``baseline`` ('mosaic' or 'frame', module docstring)."""
    use = list(errors) if files is None else files
    k = _baseline_field(baseline)
    sse_sr, sse_bi, n = (sum(errors[f][i] for f in use) for i in (0, k, 2))
    p_sr, p_bi = psnr_from_sse(sse_sr, n), psnr_from_sse(sse_bi, n)
    return p_sr, p_bi, p_sr - p_bi
