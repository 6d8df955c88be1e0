"""The ff_planner node served from ANOTHER process (started with ff_msgs_py.launch.start_module), called
over DDS on loopback with good and bad requests; plus its logic (PlannerService) without ROS.

The node runs the real planner facade for 1-DOF requests. For scara2 requests it runs
``slow_plan`` below (a stand-in that takes ``SLOW_S`` seconds, or ignores its budget when asked) so
that the concurrency and time-budget checks do not depend on how long a real 2-DOF plan takes.
"""
from __future__ import annotations

import json
import math
import os
import time

import numpy as np
import pytest

from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult

SLOW_S = 2.0   # s, how long the stand-in 2-DOF planner works


def slow_plan(request: PlanRequest, progress=None, initial_currents=None) -> PlanResult:
    """Planner entry for the node under test: the real planner (with warm starts) for arm1dof, a slow
    stand-in for scara2.

    scara2 with seed 666 ignores its time budget (sleeps 60 s) to test that the node enforces it;
    with seed 777 it works until the file $FF_TEST_RELEASE exists (or its budget is spent).
    """
    from ff_planner.library.build import plan_for_library

    if request.model != "scara2":
        return plan_for_library(request, progress, initial_currents=initial_currents)
    if request.seed == 777:
        end = time.monotonic() + request.time_budget
        while not os.path.exists(os.environ["FF_TEST_RELEASE"]) and time.monotonic() < end:
            time.sleep(0.01)
    else:
        time.sleep(60.0 if request.seed == 666 else min(SLOW_S, request.time_budget))
    prof = CurrentProfile.uniform(np.zeros((request.n_steps(), 2)), request.tf, request.coast)
    return PlanResult(success=True, message="stand-in 2-DOF plan", profile=prof, model="scara2",
                      params=request.resolved_params(), q0=np.asarray(request.q0, float),
                      qf=np.asarray(request.qf, float), uncertain=list(request.uncertain),
                      objective=request.objective, q_final=np.asarray(request.q0, float),
                      qd_final=np.zeros(2), robust=False, starts_tried=1)


# --- the node in another process --------------------------------------------------------------
@pytest.fixture(scope="module")
def planner_node(ros_env, tmp_path_factory):
    from ff_msgs_py.launch import start_module, wait_for_line

    folder = tmp_path_factory.mktemp("planner_node")
    params = folder / "planner.yaml"
    params.write_text(f"""ff_planner:
  ros__parameters:
    library_path: "{folder / 'motions.sqlite'}"
    motion_dir: "{folder / 'motions'}"
    plan_entry: "tests.ff_planner.ros.test_planner_node:slow_plan"
    workers: 2
    max_pending: 4
    default_time_budget: 150.0
    max_steps: 30
    grace: 0.3
    diagnostics_period: 0.5
""")
    env = dict(ros_env, FF_TEST_RELEASE=str(folder / "release"))
    proc = start_module("ff_planner_node", "ff_planner.ros.planner_node", ["--ros-args", "--params-file", str(params)],
                        env)
    try:
        assert wait_for_line(proc, "ff_planner ready", 240), proc.output()
        yield proc, folder
    finally:
        code = proc.stop()
        assert not proc.alive()
        assert "Traceback" not in proc.output(), proc.output()[-3000:]
        assert code is not None


@pytest.fixture(scope="module")
def client(planner_node, ros_env):
    import rclpy
    from rclpy.node import Node

    from ff_msgs.srv import PlanTrajectory

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("ff_planner_test_client", context=ctx)
    from rclpy.qos import QoSProfile

    cli = node.create_client(PlanTrajectory, "/ff_planner/plan", qos_profile=QoSProfile(depth=200))
    assert cli.wait_for_service(timeout_sec=20), "planner service not discovered"
    try:
        yield node, cli
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)


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
    files = list((planner_node[1] / "motions").glob("*.json"))
    assert files and json.loads(files[0].read_text())["format"] == "ff-motion/1"


def test_robust_1dof_plan_cold_then_warm_from_its_neighbour(client):
    fields = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pv", "pc", "pt"],
                  starts=50, seed=1)
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
    assert planner_node[0].alive()
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
    (planner_node[1] / "release").touch()
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


# --- the same logic in-process, without ROS ----------------------------------------------------
def test_service_config_refuses_unknown_names():
    from ff_planner.service.planner_service import ServiceConfigError, config_from_mapping

    cfg = config_from_mapping({"workers": 3, "arm1dof.params.pc": 0.25, "scara2.preset": "table3"})
    assert cfg.workers == 3 and cfg.model_params("arm1dof").pc == 0.25
    with pytest.raises(ServiceConfigError, match="unknown model parameter"):
        config_from_mapping({"arm1dof.params.friction": 1.0})
    with pytest.raises(ServiceConfigError, match="unknown planner parameter"):
        config_from_mapping({"wokers": 3})
    with pytest.raises(ServiceConfigError, match="preset"):
        config_from_mapping({"arm1dof.preset": "table3"})
    with pytest.raises(ServiceConfigError, match=">= 1"):
        config_from_mapping({"workers": 0})


