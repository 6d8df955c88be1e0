"""check() and plan(): validation with error codes, the reachability check, dispatch (warm starts
included), best-effort labels."""
from __future__ import annotations

import math
import pickle
import time

import numpy as np
import pytest

import ff_planner.optimize.planner as planner
from ff_planner.core.errors import WarmStartUnavailable
from ff_planner.model.params import PRESETS
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest, PlanResult
from ff_planner.optimize.planner import CheckedRequest, Route, check, plan, reach


@pytest.mark.parametrize("kw, code, needle", [
    (dict(q0=(float("nan"),)), "INVALID_REQUEST", "finite"),
    (dict(qf=(math.inf,)), "INVALID_REQUEST", "finite"),
    (dict(tf=0.05), "INVALID_REQUEST", "must exceed the coast"),
    (dict(tf=0.01), "INVALID_REQUEST", "must exceed the coast"),
    (dict(tf=float("nan")), "INVALID_REQUEST", "finite"),
    (dict(steps=-1), "INVALID_REQUEST", "steps per joint"),
    (dict(uncertain=("pq",)), "UNKNOWN_PARAMETER", "pq"),
    (dict(model="arm7"), "UNKNOWN_MODEL", "arm7"),
    (dict(objective="fastest"), "INVALID_REQUEST", "objective"),
    (dict(qf=(1.0, 2.0)), "INVALID_REQUEST", "qf needs 1"),
    (dict(starts=-1), "INVALID_REQUEST", "starts"),
])
def test_bad_requests_raise_clear_planning_errors(kw, code, needle):
    with pytest.raises(PlanningError) as ei:
        plan(PlanRequest(**kw))
    assert ei.value.code == code
    assert needle in str(ei.value)


def test_unreachable_goal_names_the_reachable_distance():
    bound = reach(PRESETS["table2"], 1.0)[0]
    assert 15.0 < bound < 25.0
    with pytest.raises(PlanningError) as ei:
        plan(PlanRequest(qf=(bound + 0.1,)))
    assert ei.value.code == "UNREACHABLE"
    assert f"{bound:.4g} rad" in str(ei.value)
    # weaker motor -> smaller reach; a short move time too
    weak = PRESETS["table2"].replace(i_max=1.0)
    assert reach(weak, 1.0)[0] < bound and reach(PRESETS["table2"], 0.5)[0] < bound
    # a current limit below breakaway moves nothing
    assert reach(PRESETS["table2"].replace(i_max=0.1), 1.0)[0] == 0.0
    with pytest.raises(PlanningError, match="unreachable"):
        plan(PlanRequest(qf=(0.01,), params=PRESETS["table2"].replace(i_max=0.1)))


def test_scara2_reach_bound_is_sound_against_simulation():
    from ff_planner.model.simulate import simulate

    p = PRESETS["table3"]
    tf = 0.3
    bound = reach(p, tf)
    rng = np.random.default_rng(3)
    for _ in range(5):
        prof = CurrentProfile.uniform(rng.choice([-10.0, 10.0], (3, 2)), tf, 0.0)
        r = simulate(p, prof, [0.0, 0.0], trajectory=True)
        assert np.max(np.abs(r.q)) <= bound[0]
    req = PlanRequest(model="scara2", q0=(0.0, 0.0), qf=(bound[0] + 1.0, 0.0), tf=tf,
                      uncertain=("pc1",))
    with pytest.raises(PlanningError) as ei:
        check(req)
    assert ei.value.code == "UNREACHABLE" and "joint 1" in str(ei.value)


def test_dispatches_baselines():
    r = plan(PlanRequest(objective="time-optimal"))
    assert r.success and r.objective == "time-optimal" and r.profile.n_steps == 2
    assert r.extra["reach_bound"][0] > 1.0


def _fake_result(request, success):
    prof = CurrentProfile.uniform([[0.0]] * 3, request.tf)       # at rest: a plan that ends
    return PlanResult(success=success, message="fake", profile=prof, model=request.model,
                      params=request.resolved_params(), q0=np.zeros(1), qf=np.ones(1),
                      uncertain=list(request.uncertain), objective=request.objective)


