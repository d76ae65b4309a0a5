"""DIR/report.html of every `process` run: what report.json, frames.csv, poses.csv and preview.png
say, as a page a user opens (io/report_html.py writes it; app/report_figures.py draws it).

Sections, each drawn where the run has its data and saying so where it has none: the summary; the
coverage (the mosaic with each frame's outline, frames not in it marked); the registrations along
the flight; the positions on the map (GNSS, fused, frame centres by the mosaic and by the metadata,
ground control with its residuals); a survey's pair graph; the time per stage and the memory; the
SR gains. A section that cannot be drawn says why on the page and in the log; it never fails the run.
"""
from __future__ import annotations

import csv
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..io.report_html import ReportFigure, ReportSection, write_report_html
from . import report_figures as figs

__all__ = ['EARLY_SECTIONS', 'MOSAIC_SECTIONS', 'REPORT_HTML', 'EarlySections', 'RunFrames', 'read_run_frames', 'start_sections',
           'start_warm_up', 'write_run_report']

_LOG = logging.getLogger(__name__)
REPORT_HTML = 'report.html'
#: Longest side of the mosaic thumbnail in the figures (pixels).
THUMB_MAX_SIDE_PX = 640


@dataclass
class RunFrames:
    """frames.csv as arrays: ok (N,) bool, inliers (N,), rms_px (N,), mosaic_H_frame (N, 3, 3) (NaN:
    not in mosaic.png), meta_latlon (N, 2) degrees (NaN), placed_by (N,) str."""

    ok: np.ndarray
    inliers: np.ndarray
    rms_px: np.ndarray
    mosaic_H_frame: np.ndarray
    meta_latlon: np.ndarray
    placed_by: np.ndarray


def read_run_frames(path: Path) -> RunFrames:
    """frames.csv (DESIGN.md contract) read column-wise; missing optional columns are NaN or ''."""
    with open(path, newline='') as handle:
        rows = list(csv.DictReader(handle))

    def col(name: str) -> np.ndarray:
        return np.array([float(r.get(name) or 'nan') for r in rows], dtype=np.float64)

    H = np.stack([col(f'h{r}{c}') for r in range(3) for c in range(3)], axis=1).reshape(-1, 3, 3) if rows \
        else np.zeros((0, 3, 3))
    return RunFrames(col('ok') == 1.0, col('inliers'), col('rms_px'), H,
                     np.stack([col('meta_latitude'), col('meta_longitude')], axis=1) if rows else np.zeros((0, 2)),
                     np.array([r.get('placed_by') or '' for r in rows], dtype=object))


