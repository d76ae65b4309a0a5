"""Ground control for the mosaic of a bag or a video (app/video_control.py): a simulated flight, its
frames written by `srmosaic frames`, targets planted on the simulated ground and picked in the frames
that see them (named as `srmosaic frames` names the files). The control alone places a flight
without GNSS, check points measure it against their surveyed positions, a wrong target is left out."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from srmosaic_ros.app.frame_names import frame_file_name, stamp_of_name
from srmosaic_ros.core.georef.geodetic import LocalTangentPlane
from srmosaic_ros.sim import SimConfig, simulate
from srmosaic_ros.sim.record import write_flight
from cli_runner import run_cli

W, H = 320, 240
NO_TELEMETRY = ('--fix-topic', '', '--imu-topic', '')


@pytest.fixture(scope='module')
def flight(tmp_path_factory: pytest.TempPathFactory):
    """(bag, truth, targets): a 40-frame line at 100 m; targets every 9 m along it, 12 m either side,
    each [(name, east-north (2,) of the simulation's plane, [(frame index, x, y)])] in every 6th frame
    that sees it."""
    sim = simulate(SimConfig(width=W, height=H, world_gsd_m=0.3, trajectory='line', frames=40, rate_hz=5.0,
                             speed_m_s=8.0, gust_deg=1.0, seed=11))
    bag = write_flight(sim, tmp_path_factory.mktemp('vgcp') / 'bag')
    truth = sim.truth
    enu_H = [truth.enu_H_world_px @ f.world_px_H_frame for f in truth.frames]
    centre = np.array([(W - 1) / 2.0, (H - 1) / 2.0, 1.0])
    centres = np.array([(M @ centre)[:2] / (M @ centre)[2] for M in enu_H])
    start, end = centres[0], centres[-1]
    along = (end - start) / np.linalg.norm(end - start)
    across = np.array([-along[1], along[0]])
    targets = []
    for t, d in enumerate(np.arange(3.0, np.linalg.norm(end - start) - 2.0, 9.0)):
        X = start + d * along + (12.0 if t % 2 else -12.0) * across
        seen = []
        for k in range(0, len(enu_H), 6):
            q = np.linalg.inv(enu_H[k]) @ np.array([X[0], X[1], 1.0])
            x, y = q[:2] / q[2]
            if 8 <= x <= W - 9 and 8 <= y <= H - 9:
                seen.append((k, float(x), float(y)))
        if seen:
            targets.append((f't{t:02d}', X, seen))
    return bag, truth, targets


def _gcp_file(path: Path, truth, targets, *, moved: dict[str, float] | None = None) -> Path:
    """The targets in EPSG:4326, picks named by frame file names; ``moved``: name -> metres east."""
    ltp = LocalTangentPlane(*truth.origin)
    lines = ['EPSG:4326']
    for name, en, seen in targets:
        e = en + np.array([(moved or {}).get(name, 0.0), 0.0])
        lat, lon, _ = ltp.geodetic_from_enu(np.array([[e[0], e[1], 0.0]]))
        lines += [f'{float(lon[0]):.9f} {float(lat[0]):.9f} 0.0 {x:.2f} {y:.2f} '
                  f'{frame_file_name(k, truth.frames[k].stamp_ns)} {name}' for k, x, y in seen]
    path.write_text('\n'.join(lines) + '\n')
    return path


def test_frames_are_written_named_by_the_stamps_process_reads(flight, tmp_path: Path) -> None:
    bag, truth, _ = flight
    run = run_cli('frames', str(bag), str(tmp_path / 'frames'), '--every', '10')
    assert run.returncode == 0, run.stderr
    files = sorted((tmp_path / 'frames').iterdir())
    assert [stamp_of_name(f.name) for f in files] == [truth.frames[k].stamp_ns for k in range(0, 40, 10)]
    assert files[1].name == frame_file_name(10, truth.frames[10].stamp_ns)
    import cv2

    assert cv2.imread(str(files[0])).shape == (H, W, 3)
    assert stamp_of_name('33333333') == 33333333 and stamp_of_name('frame_000001_5ns.jpg') == 5
    assert stamp_of_name('IMG_0001.JPG') is None


def test_control_places_a_flight_without_gnss_and_check_points_measure_it(flight, tmp_path: Path) -> None:
    bag, truth, targets = flight
    assert len(targets) >= 6, len(targets)
    gcp = _gcp_file(tmp_path / 'gcp_list.txt', truth, targets)
    out = tmp_path / 'out'
    run = run_cli('process', str(bag), '--out', str(out), '--gcp', str(gcp), '--check-points', '2', '--no-progress',
                  *NO_TELEMETRY)
    assert run.returncode == 0, run.stderr
    report = json.loads((out / 'report.json').read_text())
    g = report['gcp']
    assert g['placed_mosaic'] == 'similarity' and len(g['check']) == 2 and not g['rejected'], g
    assert report['georeferenced']['method'] == 'ground control (similarity)'
    assert g['control_targets_measured'] >= 4 and g['check_targets_measured'] == 2
    # the check points never entered the fit: within a few ground pixels of their surveyed positions
    assert g['check_rms_gsd'] is not None and g['check_rms_gsd'] < 3.0, g
    assert 'ground control: 2 check target(s)' in run.stdout, run.stdout
    import rasterio

    with rasterio.open(out / 'mosaic.tif') as ds:  # GDAL reads the raster the control placed
        assert ds.crs.to_epsg() == g['epsg']
        assert np.allclose(ds.transform.to_gdal(), report['georeferenced']['geotransform'], rtol=1e-9, atol=1e-6)
        assert abs(np.hypot(ds.transform.a, ds.transform.d) - g['gsd_m_per_px']) < 1e-6 * g['gsd_m_per_px']
    # the placement is the control's, not a default: the GSD the targets give is the simulation's own
    assert abs(g['gsd_m_per_px'] / report['georeferenced']['gsd_m_per_px'] - 1.0) < 1e-9


def test_control_refines_a_gnss_placed_mosaic_and_a_wrong_target_is_left_out(flight, tmp_path: Path) -> None:
    bag, truth, targets = flight
    wrong = targets[len(targets) // 2][0]
    gcp = _gcp_file(tmp_path / 'gcp_list.txt', truth, targets, moved={wrong: 15.0})
    out = tmp_path / 'out'
    run = run_cli('process', str(bag), '--out', str(out), '--gcp', str(gcp), '--no-progress')
    assert run.returncode == 0, run.stderr
    report = json.loads((out / 'report.json').read_text())
    g = report['gcp']
    assert [r['name'] for r in g['rejected']] == [wrong], g['rejected']
    assert report['georeferenced']['placed_before_control'] == 'filter'
    point = next(p for p in g['points'] if p['name'] == wrong)
    assert point['error_m'] > 10.0 and 'wrong point' in point['note']
    assert any(wrong in w for w in g['warnings'])  # report.html lists it with the run's warnings
    assert g['control_rms_gsd'] < 3.0, g


def test_picks_that_name_no_frame_or_control_without_a_file_are_refused(flight, tmp_path: Path) -> None:
    bag, truth, targets = flight
    bad = tmp_path / 'gcp_list.txt'
    bad.write_text('EPSG:32611\n500000 4000000 0 10 10 IMG_0001.JPG a\n500010 4000000 0 20 10 IMG_0002.JPG b\n')
    run = run_cli('process', str(bag), '--out', str(tmp_path / 'out'), '--gcp', str(bad), '--no-progress', *NO_TELEMETRY)
    assert run.returncode == 2 and 'names no frame' in run.stderr and 'srmosaic frames' in run.stderr, run.stderr
    run = run_cli('process', str(bag), '--out', str(tmp_path / 'out2'), '--check-points', '2', '--no-progress')
    assert run.returncode == 2 and '--gcp FILE' in run.stderr, run.stderr
    assert not (tmp_path / 'out2' / 'report.json').exists()
