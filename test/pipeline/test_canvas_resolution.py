"""A canvas sampled as fine as its frames (mosaic.resolution 'finest', pipeline/canvas_resolution.py): on a
flight whose lens zooms in, the canvas takes the sharpest frames' sampling, the mosaic keeps their detail
(within 1 dB of the frame's own round trip through the canvas's warps), and the georeference follows
(the raster's gsd, mosaic.tif's pixel size)."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.app.process import process_input
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.mosaic import resample
from srmosaic_ros.core.mosaic.resolution import frame_scale
from srmosaic_ros.core.types import Frame
from srmosaic_ros.pipeline import Pipeline
from srmosaic_ros.sim import SimConfig, simulate, write_flight
from srmosaic_ros.sim.flight import zoom_at

# the lens zooms from 1x to 2x over the 16 frames (4 s at 4 Hz); the first 13 settle (settle_s 3)
CFG = SimConfig(frames=16, width=256, height=192, zoom=2.0, zoom_period_s=8.0, rate_hz=4.0, speed_m_s=4.0, seed=2)


@pytest.fixture(scope='module')
def flight():
    return simulate(CFG)


def _chained(flight, resolution: str, oversample: float = 1.0) -> Pipeline:
    """The frames alone (no telemetry, no intrinsics: the canvas is the first frame's plane), every frame painted."""
    pipe = Pipeline(pipeline_config({'mosaic.resolution': resolution, 'mosaic.oversample': oversample, 'mosaic.paint_stride': 1}))
    for f in flight.frames:
        pipe.feed(Frame(f.stamp_ns, f.image))
    pipe.flush()
    pipe.finish()
    return pipe


def _psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    d = a[mask].astype(np.float64) - b[mask].astype(np.float64)
    return 10.0 * math.log10(255.0**2 / float(np.mean(d * d)))


def _fidelity(pipe: Pipeline, k: int, image: np.ndarray) -> tuple[float, float]:
    """(mosaic -> frame, frame round trip) luma PSNR (dB) over frame k's pixels the mosaic shows from it
    (bench/mosaic_fidelity.py's measure, for one frame)."""
    canvas, m = pipe.segments[0].canvas, pipe.records[k].seg_H_frame
    h, w = image.shape[:2]
    c = np.array([[-0.5, -0.5, 1.0], [w - 0.5, -0.5, 1.0], [w - 0.5, h - 0.5, 1.0], [-0.5, h - 0.5, 1.0]]) @ m.T
    xy = c[:, :2] / c[:, 2:]
    x0, y0 = np.floor(xy.min(axis=0)).astype(int) - 3
    x1, y1 = np.ceil(xy.max(axis=0)).astype(int) + 4
    box_H_frame = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ m
    inv = cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP
    mosaic, _ = canvas.render((x0, y0, x1, y1))
    back = cv2.warpPerspective(np.clip(mosaic * 255.0, 0, 255).astype(np.float32), box_H_frame, (w, h), flags=inv,
                               borderMode=cv2.BORDER_REPLICATE)
    shown = cv2.warpPerspective((canvas.labels((x0, y0, x1, y1)) == k).astype(np.uint8), box_H_frame, (w, h),
                                flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
    shown = cv2.erode(shown, np.ones((7, 7), np.uint8), borderValue=0) > 0
    assert shown.sum() > 0.1 * w * h  # the frame shows over a good part of its view
    alone = resample.warp(image, box_H_frame, (x1 - x0, y1 - y0), canvas.interpolation).astype(np.float32)
    trip = cv2.warpPerspective(alone, box_H_frame, (w, h), flags=inv, borderMode=cv2.BORDER_REPLICATE)
    luma = np.array([0.299, 0.587, 0.114])
    ref = image.astype(np.float64) @ luma
    return _psnr(np.clip(back, 0, 255) @ luma, ref, shown), _psnr(np.clip(trip, 0, 255) @ luma, ref, shown)


def test_a_zooming_flight_gets_a_canvas_as_fine_as_its_sharpest_frames(flight) -> None:
    first, finest = _chained(flight, 'first'), _chained(flight, 'finest')
    for pipe in (first, finest):
        assert all(r.painted for r in pipe.records) and len(pipe.segments) == 1
    w, h = CFG.width, CFG.height
    # 'first': frame 0 is the plane; 'finest': the sharpest tenth of the 13 settling frames (zoom up to 1.85) map 1:1
    assert frame_scale(first.records[0].seg_H_frame, w, h) == pytest.approx(1.0)
    zoom = frame_scale(finest.records[0].seg_H_frame, w, h)
    assert zoom_at(CFG, 2.5) < zoom < zoom_at(CFG, 3.25), zoom
    # the same mosaic, sampled finer: every placement is the first one's, zoomed
    for a, b in zip(first.records, finest.records, strict=True):
        np.testing.assert_allclose(np.diag([zoom, zoom, 1.0]) @ a.seg_H_frame / a.seg_H_frame[2, 2],
                                   b.seg_H_frame / b.seg_H_frame[2, 2], rtol=1e-6, atol=1e-6)
    k = 15  # the sharpest frame (zoom 1.98), shown where it is newest: on the first frame's plane it shrinks to half
    assert frame_scale(first.records[k].seg_H_frame, w, h) < 0.6
    fid_first, trip_first = _fidelity(first, k, flight.frames[k].image)
    fid_finest, trip_finest = _fidelity(finest, k, flight.frames[k].image)
    assert fid_finest > trip_finest - 1.0, (fid_finest, trip_finest)
    assert fid_finest > fid_first + 3.0, (fid_finest, fid_first)   # the detail a canvas half as fine loses
    x0, y0, x1, y1 = finest.segments[0].canvas.bounds()
    fx0, fy0, fx1, fy1 = first.segments[0].canvas.bounds()
    assert (x1 - x0) == pytest.approx(zoom * (fx1 - fx0), abs=4)


def test_oversample_refines_the_first_frames_sampling_from_the_start(flight) -> None:
    first, over = _chained(flight, 'first'), _chained(flight, 'first', 1.5)
    for a, b in zip(first.records, over.records, strict=True):  # painted as they came, on a canvas 1.5x finer
        np.testing.assert_allclose(np.diag([1.5, 1.5, 1.0]) @ a.seg_H_frame / a.seg_H_frame[2, 2],
                                   b.seg_H_frame / b.seg_H_frame[2, 2], rtol=1e-6, atol=1e-6)


def test_the_georeference_follows_a_finer_canvas(flight, tmp_path) -> None:
    bag = write_flight(flight, tmp_path / 'bag')
    reports, figures = {}, {}
    for resolution in ('first', 'finest'):
        out = tmp_path / resolution
        reports[resolution] = process_input(bag, out, pipeline_config({'mosaic.resolution': resolution}), progress=False)
        figures[resolution] = evaluate_dir(out, bag / 'ground_truth.json')
    import rasterio
    with rasterio.open(tmp_path / 'finest' / 'mosaic.tif') as tif:
        t = tif.transform
        px = math.hypot(t.a, t.d), math.hypot(t.b, t.e)  # the pixel's sides (the re-anchoring turns it slightly)
    gsd = reports['finest']['georeferenced']['gsd_m_per_px']   # the raster's, times the re-anchoring's scale
    assert px == pytest.approx((gsd, gsd), rel=1e-9)
    assert json.loads((tmp_path / 'finest' / 'report.json').read_text())['georeferenced']['gsd_m_per_px'] == gsd
    # the first frame's ground sampling (its height over its focal length) is 'first''s; 'finest' is as fine as
    # the sharpest settling frames
    first_gsd = reports['first']['georeferenced']['gsd_m_per_px']
    assert first_gsd == pytest.approx(CFG.altitude_m / flight.frames[0].camera.fx, rel=0.05)
    assert first_gsd / zoom_at(CFG, 3.25) < gsd < first_gsd / zoom_at(CFG, 2.5), (gsd, first_gsd)
    # placed on the ground as well: the same error in metres (in mosaic pixels it grows with the zoom)
    fig, fig0 = figures['finest'], figures['first']
    assert fig['frames_registered'] == fig0['frames_registered'] == CFG.frames
    assert fig['georef_error_rms_m'] == pytest.approx(fig0['georef_error_rms_m'], rel=0.05), (fig, fig0)
    assert fig['corner_error_mean_px'] * gsd < 2.0 * fig0['corner_error_mean_px'] * first_gsd + 0.01, (fig, fig0)
