"""Smoke test: an ff_msgs service served by another process, called over DDS on loopback."""
from __future__ import annotations

import pytest
from rclpy.executors import SingleThreadedExecutor

from ff_msgs.srv import PlanTrajectory
from ff_msgs_py.launch import domain_in_use, free_domain_id, start_module, wait_for_line

pytestmark = pytest.mark.integration


def call(node, client, request, timeout=10.0):
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    future = client.call_async(request)
    ex.spin_until_future_complete(future, timeout_sec=timeout)
    ex.remove_node(node)
    assert future.done(), "no answer from the service"
    return future.result()


def test_plan_service_in_other_process(ros_env, rclpy_node):
    proc = start_module("plan_echo", "tests.support.plan_echo_node", [], ros_env)
    try:
        assert wait_for_line(proc, "plan_echo ready", 30), proc.output()
        client = rclpy_node.create_client(PlanTrajectory, "/plan_echo/plan")
        assert client.wait_for_service(timeout_sec=15), "service not discovered"
        res = call(rclpy_node, client, PlanTrajectory.Request(model="arm1dof", qf=[1.25], move_time=1.0))
        assert res.success and res.error_code == PlanTrajectory.Response.OK
        assert list(res.q_final) == [1.25]
        assert list(res.profile.step_times) == [0.0, 0.95]
        bad = call(rclpy_node, client, PlanTrajectory.Request(model="nope", qf=[1.0], move_time=1.0))
        assert not bad.success and bad.error_code == PlanTrajectory.Response.UNKNOWN_MODEL
        assert proc.alive()
    finally:
        proc.stop()
    assert not proc.alive()


def test_free_domain_skips_a_domain_in_use(ros_env):
    busy = int(ros_env["ROS_DOMAIN_ID"])
    proc = start_module("plan_echo_domain", "tests.support.plan_echo_node", [], ros_env)
    try:
        assert wait_for_line(proc, "plan_echo ready", 30), proc.output()
        assert domain_in_use(busy)
        picks = {free_domain_id() for _ in range(200)}
        assert busy not in picks and picks <= set(range(1, 101))
    finally:
        proc.stop()
