"""Gravity: the vertical 2-link arm (config/arms/vertical2). Its gravity torques equal Pinocchio's;
with the holding current at rest the arm stays put; a move with gravity ends where the
independent reference simulation says."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from ff_planner.arm import sim
from ff_planner.arm.model import load_arm
from ff_planner.arm.reference import reference_rest
from ff_planner.model.profile import CurrentProfile

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"


@pytest.fixture(scope="module")
def arm():
    return load_arm(ARMS / "vertical2.cell.yaml")


def test_gravity_torque_is_pinocchios(arm):
    data = arm.pin_model.createData()
    for th in ([0.0, 0.0], [0.4, -0.9], [-1.2, 2.0]):
        g = pin.computeGeneralizedGravity(arm.pin_model, data, arm.pin_configuration(np.array(th)))
        np.testing.assert_allclose(arm.holding_torque(np.array(th)), np.asarray(g).ravel(), atol=1e-10)
    # horizontal links: m1·g·lc1 + m2·g·(l1 + lc2) on joint 1 (y axis: positive torque lifts -z)
    assert abs(arm.holding_torque(np.zeros(2))[0]) == pytest.approx(9.81 * (0.15 + 0.6 * 0.42), rel=1e-9)


def test_holding_current_keeps_the_arm_at_rest_and_zero_current_lets_it_fall(arm):
    th = np.array([0.3, -0.5])
    hold = arm.holding_torque(th) / arm.torque_per_amp
    prof = CurrentProfile.uniform(np.tile(hold, (2, 1)), 1.0, 0.05)
    s = sim.simulate(arm, prof, th, i_rest=hold)
    assert s.n_events == 0 and s.q_rest is not None and np.max(np.abs(s.q_rest - th)) == 0.0
    fall = sim.simulate(arm, CurrentProfile.uniform(np.zeros((2, 2)), 1.0, 0.05), th, settle=False)
    assert abs(fall.q_f[0] - th[0]) > 0.1      # no current: link 1 falls


def test_a_move_under_gravity_matches_the_reference(arm):
    """Link 1 hanging 1.2 rad below horizontal: a push and a pull around the holding currents,
    which the motors keep after the move; the arm settles where both simulations say."""
    q0 = np.array([1.2, 0.3])
    hold0 = arm.holding_torque(q0) / arm.torque_per_amp
    cur = np.array([hold0 + [0.6, 0.3], hold0 + [0.3, -0.2], hold0 - [0.6, 0.2], hold0 - [0.2, -0.1]])
    prof = CurrentProfile.uniform(cur, 1.0, 0.1)
    s = sim.simulate(arm, prof, q0, i_rest=hold0)
    assert s.q_rest is not None and s.n_events > 0 and np.max(np.abs(s.q_rest - q0)) > 0.05
    ref, _ = reference_rest(arm, prof, q0, i_rest=hold0)
    np.testing.assert_allclose(s.q_rest, ref, atol=1e-7)
