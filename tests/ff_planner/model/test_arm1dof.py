"""The exact 1-DOF simulator against closed forms, an independent fine-step integrator, itself."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ff_planner.core.results import SimResult
from ff_planner.model.arm1dof import advance, final_state
from ff_planner.model.friction import breaks_away, friction_torque
from ff_planner.model.params import preset
from ff_planner.model.profile import CurrentProfile, PlanningError
from ff_planner.model.simulate import rest_position, simulate

T2 = preset("table2")
T1 = preset("table1")
ROBUST = [-3.70, 2.27, 0.58, 6.94, -4.76]


def reference(params, currents, tf, coast, dt=2e-6):
    """Independent fine-step integration of Eq. 22 + Eq. 9 (Heun steps aligned with the switches,
    stop and stick/break away at a velocity sign change), using ff_planner.model.friction directly."""
    prof = CurrentProfile.uniform(currents, tf, coast)
    c = params.n * params.kt
    phases = [(prof.step_times[i + 1] - prof.step_times[i], c * I) for i, I in enumerate(currents)]
    phases.append((coast, 0.0))
    q = v = 0.0

    def acc(v, T):
        return (T - friction_torque(v, T, params.pv, params.pc, params.pt)) / params.J

    for length, T in phases:
        n = int(math.ceil(length / dt))
        h = length / n
        for _ in range(n):
            if v == 0.0:
                if not breaks_away(T, params.pc, params.pt):
                    continue
                s = math.copysign(1.0, T)
                a0 = (T - s * (params.pc + params.pt * abs(T))) / params.J
            else:
                a0 = acc(v, T)
            v1 = v + a0 * h
            if v != 0.0 and v1 * v < 0.0:       # crosses zero inside the step: stop there
                frac = v / (v - v1)
                q += 0.5 * v * frac * h
                v = 0.0
                continue
            a1 = acc(v1, T) if v1 != 0.0 else a0
            v_new = v + 0.5 * (a0 + a1) * h
            q += 0.5 * (v + v_new) * h
            v = v_new
    return q, v


def test_constant_current_closed_form_coulomb_only():
    # table 1 (pv = 0): constant acceleration b = (T - pc)/J from rest
    I, t = 2.0, 0.3
    q, v = advance(T1, 0.0, 0.0, I, t)
    b = (T1.n * T1.kt * I - T1.pc) / T1.J
    assert q == pytest.approx(0.5 * b * t * t, rel=1e-14)
    assert v == pytest.approx(b * t, rel=1e-14)


def test_constant_current_closed_form_viscous():
    I, t = 3.0, 0.7
    T = T2.n * T2.kt * I
    a, b = -T2.pv / T2.J, (T - T2.pc - T2.pt * T) / T2.J
    q, v = advance(T2, 0.1, 0.0, I, t)
    assert v == pytest.approx(b * math.expm1(a * t) / a, rel=1e-13)
    assert q == pytest.approx(0.1 + b * (math.expm1(a * t) - a * t) / a ** 2, rel=1e-12)


def test_sticks_below_breakaway_and_moves_above():
    i_break = T2.pc / (1 - T2.pt) / (T2.n * T2.kt)
    assert advance(T2, 0.2, 0.0, 0.99 * i_break, 1.0) == (0.2, 0.0)
    q, v = advance(T2, 0.2, 0.0, 1.01 * i_break, 1.0)
    assert q > 0.2 and v > 0.0
    q, v = advance(T2, 0.0, 0.0, -1.01 * i_break, 1.0)
    assert q < 0.0 and v < 0.0


def test_stops_and_sticks_under_zero_current():
    q, v = advance(T2, 0.0, 0.5, 0.0, 1.0)
    a = -T2.pv / T2.J
    b = -T2.pc / T2.J
    t_stop = -math.log1p(a * 0.5 / b) / a
    assert t_stop < 1.0 and v == 0.0
    assert q == pytest.approx(0.5 * math.expm1(a * t_stop) / a
                              + b * (math.expm1(a * t_stop) - a * t_stop) / a ** 2, rel=1e-12)


@pytest.mark.parametrize("currents", [ROBUST, [4.0, -6.0, 1.5], [0.5, -0.1, 0.3, 9.0, -9.5]])
def test_matches_independent_fine_step_integration(currents):
    prof = CurrentProfile.uniform(currents, 1.0)
    r = simulate(T2, prof, [0.0])
    q_ref, v_ref = reference(T2, currents, 1.0, 0.05, dt=1e-5)
    assert r.q_f[0] == pytest.approx(q_ref, abs=3e-4)
    assert r.qd_f[0] == pytest.approx(v_ref, abs=2e-3)


def test_robust_plan_arrives_near_goal_at_rest():
    prof = CurrentProfile.uniform(ROBUST, 1.0)
    r = simulate(T2, prof, [0.0])
    assert abs(r.q_f[0] - 1.0) < 5e-3 and r.qd_f[0] == 0.0
    kinds = [k for _, k in r.events]
    assert kinds[0] == "breakaway" and kinds[-1] == "stick" and "reverse" in kinds


def test_trajectory_consistent_with_final_state_and_events():
    prof = CurrentProfile.uniform([4.0, -6.0, 1.5], 1.0)
    r = simulate(T2, prof, [0.3], trajectory=True, dt=1e-3)
    assert isinstance(r, SimResult)
    assert r.t[0] == 0.0 and r.t[-1] == pytest.approx(1.0)
    assert r.q.shape == (r.t.size, 1) and r.current.shape == (r.t.size, 1)
    assert r.q[-1, 0] == pytest.approx(r.q_f[0], abs=1e-12)
    assert r.q[0, 0] == 0.3
    # velocity is the derivative of position along the samples
    mid = slice(100, 200)
    dq = np.gradient(r.q[:, 0], r.t)[mid]
    assert np.allclose(dq, r.qd[mid, 0], atol=5e-3)
    # sampled beyond tf: the arm ends at its rest position
    r2 = simulate(T2, prof, [0.3], trajectory=True, t_end=10.0)
    assert r2.q[-1, 0] == pytest.approx(rest_position(T2, prof, [0.3])[0], abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=1, max_size=6), st.floats(0.01, 0.99))
def test_splitting_an_interval_changes_nothing(currents, frac):
    """advance() over pieces == one simulation (the drive emulator relies on this)."""
    prof = CurrentProfile.uniform(currents, 1.0)
    q_ref, v_ref = final_state(T2, prof, 0.0)
    q, v = 0.0, 0.0
    times = prof.step_times
    for i, I in enumerate(currents):
        dt = times[i + 1] - times[i]
        q, v = advance(T2, q, v, I, frac * dt)
        q, v = advance(T2, q, v, I, (1 - frac) * dt)
    q, v = advance(T2, q, v, 0.0, 1.0 - times[-1])
    assert q == pytest.approx(q_ref, abs=1e-9)
    assert v == pytest.approx(v_ref, abs=1e-8)


def test_rest_position_and_runaway():
    prof = CurrentProfile.uniform([1.0, 0.0], 1.0, 0.05)   # still moving at tf
    r = simulate(T2, prof, [0.0])
    assert r.qd_f[0] > 0.5
    rest = rest_position(T2, prof, [0.0])[0]
    assert rest > r.q_f[0]
    # strong negative viscous friction: never stops
    runaway = T2.replace(pv=-5.0)
    assert math.isnan(rest_position(runaway, prof, [0.0])[0])


def test_bad_input_is_a_clear_error():
    prof = CurrentProfile.uniform([1.0, 2.0], 1.0)
    with pytest.raises(ValueError, match="q0"):
        simulate(T2, prof, [float("nan")])
    with pytest.raises(ValueError, match="q0 needs 1"):
        simulate(T2, prof, [0.0, 1.0])
    with pytest.raises(ValueError, match="dt"):
        advance(T2, 0.0, 0.0, 1.0, -0.1)
    bad = CurrentProfile(np.array([0.0, 0.5, 0.4]), np.array([1.0, 2.0]), 1.0)
    with pytest.raises(PlanningError):
        simulate(T2, bad, [0.0])
