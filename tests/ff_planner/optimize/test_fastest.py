"""The tolerance-first tf search (fastest.plan_fastest) with stand-in planners whose certified
error is a known function of tf, and once with the real facade."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from ff_planner.core.errors import PlanningError
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult, RobustnessCertificate
from ff_planner.optimize.fastest import SearchSettings, plan_fastest, shortest_reachable_tf
from ff_planner.optimize.planner import check


def _stand_in(worst_of_tf, calls=None, success=lambda tf: True):
    """plan_fn whose plan at tf is certified at worst_of_tf(tf) rad."""
    def fn(req, progress=None):
        tf = float(req.tf)
        if calls is not None:
            calls.append(tf)
        prof = CurrentProfile.uniform([[0.0]] * 3, tf)
        cert = RobustnessCertificate(box={"pc": 0.2}, worst_rest_error=worst_of_tf(tf),
                                     worst_at={"pc": 1.2}, per_parameter={"pc": 0.0},
                                     moving_at_tf=0.0, switch_timing=[0.0] * 3, samples=1)
        ok = success(tf)
        return PlanResult(success=ok, message=f"plan at {tf:.3f}", profile=prof, model=req.model,
                          params=req.resolved_params(), q0=np.zeros(1), qf=np.ones(1),
                          uncertain=list(req.uncertain), objective=req.objective,
                          robust=ok, certificate=cert, error_code="OK" if ok else "NO_ROBUST_PLAN")
    return fn


REQ = PlanRequest(qf=(1.0,), tf=3.0, tolerance=2e-3, move_time_max=3.0, uncertain=("pc",))


def test_finds_the_threshold_of_a_monotone_error_within_the_resolution():
    threshold = 1.234
    calls: list[float] = []
    r = plan_fastest(REQ, plan_fn=_stand_in(lambda tf: 2e-3 * (threshold / tf) ** 2, calls))
    info = r.extra["tolerance_search"]
    assert r.success and info["met"] and info["complete"]
    assert threshold <= r.profile.tf <= threshold * 1.011 + 1e-3
    assert r.certificate.worst_rest_error <= 2e-3
    assert len(info["trials"]) == len(calls) and calls[0] == 3.0
    assert all(t["tf"] == pytest.approx(c) for t, c in zip(info["trials"], calls))
    assert "fastest tf certified within 2 mrad" in r.message


def test_goes_on_past_a_failing_tf_and_keeps_the_shortest_pass():
    """Not monotone: fails in a band (1.5-1.9 s, where the knee bisection looks first) above
    the true threshold (1.0 s)."""
    def worst(tf):
        if 1.5 <= tf <= 1.9:
            return 3e-3
        return 1e-3 if tf >= 1.0 else 50e-3
    r = plan_fastest(REQ, plan_fn=_stand_in(worst))
    assert r.success and 1.0 <= r.profile.tf <= 1.0 * 1.011 + 1e-3
    failing = [t for t in r.extra["tolerance_search"]["trials"] if not t["meets"]]
    assert any(1.5 <= t["tf"] <= 1.9 for t in failing)


def test_never_answers_a_failing_plan_as_a_success():
    r = plan_fastest(REQ, plan_fn=_stand_in(lambda tf: 5e-3 + 1e-3 / tf))
    info = r.extra["tolerance_search"]
    assert not r.success and r.best_effort and r.error_code == "NO_ROBUST_PLAN"
    assert not info["met"] and not any(t["meets"] for t in info["trials"])
    least = min(t["worst_rest_error"] for t in info["trials"])
    assert r.certificate.worst_rest_error == pytest.approx(least)
    assert "no move time up to 3 s is certified within 2 mrad" in r.message


def test_a_plan_that_is_not_a_success_does_not_meet_the_tolerance():
    """Certified within the tolerance but not a success (e.g. leaves the limits): not a pass."""
    r = plan_fastest(REQ, plan_fn=_stand_in(lambda tf: 1e-3, success=lambda tf: tf > 2.0))
    assert r.success and r.profile.tf > 2.0
    assert all(not t["meets"] for t in r.extra["tolerance_search"]["trials"] if t["tf"] <= 2.0)


def test_stops_descending_after_hopeless_tfs():
    calls: list[float] = []
    r = plan_fastest(REQ, plan_fn=_stand_in(lambda tf: 1e-3 if tf > 2.5 else 1.0, calls))
    assert r.success and 2.5 < r.profile.tf <= 2.55 * 1.011
    coarse = [c for c in calls if c < 2.5]
    assert min(coarse) > 1.5          # two hopeless coarse tfs, then bisection only


def test_time_budget_ends_the_search_with_the_best_pass_so_far():
    def slow(req, progress=None):
        time.sleep(0.1)
        return _stand_in(lambda tf: 1e-3)(req, progress)
    t0 = time.perf_counter()
    r = plan_fastest(PlanRequest(**{**REQ.__dict__, "time_budget": 0.35}), plan_fn=slow,
                     settings=SearchSettings(min_trial_budget=0.01))
    wall = time.perf_counter() - t0
    info = r.extra["tolerance_search"]
    assert r.success and not info["complete"] and "time budget ended the search" in r.message
    assert wall < 0.35 + 0.3 and r.solve_time == pytest.approx(info["time_s"])


def test_an_invalid_or_unreachable_request_is_refused():
    with pytest.raises(PlanningError) as ei:
        plan_fastest(PlanRequest(qf=(1e3,), tf=3.0, tolerance=1e-3), plan_fn=_stand_in(lambda tf: 0.0))
    assert ei.value.code == "UNREACHABLE"
    with pytest.raises(PlanningError):
        plan_fastest(PlanRequest(), plan_fn=_stand_in(lambda tf: 0.0))     # no tolerance


def test_shortest_reachable_tf_is_where_the_reach_bound_covers_the_move():
    req = PlanRequest(qf=(1.0,), tf=3.0)
    t = shortest_reachable_tf(req, check(req).params, 3.0, 1e-3)
    assert check(PlanRequest(qf=(1.0,), tf=t)).reach[0] >= 1.0
    with pytest.raises(PlanningError):
        check(PlanRequest(qf=(1.0,), tf=t - 2e-3))


def test_real_planner_energy_optimal_search():
    """The facade itself: deterministic baseline, every trial's certificate as reported."""
    req = PlanRequest(objective="energy-optimal", qf=(1.0,), tf=1.5, tolerance=0.7,
                      move_time_max=1.5)
    r = plan_fastest(req)
    info = r.extra["tolerance_search"]
    assert r.success and r.certificate.worst_rest_error <= 0.7
    for t in info["trials"]:
        w = t["worst_rest_error"]
        assert t["meets"] == (w is not None and math.isfinite(w) and w <= 0.7)
    assert r.profile.tf == min(t["tf"] for t in info["trials"] if t["meets"])


