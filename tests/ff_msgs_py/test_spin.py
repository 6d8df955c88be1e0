"""ff_msgs_py.spin: an executor spun through it outlives entities destroyed from another thread."""
from __future__ import annotations

import threading
import time

import pytest
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException

from ff_msgs_py.spin import spin


class _Executor:
    """spin() raises each of ``outcomes`` in turn (None: returns)."""

    def __init__(self, outcomes) -> None:
        self.outcomes, self.calls = list(outcomes), 0

    def spin(self) -> None:
        self.calls += 1
        out = self.outcomes.pop(0)
        if out is not None:
            raise out


def test_an_invalid_handle_is_spun_past_and_counted():
    ex = _Executor([InvalidHandle("destruction was requested")] * 3 + [None])
    assert spin(ex) == 3 and ex.calls == 4


def test_a_shutdown_ends_it_and_other_errors_propagate():
    assert spin(_Executor([ExternalShutdownException()])) == 0
    with pytest.raises(ZeroDivisionError):
        spin(_Executor([InvalidHandle("x"), ZeroDivisionError()]))


@pytest.mark.integration
def test_a_node_is_served_on_while_another_thread_destroys_its_publishers(ros_env):
    """Publishers and subscriptions (with the QoS event handlers rclpy gives them) created and
    destroyed from the test's thread as fast as it can while a MultiThreadedExecutor spins the
    node, whose 0.5 ms timer keeps it rebuilding its wait set: the spinning thread lives on and
    the timer keeps firing. (With ``executor.spin()`` alone the thread died of InvalidHandle
    after 0.6 s of this, 57 pairs destroyed; through ``spin``: 6,505 pairs in 10 s, 7 races
    spun past.)"""
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import Bool

    from tests.support.ros_harness import ros_context

    with ros_context() as ctx:
        node = Node("ff_spin_test", context=ctx)
        for i in range(20):          # a wait set as long as a real node's
            node.create_subscription(Bool, f"~/topic{i}", lambda _m: None, 1)
        ex = MultiThreadedExecutor(num_threads=4, context=ctx)
        ex.add_node(node)
        died: list[BaseException] = []

        def run() -> None:
            try:
                spin(ex)
            except BaseException as exc:  # noqa: BLE001 - asserted below
                died.append(exc)

        th = threading.Thread(target=run, daemon=True)
        th.start()
        ticks = [0]
        node.create_timer(0.0005, lambda: ticks.__setitem__(0, ticks[0] + 1))
        try:
            churned = 0
            end = time.monotonic() + 3.0
            while time.monotonic() < end and not died:
                pub = node.create_publisher(Bool, "~/churn_out", 1)
                sub = node.create_subscription(Bool, "~/churn_in", lambda _m: None, 1)
                node.destroy_publisher(pub)
                node.destroy_subscription(sub)
                churned += 1
            assert not died and th.is_alive(), (died, churned)
            before = ticks[0]
            time.sleep(0.3)
            assert ticks[0] > before, "the node's timer stopped firing"
            assert churned >= 50, churned
        finally:
            ex.shutdown()
            th.join(5.0)
            node.destroy_node()
