"""SCARA plans under per-joint limits: robust-box holds joint 1's range in its search; the
certificate's excursion (both joints, six friction parameters) is checked and a plan that leaves
the limits is labelled, never answered OK (rad, rad/s)."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model import scara2
from ff_planner.model.limits import MotionLimits
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.certificate2d import CERT_H
from ff_planner.optimize.planner import plan
from ff_planner.optimize.limits2d import LIMITS_MARGIN2
from ff_planner.optimize.sample_box import box_corners, box_fractions, box_uniform

P = Scara2Params()
NAMES = list(scara2.FRICTION_NAMES)
# section 4.2 task reversed: without limits the robust-box plan swings joint 1 out to ~1.44 rad
TASK = dict(model="scara2", q0=(0.5, 0.0), qf=(-0.5, 0.0), tf=1.0, uncertain=NAMES, seed=0,
            time_budget=60)
Q1_MAX = 1.3


def _track(prof, scale: np.ndarray) -> scara2.Scara2Track:
    pp = P.replace(**{k: getattr(P, k) * float(s) for k, s in zip(NAMES, scale)})
    return scara2.track_scara2(pp, prof, TASK["q0"], h=CERT_H)


@pytest.fixture(scope="module")
def limited():
    req = PlanRequest(**TASK, objective="robust-box",
                      limits=MotionLimits.of(position_max=(Q1_MAX, 1.0)))
    return plan(req)


def test_box_plan_keeps_joint1_below_its_limit(limited):
    r = limited
    assert r.success and r.error_code == "OK" and not r.best_effort
    assert r.extra["method"] == "hold-link2-box" and r.extra["limits_joint1_excess"] == 0.0
    assert "limit_violations" not in r.extra and r.extra["limits_checked"] is True
    ex = r.certificate.excursion
    assert ex is not None and ex.worst_max[0] <= Q1_MAX and ex.worst_max[1] <= 1.0
    # the limit binds (without it this task's plan reaches ~1.44 rad): the minimax holds joint 1
    # on its bound less the margin
    assert ex.worst_max[0] >= Q1_MAX - 10 * LIMITS_MARGIN2
    assert ex.violations(MotionLimits.of(position_max=(Q1_MAX, 1.0))) == []
    sim = scara2.simulate_detail(P, r.profile, TASK["q0"], settle=True)
    assert all(sim.stuck_tf) and np.max(np.abs(sim.q_f - np.array(TASK["qf"]))) <= 1e-6


def test_excursion_within_limit_at_box_points_resimulated(limited):
    """At the box corners (the certificate's points) and at fresh uniform points of the whole
    six-parameter box, re-simulated: joint 1 never above Q1_MAX, never above the certificate's
    worst; every point comes to rest."""
    r = limited
    fr = box_fractions(NAMES, None)
    pts = np.vstack([box_corners(fr, NAMES), box_uniform(fr, NAMES, 12, seed=2024)])
    worst = r.certificate.excursion.worst_max[0]
    for s in pts:
        tr = _track(r.profile, s)
        assert tr.q_rest is not None
        assert tr.q_max[0] <= Q1_MAX
        assert tr.q_max[0] <= worst + 1e-9


def test_scara_derivative_plan_within_limits_skips_plans_outside():
    """robust-derivative goes past robust plans that leave joint 1's range; its answer keeps
    within it at the certificate's points (without the limit: ~1.12 rad)."""
    req = PlanRequest(**TASK, objective="robust-derivative",
                      limits=MotionLimits.of(position_max=(1.1, 1.0)))
    r = plan(req)
    assert r.success and r.error_code == "OK" and r.extra["limits_joint1_excess"] == 0.0
    assert r.certificate.excursion.worst_max[0] <= 1.1
    for s in box_uniform(box_fractions(NAMES, None), NAMES, 6, seed=7):
        assert _track(r.profile, s).q_max[0] <= 1.1


def test_scara_plan_leaving_limits_is_labelled():
    """No robust plan of the search keeps joint 1 below 0.6 rad (the goal is 0.5 rad; plans
    overshoot to ~0.8 rad over the box): the best comes back labelled, not OK."""
    req = PlanRequest(model="scara2", q0=(-0.5, 0.0), qf=(0.5, 0.0), tf=1.0, uncertain=NAMES,
                      seed=0, time_budget=60, objective="robust-derivative",
                      limits=MotionLimits.of(position_max=(0.6, 1.0)))
    r = plan(req)
    assert not r.success and r.error_code == "NO_ROBUST_PLAN" and r.best_effort
    assert r.extra["limit_violations"] and "joint 1" in r.extra["limit_violations"][0]
    assert r.certificate.excursion.worst_max[0] > 0.6
    assert "leaves the limits" in r.message
