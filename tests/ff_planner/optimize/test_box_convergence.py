"""robust-box free-time solver: one-sided slopes at zero current, the smooth-maximum solver's
convergence, and the iterations and converged flags a plan reports."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ff_planner.model.profile import PlanRequest
from ff_planner.optimize import box_robust as B
from ff_planner.optimize.planner import plan
from ff_planner.optimize.robust1d import _Problem
from ff_planner.optimize.sample_box import box_fractions, box_minimax_samples

KEYS = ("pv", "pc", "pt")


def _free_box(n: int, times: np.ndarray) -> B._FreeBox:
    p = plan(PlanRequest(objective="robust-derivative", steps=5, starts=50)).params
    prob = B._with_times(_Problem(PlanRequest(objective="robust-box", steps=n), p, n), times)
    return B._FreeBox(prob, box_minimax_samples(box_fractions(KEYS), KEYS), (0.05, 0.25))


def test_a_zero_current_takes_the_slope_of_its_side():
    """At I_j = 0 the friction level pc + pt·|T| has a kink: the plain Jacobian column is the
    mean of the two one-sided slopes; with the sides kept it is the slope of the kept side
    (central differences of the exact simulator on that side only)."""
    times = np.array([0.0, 0.2, 0.45, 0.7, 0.95])
    cur = np.array([8.0, 0.0, -6.0, 2.0])
    box = _free_box(4, times)
    x = box.start(cur, times)
    _, Ge_mean, _, _ = box.terms(x)
    h = 1e-6
    slopes = {}
    for side in (1.0, -1.0):
        xa, xb = x.copy(), x.copy()
        xa[1], xb[1] = side * 2 * h, side * h
        ea, eb = box.values(xa)[0], box.values(xb)[0]
        slopes[side] = (ea - eb) / (side * h)          # one-sided, within the side
        sides = cur.copy()
        sides[1] = math.copysign(0.0, side)
        box.keep_sides(sides)
        box.memo.clear()
        _, Ge, _, _ = box.terms(x)
        assert np.allclose(Ge[:, 1], slopes[side], rtol=1e-4, atol=1e-9)
        box.orthant = False
        box.memo.clear()
    assert not np.allclose(slopes[1.0], slopes[-1.0], rtol=1e-3)      # a kink indeed
    assert np.allclose(Ge_mean[:, 1], 0.5 * (slopes[1.0] + slopes[-1.0]), rtol=1e-4, atol=1e-9)


@pytest.fixture(scope="module")
def lm_start():
    r = plan(PlanRequest(objective="robust-derivative", steps=8, starts=200))
    assert r.success and r.robust
    prob = B._with_times(_Problem(PlanRequest(objective="robust-box", steps=8), r.params, 8),
                         r.profile.step_times)
    return prob, np.ascontiguousarray(r.profile.currents[:, 0])


def test_smooth_solver_converges_keeps_sides_and_never_returns_a_worse_iterate(lm_start):
    prob, I0 = lm_start
    box = B._FreeBox(prob, box_minimax_samples(box_fractions(KEYS), KEYS), (0.05, 0.25))
    box.keep_sides(I0)
    x0 = box.start(I0, prob.times)
    m0 = box.merit(x0)
    with B._OneBlasThread():        # as in a plan
        x = box.solve_smooth(x0, deadline=math.inf)
    assert box.info["converged"], box.info              # SLSQP's own test, both stages
    assert box.info["iterations"] < len(B.SMOOTH_BETAS) * B.SMOOTH_STAGE_ITER
    assert box.merit(x) < 0.5 * m0
    assert np.all(np.sign(x[:8]) * np.sign(I0) >= 0.0)      # no current crossed zero
    t = box.times(x)
    assert np.all(np.diff(t) >= B.MIN_STEP - 1e-9) and 0.05 - 1e-9 <= 1.0 - t[-1] <= 0.25 + 1e-9


def test_plans_report_their_free_time_solves():
    """Every free-time solve of a default plan is reported: its iterations and whether SLSQP's
    test was met; with the smooth solver (ORTHANT) the default plan's solves converge."""
    saved = B.ORTHANT
    try:
        for on in (False, True):
            B.ORTHANT = on
            r = plan(PlanRequest(seed=0))
            ft = r.extra["free_time_solves"]
            assert r.success and r.robust and ft["solves"] >= 1
            assert len(ft["iterations"]) == ft["solves"] and 0 <= ft["converged"] <= ft["solves"]
            if on:
                assert ft["converged"] == ft["solves"], ft
                assert max(ft["iterations"]) < len(B.SMOOTH_BETAS) * B.SMOOTH_STAGE_ITER
    finally:
        B.ORTHANT = saved
