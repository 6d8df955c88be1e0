"""Position and speed limits as constraints of the 1-DOF planners (rad, rad/s).

Oracle: the simulator's dense trajectory (0.1 ms and every event) until rest at the box corners
and fresh uniform points, independently of the excursion kernels the planners use.
"""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.core.errors import PlanningError
from ff_planner.model.arm1dof import simulate_arm1dof
from ff_planner.model.limits import MotionLimits
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.baselines import plan_baseline
from ff_planner.optimize.box_robust import plan_box_robust_1dof
from ff_planner.optimize.certificate import certify_1dof
from ff_planner.optimize.limits1d import Limits1D
from ff_planner.optimize.robust1d import plan_robust_1dof
from ff_planner.optimize.sample_box import box_corners

PAPER_LIMITS = MotionLimits.of([-0.3], [1.05], [4.0])
UNC = ("pv", "pc", "pt")


def _dense_excursion(params, profile, scale):
    p = params.replace(pv=params.pv * scale[0], pc=params.pc * scale[1], pt=params.pt * scale[2])
    sim = simulate_arm1dof(p, profile, 0.0, trajectory=True, dt=1e-4, t_end=4.0)
    assert sim.qd[-1, 0] == 0.0
    return float(sim.q.min()), float(sim.q.max()), float(np.abs(sim.qd).max())


def _assert_within(result, lim: MotionLimits, fresh: int = 16):
    """The plan's motion stays within ``lim`` at the corners, the centre and fresh points."""
    lo, hi, vm = lim.position_min[0], lim.position_max[0], lim.velocity_max[0]
    rng = np.random.default_rng(5)
    points = np.vstack([box_corners({u: 0.2 for u in UNC}, UNC),
                        rng.uniform(0.8, 1.2, (fresh, 3))])
    for s in points:
        q_lo, q_hi, v = _dense_excursion(result.params, result.profile, s)
        assert q_lo >= lo - 1e-6 and q_hi <= hi + 1e-6 and v <= vm + 1e-6, (s, q_lo, q_hi, v)


def test_limits_check_agrees_with_the_certificate_excursion():
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", seed=0, starts=5000))
    ex = certify_1dof(r.params, r.profile, 0.0, 1.0, UNC).excursion
    assert ex is not None
    inside = MotionLimits.of([ex.worst_min[0] - 1e-6], [ex.worst_max[0] + 1e-6],
                             [ex.worst_speed[0] + 1e-6])
    lim = Limits1D.of(inside, r.params, 0.0, 1.0, UNC)
    assert lim is not None and lim.ok(r.profile.step_times, r.profile.currents[:, 0])
    tight = MotionLimits.of([ex.worst_min[0] + 1e-3], None, None)
    lim2 = Limits1D.of(tight, r.params, 0.0, 1.0, UNC)
    assert lim2 is not None
    assert lim2.excess(r.profile.step_times, r.profile.currents[:, 0]) == pytest.approx(1e-3,
                                                                                       abs=1e-9)


def test_robust_derivative_honours_loose_limits_and_refuses_tight_ones():
    loose = MotionLimits.of([-1.5], [2.5], [12.0])
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", seed=0, starts=5000,
                                     limits=loose))
    assert r.success and r.robust
    _assert_within(r, loose, fresh=4)
    tight = MotionLimits.of([-0.05], [1.02], [3.0])
    r2 = plan_robust_1dof(PlanRequest(objective="robust-derivative", seed=0, starts=300,
                                      limits=tight))
    assert not r2.success and r2.profile is None          # never a plan outside the limits
    assert "widen the position range" in r2.message and "velocity_max 3" in r2.message


