"""The nodes' tests run real graphs over DDS on loopback, each test in a ROS domain of its own."""
from __future__ import annotations

import os

import pytest

from ros_graph import ros_domain_id


@pytest.fixture
def ros_env(monkeypatch):
    """This test's ROS_DOMAIN_ID (ros_graph.ros_domain_id) and LOCALHOST discovery, set in this process
    (for the listener) and returned as the environment for the processes under test."""
    monkeypatch.setenv('ROS_DOMAIN_ID', str(ros_domain_id()))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return dict(os.environ)
