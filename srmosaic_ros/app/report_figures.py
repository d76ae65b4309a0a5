"""The figures of report.html (app/run_report.py), drawn with matplotlib's Agg canvas into PNG bytes
(JPEG for the two drawn over the mosaic's thumbnail).

matplotlib is imported when the first figure is drawn, never at the package's import. Every figure
is small (FIG_DPI, a few inches) and draws its many items as one collection each (PolyCollection,
LineCollection, one scatter), never one artist per frame: its cost does not grow with Python
loops over thousands of artists.
"""
from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ['FIG_DPI', 'coverage_figure', 'map_figure', 'pair_graph_figure', 'registration_figure', 'sr_figure',
           'sr_compare_figure', 'stage_times_figure', 'survey_pairs_figure', 'warm_up']

#: Dots per inch of every figure (the page shows them at about their own size).
FIG_DPI = 80
#: Colours: placed frames, failed frames, frames placed by their pose alone, GNSS, fused.
PLACED, FAILED, BY_POSE, GNSS, FUSED = '#1f77b4', '#d62728', '#ff7f0e', '#7f7f7f', '#2ca02c'


def warm_up() -> None:
    """Import matplotlib and draw one small figure with text (fonts found, caches filled): what a
    first figure costs beyond its own drawing. `process` runs it on a thread while GDAL and the PNG
    writer compress the mosaic (io/outputs.py; their work releases the GIL), so report.html's
    figures start warm; it touches nothing the run uses."""
    fig = _figure(1.0, 1.0)
    ax = fig.add_subplot()
    ax.plot([0, 1], [0, 1])
    ax.set_xlabel('x', fontsize=8)
    _png(fig)