def _frame_points(H: np.ndarray, sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4, 2) outlines and (N, 2) centres in mosaic pixels of frames of sizes (N, 2) (w, h)
    through H (N, 3, 3) (NaN where H is)."""
    w, h = sizes[:, 0].astype(float), sizes[:, 1].astype(float)
    xs = np.stack([-0.5 + 0 * w, w - 0.5, w - 0.5, -0.5 + 0 * w, (w - 1) / 2], axis=1)
    ys = np.stack([-0.5 + 0 * h, -0.5 + 0 * h, h - 0.5, h - 0.5, (h - 1) / 2], axis=1)
    pts = np.stack([xs, ys, np.ones_like(xs)], axis=1)  # (N, 3, 5)
    q = H @ pts
    with np.errstate(invalid='ignore', divide='ignore'):
        xy = (q[:, :2] / q[:, 2:3]).transpose(0, 2, 1)  # (N, 5, 2)
    return xy[:, :4], xy[:, 4]


def _thumb(out: Path) -> np.ndarray | None:
    """preview.png (the whole main mosaic, downscaled) as RGB(A) uint8 of at most THUMB_MAX_SIDE_PX;
    the figures stretch it over the mosaic's extent. None: no preview.png."""
    import cv2

    img = cv2.imread(str(out / 'preview.png'), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    f = min(1.0, THUMB_MAX_SIDE_PX / max(img.shape[:2]))
    if f < 1.0:
        img = cv2.resize(img, (max(1, round(img.shape[1] * f)), max(1, round(img.shape[0] * f))),
                         interpolation=cv2.INTER_AREA)
    code = {3: cv2.COLOR_BGR2RGB, 4: cv2.COLOR_BGRA2RGBA}.get(img.shape[2] if img.ndim == 3 else 1)
    return cv2.cvtColor(img, code) if code is not None else img


def _main_size(report: dict[str, Any]) -> tuple[int, int] | None:
    for seg in report.get('segments') or []:
        if seg.get('file') == 'mosaic.png':
            return int(seg['size_px'][0]), int(seg['size_px'][1])
    return None


def _fmt(v: Any, unit: str = '', digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return 'n/a'
    if isinstance(v, float):
        return f'{v:.{digits}g}{unit}'
    return f'{v}{unit}'


class _Run:
    """The run's files and report, read once for the sections."""

    def __init__(self, out: Path, report: dict[str, Any], frame_sizes: np.ndarray | None,
                 gnss_latlon: np.ndarray | None) -> None:
        self.out, self.report = out, report
        self.frames = read_run_frames(out / 'frames.csv') if (out / 'frames.csv').is_file() else None
        n = len(self.frames.ok) if self.frames is not None else 0
        self.sizes = np.asarray(frame_sizes, dtype=float).reshape(-1, 2) if frame_sizes is not None else None
        if self.sizes is not None and len(self.sizes) != n:
            self.sizes = None  # not one size per frames.csv row: outlines are not drawn
        self.gnss = np.asarray(gnss_latlon, dtype=float).reshape(-1, 2) if gnss_latlon is not None else np.zeros((0, 2))
        self.size_px = _main_size(report)
        self.survey = report.get('survey')
        self.outline = self.centre = None
        if self.frames is not None and self.sizes is not None:
            self.outline, self.centre = _frame_points(self.frames.mosaic_H_frame, self.sizes)
        self._thumb: list[np.ndarray | None] = []

    def thumb(self) -> np.ndarray | None:
        if not self._thumb:
            self._thumb.append(_thumb(self.out))
        return self._thumb[0]


def _summary(run: _Run) -> ReportSection:
    r = run.report
    geo = r.get('georeferenced') or None
    frames_in, registered = r.get('frames_in'), r.get('frames_registered')
    rows = [('Input', f'{r.get("input", "?")} ({r.get("input_kind", "?")})'),
            ('Frames in', _fmt(frames_in)), ('Frames in mosaic.png', _fmt(registered)),
            ('Frames left out of mosaic.png', _fmt(frames_in - registered if frames_in is not None
                                                   and registered is not None else None))]
    left_out = sum((r.get('images_left_out') or {}).values())
    if left_out:
        rows.append(('Images left out before processing', str(left_out)))
    if geo:
        rows += [('Georeferenced', f'yes ({geo.get("method", "?")})'), ('CRS', f'EPSG:{geo.get("epsg")}'),
                 ('GSD', _fmt(geo.get('gsd_m_per_px'), ' m/px'))]
    else:
        rows.append(('Georeferenced', 'no'))
    if run.survey:
        rows.append(('Ground scale', f'{_fmt(run.survey.get("scale_m"), " m")} from {run.survey.get("scale_source")}'))
    rows += [('Wall time', _fmt(r.get('wall_s'), ' s')), ('Frames per second', _fmt(r.get('frames_per_s'))),
             ('Peak memory', _fmt(r.get('peak_rss_mb'), ' MB', 4))]
    warnings = []
    for key in ('error', 'not_georeferenced_reason'):
        if r.get(key):
            warnings.append(f'{key.replace("_", " ")}: {r[key]}')
    if run.survey and run.survey.get('scale_is_guess'):
        warnings.append(f'the ground scale is a guess: {run.survey.get("scale_source")}')
    for key in ('failure_reasons', 'skipped_messages', 'images_left_out', 'image_decoder_warnings'):
        if r.get(key):
            warnings.append(f'{key.replace("_", " ")}: ' + '; '.join(f'{k}: {v}' for k, v in r[key].items()))
    problems = (r.get('metadata') or {}).get('problems') or {}
    if problems:
        warnings.append('metadata problems: ' + '; '.join(f'{k}: {v}' for k, v in problems.items()))
    warnings += [f'ground control: {w}' for w in (r.get('gcp') or {}).get('warnings', [])]
    return ReportSection('summary', 'Summary', rows=rows, warnings=warnings,
                         notes=[] if warnings else ['No warnings or problems were reported.'])


def _coverage(run: _Run) -> ReportSection:
    sec = ReportSection('coverage', 'Coverage')
    if run.size_px is None or run.frames is None:
        sec.empty = 'No mosaic.png was written (no frame was placed): there is no coverage to show.'
        return sec
    thumb = run.thumb()
    ok = run.frames.ok
    failed = np.zeros((0, 2))
    outlines = np.zeros((0, 4, 2))
    by_pose = None
    if run.centre is not None:
        placed = ok & np.isfinite(run.centre).all(axis=1)
        outlines = run.outline[placed]
        by_pose = run.frames.placed_by[placed] == 'pose'
        idx = np.flatnonzero(placed)
        if (~ok).any() and len(idx):
            bad = np.flatnonzero(~ok)  # drawn where the flight was: between their placed neighbours
            failed = np.stack([np.interp(bad, idx, run.centre[idx, 0]), np.interp(bad, idx, run.centre[idx, 1])], axis=1)
    else:
        sec.notes.append('The frames\' sizes are not known here: their outlines are not drawn.')
    n_bad = int((~ok).sum())
    pose = int(by_pose.sum()) if by_pose is not None else 0
    caption = (f'{int(ok.sum())} frames outlined on the mosaic (blue' + (f'; orange: {pose} placed by their pose alone'
                                                                          if pose else '') +
               f'); {n_bad} not in it' + (' (red x, drawn between their placed neighbours).' if n_bad else '.'))
    sec.figures.append(ReportFigure(figs.coverage_figure(thumb, run.size_px, outlines, failed, by_pose),
                                    'mosaic coverage with frame outlines', caption,
                                    {'failed-frames': str(n_bad), 'outlines': str(len(outlines))}))
    return sec


def _registration(run: _Run) -> ReportSection:
    sec = ReportSection('registration', 'Registration along the flight')
    fr = run.frames
    if fr is None or not len(fr.ok):
        sec.empty = 'No frames.csv: no registration to show.'
        return sec
    n = len(fr.ok)
    index = np.arange(n)
    if run.survey and run.survey.get('pairs_graph') is not None:
        graph = run.survey['pairs_graph']
        quality = run.survey.get('pairs_quality') or [None] * len(graph)
        used = np.zeros(n, int)
        inl: list[list[float]] = [[] for _ in range(n)]
        for ((i, j), u), q in zip(graph, quality):
            for k in (i, j):
                if u and 0 <= k < n:
                    used[k] += 1
                    if q is not None:
                        inl[k].append(q[0])
        med = np.array([float(np.median(v)) if v else np.nan for v in inl])
        sec.figures.append(ReportFigure(figs.survey_pairs_figure(index, used, med, fr.ok, fr.placed_by == 'pose'),
                                        'registered pairs per still', 'Pairs the global solve used per still (orange: '
                                        'placed by its pose alone) and the median inliers of those pairs; red: '
                                        'stills not placed.', {'failed-frames': str(int((~fr.ok).sum()))}))
        return sec
    tracked = fr.ok & (fr.inliers == 0) & ~np.isfinite(fr.rms_px)
    reg = run.report.get('registration') or {}
    sec.rows = [('Median inliers', _fmt(reg.get('median_inliers'))), ('Median RMS', _fmt(reg.get('median_rms_px'), ' px')),
                ('Frames tracked photometrically', _fmt(reg.get('tracked')))]
    sec.figures.append(ReportFigure(figs.registration_figure(index, fr.inliers, fr.rms_px, fr.ok, tracked),
                                    'registration inliers and residuals per frame',
                                    'Inliers and RMS residual of each frame\'s registration to the one before (grey '
                                    'ticks: placed by photometric tracking, no inliers); red: frames not in the mosaic.',
                                    {'failed-frames': str(int((~fr.ok).sum()))}))
    return sec


def _to_utm(latlon: np.ndarray, epsg: int) -> np.ndarray:
    from pyproj import Transformer

    if not len(latlon):
        return np.zeros((0, 2))
    e, n = Transformer.from_crs(4326, epsg, always_xy=True).transform(latlon[:, 1], latlon[:, 0])
    return np.stack([np.asarray(e, float), np.asarray(n, float)], axis=1)


def _read_poses(path: Path) -> np.ndarray:
    if not path.is_file():
        return np.zeros((0, 2))
    data = np.genfromtxt(path, delimiter=',', names=True, usecols=(1, 2), ndmin=1)
    return np.stack([data['latitude'], data['longitude']], axis=1) if data.size else np.zeros((0, 2))


def _map(run: _Run) -> ReportSection:
    from ..core.georef.georeferencer import utm_epsg

    sec = ReportSection('map', 'Positions on the map')
    r = run.report
    geo = r.get('georeferenced') or {}
    fused = _read_poses(run.out / 'poses.csv')
    meta = run.frames.meta_latlon if run.frames is not None else np.zeros((0, 2))
    gnss = run.gnss[np.isfinite(run.gnss).all(axis=1)]
    points = [p for p in ((r.get('gcp') or {}).get('points') or []) if p.get('surveyed_utm')]
    any_ll = next((a for a in (gnss, fused, meta[np.isfinite(meta).all(axis=1)]) if len(a)), None)
    epsg = geo.get('epsg') or (r.get('gcp') or {}).get('epsg') or (
        utm_epsg(*np.median(any_ll, axis=0)) if any_ll is not None else None)
    if not epsg:
        sec.empty = ('The run has no positions: no GNSS, no fused poses, no ground control (the mosaic is not '
                     'georeferenced).')
        return sec
    tracks: list[tuple[str, np.ndarray, str, str]] = []
    if len(gnss):
        tracks.append((f'GNSS ({len(gnss)})', _to_utm(gnss, epsg), figs.GNSS, 'rings'))
    if len(fused):
        tracks.append((f'fused poses ({len(fused)})', _to_utm(fused, epsg), figs.FUSED, 'line'))
    has_meta = np.isfinite(meta).all(axis=1)
    gt = geo.get('geotransform')
    mosaic_en = np.zeros((0, 2))
    if gt and run.centre is not None:
        c = run.centre
        mosaic_en = np.stack([gt[0] + (c[:, 0] + 0.5) * gt[1] + (c[:, 1] + 0.5) * gt[2],
                              gt[3] + (c[:, 0] + 0.5) * gt[4] + (c[:, 1] + 0.5) * gt[5]], axis=1)
        tracks.append(('frame centres in the mosaic', mosaic_en[np.isfinite(mosaic_en).all(axis=1)], figs.PLACED, 'dots'))
    if has_meta.any():
        meta_en = _to_utm(meta[has_meta], epsg)
        tracks.append(('frame centres by the metadata', meta_en, figs.BY_POSE, 'dots'))
        if len(mosaic_en):
            d = mosaic_en[has_meta] - meta_en
            d = d[np.isfinite(d).all(axis=1)]
            if len(d):
                sec.rows.append(('Frame centres, mosaic against metadata', f'{math.sqrt(float(np.mean(np.sum(d**2, 1)))):.2f} m '
                                 f'RMS over {len(d)} frames'))
    gcp_pts = []
    for p in points:
        res = p.get('residual_m')
        gcp_pts.append((p['name'], p['role'], np.array(p['surveyed_utm'], float), None if res is None else np.array(res, float)))
    if not tracks and not gcp_pts:
        sec.empty = 'The run has no positions: no GNSS, no fused poses, no ground control.'
        return sec
    allpts = np.concatenate([t[1] for t in tracks] + [np.array([g[2] for g in gcp_pts]).reshape(-1, 2)])
    origin = np.round(np.nanmean(allpts, axis=0))
    tracks = [(a, b - origin, c, d) for a, b, c, d in tracks]
    gcp_pts = [(a, b, c - origin, d) for a, b, c, d in gcp_pts]
    scale = 1.0
    res = [np.hypot(*g[3]) for g in gcp_pts if g[3] is not None]
    if res and max(res) > 0:
        extent = float(np.nanmax(np.ptp(allpts, axis=0))) or 1.0
        scale = max(1.0, round(0.08 * extent / max(res)))
        gcp = r['gcp']
        sec.rows += [('Control RMS', f'{_fmt(gcp.get("control_rms_m"), " m")} ({_fmt(gcp.get("control_rms_gsd"), " GSD")})'),
                     ('Check RMS', f'{_fmt(gcp.get("check_rms_m"), " m")} ({_fmt(gcp.get("check_rms_gsd"), " GSD")})')]
    caption = (f'Metres east and north of E {origin[0]:.0f}, N {origin[1]:.0f} (EPSG:{epsg}).'
               + (f' Ground control residuals drawn {scale:g} x their length.' if gcp_pts else ''))
    sec.figures.append(ReportFigure(figs.map_figure(tracks, gcp_pts, scale), 'positions on the map', caption,
                                    {'tracks': str(len(tracks)), 'gcp-points': str(len(gcp_pts))}))
    return sec


def _pair_graph(run: _Run) -> ReportSection:
    sec = ReportSection('pairs', 'Pair graph of the survey')
    graph = (run.survey or {}).get('pairs_graph')
    if graph is None:
        sec.empty = 'Not a survey aligned globally (the frames are chained one to the next): there is no pair graph.'
        return sec
    if run.size_px is None or run.centre is None:
        sec.empty = 'The stills were not placed in a mosaic: there is no pair graph to draw.'
        return sec
    edges = np.array([e for e, _ in graph], dtype=int).reshape(-1, 2)
    used = np.array([bool(u) for _, u in graph], dtype=bool)
    centres = np.where(run.frames.ok[:, None], run.centre, np.nan)
    sec.rows = [('Pairs tried', _fmt(run.survey.get('pairs_tried'))), ('Pairs registered', str(len(edges))),
                ('Pairs the solve used', str(int(used.sum())))]
    sec.figures.append(ReportFigure(figs.pair_graph_figure(run.thumb(), run.size_px, centres, edges, used),
                                    'pair graph of the survey', 'Each registered pair of stills joins their centres '
                                    '(green: used by the global solve; red, dashed: dropped as inconsistent).',
                                    {'pairs': str(len(edges)), 'pairs-used': str(int(used.sum()))}))
    return sec


def _times(run: _Run) -> ReportSection:
    sec = ReportSection('time', 'Time per stage and memory')
    r = run.report
    stages = {k: float(v.get('total_s', 0.0)) for k, v in (r.get('stage_times') or {}).items() if k != 'total'}
    if not stages and run.survey:
        stages = {k: float(v) for k, v in (run.survey.get('time_s') or {}).items()
                  if k in ('register', 'solve', 'paint', 'write') and v is not None}
    if r.get('sr', {}).get('wall_s') is not None:
        stages['super-resolution'] = float(r['sr']['wall_s'])
    sec.rows = [('Wall time', _fmt(r.get('wall_s'), ' s')), ('Peak memory (RSS)', _fmt(r.get('peak_rss_mb'), ' MB', 4))]
    if not stages:
        sec.notes.append('The run kept no time per stage.')
        return sec
    sec.figures.append(ReportFigure(figs.stage_times_figure(stages), 'time per stage',
                                    'Seconds spent in each stage over the run (this page\'s own writing is counted '
                                    'in report.json after it).', {'stages': str(len(stages))}))
    return sec


def _sr(run: _Run) -> ReportSection:
    sec = ReportSection('sr', 'Super-resolution')
    sr = run.report.get('sr')
    if not sr:
        sec.empty = 'SR did not run (process --sr runs it).'
        return sec
    sec.rows = [('Factor', _fmt(sr.get('factor'))), ('Tiles written', _fmt(sr.get('tiles'))),
                ('Tiles planned', _fmt(sr.get('tiles_planned'))), ('Tiles left to the mosaic', _fmt(sr.get('tiles_refused'))),
                ('PSF sigma', _fmt(sr.get('psf_sigma_px'), ' px'))]
    example = _sr_example(run)
    if example is not None:
        name, bicubic, image = example
        sec.figures.append(ReportFigure(figs.sr_compare_figure(bicubic, image, int(sr['factor'])), 'an SR tile beside '
                                        'the mosaic', f'{name} (the tile made from the most frames) beside the same '
                                        'region of mosaic.png upsampled bicubically.', {'example': name}))
    gains = []
    for t in sr.get('per_tile') or []:
        rms = t.get('held_out_rms') or [None, None]
        if len(rms) == 2 and rms[0] and rms[1]:
            gains.append(20.0 * math.log10(rms[1] / rms[0]))
    if not gains:
        sec.notes.append('No tile was checked against a frame left out (sr.self_check 0, or too few frames): '
                         'no gain to show (srmosaic evaluate measures SR against ground truth or held-out frames).')
        return sec
    sec.rows.append(('Median gain over the mosaic', f'{float(np.median(gains)):.2f} dB'))
    sec.figures.append(ReportFigure(figs.sr_figure(np.array(gains), int(sr.get('tiles_refused') or 0)),
                                    'SR gain per tile', 'Per tile: how much better the SR estimate predicts a frame '
                                    'it was not given than the mosaic does (RMS ratio, dB; core/sr/self_check.py).',
                                    {'tiles': str(len(gains))}))
    return sec


#: The mosaic is read for the SR example only up to this size when it has no mosaic.tif to read a window of.
SR_EXAMPLE_MAX_MOSAIC_PX = 64_000_000


def _sr_example(run: _Run) -> tuple[str, np.ndarray, np.ndarray] | None:
    """(file, the mosaic's region bicubic, the SR tile), RGB uint8 of one size, of the tile made from
    the most frames (sr/tiles.json and report.json sr.per_tile); None when there is none to show."""
    import json

    import cv2

    sr_dir = run.out / 'sr'
    if not (sr_dir / 'tiles.json').is_file():
        return None
    frames = {t['file']: t.get('frames', 0) for t in run.report['sr'].get('per_tile') or [] if t.get('file')}
    tiles = [t for t in json.loads((sr_dir / 'tiles.json').read_text()) if (sr_dir / t['file']).is_file()]
    if not tiles:
        return None
    tile = max(tiles, key=lambda t: (frames.get(t['file'], 0), -t['y0'], -t['x0']))
    x0, y0, w, h, f = (int(tile[k]) for k in ('x0', 'y0', 'width', 'height', 'factor'))
    image = cv2.imread(str(sr_dir / tile['file']), cv2.IMREAD_COLOR)
    if (run.out / 'mosaic.tif').is_file():
        import rasterio
        from rasterio.windows import Window

        with rasterio.open(run.out / 'mosaic.tif') as ds:
            region = np.moveaxis(ds.read(indexes=[1, 2, 3] if ds.count >= 3 else [1, 1, 1], window=Window(x0, y0, w, h)),
                                 0, -1)[:, :, ::-1]
    elif run.size_px is not None and run.size_px[0] * run.size_px[1] <= SR_EXAMPLE_MAX_MOSAIC_PX:
        region = cv2.imread(str(run.out / 'mosaic.png'), cv2.IMREAD_COLOR)[y0:y0 + h, x0:x0 + w]
    else:
        return None
    # tile pixel (u, v) shows mosaic point (x0 + (u + 0.5) / f - 0.5, ...): cv2.resize's half-pixel convention
    bicubic = cv2.resize(np.ascontiguousarray(region), (image.shape[1], image.shape[0]), interpolation=cv2.INTER_CUBIC)
    return tile['file'], cv2.cvtColor(bicubic, cv2.COLOR_BGR2RGB), cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


SECTIONS: tuple[Callable[[_Run], ReportSection], ...] = (_summary, _coverage, _registration, _map, _pair_graph,
                                                         _times, _sr)
TITLES = {'_summary': 'Summary', '_coverage': 'Coverage', '_registration': 'Registration along the flight',
          '_map': 'Positions on the map', '_pair_graph': 'Pair graph of the survey', '_times': 'Time per stage and memory',
          '_sr': 'Super-resolution'}


def start_warm_up() -> threading.Thread:
    """report_figures.warm_up on a daemon thread, started: give it to write_run_report (``warm``).
    A failure there is left for the figures themselves to meet and report."""
    def run() -> None:
        _warm_up()

    thread = threading.Thread(target=run, name='report-figures-warm-up', daemon=True)
    thread.start()
    return thread


def _warm_up() -> None:
    try:
        figs.warm_up()
    except Exception as exc:  # noqa: BLE001 -- the figures meet it again, and say so on the page
        _LOG.debug('report.html warm-up: %s', exc)


#: The sections drawn from frames.csv, poses.csv and the report alone, not from the mosaic's images:
#: start_sections draws them while the mosaic is rendered.
EARLY_SECTIONS: tuple[Callable[[_Run], ReportSection], ...] = (_registration, _map)
#: The sections drawn over preview.png (EarlySections.add_mosaic_sections, once it is written).
MOSAIC_SECTIONS: tuple[Callable[[_Run], ReportSection], ...] = (_coverage, _pair_graph)


class EarlySections:
    """report_figures.warm_up, then the EARLY_SECTIONS of a run, and on add_mosaic_sections() the
    MOSAIC_SECTIONS, drawn in that order on a daemon thread (start_sections); write_run_report
    (``early``) waits for them and draws the others."""

    def __init__(self, out: Path, report: dict[str, Any], frame_sizes: np.ndarray | None,
                 gnss_latlon: np.ndarray | None, warm: threading.Thread | None = None) -> None:
        import queue

        self.run: _Run | None = None
        self.drawn: dict[str, tuple[ReportSection, str | None]] = {}  # section function's name -> (section, failed title)
        self._args = (out, report, frame_sizes, gnss_latlon)
        self._warm = warm
        self._todo: queue.SimpleQueue[Callable[[_Run], ReportSection] | None] = queue.SimpleQueue()
        for build in EARLY_SECTIONS:
            self._todo.put(build)
        self.thread = threading.Thread(target=self._draw, name='report-sections', daemon=True)
        self.thread.start()

    def add_mosaic_sections(self) -> None:
        """preview.png is written: draw the MOSAIC_SECTIONS too."""
        for build in MOSAIC_SECTIONS:
            self._todo.put(build)

    def _draw(self) -> None:
        if self._warm is not None:
            self._warm.join()
        else:
            _warm_up()
        try:
            self.run = _Run(*self._args)
        except Exception as exc:  # noqa: BLE001 -- write_run_report reads the files again and meets it there
            _LOG.debug('report.html: the run could not be read ahead: %s', exc)
        while (build := self._todo.get()) is not None:
            if self.run is not None:
                self.drawn[build.__name__] = _draw_section(build, self.run)

    def wait(self) -> _Run | None:
        """The run the sections were drawn from (None: it could not be read here), once they are drawn."""
        self._todo.put(None)
        self.thread.join()
        return self.run


def start_sections(out: Path, report: dict[str, Any], *, frame_sizes: Sequence[Sequence[int]] | np.ndarray | None = None,
                   gnss_latlon: np.ndarray | None = None, warm: threading.Thread | None = None) -> EarlySections:
    """Start drawing report.html's EARLY_SECTIONS of the run in ``out`` (frames.csv and poses.csv
    written) on a thread; ``report`` is report.json's content so far, the same dict that is later
    given to write_run_report (``early``), which waits for them. Arguments as write_run_report's;
    ``warm``: start_warm_up()'s thread, started earlier (None: the warm-up is this thread's first work)."""
    return EarlySections(out, report, None if frame_sizes is None else np.asarray(frame_sizes), gnss_latlon, warm)


def _draw_section(build: Callable[[_Run], ReportSection], run: _Run) -> tuple[ReportSection, str | None]:
    """(the section, None), or when it cannot be drawn (a section saying why, its title)."""
    try:
        return build(run), None
    except Exception as exc:  # noqa: BLE001 -- a report's figure never fails the run it reports
        name = build.__name__
        _LOG.warning('report.html: the section %r could not be drawn (%s: %s); the run\'s other outputs are '
                     'complete.', TITLES[name], type(exc).__name__, exc)
        return ReportSection(name.strip('_'), TITLES[name], empty=f'This section could not be drawn: '
                             f'{type(exc).__name__}: {exc}'), TITLES[name]


def write_run_report(out: Path, report: dict[str, Any], *, frame_sizes: Sequence[Sequence[int]] | np.ndarray | None = None,
                     gnss_latlon: np.ndarray | None = None, warm: threading.Thread | None = None,
                     early: EarlySections | None = None) -> dict[str, Any]:
    """Write ``out``/report.html from the run's files in ``out`` and its ``report`` (report.json's
    content). frame_sizes: (N, 2) (width, height) of each frames.csv row's frame (None: outlines not
    drawn); gnss_latlon: (M, 2) degrees, the input's GNSS fixes; warm: start_warm_up()'s thread, waited
    for (its wait counted in ``time_s``); early: start_sections()'s, whose sections are taken as drawn
    (frame_sizes and gnss_latlon then as given to it). Returns report.json's ``report_html``:
    the file, the figures drawn, the sections that failed and the seconds it took (the wait for
    ``early``; not its drawing meanwhile)."""
    t0 = time.perf_counter()
    if warm is not None:
        warm.join()
    run = early.wait() if early is not None else None
    drawn = early.drawn if early is not None and run is not None else {}
    if run is None:
        run = _Run(out, report, None if frame_sizes is None else np.asarray(frame_sizes), gnss_latlon)
    sections, failed = [], []
    for build in SECTIONS:
        section, failure = drawn.get(build.__name__) or _draw_section(build, run)
        sections.append(section)
        if failure is not None:
            failed.append(failure)
    title = f'srmosaic run: {Path(str(report.get("input", out))).name}'
    subtitle = (f'{report.get("input", "?")} ({report.get("input_kind", "?")}); the run\'s files (report.json, '
                'frames.csv, the mosaic) are beside this page')
    write_report_html(out / REPORT_HTML, title, subtitle, sections)
    return {'file': REPORT_HTML, 'figures': sum(len(s.figures) for s in sections if not s.empty),
            'sections_failed': failed, 'time_s': round(time.perf_counter() - t0, 3)}