def _route_to(monkeypatch, fn, warm_start=False):
    """Send the default request (arm1dof, the default objective) to ``fn``."""
    monkeypatch.setitem(planner.ROUTES, ("arm1dof", PlanRequest().objective), Route(fn, warm_start))


def test_failed_plans_are_labelled_best_effort(monkeypatch):
    _route_to(monkeypatch, lambda r, p: _fake_result(r, False))
    r = plan(PlanRequest())
    assert not r.success and r.best_effort and r.error_code == "NO_ROBUST_PLAN"
    assert "best plan found" in r.message


def test_late_results_are_labelled(monkeypatch):
    def slow(req, progress):
        time.sleep(0.05)
        return _fake_result(req, False)

    _route_to(monkeypatch, slow)
    r = plan(PlanRequest(time_budget=0.01))
    assert r.error_code == "TIME_BUDGET_EXHAUSTED" and r.extra["over_time_budget"]
    assert r.best_effort


def test_progress_is_passed_through(monkeypatch):
    seen = []

    def fn(req, progress):
        progress({"starts_done": 1})
        return _fake_result(req, True)

    _route_to(monkeypatch, fn)
    r = plan(PlanRequest(steps=5), progress=seen.append)
    assert r.success and not r.best_effort and seen == [{"starts_done": 1}]


def test_robust_k3_plan_through_the_facade_is_truly_robust(robust_plan_1dof):
    """1-DOF, k = 3, 0 -> 1 rad in 1 s: true derivatives <= 1e-6, on target, at rest."""
    from ff_planner.model.sensitivity import sensitivities

    r = robust_plan_1dof
    assert r.success and r.robust and not r.best_effort and r.error_code == "OK"
    p = r.params
    cen = sensitivities(p, r.profile, [0.0], ["pv", "pc", "pt"], method="central", rel_step=1e-6)
    ex = sensitivities(p, r.profile, [0.0], ["pv", "pc", "pt"], method="exact")
    for n in ("pv", "pc", "pt"):
        assert abs(cen[n]) <= 1e-6 and abs(ex[n]) <= 1e-6 and abs(r.sensitivities[n]) <= 1e-6
    assert abs(r.q_final[0] - 1.0) <= 1e-6 and r.qd_final[0] == 0.0
    assert np.max(np.abs(r.profile.currents)) <= p.i_max


def test_check_once_then_plan_without_checking_again(monkeypatch):
    """A CheckedRequest pickles (it travels to worker processes) and is planned as it is."""
    checked = check(PlanRequest(objective="time-optimal"))
    assert isinstance(checked, CheckedRequest) and checked.params == PRESETS["table2"]
    assert len(checked.reach) == 1 and checked.reach[0] > 1.0
    again = pickle.loads(pickle.dumps(checked))
    assert again == checked

    def no_check(request):
        raise AssertionError("checked twice")

    monkeypatch.setattr(planner, "check", no_check)
    r = plan(again)
    assert r.success and r.extra["reach_bound"] == list(checked.reach)


def test_no_planner_for_the_objective_is_an_invalid_request():
    with pytest.raises(PlanningError) as ei:
        check(PlanRequest(model="scara2", q0=(0.0, 0.0), qf=(1.0, 0.0), objective="time-optimal",
                          uncertain=("pc1",)))
    assert ei.value.code == "INVALID_REQUEST" and "arm1dof only" in str(ei.value)


def test_warm_starts_follow_the_dispatch_table(monkeypatch):
    seen = {}

    def fn(req, progress, initial_currents=None):
        seen["init"] = initial_currents
        return _fake_result(req, True)

    init = np.ones((5, 1))
    _route_to(monkeypatch, fn, warm_start=True)
    assert plan(PlanRequest(steps=5), initial_currents=init).success
    assert np.array_equal(seen["init"], init)
    _route_to(monkeypatch, fn, warm_start=False)
    with pytest.raises(WarmStartUnavailable):
        plan(PlanRequest(steps=5), initial_currents=init)
    with pytest.raises(WarmStartUnavailable):
        plan(PlanRequest(objective="time-optimal"), initial_currents=init)


