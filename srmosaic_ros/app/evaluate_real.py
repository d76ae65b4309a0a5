"""`srmosaic evaluate DIR` without --truth: figures of a real run that need no ground truth.

A process output (mosaic.png, frames.csv, report.json, and mosaic.tif when georeferenced) is
judged against its own input, re-read in frame order:

- ``fraction_in_main``: frames in the main mosaic (frames.csv ok=1) over frames.csv rows.
- Consistency: each frame of the main mosaic is warped into mosaic.png by its mosaic_H_frame,
  over the frame's bounding box in the mosaic only, and the normalised cross-correlation (NCC) of
  the grey levels of the warped frame and of the mosaic is taken inside the frame's footprint
  (the warped frame's valid mask eroded by 2 px, and mosaic alpha > 0). The mosaic is partly made
  of the frame itself, so a frame alone under itself scores 1.0 by construction: this figure says
  how well each frame agrees with the composite, and ghosting, misregistration, wedges between
  frames and blur all lower it. It is not an absolute registration error.
- Sharpness: per frame, the gradient energy (mean squared 3x3 Sobel gradient of the grey image,
  intensities in [0, 1]) of the mosaic over that of the warped frame, in the same footprint (its
  mosaic alpha eroded by 1 px more, so that no gradient reads a transparent pixel), the frame's
  taken at the mosaic's mean level there (energy scales with the square of an exposure gain, and
  the mosaic may have matched the frames' exposures). 1.0: the composite is as sharp as the frames;
  below: it is blurred, by averaging frames that do not line up, or by resampling.
- Seen from the frames (``ncc_frame``, ``sharpness_frame``): the same two figures the other way
  round, the mosaic resampled onto the frame's own pixels (over the part of the frame the canvas
  painted, where the mosaic covers it) and compared there, every frame pixel counting once. Where a
  frame lands on the mosaic smaller than it is (an oblique forward flight mosaicked in its first
  frame's plane: the later frames' near ground is crushed into the first frame's far field), the
  mosaic keeps little of what the frame saw: the mosaic-space figures cannot tell (they compare at
  the mosaic's sampling, where that frame is reduced too), these do. The mosaic is averaged over
  each frame pixel's footprint (rendered SUPERSAMPLE times finer where the frame is magnified on it,
  then area-reduced), so a mosaic finer than the frame is not charged with aliasing. Sharpness is
  taken at the scale of a few frame pixels (both images smoothed by DETAIL_SIGMA_PX): a frame alone
  under its own warp then scores NCC 1 and a sharpness below 1 by what the two bilinear resamplings
  there and back cost (docs/results.md, "The mosaic against its frames"). Frames wider than the run's mosaic.max_width are
  compared at that width, the sampling the user chose for the mosaic.
- Position error, when mosaic.tif exists and frames.csv carries ``meta_latitude,meta_longitude``
  (WGS84 degrees, where the footage's own metadata puts the frame centre on the ground): each
  frame's centre pixel ((w - 1) / 2, (h - 1) / 2) through mosaic_H_frame and mosaic.tif's
  geotransform, against the metadata position in mosaic.tif's CRS (pyproj), in metres.

Modules: real_agreement.py computes the per-frame figures (its docstring: pixel convention and
cost), real_position.py the position error, report_json.py reads report.json; this one re-reads
the input, gathers the figures and prints them (their public names are re-exported here).
"""
from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from ..core.image_ops import to_gray_float01
from ..core.mosaic import resample
from ..core.types import CameraIntrinsics, Frame
from ..core.undistort import Undistorter
from ..errors import InputError
from .real_agreement import MAX_COMPARE_PX, FrameAgreement, _agreement, _MosaicWindows
from .real_position import META_COLUMNS, _position_figures, read_meta_positions
from .report_json import REPORT_SHAPE, _load_run, load_report

if TYPE_CHECKING:
    from ..io.bags import TopicConfig

__all__ = [
    'REPORT_SHAPE',
    'load_report',
    'MAX_COMPARE_PX',
    'META_COLUMNS',
    'FrameAgreement',
    'evaluate_real',
    'format_real_figures',
    'read_meta_positions',
]

#: Below this median sharpness seen from the frames (a frame alone scores somewhat below 1: module
#: docstring) evaluate says the mosaic is much coarser than its frames.
COARSE_MOSAIC_SHARPNESS = 0.5


def _pick(n: int, max_frames: int | None) -> np.ndarray:
    """Indices of at most max_frames of n, spread evenly over the run (first and last included)."""
    if max_frames is None or max_frames >= n:
        return np.arange(n)
    if max_frames < 1:
        msg = f'max_frames must be at least 1, got {max_frames}.'
        raise InputError(msg)
    return np.unique(np.round(np.linspace(0, n - 1, max_frames)).astype(int))


def _nan_stat(values: list[float], fn: Any) -> float | None:
    v = np.array([x for x in values if math.isfinite(x)])
    return float(fn(v)) if v.size else None


