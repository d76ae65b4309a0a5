"""The package as ROS 2 tools see it: node executables, launch files, namespaces, /diagnostics, colcon.

DDS tests use their own ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, as in
test_mosaic_node.py, test_sr_node.py and test_launch.py; waits are conditions polled with generous timeouts.
"""
from __future__ import annotations

import importlib.metadata
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ros_graph import GraphListener, stop_process, supervised_processes

from srmosaic_ros.errors import ConfigError
from srmosaic_ros.nodes.executables import EXECUTABLES
from srmosaic_ros.nodes.launch_xml import read_launch_xml
from srmosaic_ros.nodes.launcher import xml_node_command
from repo_paths import REPO

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'
LAUNCH = ROOT / 'launch' / 'srmosaic.launch.xml'
MOSAIC = 'srmosaic: registration and mosaic'


def test_console_scripts_are_the_node_executables():
    scripts = {ep.name: ep.value for ep in importlib.metadata.entry_points(group='console_scripts')
               if ep.value.startswith('srmosaic_ros.')}
    assert scripts == {'srmosaic': 'srmosaic_ros.cli:console_main', **EXECUTABLES}
    for name, target in EXECUTABLES.items():
        module, _, function = target.partition(':')
        assert callable(getattr(importlib.import_module(module), function)), name


def test_launch_file_nodes_and_namespaces(tmp_path):
    default = read_launch_xml(LAUNCH)
    assert [(n.executable, n.namespace) for n in default] == [('mosaic_node', '/'), ('sr_node', '/')]
    assert all(Path(f).name == 'default.yaml' and Path(f).is_file() for n in default for f in n.param_files)
    nodes = read_launch_xml(LAUNCH, {'namespace': 'uav1', 'georef_standalone': 'true', 'sr': 'false'})
    assert [(n.executable, n.namespace, n.name) for n in nodes] == [
        ('mosaic_node', '/uav1', 'srmosaic_mosaic'), ('georef_node', '/uav1', 'srmosaic_georef')]
    assert nodes[0].parameters == {'live.georef_standalone': 'true', 'live.autostart': 'false'}
    # the managed nodes are brought up by the launcher (launch_ros's <lifecycle_node autostart>)
    assert [(n.managed, n.autostart) for n in nodes] == [(True, True), (True, True)]
    assert [(n.managed, n.autostart) for n in default] == [(True, True), (False, False)]
    manual = read_launch_xml(LAUNCH, {'autostart': 'false', 'sr': 'false'})
    assert [(n.executable, n.managed, n.autostart) for n in manual] == [('mosaic_node', True, False)]
    cmd = xml_node_command(nodes[0], [], ['--params-file', str(tmp_path / 'cli.yaml')], tmp_path)
    assert cmd[1:4] == ['-m', 'srmosaic_ros.nodes.executables', 'mosaic_node']
    assert ['-r', '__ns:=/uav1'] == cmd[5:7] and ['-r', '__node:=srmosaic_mosaic'] == cmd[7:9]
    files = [cmd[i + 1] for i, w in enumerate(cmd) if w == '--params-file']
    # the launch file's parameter file, its parameters, then the command line's: the command line wins
    assert files[0] == nodes[0].param_files[0] and files[-1] == str(tmp_path / 'cli.yaml')
    assert 'georef_standalone: true' in Path(files[1]).read_text()
    # The Python launch file includes the XML one (ros2 launch takes either).
    source = (ROOT / 'launch' / 'srmosaic.launch.py').read_text()
    compile(source, 'srmosaic.launch.py', 'exec')
    assert "'srmosaic.launch.xml'" in source and 'def generate_launch_description' in source


