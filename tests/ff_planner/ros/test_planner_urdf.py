"""The ff_planner node (another process, over DDS on loopback) serving arms from a URDF by model
id ``urdf:NAME``: a shipped arm (registered by config/planner.yaml) and one the test registers with
arms.NAME.urdf / arms.NAME.cell are planned robust-box with their certificate; malformed and
unknown names and requests an arm cannot serve are answered with one clear error and the node
goes on serving; a registered file that does not exist stops the node at start with a clear line."""
from __future__ import annotations

import math
import re
import time
from pathlib import Path

import pytest

from tests.ff_planner.ros.conftest import write_parameters

pytestmark = pytest.mark.integration

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"


BASE_PARAMETERS = """    library_path: ""
    use_library: false
    drive_config: ""
    workers: 1
    warmup: false
    default_time_budget: 20.0
    diagnostics_period: 0.0
"""


# the node in another process: tests/ff_planner/ros/conftest.py (planner_node, client)
def planner_parameters(folder: Path) -> str:
    return BASE_PARAMETERS + f"""    arms:
      mine: {{urdf: "{ARMS / 'arm1dof.urdf'}", cell: "{ARMS / 'arm1dof.cell.yaml'}"}}
"""


def _call(client, timeout=240.0, **fields):
    from rclpy.executors import SingleThreadedExecutor

    from ff_msgs.srv import PlanTrajectory

    node, cli = client
    fut = cli.call_async(PlanTrajectory.Request(**fields))
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + timeout
    try:
        while not fut.done() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
    finally:
        ex.remove_node(node)
    assert fut.done(), f"no answer to {fields}"
    return fut.result()


def test_the_node_logs_its_registered_arms(planner_node):
    out = planner_node.output()
    for name in ("urdf:arm1dof", "urdf:arm3h", "urdf:scara2", "urdf:vertical2", "urdf:mine"):
        assert name in out, out[-2000:]


@pytest.mark.parametrize("model", ["urdf:arm1dof", "urdf:mine"])
def test_a_registered_arm_is_planned_with_its_certificate(client, model):
    from ff_msgs.srv import PlanTrajectory

    res = _call(client, model=model, q0=[0.0], qf=[0.5], move_time=1.0, time_budget=20.0)
    assert res.success and res.error_code == PlanTrajectory.Response.OK, res.message
    assert "plan for " + model in res.message and "certified worst rest error" in res.message
    assert res.certificate.certified and len(res.certificate.worst_per_joint) == 1
    assert 0.0 < res.certificate.worst_rest_error < 0.5
    assert set(res.certificate.box_names) == {"pv@joint1", "pc@joint1", "pt@joint1"}
    assert list(res.profile.joint_names) == ["joint1"] and res.profile.model == model
    assert abs(res.profile.predicted_rest[0] - 0.5) < 1e-6 and abs(res.q_final[0] - 0.5) < 1e-6
    assert res.profile.n_steps >= 1 and len(res.profile.currents) == res.profile.n_steps
    assert max(abs(c) for c in res.profile.currents) <= 10.0 + 1e-9    # the cell's i_max


BAD = [
    (dict(model="urdf:"), "INVALID_REQUEST", "malformed"),
    (dict(model="urdf:no such"), "INVALID_REQUEST", "malformed"),
    (dict(model="urdf:arm9"), "UNKNOWN_MODEL", "no arm named 'arm9'"),
    (dict(model="urdf:arm3h"), "INVALID_REQUEST", "need 3 values"),
    (dict(model="urdf:arm1dof", objective="time-optimal"), "INVALID_REQUEST", "robust-box only"),
    (dict(model="urdf:arm1dof", uncertain=["pc"]), "INVALID_REQUEST", "uncertain: not taken"),
    (dict(model="urdf:arm1dof", move_time=0.0), "INVALID_REQUEST", "move_time"),
    (dict(model="urdf:arm1dof", tolerance=-0.01), "INVALID_REQUEST", "tolerance must be >= 0 rad"),
    (dict(model="urdf:arm1dof", tolerance=math.nan), "INVALID_REQUEST", "tolerance must be >= 0 rad"),
    (dict(model="urdf:arm1dof", move_time_max=2.0), "INVALID_REQUEST", "give a tolerance too"),
    (dict(model="urdf:arm1dof", tolerance=0.1, move_time_max=61.0), "INVALID_REQUEST",
     "move_time_max must be in (0.05, 60] s"),
    (dict(model="urdf:arm1dof", tolerance=0.1, move_time_max=0.04), "INVALID_REQUEST",
     "move_time_max must be in (0.05, 60] s"),
    (dict(model="urdf:arm1dof", tolerance=0.1, move_time_max=math.inf), "INVALID_REQUEST",
     "move_time_max must be in"),
]


