"""A DJI video with its .SRT beside it: the telemetry is found and used without --telemetry."""
from __future__ import annotations

import datetime as dt
from pathlib import Path

import pytest

from srmosaic_ros.config import PipelineConfig
from srmosaic_ros.app.evaluate import evaluate_dir
from srmosaic_ros.io.video import write_video
from srmosaic_ros.app.process import process_input
from srmosaic_ros.sim import SimConfig, save_truth, simulate

# a Mavic 3 block, as test/data/real/dji_srt/MAVIC3_first50.srt writes them
BLOCK = ('{n}\n{a} --> {b}\n<font size="28">FrameCnt: {n}, DiffTime: 250ms\n{when}\n[iso: 220] [shutter: 1/8000.0] '
         '[fnum: 3.2] [ev: 0] [ct: 5115] [color_md : default] [focal_len: 24.00] [latitude: {lat:.6f}] '
         '[longitude: {lon:.6f}] [rel_alt: {rel:.3f} abs_alt: {alt:.3f}] </font>\n\n')


def _clock(ns: int) -> str:
    s, ms = divmod(ns // 1_000_000, 1000)
    return f'{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d},{ms:03d}'


@pytest.fixture(scope='module')
def dji_video(tmp_path_factory) -> Path:
    flight = simulate(SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='line', frames=24, rate_hz=4.0,
                                fix_rate_hz=4.0, gust_deg=0.3, seed=5))  # a gimbal holds the camera nadir
    root = tmp_path_factory.mktemp('dji')
    write_video(root / 'DJI_0001.MP4', (f.image for f in flight.frames), fps=4.0)
    t0 = flight.frames[0].stamp_ns
    with open(root / 'DJI_0001.SRT', 'w') as handle:
        for k, (fix, truth) in enumerate(zip(flight.fixes, flight.truth.frames)):
            when = dt.datetime.fromtimestamp(fix.stamp_ns / 1e9, tz=dt.timezone.utc).strftime('%Y-%m-%d %H:%M:%S.%f')
            handle.write(BLOCK.format(n=k + 1, a=_clock(fix.stamp_ns - t0), b=_clock(fix.stamp_ns - t0 + 250_000_000),
                                      when=when[:-3], lat=fix.latitude_deg, lon=fix.longitude_deg,
                                      rel=float(truth.camera_enu_m[2]), alt=fix.altitude_m))
    save_truth(flight.truth, root / 'truth.json')
    # the GNSS error of the fixes written (m): simulated GNSS wanders, so no placement beats it by much
    import numpy as np

    d = [(f.latitude_deg - t.latitude_deg, f.longitude_deg - t.longitude_deg) for f, t in zip(flight.fixes,
                                                                                           flight.truth.frames)]
    d = np.array(d) * np.array([111_320.0, 111_320.0 * np.cos(np.radians(flight.truth.frames[0].latitude_deg))])
    (root / 'gnss_rms_m').write_text(str(float(np.sqrt(np.mean(np.sum(d**2, axis=1))))))
    return root


def test_srt_beside_a_video_georeferences_it(dji_video: Path, tmp_path: Path) -> None:
    report = process_input(dji_video / 'DJI_0001.MP4', tmp_path / 'hfov', PipelineConfig(), hfov_deg=60.0,
                           progress=False)
    meta = report['metadata']
    assert meta['source'] == 'DJI SRT (mavic3)' and meta['frames_with_position'] == 24
    # the take-off point: abs_alt - rel_alt, the simulated ground at 0 m (GNSS altitude sigma 5 m)
    assert abs(meta['ground_altitude']['m']) < 5.0
    assert report['georeferenced']['method'] == 'filter'
    figures = evaluate_dir(tmp_path / 'hfov', dji_video / 'truth.json')
    assert figures['frames_registered'] == 24
    gnss = float((dji_video / 'gnss_rms_m').read_text())
    # No Imu: the heading is learnt from the fixes against the registrations. The fused positions
    # beat the fixes themselves (measured 1.1 m against 3.2 m; seeds 1-8: 0.9-1.6 m against 2.7-3.8 m);
    # the frame corners carry the scale error of a height known only from the GNSS altitude (sigma
    # 5 m at 100 m: corners 57 m from the centre move 3 m; measured 1.7 m RMS, seeds 1-8 1.3-4.1 m;
    # 3.5-15 m while an unknown heading's sigma points wrapped, see PoseUkf.angle_sd_limit_rad)
    assert figures['pose_rmse_horizontal_m'] < 0.75 * gnss, (figures['pose_rmse_horizontal_m'], gnss)
    assert figures['georef_error_rms_m'] < 6.0, figures['georef_error_rms_m']
    # without intrinsics the same telemetry places the mosaic by its geotags
    report = process_input(dji_video / 'DJI_0001.MP4', tmp_path / 'plain', PipelineConfig(), progress=False)
    assert report['georeferenced']['method'] == 'geotags'


def test_a_broken_srt_is_named_and_the_video_still_processed(dji_video: Path, tmp_path: Path) -> None:
    import shutil

    folder = tmp_path / 'v'
    folder.mkdir()
    shutil.copy(dji_video / 'DJI_0001.MP4', folder / 'DJI_0001.MP4')
    (folder / 'DJI_0001.srt').write_text('1\n00:00:00,000 --> 00:00:00,250\n<font size="28">no telemetry here</font>\n')
    report = process_input(folder / 'DJI_0001.MP4', tmp_path / 'out', PipelineConfig(), progress=False)
    assert report['frames_registered'] == 24
    assert report['metadata']['problems'].get('srt_unusable') == 1
    assert report['georeferenced'] is None

