"""The ff_planner node served from ANOTHER process (started with ff_msgs_py.launch.start_module), called
over DDS on loopback with good and bad requests.

The node runs ``tests.support.stand_in_planners.slow_plan``: the real planner facade for 1-DOF
requests, and for scara2 a stand-in that takes ``SLOW_S`` seconds (or ignores its budget when
asked), so that the concurrency and time-budget checks do not depend on how long a real 2-DOF plan
takes.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration


# --- the node in another process (tests/ff_planner/ros/conftest.py: planner_node, client) ------
PLANNER_MODULE = "tests.support.stand_in_planners"


def planner_parameters(folder: Path) -> str:
    return f"""    library_path: "{folder / 'motions.sqlite'}"
    motion_dir: "{folder / 'motions'}"
    drive_config: ""                 # continuous plans (the shipped default is drive-exact)
    workers: 2
    max_pending: 4
    default_time_budget: 150.0
    max_steps: 30
    grace: 0.3
    diagnostics_period: 0.5
"""


def planner_env(folder: Path) -> dict[str, str]:
    return {"FF_TEST_RELEASE": str(folder / "release")}


def _wait(node, futures, timeout=60.0):
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + timeout
    try:
        while not all(f.done() for f in futures) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
    finally:
        ex.remove_node(node)
    return [f.result() if f.done() else None for f in futures]


def _call(client, timeout=180.0, **fields):
    from ff_msgs.srv import PlanTrajectory

    node, cli = client
    res = _wait(node, [cli.call_async(PlanTrajectory.Request(**fields))], timeout)[0]
    assert res is not None, f"no answer to {fields}"
    return res


ONE_DOF = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, objective="time-optimal")


def test_good_request_then_warm_from_the_library(client, planner_node):
    from ff_msgs.srv import PlanTrajectory

    res = _call(client, **ONE_DOF)
    assert res.success and res.error_code == PlanTrajectory.Response.OK, res.message
    assert not res.warm_start
    assert res.profile.n_steps >= 1 and len(res.profile.step_times) == res.profile.n_steps + 1
    assert res.profile.step_times[-1] <= 1.0 - 0.05 + 1e-9
    assert abs(res.q_final[0] - 1.0) < 1e-6
    again = _call(client, **ONE_DOF)
    assert again.success and again.warm_start, again.message
    assert list(again.profile.currents) == list(res.profile.currents)
    shifted = _call(client, **dict(ONE_DOF, q0=[2.0], qf=[3.0]))     # same motion, 2 rad further on
    assert shifted.success and shifted.warm_start
    assert abs(shifted.q_final[0] - 3.0) < 1e-6
    assert list(shifted.profile.qf) == [3.0]
    # optional motion-file output
    files = list((planner_node.folder / "motions").glob("*.json"))
    assert files and json.loads(files[0].read_text())["format"] == "ff-motion/1"


def test_robust_1dof_plan_cold_then_warm_from_its_neighbour(client):
    fields = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pv", "pc", "pt"],
                  starts=50, seed=1, objective="robust-derivative")
    cold = _call(client, **fields)
    assert cold.success and cold.robust and not cold.warm_start, cold.message
    assert sorted(cold.sensitivity_names) == ["pc", "pt", "pv"]
    assert max(abs(v) for v in cold.sensitivity_values) <= 1e-6
    assert abs(cold.q_final[0] - 1.0) <= 1e-6 and abs(cold.qd_final[0]) <= 1e-6
    assert cold.profile.n_steps == 5 and cold.starts_tried >= 1
    near = _call(client, **dict(fields, qf=[1.03]))      # re-optimised from the stored plan
    assert near.success and near.robust and near.warm_start, near.message
    assert "warm start from library entry" in near.message
    assert max(abs(v) for v in near.sensitivity_values) <= 1e-6
    assert abs(near.q_final[0] - 1.03) <= 1e-6


BAD = [
    (dict(ONE_DOF, model="arm7dof"), "UNKNOWN_MODEL", "known models"),
    (dict(ONE_DOF, override_names=["friction"], override_values=[0.1]), "UNKNOWN_PARAMETER", "valid keys"),
    (dict(ONE_DOF, override_names=["pc"], override_values=[]), "INVALID_REQUEST", "override"),
    (dict(ONE_DOF, objective="robust-derivative", uncertain=["pq"]), "UNKNOWN_PARAMETER", "pq"),
    (dict(ONE_DOF, qf=[math.nan]), "INVALID_REQUEST", "finite"),
    (dict(ONE_DOF, q0=[math.inf]), "INVALID_REQUEST", "finite"),
    (dict(ONE_DOF, move_time=0.04), "INVALID_REQUEST", "coast"),
    (dict(ONE_DOF, move_time=math.nan), "INVALID_REQUEST", "move_time"),
    (dict(ONE_DOF, qf=[1.0, 2.0]), "INVALID_REQUEST", "qf needs 1"),
    (dict(ONE_DOF, model="scara2"), "INVALID_REQUEST", "q0 needs 2"),
    (dict(ONE_DOF, qf=[40.0]), "UNREACHABLE", "raise tf"),
    (dict(ONE_DOF, steps=100000), "INVALID_REQUEST", "steps"),
    (dict(ONE_DOF, starts=10 ** 9), "INVALID_REQUEST", "starts"),
    (dict(ONE_DOF, time_budget=-1.0), "INVALID_REQUEST", "time_budget"),
    (dict(ONE_DOF, time_budget=1e9), "INVALID_REQUEST", "time_budget"),
    (dict(ONE_DOF, qf=[1.234], time_budget=1e-4), "TIME_BUDGET_EXHAUSTED", "time budget"),
]


def test_bad_requests_are_answered_and_the_node_keeps_serving(client, planner_node):
    from ff_msgs.srv import PlanTrajectory

    codes = {n: getattr(PlanTrajectory.Response, n) for n in
             ("INVALID_REQUEST", "UNKNOWN_MODEL", "UNKNOWN_PARAMETER", "UNREACHABLE",
              "TIME_BUDGET_EXHAUSTED")}
    for fields, code, text in BAD:
        res = _call(client, **fields)
        assert not res.success, fields
        assert res.error_code == codes[code], (fields, res.error_code, res.message)
        assert text in res.message, (fields, res.message)
    assert planner_node.alive()
    res = _call(client, **dict(ONE_DOF, qf=[0.7]))
    assert res.success, res.message


def test_time_budget_is_enforced_and_the_worker_replaced(client, planner_node):
    from ff_msgs.srv import PlanTrajectory

    res = _call(client, model="scara2", q0=[-0.5, 0.0], qf=[0.5, 0.0], move_time=1.0, seed=666,
                time_budget=1.0)
    assert not res.success and res.error_code == PlanTrajectory.Response.TIME_BUDGET_EXHAUSTED
    assert "time budget" in res.message
    ok = _call(client, **dict(ONE_DOF, qf=[0.8]))
    assert ok.success, ok.message


def test_long_2dof_plan_does_not_block_1dof_requests(client, planner_node):
    node, cli = client
    from ff_msgs.srv import PlanTrajectory

    # the stand-in 2-DOF plan works until we create the release file (or its budget is spent);
    # budgets are generous so that a loaded machine (or JIT compilation) cannot end it early
    long_req = PlanTrajectory.Request(model="scara2", q0=[-0.5, 0.0], qf=[0.25, 0.0], move_time=1.0,
                                      time_budget=500.0, seed=777)
    pending = cli.call_async(long_req)
    answers = []
    for i in range(3):
        answers.append(_call(client, **dict(ONE_DOF, qf=[0.5 + 0.05 * i])))
        assert not pending.done(), f"the 2-DOF plan ended early: {pending.result()}"
    assert all(a.success and not a.warm_start for a in answers), [a.message for a in answers]
    (planner_node.folder / "release").touch()
    (long_res,) = _wait(node, [pending], 30)
    assert long_res is not None and long_res.success, long_res and long_res.message


def test_fifty_concurrent_requests_answered_or_cleanly_refused(client):
    node, cli = client
    from ff_msgs.srv import PlanTrajectory

    reqs = []
    for i in range(50):
        if i % 5 == 0:
            reqs.append(PlanTrajectory.Request(model="scara2", q0=[0.0, 0.0], qf=[0.1 * i, 0.0],
                                               move_time=1.0, time_budget=3.0))
        else:
            reqs.append(PlanTrajectory.Request(**dict(ONE_DOF, qf=[0.3 + 0.013 * i])))
    answers = _wait(node, [cli.call_async(r) for r in reqs], 300)
    assert all(a is not None for a in answers), "some requests were never answered"
    refused = [a for a in answers if not a.success]
    for a in refused:
        assert a.error_code == PlanTrajectory.Response.TIME_BUDGET_EXHAUSTED, a.message
        assert "overloaded" in a.message or "time budget" in a.message, a.message
    assert any(a.success for a in answers)
    assert _call(client, **dict(ONE_DOF, qf=[0.9])).success      # and it serves on


def test_diagnostics_report_solve_statistics(client):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    node, _ = client
    got = []
    sub = node.create_subscription(DiagnosticArray, "/diagnostics", got.append, 10)
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + 15
    while time.monotonic() < end and not any(s.name == "ff_planner: planning" for m in got for s in m.status):
        ex.spin_once(timeout_sec=0.1)
    ex.remove_node(node)
    node.destroy_subscription(sub)
    status = [s for m in got for s in m.status if s.name == "ff_planner: planning"]
    assert status, "no diagnostics from ff_planner"
    values = {kv.key: kv.value for kv in status[-1].values}
    assert int(values["requests"]) >= 1
    assert "latency_cold_p50" in values and "library_solved" in values


def test_box_grid_certificate_and_predicted_rest_over_the_service(client):
    from ff_msgs.srv import PlanTrajectory

    fields = dict(model="arm1dof", q0=[0.0], qf=[0.6], move_time=1.0, uncertain=["pv", "pc", "pt"],
                  steps=7, starts=100, seed=3, box_names=["pc"], box_fractions=[0.3],
                  objective="robust-derivative")
    res = _call(client, **fields)
    assert res.success and res.robust, res.message
    times = list(res.profile.step_times)
    assert all(abs(t * 1e3 - round(t * 1e3)) < 1e-6 for t in times), times     # the node's 1 ms grid
    assert len({round((b - a) * 1e3) for a, b in zip(times, times[1:])}) > 1   # 950 ms / 7: not uniform
    cert = res.certificate
    assert cert.certified and list(cert.box_names) == ["pv", "pc", "pt"]
    assert list(cert.box_fractions) == [0.2, 0.3, 0.2]
    assert len(cert.worst_at) == len(cert.per_parameter) == 3 and cert.samples > 0
    assert len(cert.switch_timing) == res.profile.n_steps
    assert cert.worst_rest_error >= max(cert.per_parameter) - 1e-12
    assert len(res.profile.predicted_rest) == 1 and abs(res.profile.predicted_rest[0] - 0.6) < 1e-4
    again = _call(client, **fields)                     # from the library: the same certificate
    assert again.warm_start and again.certificate.certified
    assert again.certificate.worst_rest_error == cert.worst_rest_error
    assert list(again.profile.predicted_rest) == list(res.profile.predicted_rest)
    free = _call(client, **dict(fields, switch_grid=-1.0, box_names=[], box_fractions=[]))
    assert free.success and "from the motion library" not in free.message, free.message  # the row does not fit
    assert list(free.certificate.box_fractions) == [0.2, 0.2, 0.2]
    assert len({round(b - a, 12) for a, b in zip(free.profile.step_times, free.profile.step_times[1:])}) == 1
    bad = _call(client, **dict(fields, box_names=["pq"], box_fractions=[0.1]))
    assert not bad.success and bad.error_code == PlanTrajectory.Response.INVALID_REQUEST
    assert "not uncertain" in bad.message and not bad.certificate.certified
    baseline = _call(client, **dict(ONE_DOF, qf=[0.45]))
    assert baseline.success and "switch_grid" in baseline.message     # said, not silently ignored


def test_limits_tolerance_and_the_excursion_over_the_service(client):
    """The request's limits reach the plan (a broken one labelled, with the excursion in the
    certificate); a tolerance request answers the fastest tf certified within it."""
    from ff_msgs.srv import PlanTrajectory

    base = dict(model="arm1dof", q0=[0.0], qf=[1.0], uncertain=["pv", "pc", "pt"],
                objective="energy-optimal")
    free = _call(client, **dict(base, move_time=1.0))
    assert free.success, free.message
    cert = free.certificate
    assert cert.certified and len(cert.excursion_worst_speed) == 1
    assert cert.excursion_worst_speed[0] >= cert.excursion_nominal_speed[0] > 0.5
    assert cert.excursion_nominal_min[0] <= 0.0 and cert.excursion_worst_max[0] >= 1.0
    res = _call(client, **dict(base, move_time=1.0, velocity_max=[0.5]))
    assert not res.success and res.error_code in (PlanTrajectory.Response.NO_ROBUST_PLAN,
                                                  PlanTrajectory.Response.UNREACHABLE)
    assert "velocity_max 0.5" in res.message
    bad = _call(client, **dict(base, move_time=1.0, position_min=[0.5]))
    assert not bad.success and bad.error_code == PlanTrajectory.Response.INVALID_REQUEST
    assert "position_min" in bad.message
    tol = _call(client, **dict(base, move_time=0.0, tolerance=0.7, move_time_max=1.5,
                               time_budget=60.0))
    assert tol.success, tol.message
    assert tol.certificate.worst_rest_error <= 0.7 and tol.profile.move_time < 1.5
    assert "fastest tf certified within 700 mrad" in tol.message
