"""Shared fixtures: a per-run loopback-only ROS environment for this test process and its children."""
from __future__ import annotations

import os
import tempfile

import pytest

from ff_msgs_py.launch import apply_ros_environment, ros_environment


@pytest.fixture(scope="session")
def ros_env() -> dict[str, str]:
    """Environment for child processes; also applied to this process (rclpy in tests)."""
    log_dir = tempfile.mkdtemp(prefix="ff-test-roslog-")
    env = ros_environment(log_dir=log_dir)
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (repo, env.get("PYTHONPATH", "")) if p)
    apply_ros_environment(env)
    return env


@pytest.fixture
def rclpy_node(ros_env):
    """An rclpy context + node for calling services/actions from the test process."""
    import rclpy
    from rclpy.node import Node

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("ff_test_client", context=ctx)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