def test_tradeoff_plans_each_tf_without_and_with_the_limits():
    from ff_planner.model.limits import MotionLimits
    from ff_planner.optimize.fastest import tradeoff

    seen: list[tuple[float, bool]] = []

    def fn(req, progress=None):
        seen.append((float(req.tf), req.limits is not None))
        return _stand_in(lambda tf: 1e-3 / tf)(req, progress)

    req = PlanRequest(qf=(1.0,), tf=1.0, uncertain=("pc",), limits=MotionLimits.of(None, None, [4.0]))
    pts = tradeoff(req, points=4, tf_max=2.0, plan_fn=fn)
    assert [p.label for p in pts] == ["no limits"] * 4 + ["limits"] * 4
    assert [s[1] for s in seen] == [False] * 4 + [True] * 4
    tfs = [p.tf for p in pts[:4]]
    assert tfs == sorted(tfs) and tfs[-1] == 2.0 and tfs[0] >= 0.2
    assert all(p.worst_rest_error == pytest.approx(1e-3 / p.tf) for p in pts)
    assert len(tradeoff(PlanRequest(qf=(1.0,), uncertain=("pc",)), points=3, tf_max=2.0,
                        plan_fn=fn)) == 3           # no limits: one set


def test_a_near_miss_is_planned_again_with_the_next_seed():
    def fn(req, progress=None):
        worst = 1e-3 if req.seed == 1 else (3e-3 if req.tf < 2.0 else 1e-3)   # seed 0: near miss
        return _stand_in(lambda tf: worst)(req, progress)

    r = plan_fastest(REQ, plan_fn=fn)
    trials = r.extra["tolerance_search"]["trials"]
    assert r.success and r.profile.tf < 2.0
    retried = [t for t in trials if t["seed"] == 1]
    assert retried and all(t["meets"] for t in retried)
    far = plan_fastest(REQ, plan_fn=_stand_in(lambda tf: 1e-3 if tf > 2.0 else 10e-3))
    assert all(t["seed"] == 0 for t in far.extra["tolerance_search"]["trials"])   # no near miss


