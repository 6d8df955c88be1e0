"""Current quantisation: the profile as the drive applies it, and what is computed for it."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.core.errors import PlanningError
from ff_planner.model.profile import CurrentProfile, PlanRequest
from ff_planner.model.simulate import rest_position
from ff_planner.optimize.certificate import certify_1dof
from ff_planner.optimize.planner import apply_current_quantum, check, plan
from ff_planner.optimize.quantize import quantize_profile

from .test_box_robust import fresh_points, rest_errors

Q = 0.003       # A, an EPOS4 with a 3 A nominal current: setpoints in per mille


def on_quantum(currents: np.ndarray, q: float) -> bool:
    return bool(np.allclose(currents / q, np.round(currents / q), rtol=0.0, atol=1e-9))


def test_quantize_profile_rounds_and_stays_inside_the_limit():
    prof = CurrentProfile.uniform([[1.0004], [-0.0016], [9.9995]], 1.0, 0.05)
    out = quantize_profile(prof, Q, [10.0])
    assert on_quantum(out.currents, Q)
    assert out.currents[:, 0] == pytest.approx([0.999, -0.003, 9.999], abs=1e-12)
    assert np.all(np.abs(out.currents) <= 10.0)
    np.testing.assert_array_equal(out.step_times, prof.step_times)
    with pytest.raises(ValueError, match="quantum"):
        quantize_profile(prof, 0.0)


@pytest.fixture(scope="module")
def pair():
    req = PlanRequest(objective="robust-derivative", starts=200)
    return plan(req), plan(PlanRequest(objective="robust-derivative", starts=200, current_quantum=Q))


def test_plan_is_rounded_and_its_rest_and_certificate_are_the_rounded_profiles(pair):
    exact, rounded = pair
    assert not on_quantum(exact.profile.currents, Q) and on_quantum(rounded.profile.currents, Q)
    assert np.max(np.abs(rounded.profile.currents - exact.profile.currents)) <= Q / 2 + 1e-12
    info = rounded.extra["current_quantum"]
    assert info["quantum"] == Q and 0.0 < info["max_change_A"] <= Q / 2 + 1e-12
    rest = rest_position(rounded.params, rounded.profile, [0.0])[0]
    assert rounded.extra["rest_position"] == [pytest.approx(rest, abs=1e-12)]
    assert info["rest_shift_rad"][0] == pytest.approx(
        rest - rest_position(exact.params, exact.profile, [0.0])[0], abs=1e-12)
    # the rounding moves the rest position (a per-mille current step is not nothing) ...
    assert abs(info["rest_shift_rad"][0]) > 1e-7
    # ... and leaves derivatives that are no longer zero to 1e-6, which the answer says
    assert info["max_abs_derivative"] > exact.extra["verification"]["max_abs_derivative"]
    want = certify_1dof(rounded.params, rounded.profile, 0.0, 1.0, ["pv", "pc", "pt"])
    assert rounded.certificate is not None
    assert rounded.certificate.worst_rest_error == pytest.approx(want.worst_rest_error, rel=1e-12)
    fresh = rest_errors(rounded, fresh_points(rounded.certificate.box, 300, seed=99))
    assert fresh.max() <= 1.1 * rounded.certificate.worst_rest_error


def test_a_plan_from_elsewhere_is_rounded_once(pair):
    exact, _ = pair
    checked = check(PlanRequest(objective="robust-derivative", current_quantum=Q))
    r = apply_current_quantum(exact, checked)
    assert on_quantum(r.profile.currents, Q) and r.certificate is not None
    cert = r.certificate
    assert apply_current_quantum(r, checked).certificate is cert      # already on the grid


def test_bad_quantum_is_refused():
    with pytest.raises(PlanningError, match="current_quantum"):
        check(PlanRequest(current_quantum=-0.001))
    with pytest.raises(PlanningError, match="current_quantum"):
        check(PlanRequest(current_quantum=float("nan")))