@pytest.mark.parametrize(('body', 'args', 'says'), [
    ('<include file="x.launch.xml"/>', {}, '<include> is not understood'),
    ('<node pkg="demo_nodes_py" exec="talker"/>', {}, 'only the executables of srmosaic_ros'),
    ('<node pkg="srmosaic_ros" exec="mosaic_node" respawn="true"/>', {}, "attributes ['respawn']"),
    ('<node pkg="srmosaic_ros" exec="mosaic_node" if="maybe"/>', {}, 'must be true, false, 1 or 0'),
    ('<node pkg="srmosaic_ros" exec="mosaic_node" namespace="$(var ns)"/>', {}, 'no <arg> or <let> before it'),
    ('<node pkg="srmosaic_ros" exec="mosaic_node" namespace="$(eval 1)"/>', {}, "'$(eval 1)'"),
    ('<arg name="ns"/><node pkg="srmosaic_ros" exec="mosaic_node"/>', {}, 'ns has no default: give it, ns:=VALUE'),
    ('<arg name="ns" default=""/><node pkg="srmosaic_ros" exec="mosaic_node"/>', {'nz': 'uav1'},
     "argument(s) ['nz'] are not declared; its arguments: ['ns']"),
    ('<node pkg="srmosaic_ros" exec="mosaic_node"><param from="/nonexistent.yaml"/></node>', {},
     'no such parameter file'),
    ('<arg name="sr" default="false"/><node pkg="srmosaic_ros" exec="sr_node" if="$(var sr)"/>', {},
     'starts no node'),
    ('<lifecycle_node pkg="srmosaic_ros" exec="mosaic_node" autostart="true"/>', {}, 'needs the attribute name'),
    ('<lifecycle_node pkg="srmosaic_ros" exec="mosaic_node" name="m" autostart="yes"/>', {},
     "autostart='yes' must be true, false, 1 or 0"),
    ('<node pkg="srmosaic_ros" exec="mosaic_node" name="m" autostart="true"/>', {}, "attributes ['autostart']"),
])
def test_launch_file_refusals_name_the_problem(tmp_path, body, args, says):
    path = tmp_path / 'bad.launch.xml'
    path.write_text(f'<launch>{body}</launch>')
    with pytest.raises(ConfigError) as info:
        read_launch_xml(path, args)
    assert says in str(info.value) and str(path) in str(info.value)


def test_launch_command_line_refusals_are_one_line(tmp_path):
    for args, says in ((['launch', str(LAUNCH), 'namespace=uav1'], 'must be name:=value'),
                       (['launch', str(LAUNCH), 'nope:=1'], "['nope'] are not declared"),
                       (['launch', str(tmp_path / 'missing.launch.xml')], 'does not exist'),
                       (['launch', str(ROOT / 'params' / 'default.yaml'), 'namespace:=uav1'], 'need a launch file')):
        run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', *args], capture_output=True, text=True,
                             timeout=60)
        assert run.returncode == 2, run
        assert says in run.stderr and 'Traceback' not in run.stderr, run.stderr
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'player', '--rate', '0', 'x'],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and 'must be a finite number > 0' in run.stderr, run.stderr
    run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'bogus'], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and 'mosaic_node' in run.stderr


class Listener(GraphListener):
    """Records the given subscriptions: got[key] lists what arrived on topic of type."""

    def __init__(self, topics: dict[str, tuple[type, str]]) -> None:
        super().__init__('srmosaic_native_listener')
        self.got = {key: self.subscribe(msg_type, topic, 200) for key, (msg_type, topic) in topics.items()}
        self.start()

    def statuses(self, key: str = 'diagnostics') -> dict[str, object]:
        """The newest DiagnosticStatus of every status name seen on `key`."""
        out = {}
        for msg in list(self.got[key]):
            for status in msg.status:
                out[status.name] = status
        return out


def _values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