def test_the_near_miss_scan_finds_a_pass_below_a_failing_band():
    """Passes at tf >= 2 s and in a narrow window 1.40-1.43 s, near misses in between."""
    def worst(tf):
        if tf >= 2.0 or 1.40 <= tf <= 1.43:
            return 1e-3
        return 3e-3 if tf >= 1.2 else 50e-3
    r = plan_fastest(REQ, plan_fn=_stand_in(worst))
    info = r.extra["tolerance_search"]
    assert r.success and 1.40 <= r.profile.tf <= 1.43, info["trials"]
    assert info["bracket"][0] < r.profile.tf == info["bracket"][1]
    no_scan = plan_fastest(REQ, plan_fn=_stand_in(worst), settings=SearchSettings(scan_rel=0.0))
    assert no_scan.profile.tf >= 2.0


def test_the_scan_also_runs_when_the_descent_found_no_pass():
    def worst(tf):
        return 1e-3 if 1.50 <= tf <= 1.53 else (3e-3 if tf >= 1.2 else 50e-3)
    r = plan_fastest(REQ, plan_fn=_stand_in(worst))
    assert r.success and 1.50 <= r.profile.tf <= 1.53


def test_real_robust_box_search_is_within_5_percent_of_a_coarse_sweep():
    """The facade's robust-box planner at N = 5 (tens of ms a plan): the tf the search finds is
    no longer than 1.05 × the shortest passing tf of a 50 ms sweep of the same planner (seed 0),
    certified within the tolerance, and the certificate holds on fresh box points."""
    from ff_planner.model.arm1dof import batch_core
    from ff_planner.optimize.planner import plan

    tol = 8e-3
    base = dict(objective="robust-box", steps=5, qf=(1.0,), time_budget=20.0)
    sweep = []
    for k in range(17):             # 0.8 ... 1.6 s
        tf = round(0.8 + 0.05 * k, 3)
        r = plan(PlanRequest(tf=tf, **base))
        w = r.certificate.worst_rest_error if r.certificate is not None else math.inf
        if r.success and w <= tol:
            sweep.append(tf)
    assert sweep, "the sweep found no passing tf"
    found = plan_fastest(PlanRequest(tf=2.0, tolerance=tol, move_time_max=2.0,
                                     **{**base, "time_budget": 60.0}))
    info = found.extra["tolerance_search"]
    assert found.success and info["complete"]
    assert found.profile.tf <= 1.05 * min(sweep) + 1e-9, (found.profile.tf, sweep, info["trials"])
    cert = found.certificate.worst_rest_error
    assert cert <= tol
    p, prof = found.params, found.profile
    rng = np.random.default_rng(7)
    scales = np.vstack([rng.uniform(0.8, 1.2, (200, 3)), np.ones((1, 3))])
    fr = np.ascontiguousarray(scales * np.array([p.pv, p.pc, p.pt]))
    q, _ = batch_core(p.J, p.n * p.kt, fr, np.ones(len(scales), bool), prof.step_times,
                      np.ascontiguousarray(prof.currents[:, 0]), prof.tf, 0.0)
    assert float(np.max(np.abs(q - 1.0))) <= cert * (1.0 + 1e-6)


def test_a_search_for_a_drive_tries_tfs_on_its_sync_grid_and_answers_drive_exact():
    from ff_planner.optimize.drive_grid import DriveCertificate, DriveGrid
    from ff_planner.optimize.planner import check as check_req

    seen: list[float] = []
    drive = DriveGrid(quantum=0.003, period=0.01, source="test")

    def fn(req, progress=None):
        seen.append(float(req.tf))
        assert getattr(req, "grid", None) == 0.01
        return _stand_in(lambda tf: 1e-3 if tf >= 1.234 else 50e-3)(req, progress)

    r = plan_fastest(PlanRequest(objective="robust-box", steps=5, qf=(1.0,), tf=2.0,
                                 tolerance=2e-3, move_time_max=2.0), plan_fn=fn, drive=drive)
    assert r.success and 1.24 - 1e-9 <= r.profile.tf <= 1.24 * 1.011 + 1e-9
    assert seen and all(abs(t / 0.01 - round(t / 0.01)) < 1e-9 for t in seen)
    real = plan_fastest(check_req(PlanRequest(objective="robust-box", steps=5, qf=(1.0,), tf=1.5,
                                              tolerance=0.05, move_time_max=1.5,
                                              time_budget=20.0), drive))
    assert real.success and isinstance(real.certificate, DriveCertificate)
    assert "drive_exact" in real.extra
    assert all(abs(t["tf"] / 0.01 - round(t["tf"] / 0.01)) < 1e-9
               for t in real.extra["tolerance_search"]["trials"])
