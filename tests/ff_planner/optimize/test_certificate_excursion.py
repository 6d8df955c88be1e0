"""The 1-DOF certificate's excursion against dense simulation at box points (rad, rad/s)."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model.arm1dof import simulate_arm1dof
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.certificate import certify_1dof
from ff_planner.optimize.robust1d import plan_robust_1dof
from ff_planner.optimize.sample_box import box_corners


def _dense(params, profile, scale):
    """(min q, max q, peak |v|) of the simulator's dense trajectory (0.1 ms) until rest."""
    p = params.replace(pv=params.pv * scale[0], pc=params.pc * scale[1], pt=params.pt * scale[2])
    sim = simulate_arm1dof(p, profile, 0.0, trajectory=True, dt=1e-4, t_end=4.0)
    assert sim.qd[-1, 0] == 0.0        # at rest within the recorded horizon
    return float(sim.q.min()), float(sim.q.max()), float(np.abs(sim.qd).max())


@pytest.fixture(scope="module", params=[0, 3])
def plan(request):
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", seed=request.param,
                                     starts=5000))
    assert r.success
    return r


def test_certificate_excursion_matches_dense_simulation(plan):
    c = certify_1dof(plan.params, plan.profile, 0.0, 1.0, ["pv", "pc", "pt"])
    ex = c.excursion
    assert ex is not None
    lo, hi, sp = _dense(plan.params, plan.profile, np.ones(3))
    assert ex.nominal_min[0] == pytest.approx(lo, abs=1e-6)
    assert ex.nominal_max[0] == pytest.approx(hi, abs=1e-6)
    assert ex.nominal_speed[0] == pytest.approx(sp, abs=1e-6)
    dense = [_dense(plan.params, plan.profile, s)
             for s in box_corners({"pv": 0.2, "pc": 0.2, "pt": 0.2}, ("pv", "pc", "pt"))]
    # the corners are certificate points: the worst covers each of them and equals their extreme
    # where a corner holds it
    assert ex.worst_min[0] <= min(d[0] for d in dense) + 1e-9
    assert ex.worst_max[0] >= max(d[1] for d in dense) - 1e-9
    assert ex.worst_speed[0] >= max(d[2] for d in dense) - 1e-9
    assert ex.worst_min[0] <= ex.nominal_min[0] and ex.worst_max[0] >= ex.nominal_max[0]
    # fresh points of the box stay within the stated worst (5 % of the swing as sampling slack)
    span = ex.worst_max[0] - ex.worst_min[0]
    rng = np.random.default_rng(11)
    for s in rng.uniform(0.8, 1.2, (20, 3)):
        d = _dense(plan.params, plan.profile, s)
        assert d[0] >= ex.worst_min[0] - 0.05 * span
        assert d[1] <= ex.worst_max[0] + 0.05 * span
        assert d[2] <= 1.05 * ex.worst_speed[0]


def test_certificate_reports_limit_violations(plan):
    from ff_planner.model.limits import MotionLimits

    ex = certify_1dof(plan.params, plan.profile, 0.0, 1.0, ["pv", "pc", "pt"]).excursion
    assert ex is not None
    assert ex.violations(MotionLimits.of([ex.worst_min[0] - 1e-3], [ex.worst_max[0] + 1e-3],
                                         [ex.worst_speed[0] + 1e-3])) == []
    bad = ex.violations(MotionLimits.of([ex.nominal_min[0] + 0.01], None,
                                        [ex.nominal_speed[0] - 0.01]))
    assert len(bad) == 2 and "position_min" in bad[0] and "velocity_max" in bad[1]
    d = certify_1dof(plan.params, plan.profile, 0.0, 1.0, ["pv", "pc", "pt"]).to_dict()
    assert d["excursion"]["worst_min"] == [ex.worst_min[0]]