def test_configured_parameters_reach_the_plan(tmp_path):
    from ff_planner.service.planner_service import (
        PlannerService,
        RequestFields,
        ServiceConfigError,
        config_from_mapping,
    )

    cfg = config_from_mapping({"arm1dof.params.pc": 0.25, "library_path": str(tmp_path / "l.sqlite")})
    svc = PlannerService(cfg)
    req = svc.make_request(RequestFields(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0,
                                         override_names=["pv"], override_values=[-0.04]))
    p = req.resolved_params()
    assert (p.pc, p.pv) == (0.25, -0.04)
    assert req.starts == cfg.default_starts and req.time_budget == cfg.default_time_budget
    assert list(req.uncertain) == ["pv", "pc", "pt"] and req.n_steps() == 5
    # a request while no workers run is answered, not raised
    res = svc.handle(req)
    assert not res.success and res.error_code == "INTERNAL_ERROR"
    svc.close()
    (tmp_path / "file").write_text("")
    with pytest.raises(ServiceConfigError, match="library_path"):
        PlannerService(config_from_mapping({"library_path": str(tmp_path / "file" / "lib.sqlite")}))


def stub_plan(request: PlanRequest, progress=None, initial_currents=None) -> PlanResult:
    """A planner stand-in for the warm/cold logic: echoes the warm-start currents it was given."""
    cur = (np.asarray(initial_currents, float) if initial_currents is not None
           else np.full((request.n_steps(), len(request.q0)), 0.5))
    prof = CurrentProfile.uniform(cur, request.tf, request.coast)
    return PlanResult(success=True, message="stub", profile=prof, model=request.model,
                      params=request.resolved_params(), q0=np.asarray(request.q0, float),
                      qf=np.asarray(request.qf, float), uncertain=list(request.uncertain),
                      objective=request.objective, q_final=np.asarray(request.qf, float),
                      qd_final=np.zeros(len(request.q0)), sensitivities={u: 0.0 for u in request.uncertain},
                      robust=True, starts_tried=0 if initial_currents is not None else request.starts,
                      extra={"got_initial": initial_currents is not None})


def test_service_warm_starts_from_the_nearest_stored_plan(tmp_path):
    from ff_planner.library.store import MotionLibrary, record_from_result
    from ff_planner.service.planner_service import PlannerService, RequestFields, ServiceConfig

    cfg = ServiceConfig(library_path=str(tmp_path / "lib.sqlite"), plan_entry="tests.ff_planner.ros.test_planner_node:stub_plan",
                        workers=2, warmup=False, warm_max_distance=0.2)
    svc = PlannerService(cfg)
    svc.start()
    try:
        base = dict(model="arm1dof", q0=[0.0], move_time=1.0, uncertain=["pc"])
        # a stored neighbour with recognisable currents (as ff-library build would leave it)
        seed_req = svc.make_request(RequestFields(qf=[1.0], **base))
        stored = stub_plan(seed_req, initial_currents=np.array([[3.0], [-1.0], [2.0]]))
        with MotionLibrary(cfg.library_path) as lib:
            assert lib.put(record_from_result(seed_req, stored), seed_req.resolved_params())
        near = svc.handle_fields(RequestFields(qf=[1.1], **base))
        assert near.success and near.warm_start and near.extra["source"] == "warm"
        assert near.extra.get("got_initial") is True
        np.testing.assert_array_equal(near.profile.currents, [[3.0], [-1.0], [2.0]])
        far = svc.handle_fields(RequestFields(qf=[1.5], **base))
        assert far.success and not far.warm_start and far.extra["source"] == "cold"
        again = svc.handle_fields(RequestFields(qf=[1.1], **base))      # now stored: a hit
        assert again.warm_start and again.extra["source"] == "hit"
        stats = svc.stats()
        assert stats["source_warm"] == 1 and stats["source_cold"] == 1 and stats["source_hit"] == 1
        assert stats["library_solved"] == 3
        # a stored "no robust plan here" answers at once when its search was as thorough as asked
        hard_req = svc.make_request(RequestFields(qf=[-2.0], starts=100, **base))
        none_found = stub_plan(hard_req)
        none_found.success, none_found.robust, none_found.error_code = False, False, "NO_ROBUST_PLAN"
        none_found.starts_tried = 100
        with MotionLibrary(cfg.library_path) as lib:
            assert lib.put(record_from_result(hard_req, none_found))
        known = svc.handle_fields(RequestFields(qf=[-2.0], starts=100, **base))
        assert not known.success and known.error_code == "NO_ROBUST_PLAN" and known.extra["source"] == "hit"
        assert "known from the motion library" in known.message
        deeper = svc.handle_fields(RequestFields(qf=[-2.0], starts=400, **base))   # more starts: solve
        assert deeper.success and deeper.extra["source"] == "cold"
        after = svc.handle_fields(RequestFields(qf=[-2.0], starts=100, **base))    # upgraded row
        assert after.success and after.extra["source"] == "hit"
    finally:
        svc.close()
