"""`srmosaic launch -p name:=value`: a bad override is refused before any node starts, with the message
the node itself would give; good ones pass. The launcher runs in this process (cli_runner.run_cli)
with the starting of children replaced by a recorder, so no graph starts and stops for a refusal."""
from __future__ import annotations

from pathlib import Path

import pytest

from cli_runner import run_cli

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / 'launch' / 'srmosaic.launch.xml'

#: (override, what the refusal says, the node kind that refuses it at start)
REFUSED = [
    ('registration.ratio:=3.0', 'Parameter registration.ratio out of range Min: 0.0, Max: 1.0', 'mosaic'),
    ('live.sr_frames_kept:=0', 'Parameter live.sr_frames_kept out of range. Min: 1, Max: 1000', 'sr'),
    ('live.sr_worker:=fork', "live.sr_worker='fork' (must be one of process, thread)", 'sr'),
    ('live.sr_refresh_growth:=0.5', 'would publish the same tiles again and again', 'sr'),
    # an output folder that cannot be written: at start, not at shutdown
    ('live.output_dir:=/proc/srmosaic-out', 'live.output_dir /proc/srmosaic-out cannot be written', 'mosaic'),
    # a params file beat -p: these were silently ignored
    ('registration.max_features:=lots', "'registration.max_features' to 'lots' of type 'STRING', expecting type 'INTEGER'",
     'mosaic'),
    ('georef.enabled:="false"', "'georef.enabled' to 'false' of type 'STRING', expecting type 'BOOL'", 'mosaic'),
]


@pytest.fixture
def started(monkeypatch):
    """The commands the launcher would start (children) or the nodes it would run here, recorded instead."""
    from srmosaic_ros.nodes import launcher

    record: list = []
    monkeypatch.setattr(launcher, '_supervise', lambda commands, driver=None: record.append([command for _, command in commands]) or 0)
    monkeypatch.setattr(launcher, 'run_named_nodes', lambda names, args: record.append(list(names)) or 0)
    return record


@pytest.mark.parametrize(('override', 'says', 'kind'), REFUSED, ids=[row[0] for row in REFUSED])
def test_bad_override_refused_before_any_node_starts(started, override, says, kind):
    run = run_cli('launch', '--ros-args', '-p', override)
    assert run.returncode == 2, run.stderr
    assert says in run.stderr and run.stderr.startswith('srmosaic launch: error: ') and run.stderr.count('\n') == 1, run.stderr
    assert started == []


@pytest.mark.ros
@pytest.mark.parametrize(('override', 'says', 'kind'), REFUSED, ids=[row[0] for row in REFUSED])
def test_the_node_refuses_what_the_launcher_refuses(ros_env, override, says, kind):
    """The same override given to the node itself (no launcher) is refused at its start with the same words."""
    import rclpy

    from srmosaic_ros.nodes.launcher import _node_classes

    context = rclpy.Context()
    rclpy.init(args=['srmosaic', '--ros-args', '-p', override], context=context)
    try:
        with pytest.raises(Exception) as refused:
            node = _node_classes()[kind](context=context)
            node.destroy_node()
        assert says in str(refused.value), refused.value
    finally:
        rclpy.shutdown(context=context)


def test_names_no_node_of_the_graph_declares_are_refused(started):
    typo = run_cli('launch', '--ros-args', '-p', 'registration.max_featres:=100')
    assert typo.returncode == 2 and 'did you mean registration.max_features?' in typo.stderr, typo.stderr
    not_started = run_cli('launch', str(LAUNCH), 'sr:=false', '--ros-args', '-p', 'sr.iterations:=3')
    assert not_started.returncode == 2, not_started.stderr
    assert '-p sr.iterations: no node this launch starts (mosaic) declares it (a parameter of sr)' in not_started.stderr
    replaced = run_cli('launch', '--ros-args', '-p', 'georef.drift_pose_correlation_frames:=3')
    assert replaced.returncode == 2 and "replaced by 'georef.drift_pose_time_constant_s'" in replaced.stderr
    assert started == []


def test_good_overrides_start_the_graph(started, tmp_path):
    """Overrides each node takes, ROS's own parameters and a launch file's <param>s pass; the children start."""
    assert run_cli('launch', '--ros-args', '-p', 'live.queue_size:=100', '-p', 'use_sim_time:=true',
                   '-p', 'qos_overrides./fix.subscription.depth:=5').returncode == 0
    assert started.pop() == ['mosaic', 'georef', 'sr']
    run = run_cli('launch', str(LAUNCH), 'map:=true', 'georef_standalone:=true', '--ros-args', '-p', 'live.map_port:=9000',
                  '-p', 'sr.iterations:=3')
    assert run.returncode == 0, run.stderr
    assert [command[3] for command in started.pop()] == ['mosaic_node', 'georef_node', 'sr_node', 'map_server']


def test_a_process_of_a_description_is_judged_on_its_own_nodes(started, tmp_path):
    description = tmp_path / 'two.yaml'
    description.write_text('processes:\n  - {name: onboard, nodes: [mosaic], parameters: {live.queue_size: 0}}\n'
                           '  - {name: ground, nodes: [sr]}\n')
    run = run_cli('launch', str(description))
    assert run.returncode == 2 and 'onboard/mosaic would refuse its parameters: invalid parameter: Invalid parameter value (0)' \
        in run.stderr, run.stderr
    description.write_text('processes:\n  - {name: onboard, nodes: [mosaic], parameters: {sr.iterations: 3}}\n'
                           '  - {name: ground, nodes: [sr]}\n')
    run = run_cli('launch', str(description))
    assert run.returncode == 2 and 'no node onboard/mosaic (mosaic) declares it (a parameter of sr)' in run.stderr, run.stderr
    assert started == []


def test_a_bad_parameter_file_is_left_to_the_nodes(started, tmp_path):
    """Only the overrides are judged: a file's own bad value reaches the node, which refuses it at start
    (test_ros_native's launcher test shows the managed node refusing to configure)."""
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    mosaic:\n      blend: bogus\n')
    assert run_cli('launch', '--params', str(bad)).returncode == 0
    assert started.pop() == ['mosaic', 'georef', 'sr']
    # with the file's value as context, an override that is fine on its own still passes
    assert run_cli('launch', '--params', str(bad), '--ros-args', '-p', 'live.queue_size:=50').returncode == 0
    assert started.pop() == ['mosaic', 'georef', 'sr']


def test_parse_overrides_reads_values_as_rcl_does():
    from srmosaic_ros.nodes.override_check import parse_overrides

    assert parse_overrides(['--ros-args', '-p', 'a.b:=3', '--param', 'c:=true', '-r', '/x:=/y', '-p', 'd:="3"', '-p', 'e:=']) == {
        'a.b': 3, 'c': True, 'd': '3', 'e': ''}
