"""`srmosaic process` and `srmosaic evaluate` as a user runs them, on the bundled demo bag and bad input."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from cli_runner import run_cli
from repo_paths import REPO

from srmosaic_ros.io.mosaic_files import FRAMES_CSV_HEADER, FRAMES_CSV_META, FRAMES_CSV_PLACED_BY, read_frames_csv

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'


def srmosaic_process(*args: str) -> subprocess.CompletedProcess:
    """A real `srmosaic` process, as a user runs it."""
    return subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', *args], capture_output=True, text=True,
                          timeout=600)


srmosaic = run_cli  # what a command refuses, and evaluate's figures: in this process (test/cli_runner.py)


@pytest.fixture(scope='module')
def demo_out(demo_run) -> Path:
    """The demo bag processed with the defaults, once for the session (test/flights.py): the tests
    only read it (or copy it). test_resume.py runs `srmosaic process` on it as a user does."""
    return demo_run[0]


def test_process_writes_the_file_contracts(demo_out):
    with open(demo_out / 'frames.csv', newline='') as handle:
        rows = list(csv.reader(handle))
    assert rows[0][:13] == FRAMES_CSV_HEADER  # the contract's columns first, extras only at the end
    assert rows[0][13:] == [*FRAMES_CSV_META, FRAMES_CSV_PLACED_BY]
    assert len(rows) == 61
    assert {r[-1] for r in rows[1:] if r[1] == '1'} == {'registration'}
    report = json.loads((demo_out / 'report.json').read_text())
    for key in ('frames_in', 'frames_registered', 'wall_s', 'peak_rss_mb'):
        assert key in report
    assert report['frames_in'] == 60
    assert report['frames_registered'] >= 58
    assert 0 < report['wall_s'] < 300
    assert report['startup_s'] > 0  # the process's start-up, which wall_s leaves out
    mosaic = cv2.imread(str(demo_out / 'mosaic.png'), cv2.IMREAD_UNCHANGED)
    assert mosaic.ndim == 3 and mosaic.shape[2] == 4
    # Every registered frame's footprint lies inside mosaic.png, and its centre pixel is covered.
    for row in read_frames_csv(demo_out / 'frames.csv'):
        if not row['ok']:
            continue
        c = row['mosaic_H_frame'] @ np.array([319.5, 239.5, 1.0])
        x, y = c[:2] / c[2]
        assert 0 <= x < mosaic.shape[1] and 0 <= y < mosaic.shape[0]
        assert mosaic[int(round(y)), int(round(x)), 3] == 255


def test_process_mosaic_matches_the_ground(demo_out):
    """The mosaic's pixels show the ground: compare frame 30 re-rendered from mosaic.png with the bag's frame."""
    from srmosaic_ros.io.bags import read_flight
    from srmosaic_ros.core.types import Frame

    rows = read_frames_csv(demo_out / 'frames.csv')
    frames = [f for f in read_flight(DEMO) if isinstance(f, Frame)]
    mosaic = cv2.cvtColor(cv2.imread(str(demo_out / 'mosaic.png'), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    k = 30
    back = cv2.warpPerspective(mosaic, rows[k]['mosaic_H_frame'], (640, 480),
                               flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    diff = np.abs(back[20:-20, 20:-20].astype(float) - frames[k].image[20:-20, 20:-20].astype(float))
    assert diff.mean() < 6.0  # noise sigma 2 + JPEG + blending of overlapping frames


def test_evaluate_reports_corner_error_under_2px(demo_out):
    run = srmosaic('evaluate', str(demo_out), '--truth', str(DEMO / 'ground_truth.json'), '--json')
    assert run.returncode == 0, run.stderr
    figures = json.loads(run.stdout)
    assert figures['fraction_registered'] > 0.95
    assert figures['corner_error_mean_px'] < 2.0
    assert figures['pair_corner_error_mean_px'] < 0.3


def test_missing_bag_is_a_clear_error(tmp_path):
    run = srmosaic_process('process', str(tmp_path / 'nope'), '--out', str(tmp_path / 'out'))
    assert run.returncode == 2
    assert 'error' in run.stderr and 'Traceback' not in run.stderr
    assert not (tmp_path / 'out' / 'mosaic.png').exists()


def test_truncated_bag_is_a_clear_error(tmp_path):
    bag = tmp_path / 'cut'
    shutil.copytree(DEMO, bag)
    db = next(bag.glob('*.db3'))
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 2])
    run = srmosaic('process', str(bag), '--out', str(tmp_path / 'out'))
    assert run.returncode == 2, run.stderr
    assert 'Traceback' not in run.stderr
    assert str(bag) in run.stderr or 'cut' in run.stderr


def test_missing_topic_names_the_way_out(tmp_path):
    run = srmosaic('process', str(DEMO), '--out', str(tmp_path / 'out'), '--image-topic', '/nope')
    assert run.returncode == 2
    assert '--image-topic' in run.stderr and 'Traceback' not in run.stderr


def test_bad_params_file_refused(tmp_path):
    params = tmp_path / 'p.yaml'
    params.write_text('/**:\n  ros__parameters:\n    registration:\n      ratioo: 0.7\n')
    run = srmosaic('process', str(DEMO), '--out', str(tmp_path / 'out'), '--params', str(params))
    assert run.returncode == 2
    assert 'unknown parameter' in run.stderr


@pytest.mark.parametrize('case', ['file', 'under_file', 'unwritable', 'long_name'])
def test_an_unusable_out_is_refused_before_any_work(tmp_path: Path, case: str) -> None:
    """--out that is a file, lies under one, cannot be written or has a 256-byte name: one line,
    exit 2, before the input is processed (it used to end in a traceback after every frame)."""
    a_file = tmp_path / 'report.txt'
    a_file.write_text('keep me')
    out = {'file': a_file, 'under_file': a_file / 'out', 'unwritable': Path('/proc/srmosaic-out'),
           'long_name': tmp_path / ('x' * 256)}[case]
    run = srmosaic('process', str(DEMO), '--out', str(out), '--no-progress')
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('srmosaic process: error: --out '), run.stderr
    assert 'Traceback' not in run.stderr and a_file.read_text() == 'keep me'
    assert 'frames in mosaic.png' not in run.stdout


def test_an_empty_folder_says_what_inputs_are_accepted(tmp_path: Path) -> None:
    (tmp_path / 'notes.txt').write_text('x')
    run = srmosaic('process', str(tmp_path), '--out', str(tmp_path / 'out'), '--no-progress')
    assert run.returncode == 2 and 'nor a folder of stills' in run.stderr and 'notes.txt' in run.stderr


@pytest.mark.parametrize('rate', ['nan', 'inf', '0', '-1', 'fast'])
def test_play_refuses_a_rate_that_is_not_a_positive_number(rate: str) -> None:
    run = srmosaic('play', str(DEMO), '--rate', rate)
    assert run.returncode == 2 and 'argument --rate' in run.stderr


@pytest.mark.parametrize('case', ['launch_params_yaml', 'launch_params_not_ros', 'launch_description_yaml',
                                  'launch_params_rcl', 'record_tiles_file', 'evaluate_cut_frames_csv'])
def test_bad_files_are_refused_in_one_line(tmp_path: Path, demo_out: Path, case: str) -> None:
    """Each of these ended in a traceback (rcl's for the parameter files, NotADirectoryError for
    record-tiles, TypeError for a frames.csv cut mid-row); now one line naming the file, exit 2."""
    garbage = tmp_path / 'garbage.yaml'
    garbage.write_text('garbage: [unclosed\n')
    not_ros = tmp_path / 'plain.yaml'
    not_ros.write_text('a: 1\n')
    mixed = tmp_path / 'mixed.yaml'  # valid YAML, refused by rcl: a list of mixed types
    mixed.write_text('/**:\n  ros__parameters:\n    live:\n      output_dir: [1, "x"]\n')
    a_file = tmp_path / 'afile'
    a_file.write_text('keep me')
    cut = tmp_path / 'cut'
    shutil.copytree(demo_out, cut)
    text = (cut / 'frames.csv').read_text()
    (cut / 'frames.csv').write_text(text[: len(text) * 6 // 10])
    args, expect = {
        'launch_params_yaml': (['launch', '--params', str(garbage)], 'is not valid YAML: expected'),
        'launch_params_not_ros': (['launch', '--params', str(not_ros)], "section 'a' has no ros__parameters"),
        'launch_description_yaml': (['launch', str(garbage)], 'launch description'),
        'launch_params_rcl': (['launch', '--params', str(mixed)], 'ROS arguments refused'),
        'record_tiles_file': (['record-tiles', str(a_file)], 'is a file, not a directory'),
        'evaluate_cut_frames_csv': (['evaluate', str(cut)], 'is cut short or damaged'),
    }[case]
    # launch parses ROS arguments with rcl: a process of its own, as it would be
    run = srmosaic_process(*args) if args[0] == 'launch' else srmosaic(*args)
    assert run.returncode == 2, run.stderr
    assert 'Traceback' not in run.stderr, run.stderr
    # rcl logs its own "[ERROR] ... Failed to parse global arguments" before ours
    lines = [ln for ln in run.stderr.strip().splitlines() if '[rcl]' not in ln]
    assert len(lines) == 1 and expect in lines[0], run.stderr
    assert a_file.read_text() == 'keep me'


def _limited(limit_bytes: int):
    """preexec_fn: a file size limit of ``limit_bytes`` (RLIMIT_FSIZE), its signal ignored so that
    writes past it fail with EFBIG as on a full disk (ENOSPC), without needing a small filesystem."""
    import resource
    import signal

    def pre() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return pre


@pytest.mark.parametrize(('limit', 'expect'), [(300_000, 'could not be written'), (1_300_000, 'with its overviews')])
def test_a_full_disk_keeps_the_earlier_run(tmp_path: Path, demo_out: Path, limit: int, expect: str) -> None:
    """Writes failing mid-file (the GeoTIFF's blocks, or its overviews) used to crash GDAL (SIGSEGV:
    no message, the staging folder and the lock left behind). Now one line, exit 2, and the earlier
    complete run in --out byte for byte as it was."""
    import hashlib

    out = tmp_path / 'out'
    shutil.copytree(demo_out, out)

    def digest() -> dict[str, str]:
        return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.iterdir()) if p.is_file()}

    before = digest()
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', 'process', str(DEMO), '--out', str(out),
                          '--no-progress'], capture_output=True, text=True, timeout=600, preexec_fn=_limited(limit))
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    last = run.stderr.strip().splitlines()[-1]
    # mosaic.png is streamed while mosaic.tif is written beside it (io/outputs.write_canvas, threads): either
    # may meet the limit first, and the line names the one that did
    assert last.startswith(('srmosaic process: error: mosaic.tif', 'srmosaic process: error: mosaic.png')), last
    assert expect in last and 'free space' in last, last
    assert 'Traceback' not in run.stderr and 'Fatal Python error' not in run.stderr
    assert digest() == before
    assert not list(out.glob('.staging-*')) and not (out / '.srmosaic.lock').exists()


def test_a_png_that_cannot_be_written_is_an_output_error(tmp_path: Path) -> None:
    """GDAL's PNG copy failing (libpng 'Write Error') is an OutputError, not a rasterio traceback."""
    script = f'''
import numpy as np, resource, signal
from srmosaic_ros.core.georef import GeoRaster
from srmosaic_ros.errors import OutputError
from srmosaic_ros.io.geotiff import png_from_geotiff, write_geotiff
img = (np.random.default_rng(0).random((600, 800, 3)) * 255).astype(np.uint8)
write_geotiff({str(tmp_path / 'a.tif')!r}, img, GeoRaster(32614, 0.2, 500000.0, 3000000.0, 0.0))
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (100000, 100000))
try:
    png_from_geotiff({str(tmp_path / 'a.tif')!r}, {str(tmp_path / 'a.png')!r})
except OutputError as exc:
    print('OutputError:', exc)
'''
    run = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert 'OutputError: a.png could not be written' in run.stdout, run.stdout + run.stderr
    assert not (tmp_path / 'a.png').exists()


