"""The planner's action ``~/plan_long`` (ff_msgs/action/PlanMotion), from another process:
progress feedback, cancel, one goal at a time, and the service answering while a goal runs.

The node runs ``tests.ff_planner.service.stand_ins.progress_plan``: the real planner for seed 0, a
stand-in reporting progress for ``starts`` x 10 ms (seed 1) or until its budget (other seeds).
"""
from __future__ import annotations

import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration


# the node in another process: tests/ff_planner/ros/conftest.py (planner_node)
PLANNER_MODULE = "tests.ff_planner.service.stand_ins"


def planner_parameters(folder: Path) -> str:
    return """    library_path: ""
    drive_config: ""                 # continuous plans (the shipped default is drive-exact)
    workers: 2
    warmup: false
    max_time_budget: 600.0
    diagnostics_period: 0.0
"""


@pytest.fixture(scope="module")
def clients(planner_node):
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.node import Node

    from ff_msgs.action import PlanMotion
    from ff_msgs.srv import PlanTrajectory

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("ff_plan_action_test", context=ctx)
    act = ActionClient(node, PlanMotion, "/ff_planner/plan_long")
    srv = node.create_client(PlanTrajectory, "/ff_planner/plan")
    assert act.wait_for_server(timeout_sec=30) and srv.wait_for_service(timeout_sec=30)
    try:
        yield node, act, srv
    finally:
        act.destroy()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def _spin_until(node, cond, timeout):
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + timeout
    try:
        while not cond() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
    finally:
        ex.remove_node(node)
    return cond()


def _send(clients, feedback, **fields):
    from ff_msgs.action import PlanMotion

    node, act, _ = clients
    fut = act.send_goal_async(PlanMotion.Goal(**fields), feedback_callback=lambda m: feedback.append(m.feedback))
    assert _spin_until(node, fut.done, 30), "goal not answered"
    return fut.result()


ONE_DOF = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pc"],
               objective="robust-derivative")


def test_a_plan_with_progress_feedback_then_a_real_plan_with_its_certificate(clients):
    from action_msgs.msg import GoalStatus

    node = clients[0]
    feedback: list = []
    handle = _send(clients, feedback, **dict(ONE_DOF, seed=1, starts=150))     # ~1.5 s of progress
    assert handle.accepted
    res_fut = handle.get_result_async()
    assert _spin_until(node, res_fut.done, 60)
    wrapped = res_fut.result()
    assert wrapped.status == GoalStatus.STATUS_SUCCEEDED, wrapped.result.message
    assert wrapped.result.success and wrapped.result.profile.n_steps == 3
    assert len(feedback) >= 3, feedback
    done = [f.starts_done for f in feedback]
    assert done == sorted(done) and done[-1] >= 20 and feedback[-1].stage == "stand-in"
    assert all(f.starts_total == 150 and f.steps == 3 for f in feedback)
    assert feedback[-1].best_cost < 0.1 and feedback[-1].elapsed > feedback[0].elapsed
    real: list = []
    handle = _send(clients, real, **dict(ONE_DOF, uncertain=["pv", "pc", "pt"], seed=0, starts=50))
    res_fut = handle.get_result_async()
    assert _spin_until(node, res_fut.done, 120)
    out = res_fut.result().result
    assert out.success and out.robust and out.certificate.certified, out.message
    assert abs(out.profile.predicted_rest[0] - 1.0) < 1e-4


def test_cancel_stops_a_long_plan_promptly_and_one_goal_at_a_time(clients):
    from action_msgs.msg import GoalStatus

    from ff_msgs.srv import PlanTrajectory

    node, _, srv = clients
    feedback: list = []
    handle = _send(clients, feedback, **dict(ONE_DOF, seed=9, time_budget=300.0))   # runs until canceled
    assert handle.accepted
    assert _spin_until(node, lambda: any(f.starts_done > 0 for f in feedback), 30), feedback
    second = _send(clients, [], **dict(ONE_DOF, seed=1, starts=5))
    assert not second.accepted                              # busy: rejected (reason in the node's log)
    fast = srv.call_async(PlanTrajectory.Request(**dict(ONE_DOF, seed=1, starts=3)))
    assert _spin_until(node, fast.done, 30) and fast.result().success    # the service serves on
    t0 = time.monotonic()
    cancel = handle.cancel_goal_async()
    res_fut = handle.get_result_async()
    assert _spin_until(node, res_fut.done, 30)
    took = time.monotonic() - t0
    assert res_fut.result().status == GoalStatus.STATUS_CANCELED
    assert "canceled" in res_fut.result().result.message and not res_fut.result().result.success
    assert cancel.done() and took < 5.0, took
    after = _send(clients, [], **dict(ONE_DOF, seed=1, starts=5))       # free again
    assert after.accepted
    res_fut = after.get_result_async()
    assert _spin_until(node, res_fut.done, 30) and res_fut.result().status == GoalStatus.STATUS_SUCCEEDED