@pytest.mark.ros
def test_two_aircraft_in_one_graph_stay_apart(ros_env, tmp_path):
    """A launch file starts a mosaic node per namespace; a bag played into /uav1 reaches only /uav1's
    node, the statuses on /diagnostics are told apart by namespace and camera, and the frame ids of
    the poses are the launch file's."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import NavSatFix
    from std_msgs.msg import Float64MultiArray

    launch_file = tmp_path / 'two.launch.xml'
    node = ('<node pkg="srmosaic_ros" exec="mosaic_node" namespace="{ns}">'
            '<param name="live.reliable_inputs" value="true"/><param name="live.queue_size" value="100"/>'
            '<param name="live.map_frame" value="{ns}_enu"/><param name="live.body_frame" value="{ns}_base"/></node>')
    launch_file.write_text('<launch><arg name="first" default="uav1"/>'
                           + node.format(ns='$(var first)') + node.format(ns='uav2') + '</launch>')
    listener = Listener({'diagnostics': (DiagnosticArray, '/diagnostics'),
                         'uav1_diagnostics': (DiagnosticArray, '/uav1/srmosaic/diagnostics'),
                         'root_diagnostics': (DiagnosticArray, '/srmosaic/diagnostics'),
                         'uav1': (Float64MultiArray, '/uav1/srmosaic/registration'),
                         'uav2': (Float64MultiArray, '/uav2/srmosaic/registration'),
                         'root': (Float64MultiArray, '/srmosaic/registration'),
                         'pose': (PoseWithCovarianceStamped, '/uav1/srmosaic/pose'),
                         'fix': (NavSatFix, '/uav1/srmosaic/fix'),
                         'odom': (Odometry, '/uav1/srmosaic/odom')})
    graph = subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.cli', 'launch', str(launch_file)], env=ros_env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    player = None
    names = {'uav1': f'uav1/{MOSAIC}', 'uav2': f'uav2/{MOSAIC}'}
    try:
        assert listener.wait_for(lambda: set(names.values()) <= set(listener.statuses()), 90), \
            f'statuses on /diagnostics: {sorted(listener.statuses())}'
        player = subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'player', str(DEMO),
                                   '--rate', '2', '--delay', '15', '--ros-args', '-r', '__ns:=/uav1'],
                                  env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        out, _ = player.communicate(timeout=120)
        assert player.returncode == 0, out
        assert listener.wait_for(lambda: len(listener.got['uav1']) >= 20, 240), \
            f"{len(listener.got['uav1'])} registrations on /uav1"
        time.sleep(1.0)
        statuses = listener.statuses()
        assert statuses[names['uav1']].hardware_id == '/uav1/camera/image_raw'
        assert statuses[names['uav2']].hardware_id == '/uav2/camera/image_raw'
        assert int(_values(statuses[names['uav1']])['frames_received']) >= 20
        assert _values(statuses[names['uav2']])['frames_received'] == '0'
        assert listener.got['uav2'] == [] and listener.got['root'] == [] and listener.got['root_diagnostics'] == []
        assert names['uav1'] in listener.statuses('uav1_diagnostics')  # and srmosaic/diagnostics under the namespace
        assert listener.got['pose'] and {p.header.frame_id for p in listener.got['pose']} == {'uav1_enu'}
        assert {f.header.frame_id for f in listener.got['fix']} == {'uav1_base'}
        # nav_msgs/Odometry: the same poses, map frame to body frame, velocity marked not provided
        odom = {(o.header.stamp.sec, o.header.stamp.nanosec): o for o in listener.got['odom']}
        assert len(odom) == len(listener.got['pose'])
        for pose in listener.got['pose']:
            o = odom[pose.header.stamp.sec, pose.header.stamp.nanosec]
            assert (o.header.frame_id, o.child_frame_id) == ('uav1_enu', 'uav1_base')
            assert o.pose.pose == pose.pose.pose and list(o.pose.covariance) == list(pose.pose.covariance)
            assert o.twist.covariance[0] == -1.0
    except AssertionError as exc:
        raise AssertionError(f'{exc}\n--- launch output ---\n{stop_process(graph)}') from None
    finally:
        if player is not None and player.poll() is None:
            player.kill()
        log = stop_process(graph)
        listener.close()
    assert graph.returncode == 0, log
    assert 'starting /uav1/mosaic_node' in log and 'starting /uav2/mosaic_node' in log, log


@pytest.mark.ros
def test_colcon_built_package_runs_as_ros2_run_would(ros_env, tmp_path):
    """`colcon build` of the source tree into a workspace; the installed executable (what
    `ros2 run srmosaic_ros mosaic_node` starts) joins the graph and reports on /diagnostics, and the
    installed launch file finds its parameters through the ament index."""
    from diagnostic_msgs.msg import DiagnosticArray

    colcon = shutil.which('colcon', path=str(Path(sys.executable).parent))
    assert colcon, 'colcon is installed with the test extras (setup.py)'
    build = subprocess.run([colcon, '--log-base', str(tmp_path / 'log'), 'build', '--paths', str(ROOT),
                            '--build-base', str(tmp_path / 'build'), '--install-base', str(tmp_path / 'install')],
                           cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    prefix = tmp_path / 'install' / 'srmosaic_ros'
    share = prefix / 'share' / 'srmosaic_ros'
    assert (share / 'params' / 'default.yaml').is_file() and (share / 'launch' / 'srmosaic.launch.xml').is_file()
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'srmosaic_ros').is_file()
    site = next(prefix.glob('lib/python3*/site-packages'))
    env = dict(ros_env, AMENT_PREFIX_PATH=str(prefix), PYTHONPATH=os.pathsep.join(
        [str(site), *filter(None, [os.environ.get('PYTHONPATH')])]))
    # ros2 launch's find-pkg-share: the installed share directory, through the ament index
    check = subprocess.run([sys.executable, '-c', 'import sys; from srmosaic_ros.nodes.launch_xml import '
                            'read_launch_xml; n = read_launch_xml(sys.argv[1]); '
                            'print(n[0].param_files[0]); import srmosaic_ros; print(srmosaic_ros.__file__)',
                            str(share / 'launch' / 'srmosaic.launch.xml')], env=env, cwd=tmp_path, capture_output=True,
                           text=True, timeout=60)
    assert check.returncode == 0, check.stderr
    params_file, module = check.stdout.split()
    assert Path(params_file) == share / 'params' / 'default.yaml'
    assert Path(module).is_relative_to(site)  # the installed copy, not the source tree
    executable = prefix / 'lib' / 'srmosaic_ros' / 'mosaic_node'
    assert os.access(executable, os.X_OK)
    listener = Listener({'diagnostics': (DiagnosticArray, '/diagnostics')})
    node = subprocess.Popen([str(executable), '--ros-args', '-r', '__ns:=/cam7'], env=env, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    with supervised_processes({'node': node}, listener.close) as logs:
        assert listener.wait_for(lambda: f'cam7/{MOSAIC}' in listener.statuses(), 90), \
            f'statuses: {sorted(listener.statuses())}'
        assert listener.statuses()[f'cam7/{MOSAIC}'].hardware_id == '/cam7/camera/image_raw'
    assert node.returncode == 0, logs['node']


def _call(listener: Listener, future, timeout: float = 30):
    assert listener.wait_for(future.done, timeout), 'parameter service did not answer'
    return future.result()


def _query(listener: Listener, client, request, tries: int = 3, timeout: float = 10):
    """The answer of an idempotent service (get_state), asked again when none comes: Fast DDS drops
    a response sent before the server has matched the client's response reader ("failed to send
    response (timeout)"), which the first request right after discovery can meet."""
    for _ in range(tries - 1):
        future = client.call_async(request)
        if listener.wait_for(future.done, timeout, scaled=False):
            return future.result()
        client.remove_pending_request(future)
    return _call(listener, client.call_async(request), timeout)