def test_bad_model_ids_and_requests_get_one_clear_error(client, planner_node):
    from ff_msgs.srv import PlanTrajectory

    for fields, code, text in BAD:
        req = dict(dict(q0=[0.0], qf=[0.5], move_time=1.0), **fields)
        res = _call(client, timeout=120.0, **req)
        assert not res.success, fields
        assert res.error_code == getattr(PlanTrajectory.Response, code), (fields, res.message)
        assert text in res.message, (fields, res.message)
    assert planner_node.alive()
    # and it still plans the suite's own models
    ok = _call(client, model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, objective="time-optimal")
    assert ok.success, ok.message


def _tried(message: str) -> list[tuple[float, float, bool]]:
    """(tf s, certified worst mrad, met) of every move time a tolerance search lists in its
    message ("tried (tf: certified mrad) 0.600 s: 256, 0.267 s: 348 (fails), ...")."""
    listed = message.split("tried (tf: certified mrad) ", 1)[1].split(". Plan:", 1)[0]
    return [(float(tf), math.inf if w == "-" else float(w), not fails)
            for tf, w, fails in re.findall(r"(\d+\.\d+) s: (-|[0-9.eE+]+)( \(fails\))?", listed)]


# 0 -> 0.5 rad, N = 6 (measured through plan_registered at load 4.8: 256 mrad at 0.600 s in
# 0.3 s, 28 mrad at 0.378 s in 2.5 s, 348-543 mrad from 0.160 s to 0.267 s, 2.5-4 s each)
TOL_MOVE = dict(model="urdf:arm1dof", q0=[0.0], qf=[0.5], steps=6)


def test_the_service_answers_the_fastest_move_time_within_a_tolerance(client):
    """Tolerance first over the service: the answer is the shortest tf tried (≤ move_time_max)
    whose certified worst rest error is within the tolerance; every shorter tf tried failed it;
    the whole search keeps to the request's time budget (move_time is ignored)."""
    from ff_msgs.srv import PlanTrajectory

    tol, tf_max, budget = 0.3, 0.6, 30.0          # rad, s, s
    res = _call(client, **dict(TOL_MOVE, move_time=5.0, tolerance=tol, move_time_max=tf_max,
                               time_budget=budget))
    assert res.success and res.error_code == PlanTrajectory.Response.OK, res.message
    assert res.message.startswith("fastest tf certified within 300 mrad: "), res.message
    tf = res.profile.move_time
    assert 0.05 < tf <= tf_max + 1e-9 and res.profile.model == "urdf:arm1dof"
    cert = res.certificate
    assert cert.certified and cert.worst_rest_error <= tol and len(cert.worst_per_joint) == 1
    assert abs(res.profile.predicted_rest[0] - 0.5) < 1e-6
    tried = _tried(res.message)
    assert tried and all(t <= tf_max + 1e-9 for t, _, _ in tried), tried
    assert tried[0][0] == pytest.approx(tf_max), tried          # move_time_max first
    answered = [(w, met) for t, w, met in tried if abs(t - tf) < 5e-4]
    assert answered and answered[-1][1] and answered[-1][0] <= 1e3 * tol + 0.5, (tf, tried)
    assert all(not met for t, _, met in tried if t < tf - 5e-4), (tf, tried)
    assert res.solve_time <= budget + 30.0, res.solve_time


