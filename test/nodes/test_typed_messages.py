"""Typed messages (live.message_types: typed): interfaces/srmosaic_interfaces built with colcon as a
ROS workspace builds it, and a graph that carries srmosaic_interfaces/Registration and
RasterGeoreference from the mosaic node to the SR node and the tile recorder, over real DDS.

The generated messages need LD_LIBRARY_PATH set before Python starts (what `source
install/setup.bash` does), so everything that touches them runs in child processes.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from ros_graph import stop_process
from repo_paths import REPO

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'


@pytest.fixture(scope='module')
def interfaces_env(tmp_path_factory) -> dict[str, str]:
    """colcon build of interfaces/srmosaic_interfaces; the environment its install/setup.bash gives."""
    work = tmp_path_factory.mktemp('interfaces_ws')
    venv = Path(sys.prefix)
    colcon = shutil.which('colcon', path=str(Path(sys.executable).parent))
    assert colcon, 'colcon is installed with the test extras (setup.py)'
    # The registry wheels install ament and rosidl into the venv: the ament index and CMake configs are there.
    env = dict(os.environ, AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv),
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    build = subprocess.run([colcon, '--log-base', str(work / 'log'), 'build', '--paths',
                            str(ROOT / 'interfaces' / 'srmosaic_interfaces'), '--build-base', str(work / 'build'),
                            '--install-base', str(work / 'install'), '--cmake-args',
                            f'-DPython3_EXECUTABLE={sys.executable}', '-DBUILD_TESTING=OFF'],
                           cwd=work, env=env, capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout[-4000:] + build.stderr[-4000:]
    prefix = work / 'install' / 'srmosaic_interfaces'
    site = next(prefix.glob('lib/python3*/site-packages'))
    assert (site / 'srmosaic_interfaces' / 'msg' / '__init__.py').is_file()
    return {'PYTHONPATH': os.pathsep.join([str(site), *filter(None, [os.environ.get('PYTHONPATH')])]),
            'LD_LIBRARY_PATH': os.pathsep.join([str(prefix / 'lib'), *filter(None, [os.environ.get('LD_LIBRARY_PATH')])])}


ROUND_TRIP = textwrap.dedent("""
    import json, numpy as np
    from srmosaic_ros.live.raster import LiveRaster
    from srmosaic_ros.nodes.messages import Messages
    typed, portable = Messages('typed'), Messages('portable')
    H, P, C = np.arange(9.0).reshape(3, 3) + 1, np.eye(3) * 2, np.diag(np.arange(1.0, 9.0))
    out = {}
    for name, m in (('typed', typed), ('portable', portable)):
        msg = m.registration(1_700_000_000_123_456_789, True, 57, 0.31, 2, H, P, True, C)
        back = m.read_registration(msg)
        out[name] = [type(msg).__name__, back.stamp_ns, back.ok, back.inliers, back.rms_px, back.segment,
                     back.seg_H_frame.tolist(), back.prev_H_cur.tolist(), back.reg_ok, back.covariance.tolist()]
        first = m.read_registration(m.registration(5, False, 0, float('nan'), -1, None, None, False, None))
        out[name + '_unknown'] = [first.seg_H_frame, first.prev_H_cur, first.covariance]
        raster = LiveRaster(32614, 0.18, 587501.44, 3338166.2, 0.01, np.array([[1.0, 0.001, 2.0], [0.0, 1.0, -3.0], [0, 0, 1]]))
        got = m.read_raster(m.raster(raster, 42))
        out[name + '_raster'] = [type(m.raster(raster)).__name__, got.epsg, got.gsd_m_per_px, got.origin_easting_m,
                                 got.origin_northing_m, got.rotation_rad, got.canvas_H_raster.tolist()]
    print(json.dumps(out))
