"""End to end on real footage: what `srmosaic inspect` says, what `process` does with it, and the
truth-free figures of `evaluate` (test/data/real: copies of ../shared/data/real files)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from srmosaic_ros.config import PipelineConfig
from srmosaic_ros.app.evaluate_real import evaluate_real
from srmosaic_ros.app.inspect_tool import format_inspection, inspect_input
from srmosaic_ros.app.process import process_input
from repo_paths import REPO, TEST_DATA
from cli_runner import run_cli

REAL = TEST_DATA / 'real'
APHILL = REAL / 'klv' / 'aphill_short.ts'


@pytest.fixture(scope='module')
def aphill_out(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('aphill')
    process_input(APHILL, out, PipelineConfig(), progress=False)
    return out


def test_klv_video_is_georeferenced_where_its_klv_says(aphill_out: Path) -> None:
    """An oblique turret video 1.7 km from its target: placed by the filter from the KLV alone,
    ortho-rectified on the map, its frame centres within 20 m RMS of the KLV's own (measured 14.9 m;
    the KLV centres themselves scatter over 70 m while the imagery stares at one point)."""
    report = json.loads((aphill_out / 'report.json').read_text())
    assert report['frames_registered'] == 48 and len(report['segments']) == 1
    assert report['video']['frames_deinterlaced'] == 48  # an interlaced stream: its top fields
    meta = report['metadata']
    assert meta['source'] == 'MISB KLV (EG0104)'
    assert meta['frames_with_position'] == meta['frames_with_attitude'] == meta['frames_with_intrinsics'] == 48
    assert meta['intrinsics_source'] == 'KLV sensor horizontal/vertical field of view'
    assert meta['ground_altitude']['source'].startswith('KLV slant range')
    geo = report['georeferenced']
    assert geo['method'] == 'filter' and geo['epsg'] == 32618
    # the ground sampling of a 0.8 deg lens at 1.73 km: range / f = 1730 / 51565 = 0.034 m
    assert 0.025 < geo['gsd_m_per_px'] < 0.045
    figures = evaluate_real(aphill_out, progress=False)
    assert figures['fraction_in_main'] == 1.0
    # best view (the default): each frame agrees with the mosaic up to the frames' own noise and
    # compression (two frames of the same ground correlate at about 0.92), as sharp as the frames
    assert figures['ncc_median'] > 0.91, figures['ncc_median']        # measured 0.929 (0.929-0.947 over RANSAC seeds; combed 0.920-0.930)
    assert figures['sharpness_median'] > 0.95, figures                # measured 1.00
    assert figures['position']['rms_m'] < 20.0, figures['position']    # measured 14.9 m


def test_inspect_names_what_each_file_carries() -> None:
    info = inspect_input(APHILL)
    assert info['klv']['standards'] == {'EG0104': 48} and info['metadata_source'] == 'MISB KLV'
    assert info['plan'].startswith('georeferenced through the filter')
    assert info['interlaced'].startswith('yes')
    lines = format_inspection(info)
    assert any('klv' in line for line in lines) and lines[-1].startswith('  process will:')
    none = inspect_input(REAL / 'klv' / 'h264_no_klv.ts')
    assert none['klv']['packets'] == 0 and 'GPS positions (no KLV, SRT or GPMF)' in none['missing']
    assert 'not georeferenced' in none['plan']
    stills = inspect_input(REAL / 'exif')
    assert stills['camera']['model'] == 'Canon PowerShot SX260 HS' and stills['camera']['fx_px'] == pytest.approx(1452.18)
    assert stills['plan'].startswith('aligned globally') and 'no gimbal angles' in stills['plan']


def test_a_video_without_metadata_says_why_it_is_not_georeferenced(tmp_path: Path) -> None:
    report = process_input(REAL / 'klv' / 'h264_no_klv.ts', tmp_path, PipelineConfig(), progress=False)
    assert report['georeferenced'] is None
    assert report['not_georeferenced_reason'].startswith('the input carries no GPS positions')
    assert report['metadata']['source'] == 'none'


def test_cli_inspect_and_truth_free_evaluate(aphill_out: Path) -> None:
    run = run_cli('inspect', str(APHILL))
    assert run.returncode == 0, run.stderr
    assert 'MISB KLV' in run.stdout and 'process will:' in run.stdout
    run = run_cli('evaluate', str(aphill_out), '--no-progress')
    assert run.returncode == 0, run.stderr
    assert 'frames in main mosaic: 48/48' in run.stdout and 'position vs metadata' in run.stdout
    run = run_cli('inspect', str(REAL / 'nothing_here.ts'))
    assert run.returncode == 2 and 'does not exist' in run.stderr and run.stderr.count('\n') == 1


def test_klv_packets_failing_their_checksum_are_counted_and_left_out(tmp_path: Path) -> None:
    """A damaged copy of the ST0601 fixture: one packet's checksum fails; it is left out, counted by
    inspect and by process's report, and the video is processed."""
    from srmosaic_ros.io.klv import read_klv

    data = bytearray((REAL / 'klv' / 'h264_klv.ts').read_bytes())
    key = bytes.fromhex('060E2B34020B01010E01030101000000')
    at = data.find(key, data.find(key) + 1)  # the second ST0601 packet
    data[at + 40] ^= 0xFF
    damaged = tmp_path / 'damaged.ts'
    damaged.write_bytes(bytes(data))
    track = read_klv(damaged)
    assert track.bad_checksum == 1 and len(track.records) == track.packets - 1
    assert inspect_input(damaged)['klv']['bad_checksum'] == 1
    report = process_input(damaged, tmp_path / 'out', PipelineConfig(), progress=False)
    assert report['frames_in'] > 0
    assert report['metadata']['problems'].get('klv_bad_checksum') == 1


def test_inspect_a_bag_lists_topics_and_what_process_uses() -> None:
    demo = inspect_input(REPO / 'bags' / 'demo')
    assert demo['kind'] == 'bag' and demo['used']['fix'] == '/fix'
    assert demo['plan'].startswith('georeferenced through the filter')
    talker = inspect_input(REAL / 'bags' / 'rosbag2' / 'galactic' / 'rosbag2_py' / 'resources' / 'talker')
    assert talker['messages'] == '20 read of 20 in the metadata' and talker['warnings']
    assert talker['plan'].startswith('refused: ') and 'no image topic' in talker['plan']
