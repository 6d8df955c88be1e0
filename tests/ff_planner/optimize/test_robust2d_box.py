"""robust-box on the SCARA arm: link 2 held, worst rest error over the box below the derivative plan's."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.planner import plan
from ff_planner.optimize.robust2d_box import BOX2_DEFAULT_STEPS

P = Scara2Params()
TASK = dict(model="scara2", q0=(-0.5, 0.0), qf=(0.5, 0.0), tf=1.0,
            uncertain=scara2.FRICTION_NAMES, seed=0, time_budget=60)


@pytest.fixture(scope="module")
def pair():
    return (plan(PlanRequest(**TASK, objective="robust-derivative")),
            plan(PlanRequest(**TASK, objective="robust-box")))


def test_box_plan_stays_truly_robust(pair):
    _, box = pair
    assert box.success and box.robust and box.error_code == "OK" and not box.best_effort
    assert box.objective == "robust-box" and box.extra["method"] == "hold-link2-box"
    assert box.profile.currents.shape == (BOX2_DEFAULT_STEPS, 2)
    assert np.all(np.abs(box.profile.currents) <= 10.0 + 1e-12)
    fd = scara2.sensitivities_scara2(P, box.profile, TASK["q0"], method="central",
                                     rel_step=1e-6)
    assert max(abs(v) for k, v in fd.items() if not k.startswith("qd")) <= 1e-6
    sim = scara2.simulate_detail(P, box.profile, TASK["q0"], settle=True)
    assert all(sim.stuck_tf)
    assert np.max(np.abs(sim.q_f - np.array(TASK["qf"]))) <= 1e-6
    assert box.extra["hold_fraction"] > 0.0


def test_box_plan_lands_closer_over_the_box(pair):
    """The 2-DOF certificate (all six parameters ±20 %): the minimax plan's worst rest error is
    well below the derivative-robust plan's, and its joint-1 worst on the planner's own samples is
    what the certificate finds."""
    deriv, box = pair
    assert box.certificate is not None and deriv.certificate is not None
    assert box.certificate.worst_rest_error <= 0.6 * deriv.certificate.worst_rest_error
    assert box.extra["box_worst_joint1"] < box.extra["derivative_start_box_worst_joint1"]
    assert box.certificate.worst_per_joint[0] >= 0.99 * box.extra["box_worst_joint1"]


def test_link2_moving_box_request_is_labelled():
    req = PlanRequest(model="scara2", q0=(0.0, 0.0), qf=(0.3, 0.3), tf=1.0,
                      uncertain=("pc1", "pc2"), steps=4, starts=1, seed=0, time_budget=1.0,
                      objective="robust-box")
    res = plan(req)
    assert res.objective == "robust-box" and res.extra["box_minimax"] is False
    assert not res.success and res.error_code in ("NO_ROBUST_PLAN", "TIME_BUDGET_EXHAUSTED")
    if res.profile is not None:
        assert res.best_effort and "NOT derivative-robust" in res.message
        assert res.certificate is not None and set(res.certificate.box) == {"pc1", "pc2"}
