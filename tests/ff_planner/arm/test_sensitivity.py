"""Forward sensitivities of the rest position from Pinocchio's analytical derivatives
(ff_planner.arm.sensitivity) against the complex-step derivatives through the compiled
simulator (another code path: complex arithmetic in the numba kernel) and central differences,
on the 3-DOF horizontal arm and the vertical 2-link arm (gravity, holding current)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ff_planner.arm import sim
from ff_planner.arm.model import load_arm
from ff_planner.arm.sensitivity import rest_sensitivity
from ff_planner.model.profile import CurrentProfile

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"
H = 4e-3
REL_TOL = 1e-5      # of the largest derivative of each block (measured ~2e-10 on arm3h)


def _complex_step_currents(arm, prof, q0, i_rest=None) -> np.ndarray:
    N, n = prof.currents.shape
    J = np.zeros((n, N * n))
    base = prof.currents.astype(complex).ravel()
    for c in range(N * n):
        cur = base.copy()
        cur[c] += 1e-30j
        r = sim.run(arm, prof, q0, currents=cur.reshape(N, n), i_rest=i_rest, h=H, settle=True)
        assert r[-1] == sim.OK
        J[:, c] = r[1][:n].imag / 1e-30
    return J


def _cases():
    arm3 = load_arm(ARMS / "arm3h.cell.yaml")
    cur3 = np.array([[2.0, -1.5, 0.8], [1.2, -0.6, 0.5], [0.1, 0.4, -0.2], [-1.0, 0.9, -0.6],
                     [-1.8, 1.1, -0.4], [0.3, -0.2, 0.1]])
    v2 = load_arm(ARMS / "vertical2.cell.yaml")
    q0 = np.array([1.2, 0.3])
    hold = v2.holding_torque(q0) / v2.torque_per_amp
    cur2 = np.array([hold + [0.6, 0.3], hold + [0.3, -0.2], hold - [0.6, 0.2], hold - [0.2, -0.1]])
    return [("arm3h", arm3, CurrentProfile.uniform(cur3, 1.2, 0.05), np.zeros(3), None),
            ("vertical2", v2, CurrentProfile.uniform(cur2, 1.0, 0.1), q0, hold)]


@pytest.fixture(scope="module", params=[0, 1], ids=["arm3h", "vertical2"])
def case(request):
    return _cases()[request.param]


def test_rest_and_event_mix(case):
    name, arm, prof, q0, hold = case
    s = sim.simulate(arm, prof, q0, h=H, i_rest=hold, record=True)
    rs = rest_sensitivity(arm, prof, q0, h=H, i_rest=hold)
    assert s.q_rest is not None
    np.testing.assert_array_equal(rs.rest, s.q_rest)
    kinds = set(int(k) // 10 for k in s.event_kind if k)
    assert 1 in kinds, "the move should end in stick events"
    if name == "vertical2":
        assert 3 in kinds, "a breakaway event (its jump of the tangent) should be exercised"
    assert rs.steps > 100


def test_friction_sensitivities_match_complex_step(case):
    name, arm, prof, q0, hold = case
    rs = rest_sensitivity(arm, prof, q0, h=H, i_rest=hold)
    cs = sim.rest_sensitivities(arm, prof, q0, h=H, i_rest=hold)
    scale = float(np.max(np.abs(cs)))
    assert scale > 1e-3
    assert np.max(np.abs(rs.d_friction - cs)) <= REL_TOL * scale, (name, rs.d_friction, cs)


def test_current_sensitivities_match_complex_step_and_central_differences(case):
    name, arm, prof, q0, hold = case
    rs = rest_sensitivity(arm, prof, q0, h=H, i_rest=hold)
    J = rs.jacobian_currents()
    Jc = _complex_step_currents(arm, prof, q0, hold)
    scale = float(np.max(np.abs(Jc)))
    assert scale > 1e-3
    assert np.max(np.abs(J - Jc)) <= REL_TOL * scale, (name, J, Jc)
    # central differences on the largest column (an independent, cruder check)
    c = int(np.argmax(np.abs(Jc).max(axis=0)))
    N, n = prof.currents.shape
    d = 1e-5
    rows = []
    for s in (1.0, -1.0):
        cur = prof.currents.copy().ravel()
        cur[c] += s * d
        p = CurrentProfile.uniform(cur.reshape(N, n), prof.tf, prof.coast)
        rows.append(sim.rest_position(arm, p, q0, h=H, i_rest=hold))
    fd = (rows[0] - rows[1]) / (2 * d)
    np.testing.assert_allclose(J[:, c], fd, atol=1e-4 * scale)
