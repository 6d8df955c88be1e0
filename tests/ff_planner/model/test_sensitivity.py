"""Exact 1-DOF derivatives (forward mode through the events) against finite differences."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ff_planner.model.arm1dof import derivatives, final_state
from ff_planner.model.params import ParameterError, preset
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.sensitivity import sensitivities

T2 = preset("table2")
T1 = preset("table1")
CASES = [
    [-3.0, 2.0, 1.0, 6.0, -4.0],
    [4.0, -6.0, 1.5],
    [-2.0, 5.0, -7.0, 3.0, 0.4, -1.0, 2.5],
]


def _central(fun, x, h):
    return (fun(x + h) - fun(x - h)) / (2 * h)


@pytest.mark.parametrize("currents", CASES)
@pytest.mark.parametrize("to_rest", [False, True])
def test_exact_matches_central_differences_in_p(currents, to_rest):
    prof = CurrentProfile.uniform(currents, 1.0)
    d = derivatives(T2, prof, 0.0, to_rest=to_rest)
    assert d.smooth
    for k in ("pv", "pc", "pt"):
        p0 = getattr(T2, k)

        def q_of(x, k=k):
            return np.array(final_state(T2.replace(**{k: x}), prof, 0.0, to_rest=to_rest))

        fd = _central(q_of, p0, 1e-6 * abs(p0))
        scale = max(1.0, abs(d.dq_dp[k]))
        assert abs(fd[0] - d.dq_dp[k]) <= 1e-6 * scale, k
        if not to_rest:
            assert abs(fd[1] - d.dqd_dp[k]) <= 1e-6 * max(1.0, abs(d.dqd_dp[k])), k


@pytest.mark.parametrize("currents", CASES[:2])
def test_exact_current_and_mixed_derivatives(currents):
    prof = CurrentProfile.uniform(currents, 1.0)
    d = derivatives(T2, prof, 0.0, to_rest=True)
    I = np.array(currents, float)
    for j in range(I.size):
        def dq(x, j=j):
            Ij = I.copy()
            Ij[j] = x
            dj = derivatives(T2, CurrentProfile.uniform(Ij, 1.0), 0.0, to_rest=True)
            return np.array([dj.q, dj.dq_dp["pv"], dj.dq_dp["pc"], dj.dq_dp["pt"]])

        fd = _central(dq, I[j], 1e-6)
        assert fd[0] == pytest.approx(d.dq_dI[j], rel=1e-6, abs=1e-8)
        assert np.allclose(fd[1:], d.d2q_dpdI[:, j], rtol=1e-6, atol=1e-7)


def test_coulomb_only_arm_pv_zero():
    """pv = 0 (table 1) goes through the series branch of the closed form."""
    prof = CurrentProfile.uniform([3.0, -4.0, 1.0], 1.0)
    d = derivatives(T1, prof, 0.0)
    fd = _central(lambda x: np.array(final_state(T1.replace(pc=x), prof, 0.0)), T1.pc, 1e-7)
    assert d.dq_dp["pc"] == pytest.approx(fd[0], rel=1e-6)
    # pv is a valid direction even at pv = 0
    fdv = _central(lambda x: np.array(final_state(T1.replace(pv=x), prof, 0.0)), 0.0, 1e-7)
    assert d.dq_dp["pv"] == pytest.approx(fdv[0], rel=1e-6)


def test_values_agree_with_plain_simulator():
    for c in CASES:
        prof = CurrentProfile.uniform(c, 1.0)
        for to_rest in (False, True):
            d = derivatives(T2, prof, 0.2, to_rest=to_rest)
            q, v = final_state(T2, prof, 0.2, to_rest=to_rest)
            assert abs(d.q - q) < 1e-12 and abs(d.qd - v) < 1e-12


def test_kink_detected_at_breakaway_edge():
    """A step current just above breakaway: derivatives are one-sided there."""
    i_break = T2.pc / (1 - T2.pt) / (T2.n * T2.kt)
    prof = CurrentProfile.uniform([i_break * (1 + 1e-7), 3.0, -3.0], 1.0)
    d = derivatives(T2, prof, 0.0)
    assert not d.smooth and d.kink_radius < 1e-6


def test_kink_detected_when_stop_is_at_a_switch():
    # find currents whose first stop lands ~1 us before the second switch
    from scipy.optimize import brentq

    def stop_time(x):
        prof = CurrentProfile.uniform([4.0, -x, 0.1], 1.0)
        from ff_planner.model.simulate import simulate
        ev = [t for t, k in simulate(T2, prof, [0.0]).events if k in ("stick", "reverse")]
        return (ev[0] if ev else 1.0) - prof.step_times[2]

    x = brentq(lambda x: stop_time(x) + 1e-6, 2.0, 3.0)
    d = derivatives(T2, CurrentProfile.uniform([4.0, -x, 0.1], 1.0), 0.0)
    assert d.kink_radius < 1e-3 and not d.smooth


def test_api_methods_agree_and_forward_is_the_paper_quotient():
    prof = CurrentProfile.uniform(CASES[0], 1.0)
    ex = sensitivities(T2, prof, [0.0], method="exact", rest=True)
    ce = sensitivities(T2, prof, [0.0], method="central", rest=True)
    fw = sensitivities(T2, prof, [0.0], method="forward")
    for k in ("pv", "pc", "pt", "qd/pc", "qrest/pt"):
        assert ex[k] == pytest.approx(ce[k], rel=1e-5, abs=1e-8)
    for k in ("pv", "pc", "pt"):   # the 0.1 % secant differs from the tangent by curvature only
        assert abs(fw[k] - ex[k]) <= 1e-3 + 1e-2 * abs(ex[k])
    with pytest.raises(ParameterError, match="unknown friction"):
        sensitivities(T2, prof, [0.0], names=["mu"])
    with pytest.raises(ParameterError, match="method"):
        sensitivities(T2, prof, [0.0], method="magic")


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-8, 8), min_size=2, max_size=6), st.sampled_from(["pv", "pc", "pt"]))
def test_exact_derivative_property(currents, name):
    """Wherever the plan is not near a kink, exact == central differences (both sides agree)."""
    prof = CurrentProfile.uniform(currents, 1.0)
    d = derivatives(T2, prof, 0.0, to_rest=True)
    if not d.smooth or not np.isfinite(d.q):
        return
    p0 = getattr(T2, name)
    h = 1e-7 * abs(p0)
    qp = final_state(T2.replace(**{name: p0 + h}), prof, 0.0, to_rest=True)[0]
    qm = final_state(T2.replace(**{name: p0 - h}), prof, 0.0, to_rest=True)[0]
    q0 = d.q
    fwd, bwd = (qp - q0) / h, (q0 - qm) / h
    tol = 1e-4 * max(1.0, abs(d.dq_dp[name]))
    assert abs(fwd - d.dq_dp[name]) <= tol and abs(bwd - d.dq_dp[name]) <= tol