@pytest.mark.ros
def test_parameters_change_or_are_refused_and_qos_overrides_apply(ros_env):
    """`ros2 param set` (rclpy's parameter client): a changeable parameter takes effect (the
    diagnostics come faster), a read-only one and a value out of range are refused with a reason;
    the standard qos_overrides.* parameters set a subscription's reliability, seen over DDS."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from rclpy.qos import ReliabilityPolicy

    listener = Listener({'diagnostics': (DiagnosticArray, '/diagnostics')})
    start = [sys.executable, '-m', 'srmosaic_ros.nodes.executables']
    ros = ['--ros-args', '-r', '__ns:=/p1']
    procs = {
        'mosaic': subprocess.Popen([*start, 'mosaic_node', *ros, '-p',
                                    'qos_overrides./p1/camera/image_raw.subscription.reliability:=reliable'],
                                   env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True),
        'sr': subprocess.Popen([*start, 'sr_node', *ros, '-p', 'live.sr_worker:=thread'], env=ros_env,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)}
    mosaic, sr = f'p1/{MOSAIC}', 'p1/srmosaic: super-resolution'

    def arrivals(name: str, seconds: float) -> int:
        before = sum(s.name == name for m in list(listener.got['diagnostics']) for s in m.status)
        time.sleep(seconds)
        return sum(s.name == name for m in list(listener.got['diagnostics']) for s in m.status) - before

    with supervised_processes(procs, listener.close) as logs:
        assert listener.wait_for(lambda: {mosaic, sr} <= set(listener.statuses()), 90), sorted(listener.statuses())
        subs = {info.node_name: info.qos_profile.reliability
                for info in listener.node.get_subscriptions_info_by_topic('/p1/camera/image_raw')}
        assert subs == {'srmosaic_mosaic': ReliabilityPolicy.RELIABLE, 'srmosaic_sr': ReliabilityPolicy.BEST_EFFORT}
        compressed = listener.node.get_subscriptions_info_by_topic('/p1/camera/image_raw/compressed')
        assert {i.qos_profile.reliability for i in compressed} == {ReliabilityPolicy.BEST_EFFORT}

        client = AsyncParameterClient(listener.node, '/p1/srmosaic_mosaic')
        assert client.wait_for_services(timeout_sec=30)
        slow = arrivals(mosaic, 3.0)  # live.preview_period_s 1.0
        result = _call(listener, client.set_parameters([Parameter('live.preview_period_s', value=0.2)]))
        assert result.results[0].successful, result
        fast = arrivals(mosaic, 3.0)
        assert slow <= 5 and fast >= 9, (slow, fast)
        refused = _call(listener, client.set_parameters([Parameter('registration.max_features', value=50),
                                                         Parameter('live.preview_period_s', value=0.0)]))
        assert not refused.results[0].successful and 'read-only' in refused.results[0].reason, refused
        assert not refused.results[1].successful, refused  # below the descriptor's 0.05
        values = _call(listener, client.get_parameters(['live.preview_period_s', 'registration.max_features']))
        assert [v.double_value for v in values.values[:1]] == [0.2] and values.values[1].integer_value == 1000

        sr_client = AsyncParameterClient(listener.node, '/p1/srmosaic_sr')
        assert sr_client.wait_for_services(timeout_sec=30)
        refused = _call(listener, sr_client.set_parameters([Parameter('live.sr_refresh_growth', value=0.5)]))
        assert not refused.results[0].successful and 'again and again' in refused.results[0].reason, refused
        ok = _call(listener, sr_client.set_parameters([Parameter('live.sr_tiles_per_round', value=3)]))
        assert ok.results[0].successful, ok
        # each node declares its own parameters only (a shared file's others are ignored)
        sr_names = set(_call(listener, sr_client.list_parameters([], 0)).result.names)
        mosaic_names = set(_call(listener, client.list_parameters([], 0)).result.names)
        assert 'sr.iterations' in sr_names and 'registration.max_features' not in sr_names
        assert 'registration.max_features' in mosaic_names and 'sr.iterations' not in mosaic_names
        assert not any(n.startswith('survey.') for n in sr_names | mosaic_names)
        descriptor = _call(listener, sr_client.describe_parameters(['live.sr_worker', 'live.sr_tiles_per_round']))
        assert [d.read_only for d in descriptor.descriptors] == [True, False]
        assert descriptor.descriptors[1].integer_range[0].to_value == 100
    for name, proc in procs.items():
        assert proc.returncode == 0, logs[name]
    assert 'live.preview_period_s is now 0.2' in logs['mosaic'] and 'live.sr_tiles_per_round is now 3' in logs['sr']


@pytest.mark.ros
def test_mosaic_node_lifecycle(ros_env, tmp_path):
    """The mosaic node as a managed node (live.autostart false): unconfigured until configured;
    inactive, it ignores a played bag (counted); active, it mosaics the same bag played again;
    deactivated, it keeps the mosaic; cleanup writes the outputs (live.output_dir)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from lifecycle_msgs.msg import State, Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from std_msgs.msg import Float64MultiArray

    out = tmp_path / 'live'
    listener = Listener({'diagnostics': (DiagnosticArray, '/lc/srmosaic/diagnostics'),
                         'registration': (Float64MultiArray, '/lc/srmosaic/registration')})
    node = subprocess.Popen([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'mosaic_node', '--ros-args',
                             '-r', '__ns:=/lc', '-p', 'live.autostart:=false', '-p', f'live.output_dir:={out}',
                             '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100',
                             '-p', 'live.preview_period_s:=0.3'],
                            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    get_state = listener.node.create_client(GetState, '/lc/srmosaic_mosaic/get_state')
    change_state = listener.node.create_client(ChangeState, '/lc/srmosaic_mosaic/change_state')

    def state() -> int:
        return _query(listener, get_state, GetState.Request()).current_state.id

    def transition(tid: int) -> None:
        assert _call(listener, change_state.call_async(ChangeState.Request(transition=Transition(id=tid)))).success

    def play(rate: int = 2) -> None:  # ignored frames are only counted: played faster
        player = subprocess.run([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'player', str(DEMO), '--rate',
                                 str(rate), '--delay', '15', '--ros-args', '-r', '__ns:=/lc'], env=ros_env,
                                capture_output=True, text=True, timeout=120)
        assert player.returncode == 0, player.stdout + player.stderr

    def value(key: str) -> str | None:
        status = listener.statuses().get(f'lc/{MOSAIC}')
        return _values(status).get(key) if status is not None else None

    with supervised_processes({'node': node}, listener.close) as logs:
        assert get_state.wait_for_service(timeout_sec=60) and change_state.wait_for_service(timeout_sec=10)
        assert state() == State.PRIMARY_STATE_UNCONFIGURED
        transition(Transition.TRANSITION_CONFIGURE)
        assert state() == State.PRIMARY_STATE_INACTIVE
        play(8)
        assert listener.wait_for(lambda: int(value('frames_while_inactive') or 0) >= 50, 30), value('frames_while_inactive')
        assert listener.got['registration'] == [] and value('frames_processed') == '0'
        assert 'inactive' in listener.statuses()[f'lc/{MOSAIC}'].message
        transition(Transition.TRANSITION_ACTIVATE)
        play()
        assert listener.wait_for(lambda: len(listener.got['registration']) == 60, 240), len(listener.got['registration'])
        transition(Transition.TRANSITION_DEACTIVATE)
        # the next diagnostics after the transition carry the count (one may still be on its way)
        assert listener.wait_for(lambda: value('frames_while_inactive') is not None, 10)
        ignored = int(value('frames_while_inactive'))
        play(8)  # paused: ignored, and the mosaic kept
        assert listener.wait_for(lambda: int(value('frames_while_inactive')) >= ignored + 50, 30)
        kept = int(value('frames_in_mosaic'))
        status = listener.statuses()[f'lc/{MOSAIC}']
        assert kept >= 55 and len(listener.got['registration']) == 60, (kept, _values(status))
        assert 'inactive' in status.message, status.message
        assert not (out / 'report.json').exists()
        transition(Transition.TRANSITION_CLEANUP)
        assert state() == State.PRIMARY_STATE_UNCONFIGURED
        report = json.loads((out / 'report.json').read_text())
        from srmosaic_ros.nodes.common import decode_registration

        painted = sum(decode_registration(r).ok for r in listener.got['registration'])
        assert report['frames_registered'] == painted >= kept, (report['frames_registered'], painted, kept)
        assert (out / 'mosaic.png').is_file()
    assert node.returncode == 0, logs['node']
    assert logs['node'].count('wrote ') == 1, logs['node']  # cleanup wrote the outputs; the exit after it did not again


@pytest.mark.ros
def test_georef_node_lifecycle(ros_env):
    """The standalone georef node as a managed node (live.autostart false), beside a mosaic node
    (also managed) that sends it the registrations: configured but inactive, it ignores a played bag
    (counted, no pose); active, it fuses the same bag played again into poses; deactivated, it
    publishes none; cleanup leaves it unconfigured."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from lifecycle_msgs.msg import State, Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    listener = Listener({'diagnostics': (DiagnosticArray, '/glc/srmosaic/diagnostics'),
                         'pose': (PoseWithCovarianceStamped, '/glc/srmosaic/pose')})
    start = [sys.executable, '-m', 'srmosaic_ros.nodes.executables']
    # (a queue for every frame: under load the mosaic node must not drop frames this test counts)
    common = ['--ros-args', '-r', '__ns:=/glc', '-p', 'live.autostart:=false', '-p', 'live.georef_standalone:=true',
              '-p', 'live.reliable_inputs:=true', '-p', 'live.preview_period_s:=0.3', '-p', 'live.queue_size:=100']
    procs = {name: subprocess.Popen([*start, executable, *common], env=ros_env, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
             for name, executable in (('georef', 'georef_node'), ('mosaic', 'mosaic_node'))}
    clients = {name: (listener.node.create_client(GetState, f'/glc/srmosaic_{name}/get_state'),
                      listener.node.create_client(ChangeState, f'/glc/srmosaic_{name}/change_state'))
               for name in procs}

    def state(name: str) -> int:
        return _query(listener, clients[name][0], GetState.Request()).current_state.id

    def transition(name: str, tid: int) -> None:
        request = ChangeState.Request(transition=Transition(id=tid))
        assert _call(listener, clients[name][1].call_async(request)).success, (name, tid)

    def play(rate: int = 2) -> None:  # ignored inputs are only counted: played faster
        player = subprocess.run([*start, 'player', str(DEMO), '--rate', str(rate), '--delay', '15', '--ros-args', '-r',
                                 '__ns:=/glc'], env=ros_env, capture_output=True, text=True, timeout=120)
        assert player.returncode == 0, player.stdout + player.stderr

    def value(key: str) -> str | None:
        status = listener.statuses().get('glc/srmosaic: georeferencing')
        return _values(status).get(key) if status is not None else None

    with supervised_processes(procs, listener.close):
        for name in procs:
            assert clients[name][0].wait_for_service(timeout_sec=60) and clients[name][1].wait_for_service(timeout_sec=10)
            assert state(name) == State.PRIMARY_STATE_UNCONFIGURED
            transition(name, Transition.TRANSITION_CONFIGURE)
        assert state('georef') == State.PRIMARY_STATE_INACTIVE
        # both inactive: ignored, and taken again when replayed. A starved host may match the player's
        # publishers with the node's subscriptions only after the player sent (volatile QoS: those are
        # lost, not ignored): play again then; a node that does not count them fails all three.
        for _ in range(3):
            play(8)
            if listener.wait_for(lambda: int(value('inputs_while_inactive') or 0) >= 50, 30):
                break
        assert int(value('inputs_while_inactive') or 0) >= 50, value('inputs_while_inactive')
        assert listener.got['pose'] == [] and value('frames_fused') == '0'
        for name in procs:
            transition(name, Transition.TRANSITION_ACTIVATE)
        play()
        assert listener.wait_for(lambda: len(listener.got['pose']) >= 50, 300), len(listener.got['pose'])  # slow under load
        transition('georef', Transition.TRANSITION_DEACTIVATE)
        assert listener.wait_for(lambda: 'inactive' in listener.statuses()['glc/srmosaic: georeferencing'].message, 10)
        transition('georef', Transition.TRANSITION_CLEANUP)
        assert state('georef') == State.PRIMARY_STATE_UNCONFIGURED


@pytest.mark.ros
def test_launcher_brings_the_managed_nodes_up(ros_env, tmp_path):
    """`srmosaic launch` of the launch file drives the managed nodes' transitions (the nodes do not
    start themselves): every node configured before any is activated; both end active. A node that
    refuses to configure ends the launch with status 2 and says which."""
    from lifecycle_msgs.msg import State
    from lifecycle_msgs.srv import GetState

    listener = Listener({})
    launch = [sys.executable, '-m', 'srmosaic_ros.cli', 'launch', str(LAUNCH), 'sr:=false']
    graph = subprocess.Popen([*launch, 'namespace:=up', 'georef_standalone:=true'], env=ros_env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    clients = {name: listener.node.create_client(GetState, f'/up/srmosaic_{name}/get_state')
               for name in ('mosaic', 'georef')}

    def active(name: str) -> bool:
        if not clients[name].service_is_ready():
            return False
        return _query(listener, clients[name], GetState.Request()).current_state.id == State.PRIMARY_STATE_ACTIVE

    with supervised_processes({'launch': graph}, listener.close) as logs:
        assert listener.wait_for(lambda: active('mosaic') and active('georef'), 120)
    lines = [line.split('srmosaic launch: ')[-1] for line in logs['launch'].splitlines() if 'srmosaic launch: /up/' in line
             and line.endswith(('configured', 'activated'))]
    assert lines == ['/up/srmosaic_mosaic: configured', '/up/srmosaic_georef: configured',
                     '/up/srmosaic_mosaic: activated', '/up/srmosaic_georef: activated'], logs['launch']
    assert graph.returncode == 0, logs['launch']
    # a bad value in a parameter file reaches the node (a bad -p override is refused before any node starts,
    # test_override_check.py), which refuses to configure
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    mosaic:\n      blend: bogus\n')
    refused = subprocess.run([*launch, 'namespace:=bad', '--params', str(bad)], env=ros_env,
                             capture_output=True, text=True, timeout=180)
    assert refused.returncode == 2, refused.stderr
    assert '/bad/srmosaic_mosaic refused to configure' in refused.stderr, refused.stderr
    assert "mosaic.blend=" in refused.stderr and 'must be one of feather, multiband, bestview' in refused.stderr


@pytest.mark.ros
def test_idle_nodes_stop_on_sigint(ros_env, tmp_path):
    """Nodes with no timer of their own (the georef node idle, the mosaic node unconfigured, the
    tile recorder waiting) stop cleanly on Ctrl-C: the executor returns to Python to run the handler."""
    listener = Listener({})
    start = [sys.executable, '-m', 'srmosaic_ros.nodes.executables']
    procs = {'srmosaic_georef': [*start, 'georef_node'],
             'srmosaic_mosaic': [*start, 'mosaic_node', '--ros-args', '-p', 'live.autostart:=false'],
             'srmosaic_tile_recorder': [*start, 'tile_recorder', str(tmp_path / 'tiles')]}
    running = {name: subprocess.Popen(cmd, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
               for name, cmd in procs.items()}
    try:
        assert listener.wait_for(lambda: set(procs) <= set(listener.node.get_node_names()), 90), \
            listener.node.get_node_names()
    finally:
        logs = {}
        for proc in running.values():
            proc.send_signal(signal.SIGINT)
        for name, proc in running.items():
            try:
                logs[name] = proc.communicate(timeout=30)[0]
            except subprocess.TimeoutExpired:
                proc.kill()
                logs[name] = f'did not stop on SIGINT: {proc.communicate()[0]}'
        listener.close()
    for name, proc in running.items():
        assert proc.returncode == 0, (name, logs[name])


def test_player_refuses_a_subscriber_count_it_cannot_read() -> None:
    for bad in ('2', '/camera/image_raw=0', '/fix=two'):
        run = subprocess.run([sys.executable, '-m', 'srmosaic_ros.nodes.executables', 'player', '--subscribers', bad,
                              str(DEMO)], capture_output=True, text=True, timeout=60)
        assert run.returncode == 2 and '--subscribers: takes TOPIC=N' in run.stderr, run.stderr