def evaluate_real(out_dir: Path, *, progress: bool = True, max_frames: int | None = None,
                  input_path: Path | None = None, camera_yaml: Path | None = None,
                  topics: TopicConfig | None = None, undistort: bool | None = None) -> dict[str, Any]:
    """Truth-free figures of the process output ``out_dir`` (see the module docstring).

    Args:
        out_dir: a `srmosaic process` output directory (frames.csv, report.json, mosaic.png).
        progress: a tqdm bar on stderr while the input is re-read.
        max_frames: compare at most this many frames of the main mosaic, spread evenly over the
            run (None: all). The position figures use every frame with metadata regardless.
        input_path: the input to re-read instead of report.json's 'input' (moved or relative).
        camera_yaml, topics: what `process` was given (--camera, topic options), so that the
            frames are re-read, and undistorted, as that run saw them. Default: the camera YAML
            report.json names (a video run records its --camera), read again.
        undistort: whether that run undistorted its frames (default: report.json's config, else
            True); the video's deinterlace mode is report.json's.

    Returns a JSON-serialisable dict: input (str), input_kind, frames_rows, frames_in_main,
    fraction_in_main (0..1), frames_compared (frames with a finite NCC), frames_not_in_input
    (main frames whose stamp the input no longer has), frames_reduced (compared on every k-th mosaic pixel, k > 1),
    ncc_median, ncc_p10, sharpness_median (None when no frame could be compared),
    frames_compared_in_frame, ncc_frame_median, ncc_frame_p10, sharpness_frame_median (the same, seen
    from the frames: the mosaic rendered onto each frame's pixels), position (None,
    or {frames, rms_m, median_m, max_m, crs}), position_note (why it is None, '' otherwise), and
    per_frame: one entry per main frame compared, {stamp_ns, ncc, sharpness_ratio, pixels, scale,
    note, ncc_frame, sharpness_frame, frame_pixels, position_error_m (metres, or None)} (NaN
    figures as None).

    Raises InputError when a file of the run is missing or unreadable, the input is gone, no frame
    is in the main mosaic, or no frame of the input has a stamp of frames.csv.
    """
    from .process import open_source

    out_dir = Path(out_dir)
    report, rows = _load_run(out_dir)
    main = [r for r in rows if r['ok']]
    if not main:
        msg = (f'{out_dir / "frames.csv"} has no frame in the main mosaic (ok=1 in none of {len(rows)} rows); '
               'nothing to evaluate: see report.json failure_reasons and re-run process.')
        raise InputError(msg)
    if input_path is None:
        if not report.get('input'):
            msg = f'{out_dir / "report.json"} does not name its input; pass the input (input_path).'
            raise InputError(msg)
        source = Path(report['input'])
        if not source.exists():
            msg = (f'the input of {out_dir}, {source} (report.json "input"), no longer exists; '
                   're-run process or pass the input (input_path).')
            raise InputError(msg)
    else:
        source = Path(input_path)
        if not source.exists():
            msg = f'input {source} does not exist; pass the input that {out_dir} was processed from.'
            raise InputError(msg)
    kind = report.get('input_kind', '')
    video = (report.get('video') or {}) if kind == 'video' else {}
    select = str(video.get('select', 'all'))
    if camera_yaml is None and video.get('camera'):
        camera_yaml = Path(video['camera'])
        if not camera_yaml.is_file():
            msg = (f'{out_dir} was processed with the camera calibration {camera_yaml} (report.json video.camera), '
                   'which no longer exists; pass it (--camera) so that the frames are undistorted as that run saw them.')
            raise InputError(msg)
    if undistort is None:
        undistort = bool(((report.get('config') or {}).get('undistort', True)))
    reread = {'deinterlace': video['deinterlace']} if video.get('deinterlace') else {}
    items, _, kind_now = open_source(source, topics=topics, select=select, camera_yaml=camera_yaml, **reread)
    meta = read_meta_positions(out_dir / 'frames.csv')
    mosaic_config = (report.get('config') or {}).get('mosaic') or {}
    max_stretch = float(mosaic_config.get('max_stretch', 0.0))
    max_width = int(mosaic_config.get('max_width', 0))
    interpolation = str(mosaic_config.get('interpolation', 'linear'))  # before the key: bilinear
    if interpolation not in resample.INTERPOLATIONS:
        msg = (f"{out_dir / 'report.json'} says the mosaic was painted with interpolation {interpolation!r}, which "
               f"this version does not know ({', '.join(resample.INTERPOLATIONS)}); evaluate it with the version that made it.")
        raise InputError(msg)

    wanted = {main[i]['stamp_ns']: main[i] for i in _pick(len(main), max_frames)}
    mosaic = _MosaicWindows(out_dir)
    undistorter, camera = Undistorter(undistort), None
    results: dict[int, FrameAgreement] = {}
    size: tuple[int, int] | None = None
    try:
        with tqdm(total=len(wanted), unit='frame', desc='evaluate', disable=not progress) as bar:
            for item in items:
                if isinstance(item, CameraIntrinsics):
                    camera = item
                if not isinstance(item, Frame) or item.stamp_ns not in wanted or item.stamp_ns in results:
                    continue
                frame = undistorter.frame(item, camera)  # as the pipeline saw it
                size = size or (frame.image.shape[1], frame.image.shape[0])
                results[item.stamp_ns] = _agreement(item.stamp_ns, to_gray_float01(frame.image),
                                                    wanted[item.stamp_ns]['mosaic_H_frame'], mosaic, max_stretch,
                                                    max_width, interpolation)
                bar.update(1)
                if len(results) == len(wanted):
                    break  # the rest of the input holds no frame to compare
    finally:
        mosaic.close()
    if not results or size is None:
        msg = (f'no frame of {source} has a stamp of {out_dir / "frames.csv"}: is it the input of that run '
               '(and, for video, the same --select)? Re-run process or pass the input (input_path).')
        raise InputError(msg)
    position, pos_err, pos_note = _position_figures(out_dir, main, meta, size, report)

    ordered = [results[s] for s in wanted if s in results]
    nccs = [a.ncc for a in ordered]
    sharp = [a.sharpness_ratio for a in ordered]
    per_frame = []
    for a in ordered:
        entry = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(a).items()}
        entry['position_error_m'] = pos_err.get(a.stamp_ns)
        per_frame.append(entry)
    return {
        'input': str(source),
        'input_kind': kind_now,
        'frames_rows': len(rows),
        'frames_in_main': len(main),
        'fraction_in_main': len(main) / len(rows),
        'frames_compared': int(sum(math.isfinite(v) for v in nccs)),
        'frames_not_in_input': len(wanted) - len(results),
        'frames_reduced': int(sum(a.scale < 1.0 for a in ordered)),
        'ncc_median': _nan_stat(nccs, np.median),
        'ncc_p10': _nan_stat(nccs, lambda v: np.percentile(v, 10)),
        'sharpness_median': _nan_stat(sharp, np.median),
        'frames_compared_in_frame': int(sum(math.isfinite(a.ncc_frame) for a in ordered)),
        'ncc_frame_median': _nan_stat([a.ncc_frame for a in ordered], np.median),
        'ncc_frame_p10': _nan_stat([a.ncc_frame for a in ordered], lambda v: np.percentile(v, 10)),
        'sharpness_frame_median': _nan_stat([a.sharpness_frame for a in ordered], np.median),
        'position': position,
        'position_note': pos_note,
        'per_frame': per_frame,
    }


