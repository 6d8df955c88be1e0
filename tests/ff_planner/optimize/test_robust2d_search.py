"""The link-2-moving evidence search: its residual recognises a truly robust plan, and a search
result reports what it found."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.robust2d import plan_robust_scara2
from ff_planner.optimize.robust2d_least_worst import robust_search

P = Scara2Params()


@pytest.fixture(scope="module")
def held():
    req = PlanRequest(objective="robust-derivative", model="scara2", q0=(0.0, 0.0), qf=(0.6, 0.0), tf=1.0,
                      uncertain=scara2.FRICTION_NAMES, seed=0, time_budget=60)
    res = plan_robust_scara2(req)
    assert res.success
    return req, res


def test_residual_is_zero_at_a_truly_robust_plan(held):
    req, res = held
    out = robust_search(P, req.q0, req.qf, 1.0, 8, 0.0, initial=[res.profile.currents.ravel()],
                        max_nfev=1, h=1e-3)
    assert out["starts"] == 1
    assert out["best_max_scaled_residual"] <= 1e-6
    assert out["max_abs_sensitivity"] <= 1e-6 and out["at_rest_tf"]
    assert out["goal_error_rad"] <= 1e-6


def test_residual_sees_a_missed_goal_and_free_times_are_a_partition(held):
    """The held plan asked to reach a goal it does not reach: residual 10 × the miss; with free
    times and u = 0 the steps are the equal ones."""
    req, res = held
    x = np.r_[res.profile.currents.ravel(), np.zeros(8)]
    out = robust_search(P, req.q0, (0.6, 0.05), 1.0, 8, 0.0, initial=[x], max_nfev=1,
                        free_times=True, h=1e-3)
    assert out["best_max_scaled_residual"] == pytest.approx(0.5, rel=1e-6)
    assert np.allclose(out["step_times_s"], res.profile.step_times)
