"""The friction law (Eq. 9) of ff_planner.model.friction in every number system, and the
simulators' agreement with it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ff_planner.model import arm1dof, scara2
from ff_planner.model.friction import (breakaway_excess, breaks_away, exceeds_stiction, friction_torque,
                                       friction_torque_array, net_torque, net_torque_array, sliding_friction,
                                       sliding_level, sliding_level_array, sliding_level_series,
                                       stiction_margin, stop_speed)
from ff_planner.model.params import Arm1DofParams, Scara2Params, preset
from ff_planner.model.taylor import row_const, row_len

T2 = preset("table2")
PV, PC, PT = -0.05, 0.19, 0.22
H = 1e-30   # complex step
STATES = [(2.0, 5.0), (-2.0, 5.0), (0.7, -3.0), (-1e-3, -0.1), (0.0, 0.1), (0.0, -0.2),
          (0.0, 1.0), (0.0, -1.0), (0.0, 0.0)]


def _cs(f, x):
    """Complex-step derivative of f at x."""
    return f(complex(x, H)).imag / H


@pytest.mark.parametrize("qd, T", STATES)
def test_complex_path_equals_float_path(qd, T):
    fz = friction_torque(complex(qd), complex(T), PV, PC, PT)
    assert fz.real == friction_torque(qd, T, PV, PC, PT) and fz.imag == 0.0
    assert net_torque(complex(qd), complex(T), PV, PC, PT).real == net_torque(qd, T, PV, PC, PT)
    assert net_torque(qd, T, PV, PC, PT) == pytest.approx(T - friction_torque(qd, T, PV, PC, PT),
                                                          abs=1e-15)


@pytest.mark.parametrize("qd, T", [s for s in STATES if s[0] != 0.0])
def test_complex_step_partials_sliding(qd, T):
    """Sliding: ∂T_p/∂pv = q̇, ∂/∂pc = s, ∂/∂pt = s·|T|, ∂/∂T = s·pt·sign(T), ∂/∂q̇ = pv."""
    s = math.copysign(1.0, qd)
    assert _cs(lambda p: friction_torque(qd, T, p, PC, PT), PV) == pytest.approx(qd, rel=1e-15)
    assert _cs(lambda p: friction_torque(qd, T, PV, p, PT), PC) == pytest.approx(s, rel=1e-15)
    assert _cs(lambda p: friction_torque(qd, T, PV, PC, p), PT) == pytest.approx(s * abs(T),
                                                                                  rel=1e-15)
    assert _cs(lambda x: friction_torque(qd, x, PV, PC, PT), T) == pytest.approx(
        s * PT * math.copysign(1.0, T), rel=1e-15)
    assert _cs(lambda v: friction_torque(v, T, PV, PC, PT), qd) == pytest.approx(PV, rel=1e-15)


def test_complex_step_partials_at_rest():
    """Stuck (|T| ≤ L): T_p = T, so ∂/∂T = 1 and no parameter matters; breaking away: ±L."""
    T = 0.1
    assert _cs(lambda x: friction_torque(0.0, x, PV, PC, PT), T) == 1.0
    assert _cs(lambda p: friction_torque(0.0, T, PV, p, PT), PC) == 0.0
    T = -1.0
    assert _cs(lambda x: friction_torque(0.0, x, PV, PC, PT), T) == pytest.approx(PT)
    assert _cs(lambda p: friction_torque(0.0, T, PV, p, PT), PC) == -1.0
    assert _cs(lambda p: friction_torque(0.0, T, PV, PC, p), PT) == pytest.approx(-abs(T))


def test_pieces_of_the_law():
    assert sliding_level(-2.0, PC, PT) == pytest.approx(PC + PT * 2.0)
    assert sliding_friction(0.5, -1.0, 2.0, PV, PC, PT) == pytest.approx(PV * 0.5 - (PC + 2 * PT))
    L = sliding_level(0.25, PC, PT)
    assert exceeds_stiction(0.25, L) == breaks_away(0.25, PC, PT) == (breakaway_excess(0.25, L) > 0)
    assert not exceeds_stiction(-0.24, sliding_level(-0.24, PC, PT))
    assert stiction_margin(0.1, L, 1.0) == pytest.approx(L - 0.1)
    assert stiction_margin(complex(0.1, H), L, -1.0).imag == pytest.approx(H)


def test_array_forms_equal_scalar_forms():
    qd = np.array([s[0] for s in STATES])
    T = np.array([s[1] for s in STATES])
    fa = friction_torque_array(qd, T, PV, PC, PT)
    na = net_torque_array(qd, T, PV, PC, PT)
    la = sliding_level_array(T, PC, PT)
    for i, (v, t) in enumerate(STATES):
        assert fa[i] == friction_torque(v, t, PV, PC, PT)
        assert na[i] == net_torque(v, t, PV, PC, PT)
        assert la[i] == sliding_level(t, PC, PT)
    assert np.array_equal(net_torque_array(qd, 0.3, PV, PC, PT),      # broadcasting a scalar
                          [net_torque(v, 0.3, PV, PC, PT) for v in qd])


@pytest.mark.parametrize("T", [2.5, -1.5, 0.0])
def test_series_form_matches_complex_step(T):
    """sliding_level_series on Taylor rows: the value and every derivative (pc, pt, the step
    current through T = c·I, and the mixed pt·I term) equal complex-step derivatives of
    sliding_level (at T = 0, where |T| has no derivative, the series takes 0 for ∂/∂I)."""
    n, j, c = 3, 1, 1.44
    W = np.zeros((5, row_len(n)))
    TT, PCR, PTR, ABS, OUT = range(5)
    row_const(W, TT, T)
    W[TT, 4 + j] = c
    row_const(W, PCR, PC)
    W[PCR, 2] = 1.0
    row_const(W, PTR, PT)
    W[PTR, 3] = 1.0
    sliding_level_series(W, OUT, TT, PCR, PTR, ABS, n)
    assert W[OUT, 0] == sliding_level(T, PC, PT)
    assert W[OUT, 2] == _cs(lambda p: sliding_level(T, p, PT), PC) == 1.0
    assert W[OUT, 3] == pytest.approx(_cs(lambda p: sliding_level(T, PC, p), PT), abs=1e-15)
    d_dI = W[OUT, 4 + j]
    d2_dpt_dI = W[OUT, 4 + n + 2 * n + j]
    if T == 0.0:
        assert d_dI == 0.0 and d2_dpt_dI == 0.0
        return

    def cs_dI(pt):
        return _cs(lambda i: sliding_level(c * i, PC, pt), T / c)

    assert d_dI == pytest.approx(cs_dI(PT), rel=1e-14)
    assert d2_dpt_dI == pytest.approx((cs_dI(PT + 1e-3) - cs_dI(PT - 1e-3)) / 2e-3, rel=1e-10)


def test_stop_speed_stops_the_arm_in_tau():
    """From stop_speed(τ) with zero current the exact 1-DOF model stops after exactly τ."""
    for p in (T2, T2.replace(pv=0.0), T2.replace(pv=0.08)):
        tau = 0.04
        v = stop_speed(p.J, p.pv, p.pc, tau)
        q, qd = arm1dof.advance(p, 0.0, v, 0.0, tau * (1 - 1e-9))
        assert 0.0 < qd < 1e-6 * v
        assert arm1dof.advance(p, 0.0, v, 0.0, tau * (1 + 1e-9))[1] == 0.0
    assert stop_speed(T2.J, T2.pv, T2.pc, 0.0) == 0.0 == stop_speed(T2.J, T2.pv, T2.pc, -1.0)


@pytest.mark.parametrize("v, current", [(1.5, 3.0), (-0.8, 3.0), (2.0, -6.0), (0.0, 5.0),
                                        (0.0, -5.0), (0.0, 0.1)])
def test_arm1dof_follows_the_law(v, current):
    """The exact 1-DOF simulator's acceleration over a tiny step is (T − T_p)/J (float)."""
    p = Arm1DofParams()
    T = p.n * p.kt * current
    dt = 1e-7
    _, v1 = arm1dof.advance(p, 0.0, v, current, dt)
    acc = net_torque(v, T, p.pv, p.pc, p.pt) / p.J
    assert (v1 - v) / dt == pytest.approx(acc, rel=1e-6, abs=1e-9)
    if v == 0.0 and not breaks_away(T, p.pc, p.pt):
        assert v1 == 0.0


def test_scara2_follows_the_law():
    """The 2-DOF integrator (complex arithmetic) accelerates as the reference dynamics, whose
    friction is friction_torque (both joints sliding)."""
    p = Scara2Params()
    q, qd, cur = np.array([0.3, -0.2]), np.array([0.6, -0.9]), np.array([4.0, -2.0])
    dt = 1e-6
    _, qd1 = scara2.advance(p, q, qd, cur, dt)
    assert (qd1 - qd) / dt == pytest.approx(scara2.forward_dynamics(p, q, qd, cur), rel=1e-5)
