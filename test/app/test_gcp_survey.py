"""`srmosaic process FOLDER` with ground control points (app/ground_control.py): simulated stills
without any GPS and an OpenDroneMap gcp_list.txt of targets planted on the simulated ground. The
control alone puts the survey on the ground; the check points, a wrong target and a contradicting
pick are reported in report.json ``gcp``."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from srmosaic_ros.app.process import process_input
from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.georef.geodetic import LocalTangentPlane
from srmosaic_ros.errors import InputError
from srmosaic_ros.sim import SimConfig, save_truth, simulate
from srmosaic_ros.sim.record import write_stills_folder
from cli_runner import run_cli


@pytest.fixture(scope='module')
def survey(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[str, np.ndarray, list]]]:
    """12 stills 20 m apart along a line, 100 m up, no GPS (the telemetry file removed); targets every
    25 m along the track, 15 m either side of it, each with the stills that see it: (folder, [(name,
    east-north-up (3,) of the simulation's plane, [(image, x, y)])])."""
    flight = simulate(SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='line', frames=12, rate_hz=0.5,
                                speed_m_s=10.0, gust_deg=1.0, seed=4))
    root = tmp_path_factory.mktemp('gcp')
    folder = write_stills_folder(flight, root / 'survey')
    (folder / 'telemetry_from_exif.csv').unlink()
    save_truth(flight.truth, root / 'truth.json')
    truth = flight.truth
    enu_H = [truth.enu_H_world_px @ f.world_px_H_frame for f in truth.frames]
    centres = np.array([(H @ [159.5, 119.5, 1.0])[:2] / (H @ [159.5, 119.5, 1.0])[2] for H in enu_H])
    start, end = centres[0], centres[-1]
    along = (end - start) / np.linalg.norm(end - start)
    across = np.array([-along[1], along[0]])
    targets = []
    for t, d in enumerate(np.arange(10.0, np.linalg.norm(end - start) - 5.0, 25.0)):
        X = start + d * along + (15.0 if t % 2 else -15.0) * across
        seen = []
        for k, H in enumerate(enu_H):
            q = np.linalg.inv(H) @ np.array([X[0], X[1], 1.0])
            x, y = q[:2] / q[2]
            if 10 <= x <= 309 and 10 <= y <= 229:
                seen.append((f'IMG_{k:04d}.png', float(x), float(y)))
        targets.append((f'gcp{t:02d}', np.array([X[0], X[1], 0.0]), seen))
    return root, targets


def _write_gcp(path: Path, root: Path, targets, *, moved: dict[str, tuple[float, float]] | None = None) -> Path:
    """The targets as EPSG:4326 (longitude, latitude) lines, ``moved`` ones shifted east/north by metres."""
    from srmosaic_ros.sim.truth import load_truth

    ltp = LocalTangentPlane(*load_truth(root / 'truth.json').origin)
    lines = ['EPSG:4326']
    for name, enu, seen in targets:
        enu = enu + np.array([*(moved or {}).get(name, (0.0, 0.0)), 0.0])
        lat, lon, _ = ltp.geodetic_from_enu(enu[None, :])
        lines += [f'{float(lon[0]):.9f} {float(lat[0]):.9f} 0.0 {x:.2f} {y:.2f} {image} {name}' for image, x, y in seen]
    path.write_text('\n'.join(lines) + '\n')
    return path


def test_control_alone_puts_stills_without_gps_on_the_ground_and_check_points_measure_it(survey, tmp_path: Path) -> None:
    root, targets = survey
    assert len(targets) >= 7 and all(len(seen) >= 2 for _, _, seen in targets)
    _write_gcp(root / 'survey' / 'gcp_list.txt', root, targets)  # found in the folder
    try:
        run = run_cli('process', str(root / 'survey'), '--out', str(tmp_path / 'out'), '--check-points', '2', '--no-progress')
    finally:
        (root / 'survey' / 'gcp_list.txt').unlink()
    assert run.returncode == 0, run.stderr
    report = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert 'ground control: 2 check target(s)' in run.stdout and '(check): ' in run.stdout, run.stdout
    assert report['georeferenced'] is not None and report['georeferenced']['epsg'] // 100 in (326, 327)
    assert 'not_georeferenced_reason' not in report
    # no GPS and no height: the scale's prior is the nominal height, but the control sets the scale
    assert report['survey']['scale_is_guess'] is False and 'ground control points set' in report['survey']['scale_source']
    assert (tmp_path / 'out' / 'mosaic.tif').is_file()
    gcp = report['gcp']
    assert gcp['placed_survey'] and len(gcp['check']) == 2 and len(gcp['control']) == len(targets) - 2
    assert gcp['rejected'] == [] and gcp['check_targets_measured'] == 2
    assert gcp['wrong_point_test'] == 'run'  # the stills place each target left out within a few sd
    # the simulated stills register to a fraction of a pixel: the check points land within a GSD or two
    assert gcp['check_rms_gsd'] < 3.0, gcp
    assert gcp['check_rms_m'] == pytest.approx(gcp['check_rms_gsd'] * gcp['gsd_m_per_px'], abs=0.01 * gcp['gsd_m_per_px'])
    for p in gcp['points']:
        assert p['role'] in ('control', 'check') and p['error_m'] is not None
        assert all(o['control'] == (p['role'] == 'control') for o in p['observations'])
    json.dumps(report, allow_nan=False)


def test_a_wrong_target_is_rejected_and_a_contradicting_pick_named(survey, tmp_path: Path) -> None:
    root, targets = survey
    wrong = targets[3][0]
    image, x, y = targets[1][2][0]  # a second name on target 1's pick: which one the stills agree with is told
    path = _write_gcp(tmp_path / 'gcp.txt', root, targets, moved={wrong: (6.0, -4.0)})
    lon, lat = path.read_text().splitlines()[1].split()[:2]  # 'bogus' at target 0, tens of metres from the pick
    with path.open('a') as handle:
        handle.write(f'{lon} {lat} 0.0 {x + 1.0:.2f} {y:.2f} {image} bogus\n')
    report = process_input(root / 'survey', tmp_path / 'out', pipeline_config(), progress=False,
                           gcp_file=tmp_path / 'gcp.txt', check_points='0')
    gcp = report['gcp']
    assert {r['name'] for r in gcp['rejected']} == {wrong}
    assert all(r['error_m'] == pytest.approx(math.hypot(6.0, 4.0), abs=1.0) for r in gcp['rejected'])
    assert gcp['control_rms_gsd'] < 3.0, gcp  # the others are not bent by it
    (pick,) = gcp['contradicting_picks']
    assert pick['image'] == image and pick['agrees_with'] == targets[1][0], pick


def test_ground_control_is_refused_where_it_cannot_be_used(survey, tmp_path: Path) -> None:
    root, targets = survey
    with pytest.raises(InputError, match='no gcp_list.txt inside or beside it'):
        process_input(root / 'survey', tmp_path / 'a', pipeline_config(), progress=False, check_points='2')
    with pytest.raises(InputError, match='--gcp .*: no such file'):
        process_input(root / 'survey', tmp_path / 'b', pipeline_config(), progress=False, gcp_file=tmp_path / 'none.txt')
    path = _write_gcp(tmp_path / 'gcp.txt', root, targets)
    with pytest.raises(InputError, match='--check-points: nope not in the GCP file'):
        process_input(root / 'survey', tmp_path / 'c', pipeline_config(), progress=False, gcp_file=path,
                      check_points='gcp00,nope')
    with pytest.raises(InputError, match='hold out at most'):
        process_input(root / 'survey', tmp_path / 'd', pipeline_config(), progress=False, gcp_file=path,
                      check_points=str(len(targets) - 1))


def test_check_points_by_count_are_inside_the_control_and_spread() -> None:
    """A 3 x 3 grid of targets 10 m apart plus one far out: the first check point is the centre, the
    next ones the targets off the hull's corners, spread; then the corners; a target whose picks all
    contradict others is chosen last."""
    from srmosaic_ros.app.ground_control import check_point_names

    xy = np.array([[x, y] for y in (0.0, 10.0, 20.0) for x in (0.0, 10.0, 20.0)] + [[60.0, 10.0]])
    names = [f't{k}' for k in range(len(xy))]
    usable = [True] * len(xy)
    assert check_point_names('1', names, xy, usable) == ['t4']
    three = check_point_names('3', names, xy, usable)
    assert three[0] == 't4' and len(set(three)) == 3 and set(three) <= {'t1', 't3', 't4', 't5', 't7'}
    six = check_point_names('6', names, xy, usable)
    assert set(six[:5]) == {'t1', 't3', 't4', 't5', 't7'} and six[5] == 't9'  # the corner farthest from them
    usable[4] = False
    assert check_point_names('1', names, xy, usable) != ['t4']
    assert check_point_names('gcp, t2 ,t3'.replace('gcp,', ''), names, xy, usable) == ['t2', 't3']
    assert check_point_names(None, names, xy, usable) == [] and check_point_names('0', names, xy, usable) == []


def test_the_command_line_refuses_a_malformed_gcp_file_for_a_bag_in_one_line(tmp_path: Path) -> None:
    from repo_paths import REPO

    (tmp_path / 'gcp_list.txt').write_text('EPSG:32611\n')
    run = run_cli('process', str(REPO / 'bags' / 'demo'), '--out', str(tmp_path / 'out'), '--gcp', str(tmp_path / 'gcp_list.txt'),
                  '--no-progress')
    assert run.returncode != 0
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and 'no observations after the coordinate system line' in lines[0], run.stderr
    assert not (tmp_path / 'out' / 'report.json').exists()


def test_the_report_names_the_stills_that_no_control_could_place(tmp_path: Path) -> None:
    """Two stills, the second in no pair and seeing only a check point: the report says why it is
    not placed and what to do."""
    from types import SimpleNamespace

    from srmosaic_ros.app.ground_control import SurveyControl
    from srmosaic_ros.core.survey.global_align import SurveySolution

    K = np.array([[100.0, 0, 49.5], [0, 100.0, 49.5], [0, 0, 1]])
    stills = [SimpleNamespace(file=Path(f'IMG_{k}.jpg'), size=(100, 100), K=K) for k in range(2)]
    (tmp_path / 'gcp.txt').write_text('EPSG:32611\n500000 4000000 0 10 10 IMG_0.jpg a\n'
                                      '500010 4000000 0 90 10 IMG_0.jpg b\n500020 4000000 0 50 50 IMG_1.jpg c\n')
    ground = SurveyControl.load(tmp_path / 'gcp.txt', stills, 0, (0.0, 0.0), 'c')
    assert ground.epsg == 32611 and ground.check == ['c']
    G = np.full((2, 3, 3), np.nan)
    G[0] = np.array([[10.0, 0, ground.control.ground_m[:2, 0].mean()], [0, -10.0, ground.control.ground_m[0, 1] - 4.0],
                     [0, 0, 1]])
    sol = SurveySolution(G, ['registration', ''], np.zeros(0), np.zeros(0, bool), {'control_placed_survey': True},
                         ground.control.use.copy())
    report = ground.report(sol, 0.1)
    assert report['warnings'][-1].startswith('1 stills not placed') and 'IMG_1.jpg' in report['warnings'][-1]
    assert report['wrong_point_test'] == 'not run (fewer than four control targets)'
    (point,) = [p for p in report['points'] if p['name'] == 'c']
    assert point['role'] == 'check' and point['error_m'] is None and point['note'].endswith('are not placed')