def _figure(width_in: float, height_in: float, *, left: float = 0.75, bottom: float = 0.5) -> Any:
    """A figure of that size (inches) with fixed margins (left and bottom, inches): a constrained or
    tight layout lays every text out again several times, most of a small figure's cost."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=FIG_DPI)
    fig.subplots_adjust(left=left / width_in, right=1.0 - 0.15 / width_in, bottom=bottom / height_in,
                        top=1.0 - 0.3 / height_in, hspace=0.15)
    FigureCanvasAgg(fig)
    return fig


#: JPEG quality of the figures drawn over the mosaic (a photograph: PNG would store it in far more bytes).
JPEG_QUALITY = 85


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=FIG_DPI, pil_kwargs={'compress_level': 3})
    return buf.getvalue()


def _jpeg(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format='jpeg', dpi=FIG_DPI, pil_kwargs={'quality': JPEG_QUALITY})
    return buf.getvalue()


def coverage_figure(thumb: np.ndarray | None, size_px: tuple[int, int], footprints: np.ndarray,
                    failed_xy: np.ndarray, by_pose: np.ndarray | None = None) -> bytes:
    """The mosaic with each placed frame's outline, and where the frames not in it were.

    thumb: RGB(A) uint8 (h, w, C) of the mosaic downscaled (None: no image); size_px: the mosaic's
    (width, height); footprints: (N, 4, 2) outlines in mosaic pixels; failed_xy: (K, 2) mosaic
    pixels where the frames not in the mosaic were (between their placed neighbours); by_pose:
    (N,) bool, outlines of frames placed by their pose alone (drawn in BY_POSE).
    """
    from matplotlib.collections import PolyCollection

    w, h = size_px
    aspect = h / max(w, 1)
    fig = _figure(6.4, float(np.clip(6.4 * aspect, 2.4, 7.0)))
    ax = fig.add_subplot()
    if thumb is not None:
        ax.imshow(thumb, extent=(-0.5, w - 0.5, h - 0.5, -0.5), interpolation='bilinear')
    colours = np.where(by_pose, BY_POSE, PLACED) if by_pose is not None and len(by_pose) else PLACED
    if len(footprints):
        ax.add_collection(PolyCollection(footprints, closed=True, facecolors='none', edgecolors=colours,
                                         linewidths=0.6, alpha=0.7))
    if len(failed_xy):
        ax.scatter(failed_xy[:, 0], failed_xy[:, 1], marker='x', s=36, c=FAILED, linewidths=1.5,
                   label=f'not in the mosaic ({len(failed_xy)})')
        ax.legend(loc='upper right', fontsize=8)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect('equal')
    ax.set_xlabel('mosaic.png x (px)', fontsize=8)
    ax.set_ylabel('y (px)', fontsize=8)
    ax.tick_params(labelsize=7)
    return _jpeg(fig) if thumb is not None else _png(fig)


def registration_figure(index: np.ndarray, inliers: np.ndarray, rms_px: np.ndarray, ok: np.ndarray,
                        tracked: np.ndarray) -> bytes:
    """Inliers and RMS residual (px) of each frame's registration along the flight.

    index: (N,) frame numbers; inliers (N,), rms_px (N,) NaN where not registered by features;
    ok: (N,) in mosaic.png; tracked: (N,) placed by photometric tracking (no inliers, drawn as ticks).
    """
    fig = _figure(7.2, 3.6)
    ax_in, ax_rms = fig.subplots(2, 1, sharex=True)
    feats = ok & ~tracked & (inliers > 0)
    ax_in.vlines(index[feats], 0, inliers[feats], colors=PLACED, linewidth=1.0, label='inliers')
    if tracked.any():
        ax_in.plot(index[tracked], np.zeros(int(tracked.sum())), '|', color=GNSS, ms=6, label='tracked')
    finite = feats & np.isfinite(rms_px)
    ax_rms.plot(index[finite], rms_px[finite], '.', color=PLACED, ms=3)
    for ax in (ax_in, ax_rms):
        if (~ok).any():
            ax.vlines(index[~ok], 0, 1, transform=ax.get_xaxis_transform(), colors=FAILED, linewidth=1.0,
                      alpha=0.6, label='not in the mosaic' if ax is ax_in else None)
        ax.tick_params(labelsize=7)
    ax_in.set_ylabel('inliers', fontsize=8)
    ax_rms.set_ylabel('RMS (px)', fontsize=8)
    ax_rms.set_xlabel('frame', fontsize=8)
    ax_in.legend(loc='upper right', fontsize=7, ncols=3)
    return _png(fig)


def survey_pairs_figure(index: np.ndarray, pairs_used: np.ndarray, median_inliers: np.ndarray,
                        placed: np.ndarray, by_pose: np.ndarray) -> bytes:
    """A survey's registrations per still: the pairs the solve used (bars) and their median inliers.

    index (N,); pairs_used (N,) int; median_inliers (N,) NaN where none; placed (N,) in the mosaic;
    by_pose (N,) placed by its pose alone.
    """
    fig = _figure(7.2, 3.6)
    ax_p, ax_in = fig.subplots(2, 1, sharex=True)
    ax_p.bar(index, pairs_used, color=np.where(by_pose, BY_POSE, PLACED), width=0.8)
    fin = np.isfinite(median_inliers)
    ax_in.plot(index[fin], median_inliers[fin], '.', color=PLACED, ms=4)
    for ax in (ax_p, ax_in):
        if (~placed).any():
            ax.vlines(index[~placed], 0, 1, transform=ax.get_xaxis_transform(), colors=FAILED, linewidth=1.2,
                      alpha=0.7, label='not placed' if ax is ax_p else None)
        ax.tick_params(labelsize=7)
    if (~placed).any():
        ax_p.legend(loc='upper right', fontsize=7)
    ax_p.set_ylabel('pairs used', fontsize=8)
    ax_in.set_ylabel('median inliers', fontsize=8)
    ax_in.set_xlabel('still', fontsize=8)
    return _png(fig)


def map_figure(tracks: Sequence[tuple[str, np.ndarray, str, str]], gcp: Sequence[tuple[str, str, np.ndarray,
               np.ndarray | None]] = (), vector_scale: float = 1.0) -> bytes:
    """Positions on the ground, metres east and north of a local origin.

    tracks: (label, (N, 2) east/north, colour, style: 'line', 'dots' or 'rings'); gcp: (name, role 'control'
    or 'check', (2,) surveyed east/north, (2,) residual east/north or None), the residuals drawn as
    arrows ``vector_scale`` times their length.
    """
    pts = np.concatenate([en for _, en, _, _ in tracks] + [np.array([p for _, _, p, _ in gcp]).reshape(-1, 2)])
    pts = pts[np.isfinite(pts).all(axis=1)]
    span = np.ptp(pts, axis=0) if len(pts) else np.ones(2)
    fig = _figure(6.4, float(np.clip(5.65 * span[1] / max(span[0], 1e-6) + 0.75, 2.6, 6.4)))
    ax = fig.add_subplot()
    for label, en, colour, style in tracks:
        if not len(en):
            continue
        if style == 'line':
            ax.plot(en[:, 0], en[:, 1], '-', color=colour, lw=1.2, label=label)
        elif style == 'rings':
            ax.plot(en[:, 0], en[:, 1], 'o', mfc='none', color=colour, ms=6, label=label)
        else:
            ax.plot(en[:, 0], en[:, 1], '.', color=colour, ms=4, label=label)
    for role, marker, colour in (('control', '^', '#9467bd'), ('check', 's', FAILED)):
        pts = [(p, r) for _, ro, p, r in gcp if ro == role]
        if not pts:
            continue
        xy = np.array([p for p, _ in pts])
        ax.scatter(xy[:, 0], xy[:, 1], marker=marker, s=40, facecolors='none', edgecolors=colour,
                   label=f'{role} points ({len(pts)})')
        res = np.array([r if r is not None else (np.nan, np.nan) for _, r in pts], dtype=float)
        fin = np.isfinite(res).all(axis=1)
        if fin.any():
            ax.quiver(xy[fin, 0], xy[fin, 1], res[fin, 0] * vector_scale, res[fin, 1] * vector_scale, color=colour,
                      angles='xy', scale_units='xy', scale=1.0, width=0.004)
    for name, _, p, _ in gcp:
        ax.annotate(name, p, fontsize=6, xytext=(3, 3), textcoords='offset points')
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_xlabel('east (m)', fontsize=8)
    ax.set_ylabel('north (m)', fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc='best')
    return _png(fig)


def pair_graph_figure(thumb: np.ndarray | None, size_px: tuple[int, int], centres: np.ndarray,
                      edges: np.ndarray, used: np.ndarray) -> bytes:
    """A survey's pair graph over its mosaic: still centres (N, 2) mosaic px (NaN: not placed), the
    registered pairs edges (P, 2) still indices, used (P,) by the solve (else drawn dashed, red)."""
    from matplotlib.collections import LineCollection

    w, h = size_px
    fig = _figure(6.4, float(np.clip(6.4 * h / max(w, 1), 2.4, 7.0)))
    ax = fig.add_subplot()
    if thumb is not None:
        ax.imshow(thumb, extent=(-0.5, w - 0.5, h - 0.5, -0.5), alpha=0.45)
    if len(edges):
        seg = centres[edges]  # (P, 2, 2)
        fin = np.isfinite(seg).all(axis=(1, 2))
        for mask, colour, style, label in ((used & fin, FUSED, 'solid', f'used ({int(used.sum())})'),
                                           (~used & fin, FAILED, 'dashed', f'dropped by the solve ({int((~used).sum())})')):
            if mask.any():
                ax.add_collection(LineCollection(seg[mask], colors=colour, linestyles=style, linewidths=0.8,
                                                 label=label))
    fin = np.isfinite(centres).all(axis=1)
    ax.scatter(centres[fin, 0], centres[fin, 1], s=10, c=PLACED, zorder=3)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect('equal')
    ax.tick_params(labelsize=7)
    if len(edges):
        ax.legend(fontsize=7, loc='upper right')
    return _jpeg(fig) if thumb is not None else _png(fig)


def stage_times_figure(seconds: dict[str, float]) -> bytes:
    """Horizontal bars of the time per stage (s), in the order given."""
    names = list(seconds)
    fig = _figure(6.4, 0.8 + 0.22 * len(names), left=1.6)
    ax = fig.add_subplot()
    y = np.arange(len(names))
    vals = np.array([seconds[k] for k in names], dtype=float)
    ax.barh(y, vals, color=PLACED)
    ax.set_yticks(y, [f'{k} {v:.2f} s' for k, v in zip(names, vals)], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, max(float(vals.max()) * 1.2, 1e-3) if len(vals) else 1.0)
    ax.set_xlabel('seconds', fontsize=8)
    ax.tick_params(axis='x', labelsize=7)
    return _png(fig)


def sr_compare_figure(bicubic: np.ndarray, sr: np.ndarray, factor: int) -> bytes:
    """One SR tile beside the mosaic's same region upsampled bicubically: two RGB uint8 (h, w, 3)
    images of one size."""
    h, w = sr.shape[:2]
    fig = _figure(6.4, float(np.clip(3.1 * h / max(w, 1) + 0.45, 1.6, 4.5)), left=0.1, bottom=0.1)
    for k, (img, title) in enumerate(((bicubic, f'mosaic, bicubic x{factor}'), (sr, f'SR x{factor}'))):
        ax = fig.add_subplot(1, 2, k + 1)
        ax.imshow(img, interpolation='nearest')
        ax.set_title(title, fontsize=8)
        ax.set_axis_off()
    return _jpeg(fig)


def sr_figure(gain_db: np.ndarray, refused: int) -> bytes:
    """Each SR tile's gain (dB) over the mosaic at predicting a frame it was not given (leave-one-out,
    core/sr/self_check.py), sorted; ``refused`` tiles (left to the mosaic) noted in the title."""
    fig = _figure(6.4, 2.6)
    ax = fig.add_subplot()
    g = np.sort(gain_db)[::-1]
    ax.bar(np.arange(len(g)), g, color=np.where(g > 0, FUSED, FAILED), width=0.9)
    ax.axhline(0.0, color='k', lw=0.6)
    ax.set_xlabel('tile (sorted)', fontsize=8)
    ax.set_ylabel('gain (dB)', fontsize=8)
    ax.set_title(f'{len(g)} tiles checked, {refused} left to the mosaic', fontsize=8)
    ax.tick_params(labelsize=7)
    return _png(fig)
