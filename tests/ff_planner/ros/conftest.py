"""Fixtures of the planner-node tests: the ``ff_planner`` node in another process (started and
stopped by PID with ff_msgs_py.launch.start_module, over DDS on loopback in the module's ROS
domain) and a ``~/plan`` service client of it.

A test module says how its node runs with module-level names:

- ``planner_parameters(folder: Path) -> str``: the lines under ``ros__parameters:`` of the node's
  planner.yaml, indented four spaces (``folder``: the module's temporary folder);
- ``PLANNER_MODULE`` (optional): the module run with ``python -m`` (default
  ``ff_planner.ros.planner_node``; a stand-in planner's module runs the node with it);
- ``planner_env(folder: Path) -> dict`` (optional): variables added to the node's environment.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

NODE_MODULE = "ff_planner.ros.planner_node"
READY = "ff_planner ready"
READY_TIMEOUT = 240.0   # s: the node's start-up (its worker processes) on a loaded 2-core machine


@dataclass
class PlannerProcess:
    """The node under test: its process (ff_msgs_py.launch.NodeProcess) and the module's folder
    (its planner.yaml; files the node writes there)."""

    proc: Any
    folder: Path

    def alive(self) -> bool:
        return bool(self.proc.alive())

    def output(self) -> str:
        return str(self.proc.output())


def write_parameters(folder: Path, body: str) -> Path:
    """``folder``/planner.yaml holding ``body`` (lines indented four spaces) as the node's
    ``ros__parameters``."""
    path = folder / "planner.yaml"
    path.write_text("ff_planner:\n  ros__parameters:\n" + body)
    return path


@pytest.fixture(scope="module")
def planner_node(request, ros_env, tmp_path_factory):
    """The module's planner node, ready (it logged "ff_planner ready"); stopped after the module,
    which fails if the node printed a traceback."""
    from ff_msgs_py.launch import start_module, wait_for_line

    module = request.module
    folder = tmp_path_factory.mktemp(module.__name__.rsplit(".", 1)[-1])
    params = write_parameters(folder, module.planner_parameters(folder))
    env = dict(ros_env, **(module.planner_env(folder) if hasattr(module, "planner_env") else {}))
    proc = start_module("ff_planner_node", getattr(module, "PLANNER_MODULE", NODE_MODULE),
                        ["--ros-args", "--params-file", str(params)], env)
    try:
        assert wait_for_line(proc, READY, READY_TIMEOUT), proc.output()
        yield PlannerProcess(proc, folder)
    finally:
        code = proc.stop()
        assert not proc.alive()
        assert "Traceback" not in proc.output(), proc.output()[-3000:]
        assert code is not None


@pytest.fixture(scope="module")
def client(planner_node, ros_env):
    """(rclpy node, PlanTrajectory client of /ff_planner/plan) in a context of their own; the
    client's queue holds a burst of requests (depth 200)."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile

    from ff_msgs.srv import PlanTrajectory

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("ff_planner_test_client", context=ctx)
    cli = node.create_client(PlanTrajectory, "/ff_planner/plan", qos_profile=QoSProfile(depth=200))
    assert cli.wait_for_service(timeout_sec=20), "planner service not discovered"
    try:
        yield node, cli
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