def format_real_figures(figures: dict[str, Any]) -> list[str]:
    """The lines `srmosaic evaluate DIR` prints for :func:`evaluate_real`'s figures."""
    n_main, n_rows = figures['frames_in_main'], figures['frames_rows']
    lines = [f'frames in main mosaic: {n_main}/{n_rows} ({100.0 * figures["fraction_in_main"]:.0f}%)']
    n = figures['frames_compared']
    if figures['ncc_median'] is None:
        lines.append('consistency (NCC frame vs mosaic): no frame could be compared')
    else:
        lines.append(f'consistency (NCC frame vs mosaic): median {figures["ncc_median"]:.3f}, '
                     f'p10 {figures["ncc_p10"]:.3f} over {n} frames (1.0: frames agree with the composite)')
    if figures['sharpness_median'] is not None:
        lines.append(f'sharpness (mosaic vs frame gradient energy): median {figures["sharpness_median"]:.3f} '
                     '(1.0: as sharp as the frames)')
    if figures.get('ncc_frame_median') is not None:
        lines.append(f'seen from the frames (the mosaic on each frame\'s pixels): consistency median '
                     f'{figures["ncc_frame_median"]:.3f}, p10 {figures["ncc_frame_p10"]:.3f}, sharpness median '
                     f'{figures["sharpness_frame_median"]:.3f} over {figures["frames_compared_in_frame"]} frames '
                     '(a frame alone under its own warp: 1.0 and about 0.85; lower sharpness: the mosaic keeps '
                     'less of the detail the frames saw)')
        if figures['sharpness_frame_median'] < COARSE_MOSAIC_SHARPNESS:
            lines.append('  the mosaic is much coarser than its frames: they land on it smaller than they are (a '
                         'forward or oblique flight drawn in its first frame\'s plane, or a zoom in), or it is blurred; '
                         'docs/guide/compositing.md, "Oblique views"')
    if figures.get('frames_reduced'):
        lines.append(f'  {figures["frames_reduced"]} frames cover more than {MAX_COMPARE_PX / 1e6:g} Mpx of the mosaic: '
                     'compared on every k-th mosaic pixel')
    if figures.get('frames_not_in_input'):
        lines.append(f'  {figures["frames_not_in_input"]} frames of frames.csv not found in the input: not compared')
    pos = figures.get('position')
    if pos is None:
        lines.append(f'position vs metadata: not available ({figures.get("position_note") or "no data"})')
    else:
        lines.append(f'position vs metadata (frame centres): RMS {pos["rms_m"]:.2f} m, median {pos["median_m"]:.2f} m, '
                     f'max {pos["max_m"]:.2f} m over {pos["frames"]} frames ({pos["crs"]})')
    return lines
