"""robust-box objective, the robustness certificate, chosen steps/starts, box samples."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.core.errors import PlanningError
from ff_planner.model.arm1dof import batch_core
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.certificate import certify_1dof, switch_timing_1dof
from ff_planner.optimize.planner import check, plan
from ff_planner.optimize.sample_box import (
    box_check_samples,
    box_corners,
    box_fractions,
    box_samples,
)

KEYS = ("pv", "pc", "pt")


def rest_errors(result, scales: np.ndarray) -> np.ndarray:
    """|rest − qf| (rad) of a plan at friction scale factors (S, 3), exact model."""
    p, prof = result.params, result.profile
    fr = np.ascontiguousarray(scales * np.array([p.pv, p.pc, p.pt]))
    q, _ = batch_core(p.J, p.n * p.kt, fr, np.ones(len(scales), bool), prof.step_times,
                      np.ascontiguousarray(prof.currents[:, 0]), prof.tf, float(result.q0[0]))
    return np.abs(q - float(result.qf[0]))


def fresh_points(box: dict, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.ones((count, 3))
    for u, f in box.items():
        out[:, KEYS.index(u)] = rng.uniform(1 - f, 1 + f, count)
    return out


@pytest.fixture(scope="module")
def derivative_plan():
    return plan(PlanRequest(objective="robust-derivative"))


@pytest.fixture(scope="module")
def box_plan():
    return plan(PlanRequest(objective="robust-box", steps=8))


def test_box_samples_cover_corners_centre_faces():
    fr = box_fractions(["pc", "pt"], {"pt": 0.1})
    assert fr == {"pc": 0.2, "pt": 0.1}
    s = box_samples(fr, KEYS)
    assert s.shape == (4 + 1 + 4, 3)
    assert np.all(s[:, 0] == 1.0)                        # pv not uncertain: nominal
    assert {tuple(r) for r in box_corners(fr, KEYS)[:4, 1:]} == {
        (0.8, 0.9), (0.8, 1.1), (1.2, 0.9), (1.2, 1.1)}
    chk = box_check_samples(fr, KEYS)
    assert chk.shape == (9 + 64, 3)
    assert np.all(np.abs(chk[:, 2] - 1.0) <= 0.1 + 1e-12)


def test_robust_box_is_derivative_robust_and_beats_robust_derivative(box_plan, derivative_plan):
    r = box_plan
    assert r.success and r.robust and r.objective == "robust-box"
    assert r.extra["verification"]["max_abs_derivative"] <= 1e-6
    assert abs(r.q_final[0] - 1.0) <= 1e-6 and r.qd_final[0] == 0.0
    assert 0.05 - 1e-12 <= r.profile.coast <= 0.25 + 1e-12
    corners = box_corners(box_fractions(KEYS), KEYS)
    assert rest_errors(r, corners).max() <= r.extra["box_worst"] + 1e-12
    assert r.extra["box_worst"] < 0.5 * rest_errors(derivative_plan, corners).max()


def test_box_and_coast_max_are_validated():
    with pytest.raises(PlanningError, match="not uncertain") as e:
        check(PlanRequest(uncertain=("pc",), box={"pt": 0.1}))
    assert e.value.code == "INVALID_REQUEST"
    with pytest.raises(PlanningError, match=r"\(0, 1\)"):
        check(PlanRequest(box={"pc": 1.5}))
    with pytest.raises(PlanningError, match="coast_max"):
        check(PlanRequest(objective="robust-box", coast=0.1, coast_max=0.05))
    with pytest.raises(PlanningError, match="tf must be in"):
        check(PlanRequest(tf=1000.0))


@pytest.mark.parametrize("which", ["derivative_plan", "box_plan"])
def test_certificate_is_honest(which, request):
    r = request.getfixturevalue(which)
    c = r.certificate
    assert c is not None and c.box == {"pv": 0.2, "pc": 0.2, "pt": 0.2}
    fresh = rest_errors(r, fresh_points(c.box, 300, seed=4242))
    assert fresh.max() <= 1.1 * c.worst_rest_error
    at = np.array([[c.worst_at[k] for k in KEYS]])
    assert np.all(np.abs(at - 1.0) <= 0.2 + 1e-9)
    assert rest_errors(r, at)[0] == pytest.approx(c.worst_rest_error, rel=1e-9, abs=1e-12)
    assert all(0.0 <= v <= c.worst_rest_error + 1e-12 for v in c.per_parameter.values())
    assert 0.0 <= c.moving_at_tf <= 1.0
    assert len(c.switch_timing) == r.profile.n_steps


def test_certificate_box_and_switch_timing(derivative_plan):
    r = derivative_plan
    narrow = certify_1dof(r.params, r.profile, 0.0, 1.0, ["pc"], {"pc": 0.05})
    assert set(narrow.per_parameter) == {"pc"} and set(narrow.worst_at) == {"pc"}
    assert narrow.worst_rest_error == pytest.approx(narrow.per_parameter["pc"], rel=1e-6)
    # switch timing: a 100 us delay of switch j, simulated, against the stated change
    st = switch_timing_1dof(r.params, r.profile, 0.0)
    j = int(np.argmax(np.abs(st)))
    p = r.params

    def rest(times):
        q, _ = batch_core(p.J, p.n * p.kt, np.array([[p.pv, p.pc, p.pt]]), np.ones(1, bool),
                          times, np.ascontiguousarray(r.profile.currents[:, 0]), r.profile.tf, 0.0)
        return float(q[0])

    late = r.profile.step_times.copy()
    late[j + 1] += 1e-4
    assert abs(st[j]) > 1e-4
    assert rest(late) - rest(r.profile.step_times) == pytest.approx(st[j], rel=0.2)


def test_every_1dof_objective_gets_a_certificate():
    r = plan(PlanRequest(objective="energy-optimal"))
    assert r.certificate is not None and r.certificate.worst_rest_error > 0.1


def test_chosen_steps_and_starts_escalate_starts_before_steps():
    r = plan(PlanRequest(objective="robust-derivative", qf=(2.0,), steps=0, starts=0))
    assert r.success and r.robust
    tried = r.extra["auto"]["tried"]
    assert [(t["steps"], t["starts"]) for t in tried[:4]] == [(5, 50), (5, 200), (5, 1000),
                                                               (6, 50)]
    assert tried[-1]["robust"] and not any(t["robust"] for t in tried[:-1])
    assert r.profile.n_steps == tried[-1]["steps"] == r.extra["auto"]["steps_chosen"]
    assert r.starts_tried == sum(t["starts_tried"] for t in tried)


def test_chosen_starts_elsewhere_fall_back_to_the_default():
    r = plan(PlanRequest(objective="time-optimal", starts=0))
    assert r.success and "auto" not in r.extra
