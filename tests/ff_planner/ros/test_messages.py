"""The planner node's message plumbing (no processes): request fields in, certificate, predicted
rest and feedback out, the switch_grid parameter's descriptor."""
from __future__ import annotations

import math

import numpy as np

from ff_msgs.action import PlanMotion
from ff_msgs.srv import PlanTrajectory
from ff_planner.model.profile import CurrentProfile, PlanResult, RobustnessCertificate
from ff_planner.ros.messages import certificate_msg, feedback_from_progress, fields_from_msg, fill_response
from ff_planner.ros.planner_node import descriptor

CERT = RobustnessCertificate(box={"pv": 0.2, "pc": 0.3}, worst_rest_error=2e-3, worst_at={"pv": 0.8, "pc": 1.3},
                             per_parameter={"pv": 4e-4, "pc": 1.5e-3}, moving_at_tf=0.1,
                             switch_timing=[1e-4, -3e-4, 2e-4], samples=321)


def _result(**kw) -> PlanResult:
    prof = CurrentProfile.uniform([[1.0], [-1.0], [0.5]], 1.0)
    return PlanResult(success=True, message="ok", profile=prof, model="arm1dof", params=None,
                      q0=np.zeros(1), qf=np.ones(1), uncertain=["pv", "pc"], objective="robust-box", **kw)


def test_goal_and_request_give_the_same_fields():
    common = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pc"], box_names=["pc"],
                  box_fractions=[0.3], coast_max=0.2, switch_grid=-1.0, starts=7, seed=3)
    a = fields_from_msg(PlanTrajectory.Request(**common))
    b = fields_from_msg(PlanMotion.Goal(**common))
    assert a == b
    assert (list(a.box_names), list(a.box_fractions), a.coast_max, a.switch_grid) == (["pc"], [0.3], 0.2, -1.0)


def test_certificate_and_predicted_rest_reach_the_response_and_the_result():
    for res in (PlanTrajectory.Response(), PlanMotion.Result()):
        fill_response(_result(certificate=CERT, extra={"predicted_rest": [0.9995]}), res)
        c = res.certificate
        assert c.certified and list(c.box_names) == ["pv", "pc"] and list(c.box_fractions) == [0.2, 0.3]
        assert list(c.worst_at) == [0.8, 1.3] and list(c.per_parameter) == [4e-4, 1.5e-3]
        assert (c.worst_rest_error, c.moving_at_tf, c.samples) == (2e-3, 0.1, 321)
        assert list(c.switch_timing) == [1e-4, -3e-4, 2e-4]
        assert list(res.profile.predicted_rest) == [0.9995] and res.profile.n_steps == 3
    bare = fill_response(_result(), PlanTrajectory.Response())
    assert not bare.certificate.certified and list(bare.profile.predicted_rest) == []
    assert not certificate_msg(None).certified


def test_feedback_from_the_planners_progress():
    fb = feedback_from_progress(PlanMotion.Feedback(), {"starts_done": 120, "best": 0.25}, stage="multistart",
                                starts_total=500, steps=5, elapsed=1.5)
    assert (fb.stage, fb.starts_done, fb.starts_total, fb.steps, fb.best_cost, fb.elapsed) == \
        ("multistart", 120, 500, 5, 0.25, 1.5)
    fb = feedback_from_progress(PlanMotion.Feedback(), {"stage": "joint1"}, stage="multistart",
                                starts_total=0, steps=0, elapsed=0.0)
    assert fb.stage == "joint1" and math.isinf(fb.best_cost) and fb.starts_done == 0


def test_switch_grid_parameter_is_described_with_units_and_range():
    d = descriptor("switch_grid", 0.001)
    assert d.read_only and "SYNC" in d.description and d.description.startswith("s, ")
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (0.0, 1.0)


def test_a_scara_certificate_carries_its_per_joint_figures():
    from dataclasses import replace

    cert = replace(CERT, worst_per_joint=[2e-3, 5e-4], switch_timing_per_joint=[[1e-4, 2e-5], [-3e-4, 0.0]])
    c = certificate_msg(cert)
    assert list(c.worst_per_joint) == [2e-3, 5e-4]
    assert list(c.switch_timing_per_joint) == [1e-4, 2e-5, -3e-4, 0.0]     # row-major switches x joints
    assert list(certificate_msg(CERT).worst_per_joint) == []
