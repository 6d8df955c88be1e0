"""robust-box for the 3-DOF horizontal arm (config/arms/arm3h), all three joints moving: the plan
and its certificate, re-checked by the independent reference simulation (Pinocchio dynamics at
every evaluation, adaptive DOP853 with its own event location) at 100 fresh box points."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ff_planner.arm import sim
from ff_planner.arm.model import load_arm
from ff_planner.arm.reference import reference_rest
from ff_planner.armplan.certificate import BoxSpec
from ff_planner.armplan.robust_box import ArmPlan, plan_box_robust_arm

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"
Q0 = np.zeros(3)
QF = np.array([0.5, -0.4, 0.6])
TF = 1.5
FRESH_SEED = 99_001      # not the certificate's seed: fresh points


@pytest.fixture(scope="module")
def arm():
    return load_arm(ARMS / "arm3h.cell.yaml")


@pytest.fixture(scope="module")
def result(arm) -> ArmPlan:
    return plan_box_robust_arm(arm, Q0, QF, TF, time_budget=30.0, seed=0)


def test_plan_reaches_the_goal_and_carries_its_certificate(arm, result):
    assert result.label in ("zero-derivative", "least-worst")
    assert result.profile.currents.shape == (result.profile.n_steps, 3)
    assert np.all(np.abs(result.profile.currents) <= arm.i_max + 1e-12)
    rest = sim.rest_position(arm, result.profile, Q0)
    assert np.max(np.abs(rest - QF)) < 1e-6
    c = result.certificate
    assert c is not None and c.excursion is not None
    assert len(c.worst_per_joint) == 3 and c.worst_rest_error == max(c.worst_per_joint)
    assert set(c.box) == set(BoxSpec.of(arm).names) and len(c.box) == 9
    assert c.samples >= 2 ** 9 + 1 + 18 + 128
    assert result.limit_violations == [] and result.success
    # the certificate's worst is not better than the first-order surrogate claims at the faces
    assert c.worst_rest_error > 0.0
    # the excursion contains both ends of the move
    assert np.all(np.array(c.excursion.worst_min) <= np.minimum(Q0, QF) + 1e-9)
    assert np.all(np.array(c.excursion.worst_max) >= np.maximum(Q0, QF) - 1e-9)


def test_independent_simulator_agrees_and_fresh_points_stay_within_the_certificate(arm, result):
    c = result.certificate
    assert c is not None
    spec = BoxSpec.of(arm)
    rows = np.random.default_rng(FRESH_SEED).uniform(-1.0, 1.0, (100, spec.k))
    worst = np.zeros(3)
    for i, s in enumerate(spec.scales(arm, rows)):
        ref, _ = reference_rest(arm, result.profile, Q0, friction_scale=s)
        assert np.all(np.isfinite(ref))
        if i < 20:   # the two simulators agree on the same point
            mine = sim.rest_position(arm, result.profile, Q0, friction_scale=s)
            assert np.max(np.abs(mine - ref)) < 1e-6
        worst = np.maximum(worst, np.abs(ref - QF))
    assert np.all(worst <= 1.10 * np.array(c.worst_per_joint)), (worst, c.worst_per_joint)
    assert np.max(worst) <= 1.10 * c.worst_rest_error
