"""nodes.runner.run_nodes and the stop signals: the first SIGINT lets the callback running finish,
then the nodes finish and the process exits 0; a second interrupts a callback that does not return.
Each case in a process of its own (run_nodes installs signal handlers and initialises rclpy)."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from repo_paths import REPO
from ros_graph import ros_domain_id

pytestmark = pytest.mark.ros

NODE = textwrap.dedent('''
    import os, signal, sys, time
    from rclpy.node import Node
    from srmosaic_ros.nodes.runner import run_nodes

    SIGNALS = int(sys.argv[1])

    class Stopper(Node):
        """Its timer's callback gets SIGINT in the middle of its work (as a node does when the
        signal lands inside rclpy's conversion of a message) and then goes on for 0.3 s."""

        def __init__(self):
            super().__init__('stopper')
            self.create_timer(0.05, self.tick)

        def tick(self):
            for _ in range(SIGNALS):
                os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.3)
            print('callback completed', flush=True)

        def finish(self):
            print('finished', flush=True)

    sys.exit(run_nodes([Stopper], ['test']))
''')


def _run(signals: int, tmp_path) -> subprocess.CompletedProcess:
    script = tmp_path / 'stopper.py'
    script.write_text(NODE)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(ros_domain_id()),
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]))
    return subprocess.run([sys.executable, str(script), str(signals)], capture_output=True, text=True, timeout=60,
                          env=env, cwd=REPO)


def test_first_sigint_lets_the_running_callback_finish_then_exits_cleanly(tmp_path):
    done = _run(1, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines() == ['callback completed', 'finished'], done.stdout + done.stderr
    assert 'Traceback' not in done.stderr, done.stderr


def test_second_sigint_interrupts_a_callback_and_still_finishes_the_nodes(tmp_path):
    done = _run(2, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines() == ['finished'], done.stdout + done.stderr
