"""`srmosaic launch`: the graph split over processes, the standalone filter, children killed or interrupted,
and command-line overrides (the overrides the launcher refuses before starting a node: test_override_check.py)."""
from __future__ import annotations

import json
import math
import os
import signal
import time
from pathlib import Path

import pytest


from live_graph import (
    DEMO,
    GEOREF,
    MOSAIC,
    SR,
    check_sr_tile_against_truth,
    children_of,
    cmdline_of,
    is_running,
    srmosaic,
    supervised,
)

pytestmark = pytest.mark.ros


def test_split_graph_in_separate_processes(ros_env, tmp_path):
    """mosaic | georef | sr, each in its own process (a launch description), the filter standalone."""
    description = tmp_path / 'split.yaml'
    description.write_text(
        'processes:\n'
        '  - {name: onboard, nodes: [mosaic], parameters: {live.queue_size: 100}}\n'
        '  - {name: georef, nodes: [georef]}\n'
        '  - {name: ground, nodes: [sr]}\n')
    graph = srmosaic('launch', str(description), '--ros-args', '-p', 'live.georef_standalone:=true',
                     '-p', 'live.reliable_inputs:=true', '-p', 'live.preview_period_s:=0.5',
                     '-p', 'live.sr_period_s:=0.5', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        names = (MOSAIC, GEOREF, SR)
        assert listener.wait_for(lambda: all(listener.diag_value('frames_received' if n != GEOREF else 'frames_fused', n)
                                             is not None for n in names), 60), 'a node of the split graph is missing'
        # No need for the whole bag here: stop as soon as every stage has delivered.
        player = srmosaic('play', str(DEMO), '--rate', '1.0', '--delay', '15', env=ros_env)
        try:
            assert listener.wait_for(lambda: len(listener.poses) >= 10 and listener.tiles and listener.previews,
                                     240), (f"{listener.diag_value('frames_processed')} frames processed, "
                                            f'{len(listener.poses)} poses, {len(listener.tiles)} SR tiles')
        finally:
            if player.poll() is None:
                player.send_signal(signal.SIGINT)
            player.communicate(timeout=60)
        assert listener.previews and listener.compressed
        # The standalone filter: one pose per fused frame, near the simulated flight.
        assert listener.wait_for(lambda: listener.compressed, 10)
        assert all(abs(p.pose.pose.position.z - 100.0) < 10.0 for p in listener.poses)
        assert all(abs(f.latitude - 30.17) < 0.01 for f in listener.fixes)
        assert {p.header.frame_id for p in listener.poses} == {'srmosaic_enu'}
        fit = check_sr_tile_against_truth(listener.tiles[0], listener.registrations)
        print('split graph SR tile', fit['placement'], 'mae', round(fit['mae'], 2), 'best shift', fit['best_shift'])
        assert max(abs(v) for v in fit['best_shift']) <= 1, fit
        assert fit['mae'] < 6.0, fit


@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='reads child processes from /proc (Linux)')
def test_standalone_filter_stopped_by_the_scheduler_fuses_as_if_it_had_run(ros_env, tmp_path):
    """The standalone georef process stopped for 1.5 s mid-flight (SIGSTOP: a loaded machine) finds
    its queues full when it resumes: every frame still gets its pose near the simulated flight, with
    no gyro gap, no gated fix or Imu and no frame out of order. It used to fuse frames before the Imu
    backlog (drained behind the fixes) had reached them, and to feed telemetry so far ahead of the
    registrations (which come mosaic.revisit_spread_frames frames late) that the filter bridged a
    camera dropout that was not one: poses 40 m off, or none. Its fixes are then those of the filter
    inside the mosaic node (the default graph, not stopped) to the millimetre."""
    from msg_adapters import stamp_to_ns

    description = tmp_path / 'split.yaml'
    description.write_text('processes:\n  - {name: onboard, nodes: [mosaic]}\n  - {name: georef, nodes: [georef]}\n')
    graph = srmosaic('launch', str(description), '--ros-args', '-p', 'live.georef_standalone:=true',
                     '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diag_value('frames_fused', GEOREF) is not None, 60), 'no georef node'
        georef = next(c for c in children_of(graph.pid) if ' node georef ' in cmdline_of(c) + ' ')
        player = srmosaic('play', str(DEMO), '--rate', '1.0', '--delay', '15', env=ros_env)
        try:
            assert listener.wait_for(lambda: listener.poses, 120), 'no pose'
            time.sleep(0.2)
            os.kill(georef, signal.SIGSTOP)
            time.sleep(1.5)
            os.kill(georef, signal.SIGCONT)
            out, _ = player.communicate(timeout=120)
            assert player.returncode == 0, out
            # the first 30 registrations (the others are painted after IDLE_PAINT_S of paused input)
            assert listener.wait_for(lambda: len(listener.poses) >= 30, 60), f'{len(listener.poses)} poses'
        finally:
            if player.poll() is None:
                player.kill()
                player.communicate()
        assert all(abs(p.pose.pose.position.z - 100.0) < 10.0 for p in listener.poses), \
            [round(p.pose.pose.position.z, 1) for p in listener.poses]
        assert listener.wait_for(lambda: listener.diag_value('poses_published', GEOREF) not in (None, '0'), 10)
        skipped = {kv.key: kv.value for msg in listener.diagnostics for status in msg.status
                   if status.name == GEOREF for kv in status.values if kv.key.startswith('filter skipped')}
        assert not skipped, skipped
    standalone = {stamp_to_ns(f.header.stamp): f for f in listener.fixes}
    graph = srmosaic('launch', '--ros-args', '-p', 'live.reliable_inputs:=true', '-p', 'live.queue_size:=100', env=ros_env)
    with supervised(graph=graph) as sup:
        listener = sup.listener
        assert listener.wait_for(lambda: listener.diag_value('frames_received') is not None, 60), 'no mosaic node'
        player = srmosaic('play', str(DEMO), '--rate', '2.0', '--delay', '15', env=ros_env)
        out, _ = player.communicate(timeout=120)
        assert player.returncode == 0, out
        assert listener.wait_for(lambda: len(listener.fixes) >= 30, 60), f'{len(listener.fixes)} fixes'
        in_node_skipped = {kv.key: kv.value for msg in listener.diagnostics for status in msg.status
                           for kv in status.values if kv.key.startswith('filter skipped')}
    in_node = {stamp_to_ns(f.header.stamp): f for f in listener.fixes}
    common = sorted(set(standalone) & set(in_node))
    assert len(common) >= 30, (len(standalone), len(in_node))
    apart = {t: math.hypot((a.latitude - b.latitude) * 111_320.0,
                           (a.longitude - b.longitude) * 111_320.0 * math.cos(math.radians(a.latitude)),
                           a.altitude - b.altitude) for t, a, b in ((t, standalone[t], in_node[t]) for t in common)}
    worst = max(apart.values())
    # it failed now and then under load (2026-12-07, also before that day's changes): say which frames
    # moved, and which run moved them (each one's distance from the simulated truth there, m)
    truth = {f['stamp_ns']: f for f in json.loads((DEMO / 'ground_truth.json').read_text())['frames']}

    def off(fix) -> float | None:
        t = truth.get(stamp_to_ns(fix.header.stamp))
        return None if t is None else round(math.hypot(
            (fix.latitude - t['latitude_deg']) * 111_320.0,
            (fix.longitude - t['longitude_deg']) * 111_320.0 * math.cos(math.radians(fix.latitude))), 2)
    assert worst < 0.01, (worst, {t: (round(d, 3), 'standalone', off(standalone[t]), 'in-node', off(in_node[t]))
                                  for t, d in apart.items() if d >= 0.01}, 'in-node filter', in_node_skipped)




def test_a_second_ctrl_c_kills_the_launch_children_still_running(ros_env, tmp_path):
    """Ctrl-C to `srmosaic launch` stops the children cleanly and waits for them (they write their
    outputs); a child that does not finish (here: stopped by SIGSTOP) kept the launcher waiting for
    ever. Now the launcher says whom it waits for, and a second Ctrl-C kills them, named (status 1)."""
    description = tmp_path / 'one.yaml'
    description.write_text('processes:\n  - {name: ground, nodes: [georef]}\n')
    graph = srmosaic('launch', str(description), env=ros_env)
    child = None
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and child is None:
            child = next((c for c in children_of(graph.pid) if ' node georef' in cmdline_of(c)), None)
            time.sleep(0.3)
        assert child is not None, 'no georef child'
        time.sleep(3.0)  # past its start
        os.kill(child, signal.SIGSTOP)  # a child that never finishes its shutdown
        graph.send_signal(signal.SIGINT)
        time.sleep(2.0)
        assert graph.poll() is None, 'the launcher did not wait for its child'
        graph.send_signal(signal.SIGINT)
        out, _ = graph.communicate(timeout=30)
    finally:
        if child is not None and is_running(child):
            os.kill(child, signal.SIGKILL)
        if graph.poll() is None:
            graph.kill()
            graph.communicate()
    assert 'srmosaic launch: stopping; waiting for ground to finish' in out, out
    assert 'srmosaic launch: killed ground' in out, out
    assert graph.returncode == 1, out
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and is_running(child):
        time.sleep(0.2)
    assert not is_running(child)


def test_command_line_overrides_beat_the_parameter_files(tmp_path):
    """rcl lets a --params-file beat a -p override; the launcher moves -p into a file given last."""
    import rclpy
    from rclpy.node import Node

    from srmosaic_ros.nodes.launcher import overrides_last, ros_args

    args = ['srmosaic', *ros_args([]), *overrides_last(['--ros-args', '-p', 'registration.max_features:=500',
                                                        '-r', '/fix:=/gps'], tmp_path)]
    assert args[-2] == '--params-file' and '-r' in args and '-p' not in args[4:]
    context = rclpy.Context()
    rclpy.init(args=args, context=context)
    try:
        node = Node('srmosaic_mosaic', context=context)
        assert node.declare_parameter('registration.max_features', 1000).value == 500
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='reads child processes from /proc (Linux)')
def test_a_launch_child_killed_is_named_and_leaves_no_sr_worker(ros_env, tmp_path):
    """kill -9 of the process running the SR node: the launcher names it and stops the other one,
    and the SR worker process (spawned by the node) ends with it; it used to idle on for minutes."""
    description = tmp_path / 'two.yaml'
    description.write_text('processes:\n  - {name: onboard, nodes: [mosaic]}\n  - {name: ground, nodes: [sr]}\n')
    graph = srmosaic('launch', str(description), env=ros_env)
    try:
        deadline, sr_child, workers = time.monotonic() + 90, None, []
        while time.monotonic() < deadline and not workers:
            sr_child = next((c for c in children_of(graph.pid) if ' node sr ' in cmdline_of(c) + ' '), None)
            if sr_child is not None:
                workers = [w for w in children_of(sr_child) if 'spawn_main' in cmdline_of(w)]
            time.sleep(0.5)
        assert sr_child is not None and workers, 'no SR node with its worker process'
        time.sleep(2.0)  # the worker past its start
        os.kill(sr_child, signal.SIGKILL)
        out, _ = graph.communicate(timeout=90)
    finally:
        if graph.poll() is None:
            graph.kill()
            graph.communicate()
    assert graph.returncode != 0
    assert 'srmosaic launch: ground was killed by SIGKILL; stopping the others' in out, out
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(is_running(w) for w in workers):
        time.sleep(0.2)
    assert not any(is_running(w) for w in workers), 'the SR worker outlived its node'
