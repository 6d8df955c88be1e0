"""Baselines of paper section 6.5 (time- and energy-optimal) and the 1-DOF reach bound."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model.params import PRESETS
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest
from ff_planner.model.simulate import simulate
from ff_planner.optimize.baselines import (R_TERMINAL, bang_bang_times, energy_optimal_1dof, plan_baseline,
                                           reach_1dof, time_optimal_1dof)

P2 = PRESETS["table2"]


def test_time_optimal_reaches_goal_at_rest_and_is_tight_with_reach_bound():
    bl = time_optimal_1dof(P2, 0.0, 1.0, 1.0, 0.05)
    r = simulate(P2, bl.profile, [0.0])
    assert abs(r.q_f[0] - 1.0) < 1e-9 and r.qd_f[0] == 0.0
    t1, t2 = bang_bang_times(P2, 1.0)
    assert 0 < t1 < t2 == pytest.approx(bl.t_arrival)
    # bang-bang is the farthest move in t2: the reach bound at t2 is exactly this distance
    assert reach_1dof(P2, t2) == pytest.approx(1.0, abs=1e-9)
    assert bl.energy == pytest.approx(R_TERMINAL * 100.0 * t2)


def test_reach_bound_is_never_beaten_by_random_profiles():
    """Whenever a random profile brings the arm to rest (a stick event at t), |q(t)| <= reach(t)."""
    rng = np.random.default_rng(1)
    tf, coast = 0.6, 0.05
    checked = 0
    for _ in range(300):
        n = int(rng.integers(1, 7))
        scale = P2.i_max * rng.choice([0.05, 0.3, 1.0])
        prof = CurrentProfile.uniform(rng.uniform(-scale, scale, (n, 1)), tf, coast)
        r = simulate(P2, prof, [0.0], trajectory=True, dt=0.01)
        for t_ev, kind in r.events:
            if kind == "stick" and t_ev > 0:
                q_ev = float(np.interp(t_ev, r.t, r.q[:, 0]))
                assert abs(q_ev) <= reach_1dof(P2, t_ev) + 1e-9
                checked += 1
    assert checked > 30
    # tight up to the coast: a bang-bang move over 0.99 of the bound fits in tf - coast
    t1, t2 = bang_bang_times(P2, 0.99 * reach_1dof(P2, tf - coast))
    assert t2 <= tf - coast


def test_time_optimal_refuses_when_tf_too_short():
    with pytest.raises(PlanningError) as ei:
        time_optimal_1dof(P2, 0.0, 1.0, 0.2, 0.05)
    assert ei.value.code == "UNREACHABLE" and "raise tf" in str(ei.value)


def test_energy_optimal_is_feasible_and_cheaper_than_time_optimal():
    bl = energy_optimal_1dof(P2, 0.0, 1.0, 1.0, 0.05, steps=60)
    tr = simulate(P2, bl.profile, [0.0], trajectory=True)
    assert abs(tr.q_f[0] - 1.0) < 1e-8 and abs(tr.qd_f[0]) < 1e-8
    assert np.all(tr.qd[:, 0] >= -1e-12), "energy-optimal move must be monotone"
    assert np.max(np.abs(bl.profile.currents)) <= P2.i_max
    h = bl.profile.step_times[1]
    assert bl.energy == pytest.approx(R_TERMINAL * np.sum(bl.profile.currents ** 2) * h)
    assert bl.energy < 0.05 * time_optimal_1dof(P2, 0.0, 1.0, 1.0, 0.05).energy
    # a feasible neighbour (same end state, currents perturbed along the constraint null space)
    # costs more: compare against scaling the move time down (needs more current)
    faster = energy_optimal_1dof(P2, 0.0, 1.0, 0.8, 0.05, steps=60)
    assert faster.energy > bl.energy


def test_energy_optimal_matches_paper_table4_relative_sensitivities():
    """Table 4 (energy optimal) reads as p·∂q/∂p: pc −0.626, pv 0.163, pt −0.499."""
    res = plan_baseline(PlanRequest(objective="energy-optimal", steps=100))
    rel = res.extra["relative_sensitivities"]
    assert rel["pc"] == pytest.approx(-0.626, rel=0.05)
    assert rel["pv"] == pytest.approx(0.163, rel=0.05)
    assert rel["pt"] == pytest.approx(-0.499, rel=0.2)
    assert not res.robust and res.success


def test_baseline_going_backwards_and_2dof_refusal():
    res = plan_baseline(PlanRequest(objective="time-optimal", q0=(0.5,), qf=(-0.5,)))
    assert res.success and res.profile.currents[0, 0] == -P2.i_max
    assert abs(res.q_final[0] + 0.5) < 1e-9
    with pytest.raises(PlanningError, match="arm1dof only"):
        plan_baseline(PlanRequest(model="scara2", q0=(0, 0), qf=(1, 0), objective="time-optimal",
                                  uncertain=("pc1",)))


def test_energy_optimal_dual_solver_matches_a_generic_qp_and_refuses_infeasible():
    from scipy.optimize import minimize

    from ff_planner.optimize.baselines import box_least_norm

    rng = np.random.default_rng(0)
    A = rng.normal(size=(2, 12))
    x_true = rng.uniform(0, 1, 12)
    b = A @ x_true
    x = box_least_norm(A, b, 0.1, 1.0)
    ref = minimize(lambda z: 0.1 * z @ z, x_true, jac=lambda z: 0.2 * z, method="SLSQP",
                   bounds=[(0, 1)] * 12, constraints=[{"type": "eq", "fun": lambda z: A @ z - b}],
                   options={"ftol": 1e-15, "maxiter": 500})
    np.testing.assert_allclose(A @ x, b, atol=1e-10)
    assert 0.1 * x @ x <= ref.fun + 1e-9 and np.all((x >= 0) & (x <= 1))
    assert box_least_norm(A, b * 100.0, 0.1, 1.0) is None   # needs x far above the box
    with pytest.raises(PlanningError, match="energy-optimal"):
        energy_optimal_1dof(P2, 0.0, 19.0, 1.0, 0.05)