# --- issue-33 checks: input the planner cannot serve, time accounting, limits ---------------------
@pytest.mark.parametrize("kw, needle", [
    (dict(q0=(1e308,), qf=(1e308,)), "beyond ±10000 rad"),
    (dict(qf=(-2e4,)), "beyond ±10000 rad"),
    (dict(params=PRESETS["table2"].replace(pt=1.5)), "pt must be < 1"),
    (dict(params=PRESETS["table2"].replace(pt=0.9)), "also at the box's edge"),
    (dict(params=PRESETS["table2"].replace(pc=1e-300)), "never comes to rest"),
    (dict(model="scara2", q0=(0.0, 0.0), qf=(0.5, 0.0), uncertain=("pc1",),
          params=PRESETS["table3"].replace(pt2=1.2)), "pt2 must be < 1"),
])
def test_requests_no_plan_can_serve_are_refused_at_once(kw, needle):
    t0 = time.perf_counter()
    with pytest.raises(PlanningError) as ei:
        check(PlanRequest(**kw))
    assert ei.value.code == "INVALID_REQUEST" and needle in str(ei.value)
    assert time.perf_counter() - t0 < 1.0


def test_pt_below_one_without_the_box_is_accepted():
    check(PlanRequest(uncertain=("pv", "pc"), params=PRESETS["table2"].replace(pt=0.9)))


def test_a_time_budget_too_short_for_any_plan_is_one_clear_error():
    with pytest.raises(PlanningError) as ei:
        plan(PlanRequest(time_budget=1e-9))
    assert ei.value.code == "TIME_BUDGET_EXHAUSTED" and "before any plan" in str(ei.value)


def test_escalation_counts_its_whole_time_and_keeps_the_budget(monkeypatch):
    calls = []

    def slow_no_plan(req, progress):
        time.sleep(0.03)
        calls.append(req.steps)
        r = _fake_result(req, False)
        r.solve_time = 0.03
        return r

    _route_to(monkeypatch, slow_no_plan)
    t0 = time.perf_counter()
    r = plan(PlanRequest(time_budget=0.5))
    wall = time.perf_counter() - t0
    assert len(calls) >= 3 and len(r.extra["auto"]["tried"]) == len(calls)
    assert r.solve_time >= 0.03 * len(calls) and r.solve_time <= wall
    assert wall < 0.5 + 0.3          # one try past the budget at most, on a loaded machine


def test_move_time_at_its_maximum_is_not_advised_longer(monkeypatch):
    def fn(req, progress):
        r = _fake_result(req, False)
        r.message = "no truly robust plan; try more steps or a longer move time"
        return r

    _route_to(monkeypatch, fn)
    r = plan(PlanRequest(tf=60.0, steps=5))
    assert "a longer move time" not in r.message and "maximum of 60 s" in r.message
    r = plan(PlanRequest(tf=10.0, steps=5))
    assert "a longer move time" in r.message


def test_a_plan_that_leaves_the_limits_is_labelled(monkeypatch):
    from ff_planner.model.limits import Excursion, MotionLimits
    from ff_planner.model.profile import RobustnessCertificate

    def fn(req, progress):
        r = _fake_result(req, True)
        r.certificate = RobustnessCertificate(
            box={"pv": 0.2}, worst_rest_error=1e-3, worst_at={"pv": 1.2},
            per_parameter={"pv": 1e-3}, moving_at_tf=0.0, switch_timing=[0.0] * 3, samples=1,
            excursion=Excursion([-0.5], [1.1], [6.0], [-0.7], [1.2], [7.0]))
        return r

    _route_to(monkeypatch, fn)
    limits = MotionLimits.of([-1.0], [1.5], [8.0])
    assert plan(PlanRequest(steps=5, limits=limits)).success       # within: unchanged
    r = plan(PlanRequest(steps=5, limits=MotionLimits.of([-0.3], [1.5], [4.0])))
    assert not r.success and r.best_effort and r.error_code == "NO_ROBUST_PLAN"
    assert len(r.extra["limit_violations"]) == 2 and "velocity_max" in r.message
    assert r.extra["limits_checked"]


def test_a_tolerance_request_is_not_planned_at_its_tf():
    with pytest.raises(PlanningError) as ei:
        plan(PlanRequest(tolerance=1e-3))
    assert "plan_fastest" in str(ei.value)