def test_an_impossible_tolerance_is_refused_in_one_line_and_changes_nothing(client, planner_node):
    """No tf ≤ move_time_max meets the tolerance: NO_ROBUST_PLAN with one line saying so and
    what to change, the least-worst plan labelled (not a success); the node's next answers are
    the ones it gave before."""
    from ff_msgs.srv import PlanTrajectory

    plain = dict(TOL_MOVE, move_time=0.6, time_budget=60.0)
    before = _call(client, **plain)
    assert before.success, before.message
    res = _call(client, **dict(TOL_MOVE, move_time=0.0, tolerance=1e-4, move_time_max=0.6,
                               time_budget=30.0))
    assert not res.success and res.error_code == PlanTrajectory.Response.NO_ROBUST_PLAN
    assert res.message.startswith("no move time up to 0.6 s is certified within 0.1 mrad: "), res.message
    assert "relax the tolerance, raise the longest move time" in res.message
    assert "\n" not in res.message
    assert res.certificate.worst_rest_error > 1e-4 and res.profile.move_time <= 0.6 + 1e-9
    assert not any(met for _, _, met in _tried(res.message))
    after = _call(client, **plain)
    assert after.success and list(after.profile.currents) == list(before.profile.currents)
    assert after.certificate.worst_rest_error == before.certificate.worst_rest_error
    assert planner_node.alive()


def test_a_registered_file_that_does_not_exist_stops_the_node_at_start(ros_env, tmp_path):
    from ff_msgs_py.launch import start_module

    params = write_parameters(tmp_path, BASE_PARAMETERS + f"""    arms:
      ghost: {{urdf: "{tmp_path / 'ghost.urdf'}", cell: "{ARMS / 'arm3h.cell.yaml'}"}}
""")
    proc = start_module("ff_planner_bad", "ff_planner.ros.planner_node",
                        ["--ros-args", "--params-file", str(params)], ros_env, log_dir=str(tmp_path))
    end = time.monotonic() + 120
    while proc.alive() and time.monotonic() < end:
        time.sleep(0.1)
    try:
        assert not proc.alive(), "the node should refuse its configuration"
        out = proc.output()
        assert "bad configuration" in out and "arms.ghost.urdf" in out and "no such file" in out, out
        assert "Traceback" not in out
    finally:
        proc.stop()


def test_the_plan_long_action_serves_a_registered_arm_too(planner_node, client):
    from action_msgs.msg import GoalStatus
    from rclpy.action import ActionClient
    from rclpy.executors import SingleThreadedExecutor

    from ff_msgs.action import PlanMotion

    node = client[0]
    act = ActionClient(node, PlanMotion, "/ff_planner/plan_long")
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)

    def spin_until(cond, timeout):
        end = time.monotonic() + timeout
        while not cond() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        return cond()

    try:
        assert act.wait_for_server(timeout_sec=30)
        for fields, status in ((dict(model="urdf:arm1dof", q0=[0.0], qf=[0.3], move_time=1.0,
                                     time_budget=20.0), GoalStatus.STATUS_SUCCEEDED),
                               (dict(model="urdf:arm9", q0=[0.0], qf=[0.3], move_time=1.0),
                                GoalStatus.STATUS_ABORTED),
                               (dict(TOL_MOVE, tolerance=1e-4, move_time_max=0.6, time_budget=30.0),
                                GoalStatus.STATUS_ABORTED)):
            fut = act.send_goal_async(PlanMotion.Goal(**fields))
            assert spin_until(fut.done, 30) and fut.result().accepted
            res_fut = fut.result().get_result_async()
            assert spin_until(res_fut.done, 240), "no result"
            wrapped = res_fut.result()
            assert wrapped.status == status, wrapped.result.message
            if status == GoalStatus.STATUS_SUCCEEDED:
                r = wrapped.result
                assert r.success and r.certificate.certified and list(r.profile.joint_names) == ["joint1"]
                assert abs(r.q_final[0] - 0.3) < 1e-6
            elif fields["model"] == "urdf:arm9":
                assert "no arm named 'arm9'" in wrapped.result.message
            else:       # the tolerance reaches the arm's search through the action too
                assert wrapped.result.error_code == PlanMotion.Result.NO_ROBUST_PLAN
                assert wrapped.result.message.startswith("no move time up to 0.6 s is certified "
                                                         "within 0.1 mrad"), wrapped.result.message
    finally:
        ex.remove_node(node)
        act.destroy()
