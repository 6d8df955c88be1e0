"""The stack client waits for the streams it records before a move, and names the one that is
silent: a publisher in another process is discovered on its own schedule, whatever services or
actions already answer. rclpy in this process, no stack."""
from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.integration


def test_wait_for_streams_names_the_silent_stream_and_returns_once_both_are_heard(ros_env):
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from ff_executor.ros.client import StackCallError, StackClient
    from tests.support.ros_harness import spinning

    client = StackClient(ros_env, "ff_client_streams_test")
    pub_node = Node("ff_fake_streams", context=client.ctx)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    truth = pub_node.create_publisher(JointState, "/ff_sim_driver/ground_truth", qos)
    currents = pub_node.create_publisher(JointState, "/ff_hwbridge/motor_currents", qos)
    try:
        with spinning(client.ctx, pub_node, threads=2):
            with pytest.raises(StackCallError) as info:
                client.wait_for_streams(timeout=0.3)
            msg = str(info.value)
            assert "/ff_sim_driver/ground_truth" in msg and "/ff_hwbridge/motor_currents" in msg

            def sample() -> JointState:
                m = JointState(name=["j1"], position=[0.0], velocity=[0.0], effort=[0.0])
                m.header.stamp = pub_node.get_clock().now().to_msg()
                return m

            end = time.monotonic() + 10.0              # until the subscription has matched
            while time.monotonic() < end and client.last_truth is None:
                truth.publish(sample())
                time.sleep(0.05)
            assert client.last_truth is not None
            with pytest.raises(StackCallError) as info:
                client.wait_for_streams(timeout=0.3)
            assert "motor_currents" in str(info.value) and "ground_truth" not in str(info.value)
            since = time.monotonic()
            end = time.monotonic() + 10.0
            while time.monotonic() < end:
                truth.publish(sample())
                currents.publish(sample())
                try:
                    client.wait_for_streams(timeout=0.05, since=since)
                    break
                except StackCallError:
                    continue
            client.wait_for_streams(timeout=1.0, since=since)      # both heard after ``since``
    finally:
        client.close()