""")


def test_typed_messages_carry_the_portable_fields(interfaces_env):
    """The typed messages hold what the portable encodings hold: a registration and a raster survive
    the round trip alike (NaN = unknown becomes None in both)."""
    run = subprocess.run([sys.executable, '-c', ROUND_TRIP], env=dict(os.environ, **interfaces_env),
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out['typed'][0] == 'Registration' and out['portable'][0] == 'Float64MultiArray'
    assert out['typed'][1:] == out['portable'][1:]
    assert out['typed'][1:6] == [1_700_000_000_123_456_789, True, 57, 0.31, 2]
    assert out['typed_unknown'] == out['portable_unknown'] == [None, None, None]
    assert out['typed_raster'][0] == 'RasterGeoreference' and out['portable_raster'][0] == 'String'
    assert out['typed_raster'][1:] == out['portable_raster'][1:]


CHECKER = textwrap.dedent("""
    import json, sys, time, rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from srmosaic_interfaces.msg import RasterGeoreference, Registration
    rclpy.init()
    node = rclpy.create_node('typed_checker', namespace='/typed')
    regs, rasters = [], []
    node.create_subscription(Registration, 'srmosaic/registration', regs.append, 200)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(RasterGeoreference, 'srmosaic/raster', rasters.append, latched)
    deadline = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < deadline and not (len(regs) >= 60 and rasters):
        rclpy.spin_once(node, timeout_sec=0.2)
    print(json.dumps({'registrations': len(regs), 'versions': sorted({int(r.version) for r in regs}),
                      'painted': sum(bool(r.ok) for r in regs), 'raster_epsg': [int(r.epsg) for r in rasters]}))
""")


@pytest.mark.ros
def test_graph_with_typed_messages(interfaces_env, ros_env, tmp_path):
    """mosaic, georef and SR nodes (one `srmosaic launch` process) and the tile recorder, all with
    live.message_types: typed under /typed: every frame of the demo bag arrives as a typed
    Registration, the raster as a RasterGeoreference, the SR node reconstructs tiles from the typed
    registrations, and the recorder georeferences them with the typed raster."""
    import rasterio

    env = dict(ros_env, **interfaces_env)
    ros = ['--ros-args', '-r', '__ns:=/typed', '-p', 'live.message_types:=typed']
    graph = subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.cli', 'launch', *ros, '-p', 'live.reliable_inputs:=true',
                              '-p', 'live.queue_size:=100', '-p', 'live.sr_period_s:=0.5'],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    recorder = subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'tile_recorder',
                                 str(tmp_path / 'tiles'), *ros], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
    checker = subprocess.Popen([sys.executable, '-c', CHECKER, '420'], env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    logs = {}
    try:
        player = subprocess.run([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'player', str(DEMO),
                                 '--rate', '2', '--delay', '60', '--subscribers', '/camera/image_raw/compressed=2',
                                 '--ros-args', '-r', '__ns:=/typed'],
                                env=env, capture_output=True, text=True, timeout=180)
        assert player.returncode == 0, player.stdout + player.stderr
        out, err = checker.communicate(timeout=480)  # polled: a loaded machine gets the time, a quiet one does not wait
        assert checker.returncode == 0, err
        got = json.loads(out)
        assert got['registrations'] == 60 and got['versions'] == [1], got
        assert got['painted'] >= 55 and got['raster_epsg'] and got['raster_epsg'][-1] > 32600, got
        tiles = tmp_path / 'tiles' / 'sr_tiles'
        deadline = 60
        while deadline > 0 and not [p for p in tiles.glob('*.tif') if not p.name.startswith('.')]:
            time.sleep(1.0)
            deadline -= 1
        written = sorted(p for p in tiles.glob('*.tif') if not p.name.startswith('.'))  # not a tile being written (.name.tmp.tif)
        assert written, f'no SR tile recorded: {sorted(p.name for p in tiles.iterdir())}'
        with rasterio.open(written[0]) as ds:
            assert ds.crs.to_epsg() == got['raster_epsg'][-1]
    except AssertionError as exc:
        raise AssertionError(f'{exc}\n--- graph ---\n{stop_process(graph)}\n--- recorder ---\n{stop_process(recorder)}') \
            from None
    finally:
        if checker.poll() is None:
            checker.kill()
        for name, proc in (('graph', graph), ('recorder', recorder)):
            logs[name] = stop_process(proc) if proc.returncode is None else ''
    assert graph.returncode == 0, logs['graph']
    assert recorder.returncode == 0, logs['recorder']


@pytest.mark.ros
def test_typed_without_the_interfaces_is_refused_with_the_way_out(ros_env):
    """A node asked for typed messages where srmosaic_interfaces is not built says so and how to get it."""
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'sr_node', '--ros-args', '-p',
                          'live.message_types:=typed'], env=ros_env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stdout + run.stderr
    assert 'live.message_types: typed needs the srmosaic_interfaces messages' in run.stderr
    assert 'colcon' in run.stderr and 'live.message_types: portable' in run.stderr
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'sr_node', '--ros-args', '-p',
                          'live.message_types:=json'], env=ros_env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "live.message_types='json' (must be one of portable, typed)" in run.stderr, run.stderr
