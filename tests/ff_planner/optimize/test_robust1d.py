"""Robust 1-DOF planning: truly robust plans (true derivatives), clear answers when none exist."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model.arm1dof import FRICTION
from ff_planner.model.params import preset
from ff_planner.model.profile import PlanningError, PlanRequest
from ff_planner.model.simulate import rest_position, simulate
from ff_planner.optimize.planner import plan
from ff_planner.optimize.robust1d import plan_robust_1dof, stop_speed_bound
from ff_planner.optimize.sample_box import sample_scales

T2 = preset("table2")


def test_k3_plan_is_truly_robust(robust_plan_1dof):
    r = robust_plan_1dof
    assert r.success and r.robust and not r.best_effort and r.error_code == "OK"
    assert r.profile.n_steps == 5
    assert np.all(np.abs(r.profile.currents) <= T2.i_max)
    assert abs(r.q_final[0] - 1.0) <= 1e-6 and r.qd_final[0] == 0.0
    ver = r.extra["verification"]
    for k in ("pv", "pc", "pt"):
        assert abs(r.sensitivities[k]) <= 1e-6
        assert abs(ver["central"][k]) <= 1e-6           # small-step central differences agree
    assert ver["kink_radius"] >= 1e-3                    # not at a stiction/switch kink


def test_k3_plan_holds_when_resimulated_with_perturbed_parameters(robust_plan_1dof):
    """Independent check through simulate(): the final position moves only to second order."""
    prof = robust_plan_1dof.profile
    q_nom = simulate(T2, prof, [0.0]).q_f[0]
    for k in ("pv", "pc", "pt"):
        p0 = getattr(T2, k)
        for rel in (1e-5, 1e-4):
            qp = simulate(T2.replace(**{k: p0 * (1 + rel)}), prof, [0.0]).q_f[0]
            qm = simulate(T2.replace(**{k: p0 * (1 - rel)}), prof, [0.0]).q_f[0]
            # first order would move by |dq/dp|·p·rel; robust means both sides ≪ that scale
            assert abs(qp - q_nom) < 1e-4 * rel ** 0.5 + 1e-9, (k, rel, qp - q_nom)
            assert abs(qm - q_nom) < 1e-4 * rel ** 0.5 + 1e-9, (k, rel, qm - q_nom)
    assert rest_position(T2, prof, [0.0])[0] == pytest.approx(1.0, abs=1e-6)
    fc = robust_plan_1dof.extra["finite_change"]
    assert set(fc) == {"pv", "pc", "pt", "all"} and "+40%" in fc["pc"]


@pytest.mark.parametrize("name", ["pv", "pc", "pt"])
def test_single_parameter_plans(name):
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", uncertain=(name,), starts=500, seed=1))
    assert r.success and r.robust and r.profile.n_steps == 3
    assert abs(r.sensitivities[name]) <= 1e-6
    assert abs(r.extra["verification"]["central"][name]) <= 1e-6


def test_too_few_steps_says_no_robust_plan():
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", steps=4, starts=300, seed=0))
    assert not r.success and not r.robust and r.best_effort
    assert r.error_code == "NO_ROBUST_PLAN" and "N = 4" in r.message
    assert r.profile is not None and r.starts_tried == 300


def test_robust_sampled_improves_finite_change_error():
    r = plan_robust_1dof(PlanRequest(objective="robust-sampled", steps=7, starts=400, seed=2))
    assert r.success and r.robust
    assert r.extra["sampled_rms"] <= r.extra["sampled_rms_before_refine"] + 1e-12
    assert r.extra["sampled_rms"] < 0.1


def test_warm_start_from_a_plan_takes_one_start(robust_plan_1dof):
    init = robust_plan_1dof.profile.currents[:, 0] + 0.01
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", starts=10, seed=5), initial_currents=init)
    assert r.success and r.warm_start and r.starts_tried == 1


def test_time_budget_is_honoured():
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", steps=4, starts=100000, seed=0, time_budget=0.05))
    assert not r.success and r.error_code == "TIME_BUDGET_EXHAUSTED"
    assert r.solve_time < 2.0 and r.starts_tried < 100000


def test_bad_requests_are_clear_errors():
    with pytest.raises(PlanningError, match="arm1dof"):
        plan_robust_1dof(PlanRequest(objective="robust-derivative", model="scara2", q0=(0.0, 0.0), qf=(1.0, 0.0),
                                     uncertain=("pc1",)))
    with pytest.raises(PlanningError, match="initial_currents"):
        plan_robust_1dof(PlanRequest(objective="robust-derivative"), initial_currents=[1.0, 2.0])
    with pytest.raises(ValueError, match="tf"):
        plan(PlanRequest(objective="robust-derivative", tf=0.04))
    with pytest.raises(ValueError):
        plan(PlanRequest(objective="robust-derivative", uncertain=("mu",)))
    with pytest.raises(PlanningError, match="robust-derivative"):
        plan_robust_1dof(PlanRequest(objective="time-optimal"))


def test_helpers():
    vb = stop_speed_bound(T2, 0.05)
    assert 0.05 < vb < 0.06
    s = sample_scales(["pc", "pt"], FRICTION)
    assert s.shape == (4 * 2 + 4, 3) and np.all(s[:, 0] == 1.0)


def test_switch_times_on_a_cycle_grid():
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", uncertain=("pc",), starts=500, seed=1), grid=1e-3)
    assert r.success and r.robust
    t = r.profile.step_times
    assert np.allclose(t / 1e-3, np.round(t / 1e-3), atol=1e-9) and t[-1] <= 0.95 + 1e-12
    assert not np.allclose(t, np.linspace(0, 0.95, 4))      # N = 3: 0.3167 s is off-grid
    with pytest.raises(PlanningError, match="grid"):
        plan_robust_1dof(PlanRequest(objective="robust-derivative", uncertain=("pc",)), grid=0.5)


def test_progress_reports_and_smallest_steps():
    from ff_planner.optimize.robust1d import smallest_robust_steps

    seen = []
    r, evidence = smallest_robust_steps(PlanRequest(objective="robust-derivative",
                                                    steps=4, starts=200, seed=0), n_max=5,
                                        progress=seen.append)
    assert r is not None and r.profile.n_steps == 5
    assert [e["steps"] for e in evidence] == [4, 5] and not evidence[0]["robust"]
    assert seen and {"starts_done", "robust_found", "best"} <= set(seen[0])


def test_zero_nominal_parameter_still_counts():
    """Table 1 has pv = 0: its derivative row must not vanish by scaling with p = 0."""
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative",
                                     params=preset("table1"), uncertain=("pv", "pc"), steps=5,
                                     starts=2000, seed=0))
    assert r.success and r.robust
    assert abs(r.sensitivities["pv"]) <= 1e-6 and abs(r.sensitivities["pc"]) <= 1e-6


def test_same_seed_same_plan():
    a = plan_robust_1dof(PlanRequest(objective="robust-derivative", starts=500, seed=7))
    b = plan_robust_1dof(PlanRequest(objective="robust-derivative", starts=500, seed=7))
    assert a.success and np.array_equal(a.profile.currents, b.profile.currents)
    assert a.starts_tried == b.starts_tried