def test_robust_box_paper_limits_give_a_plan_within_them():
    r = plan_box_robust_1dof(PlanRequest(seed=0, steps=12, limits=PAPER_LIMITS,
                                         time_budget=60.0))
    assert r.profile is not None
    # no truly robust plan keeps within these limits: the least-worst plan within them,
    # labelled
    assert not r.success and r.best_effort and "NOT derivative-robust" in r.message
    cert = certify_1dof(r.params, r.profile, 0.0, 1.0, UNC)
    assert cert.excursion is not None and cert.excursion.violations(PAPER_LIMITS) == []
    assert cert.worst_rest_error < 0.1      # far below the energy-optimal 0.457 rad
    assert cert.worst_rest_error == pytest.approx(r.extra["box_worst"], rel=0.1)
    _assert_within(r, PAPER_LIMITS)


def test_robust_box_keeps_its_plan_when_the_limits_do_not_bind():
    free = plan_box_robust_1dof(PlanRequest(seed=1, steps=5))
    ex = certify_1dof(free.params, free.profile, 0.0, 1.0, UNC).excursion
    assert ex is not None
    lim = MotionLimits.of([ex.worst_min[0] - 0.01], [ex.worst_max[0] + 0.01],
                          [ex.worst_speed[0] + 0.01])
    r = plan_box_robust_1dof(PlanRequest(seed=1, steps=5, limits=lim))
    assert r.success and r.robust
    assert np.allclose(r.profile.currents, free.profile.currents)


@pytest.mark.parametrize("objective", ["energy-optimal", "time-optimal"])
def test_baselines_refuse_limits_they_leave(objective):
    with pytest.raises(PlanningError, match="cannot honour them.*") as err:
        plan_baseline(PlanRequest(objective=objective, limits=PAPER_LIMITS))
    assert err.value.code == "UNREACHABLE" and "joint 1 reaches" in str(err.value)
    wide = MotionLimits.of([-0.5], [2.0], [12.0])
    r = plan_baseline(PlanRequest(objective=objective, limits=wide))
    assert r.success
    _assert_within(r, wide, fresh=4)


def test_limit_constraints_and_their_jacobian():
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", seed=2, starts=5000))
    lim = Limits1D.of(PAPER_LIMITS, r.params, 0.0, 1.0, UNC)
    assert lim is not None
    t = np.array(r.profile.step_times, dtype=float)
    cur = np.array(r.profile.currents[:, 0], dtype=float)
    g, G = lim.terms(t, cur, lim.corners, 4)
    assert g.shape == (3 * lim.corners.shape[0],) and G.shape == (g.shape[0], 9)
    assert np.allclose(g, lim.values(t, cur, lim.corners))
    # g in mrad: the nominal row (the centre is the last corner row) against the excursion
    ex = certify_1dof(r.params, r.profile, 0.0, 1.0, UNC).excursion
    assert ex is not None
    assert g[-3] == pytest.approx(1e3 * (ex.nominal_min[0] + 0.3), abs=1e-6)
    assert g[-1] == pytest.approx(1e3 * (4.0 - ex.nominal_speed[0]), abs=1e-6)
    # the forward-difference Jacobian against central differences of the values (away from
    # kinks of the max: compare columns where the two agree to first order)
    h = 1e-5
    for j in (0, 2, 4):
        cp, cm = cur.copy(), cur.copy()
        cp[j] += h
        cm[j] -= h
        col = (lim.values(t, cp, lim.corners) - lim.values(t, cm, lim.corners)) / (2 * h)
        assert np.allclose(G[:, j], col, rtol=1e-3, atol=1e-2)
    for j in (1, 3):
        tp, tm = t.copy(), t.copy()
        tp[j] += 1e-7
        tm[j] -= 1e-7
        col = (lim.values(tp, cur, lim.corners) - lim.values(tm, cur, lim.corners)) / 2e-7
        assert np.allclose(G[:, 5 + j - 1], col, rtol=1e-2, atol=1.0)


def test_robust_sampled_keeps_its_candidates_within_limits():
    loose = MotionLimits.of([-1.5], [2.5], [12.0])
    r = plan_robust_1dof(PlanRequest(objective="robust-sampled", seed=0, starts=2000,
                                     limits=loose))
    assert r.success and r.robust
    _assert_within(r, loose, fresh=2)
