"""2-DOF box certificate: present on SCARA plans, and honest against fresh samples of the box."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanRequest
from ff_planner.optimize.certificate2d import certify_scara2
from ff_planner.optimize.planner import plan
from ff_planner.optimize.sample_box import box_fractions, box_uniform

P = Scara2Params()
FRESH_SEED = 424_242          # not the certificate's own seed
NAMES = list(scara2.FRICTION_NAMES)


def _fresh_errors(p: Scara2Params, profile: CurrentProfile, q0, qf, scales: np.ndarray,
                  keys) -> np.ndarray:
    """|rest − qf| (S, 2) at the default 1 ms substep, independently of the certificate."""
    out = np.empty((scales.shape[0], 2))
    for i, s in enumerate(scales):
        pp = p.replace(**{k: getattr(p, k) * float(f) for k, f in zip(keys, s)})
        out[i] = np.abs(scara2.rest_position_scara2(pp, profile, q0) - np.asarray(qf))
    return out


@pytest.fixture(scope="module")
def held():
    """The section 4.2 task (link 2 held) through the facade, all six parameters uncertain."""
    req = PlanRequest(objective="robust-derivative",
                      model="scara2", q0=(-0.5, 0.0), qf=(0.5, 0.0), tf=1.0, uncertain=NAMES,
                      starts=32, seed=0, time_budget=60)
    return req, plan(req)


@pytest.fixture(scope="module")
def both_moving():
    """A profile that moves both links (not planned: its goal is its nominal rest position)."""
    q0 = np.array([0.0, 0.0])
    cur = np.array([[1.04, 0.30], [1.04, 0.30], [-0.61, 0.04], [-0.61, 0.04]])
    prof = CurrentProfile.uniform(cur, 1.0, 0.05)
    qf = scara2.rest_position_scara2(P, prof, q0)
    assert np.all(np.abs(qf - q0) > 0.05)
    return prof, q0, qf


def test_scara2_plans_carry_a_box_certificate(held):
    req, res = held
    assert res.success and res.robust
    c = res.certificate
    assert c is not None
    assert set(c.box) == set(NAMES) and all(v == pytest.approx(0.2) for v in c.box.values())
    assert len(c.worst_per_joint) == 2
    assert c.worst_rest_error == pytest.approx(max(c.worst_per_joint))
    assert set(c.worst_at) == set(NAMES)
    assert all(0.8 - 1e-12 <= v <= 1.2 + 1e-12 for v in c.worst_at.values())
    assert set(c.per_parameter) == set(NAMES)
    assert max(c.per_parameter.values()) <= c.worst_rest_error + 1e-12
    assert 0.0 <= c.moving_at_tf <= 1.0
    n = res.profile.n_steps
    assert len(c.switch_timing) == n and len(c.switch_timing_per_joint) == n
    assert all(len(row) == 2 for row in c.switch_timing_per_joint)
    d = c.to_dict()
    assert d["worst_per_joint"] == c.worst_per_joint
    assert len(d["switch_timing_per_joint_per_100us"]) == n


def test_worst_point_is_where_the_certificate_says(held):
    req, res = held
    c = res.certificate
    where = np.array([[c.worst_at[k] for k in NAMES]])
    e = _fresh_errors(P, res.profile, req.q0, req.qf, where, NAMES)
    assert float(e.max()) == pytest.approx(c.worst_rest_error, rel=1e-3, abs=1e-6)


@pytest.mark.parametrize("case", ["held", "both_moving"])
def test_certificate_is_honest_on_fresh_points(case, request):
    """300 fresh uniform points of the box, simulated at the default substep: none is more than
    10 % above the stated worst, overall and per joint."""
    if case == "held":
        req, res = request.getfixturevalue("held")
        prof, q0, qf, c = res.profile, req.q0, req.qf, res.certificate
    else:
        prof, q0, qf = request.getfixturevalue("both_moving")
        c = certify_scara2(P, prof, q0, qf, NAMES)
    fresh = box_uniform(box_fractions(NAMES, None), NAMES, 300, seed=FRESH_SEED)
    e = _fresh_errors(P, prof, q0, qf, fresh, NAMES)
    assert np.all(np.isfinite(e))
    assert float(e.max()) <= 1.1 * c.worst_rest_error
    for j in range(2):
        assert float(e[:, j].max()) <= 1.1 * c.worst_per_joint[j] + 1e-9


def test_per_parameter_is_honest_on_fresh_lines(both_moving):
    prof, q0, qf = both_moving
    c = certify_scara2(P, prof, q0, qf, NAMES)
    rng = np.random.default_rng(FRESH_SEED)
    for j, k in enumerate(NAMES):
        line = np.ones((12, len(NAMES)))
        line[:, j] = rng.uniform(0.8, 1.2, 12)
        e = _fresh_errors(P, prof, q0, qf, line, NAMES)
        assert float(e.max()) <= 1.1 * c.per_parameter[k] + 1e-9, k


def test_moving_fraction_matches_fresh_samples(held):
    req, res = held
    c = res.certificate
    fresh = box_uniform(c.box, NAMES, 200, seed=FRESH_SEED)
    still = []
    for s in fresh:
        pp = P.replace(**{k: getattr(P, k) * float(f) for k, f in zip(NAMES, s)})
        sim = scara2.simulate_detail(pp, res.profile, req.q0)
        still.append(sim.stuck_tf[0] and sim.stuck_tf[1])
    assert 0.0 < c.moving_at_tf < 1.0
    assert abs((1.0 - float(np.mean(still))) - c.moving_at_tf) <= 0.15


def test_own_box_and_switch_timing(both_moving):
    prof, q0, qf = both_moving
    c = certify_scara2(P, prof, q0, qf, NAMES, box={"pc1": 0.3, "pc2": 0.3})
    assert c.box["pc1"] == 0.3 and c.box["pt2"] == 0.2
    assert 0.7 - 1e-12 <= c.worst_at["pc1"] <= 1.3 + 1e-12
    # the switch with the largest effect 50 µs early moves the rest position by about minus half
    # the stated change per 100 µs delay, on both joints
    rows = np.array(c.switch_timing_per_joint)
    j = int(np.argmax(np.abs(rows).max(axis=1)))
    assert np.all(np.abs(rows[j]) > 1e-6)
    t = prof.step_times.copy()
    t[j + 1] -= 5e-5
    early = CurrentProfile(t, prof.currents, prof.tf, prof.coast)
    moved = scara2.rest_position_scara2(P, early, q0) - qf
    assert np.allclose(moved, -0.5 * rows[j], rtol=0.2, atol=1e-7)
    assert c.switch_timing[j] == pytest.approx(rows[j][int(np.argmax(np.abs(rows[j])))])