def test_the_command_line_starts_without_the_pipeline() -> None:
    """Building the parser (every `srmosaic ... --help`, and the launcher reading parameter files)
    imports neither torch nor filterpy: they took 4.5 s before each command got to its work."""
    script = ('import sys; from srmosaic_ros.cli import build_parser; build_parser(); '
              'from srmosaic_ros.nodes.launcher import load_description; '
              "print(sorted(m for m in ('torch', 'filterpy', 'rclpy') if m in sys.modules))")
    run = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ['[]'], run.stdout


def test_the_program_ends_after_its_exit_handlers(tmp_path: Path) -> None:
    """`srmosaic process` as a program (cli.console_main) ends without the interpreter's teardown,
    but only after the exit handlers ran (a canvas's spill folder is removed by one) and with its
    output flushed; its exit status is the command's."""
    marker = tmp_path / 'finalized'
    script = f'''
import sys, weakref
from srmosaic_ros import cli
class Held: pass
held = Held()
weakref.finalize(held, open({str(marker)!r}, 'w').close)  # as TileStore removes its spill folder
print('before', flush=False)
sys.argv = ['srmosaic', 'process', {str(tmp_path / 'missing.bag')!r}, '--out', {str(tmp_path / 'out')!r}]
cli.console_main()
print('the interpreter went on')
'''
    run = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert run.stdout == 'before\n'  # flushed, and nothing after console_main ran
    assert 'srmosaic process: error:' in run.stderr and 'missing.bag' in run.stderr
    assert marker.exists()
