"""Planner-test fixtures."""
from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def robust_plan_1dof():
    """The canonical derivative-robust plan: 1-DOF table 2 arm, 0 → 1 rad in 1 s, pv, pc, pt
    uncertain, N = 5, robust-derivative (3000 starts, seed 0); read-only. Overrides the suite's
    fixture of the same name so that the planner tests keep the paper's objective pinned."""
    from ff_planner.model.profile import PlanRequest
    from ff_planner.optimize.planner import plan

    result = plan(PlanRequest(model="arm1dof", q0=[0.0], qf=[1.0], tf=1.0, uncertain=["pv", "pc", "pt"],
                              objective="robust-derivative", starts=3000, seed=0))
    assert result.success and result.robust, result.message
    return result
