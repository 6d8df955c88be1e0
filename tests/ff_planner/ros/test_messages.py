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


def test_new_request_fields_are_read_from_the_request_and_the_goal():
    common = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=0.0, position_min=[-0.3],
                  position_max=[1.05], velocity_max=[4.0], tolerance=2e-3, move_time_max=2.5)
    a = fields_from_msg(PlanTrajectory.Request(**common))
    assert a == fields_from_msg(PlanMotion.Goal(**common))
    assert (list(a.position_min), list(a.position_max), list(a.velocity_max)) == ([-0.3], [1.05], [4.0])
    assert (a.tolerance, a.move_time_max) == (2e-3, 2.5)


def _cert_with_excursion():
    from dataclasses import replace

    from ff_planner.model.limits import Excursion

    return replace(CERT, excursion=Excursion([-0.9], [1.1], [8.3], [-1.07], [1.13], [8.65]),
                   worst_per_joint=[2e-3, 1e-3], switch_timing_per_joint=[[1e-4, 2e-4], [3e-4, 4e-4]])


def test_the_certificate_and_its_excursion_round_trip_through_the_message():
    from ff_msgs_py.convert import certificate_from_msg, certificate_to_msg

    cert = _cert_with_excursion()
    msg = certificate_to_msg(cert)
    assert list(msg.excursion_worst_min) == [-1.07] and list(msg.excursion_nominal_speed) == [8.3]
    back = certificate_from_msg(msg)
    assert back == cert
    assert certificate_from_msg(certificate_to_msg(None)) is None
    plain = certificate_to_msg(CERT)
    assert list(plain.excursion_worst_max) == [] and certificate_from_msg(plain).excursion is None


def test_response_to_result_carries_the_certificate_into_the_motion_file(tmp_path):
    """ff-ctl plan -o: the motion file written from the service's answer has its certificate."""
    from ff_msgs_py.convert import response_to_result
    from ff_planner.export.motion_file import write_motion
    from ff_planner.model.profile import PlanRequest

    res = fill_response(_result(certificate=_cert_with_excursion(), q_final=np.ones(1),
                                qd_final=np.zeros(1)), PlanTrajectory.Response())
    back = response_to_result(res, PlanRequest(uncertain=("pv", "pc")))
    assert back.certificate == _cert_with_excursion()
    path = tmp_path / "m.json"
    write_motion(path, back)
    import json

    cert = json.loads(path.read_text())["certificate"]
    assert cert["worst_rest_error"] == 2e-3 and cert["excursion"]["worst_speed"] == [8.65]


def test_request_to_msg_and_back_carries_limits_tolerance_box_and_coast_max():
    from ff_msgs_py.convert import request_to_msg
    from ff_planner.model.limits import MotionLimits
    from ff_planner.model.profile import PlanRequest
    from ff_planner.ros.messages import fields_from_msg
    from ff_planner.service.planner_service import PlannerService, ServiceConfig

    service = PlannerService(ServiceConfig(library_path="", warmup=False))

    def request_from_msg(m):        # what the planner node makes of a message
        return service.make_request(fields_from_msg(m)).request

    req = PlanRequest(qf=(1.0,), tf=2.0, box={"pc": 0.3}, coast_max=0.2,
                      limits=MotionLimits.of([-0.3], [1.05], [4.0]), tolerance=2e-3,
                      move_time_max=2.0)
    msg = request_to_msg(req)
    assert list(msg.position_min) == [-0.3] and msg.tolerance == 2e-3 and msg.move_time_max == 2.0
    assert list(msg.box_names) == ["pc"] and msg.coast_max == 0.2
    back = request_from_msg(msg)
    assert (back.limits, back.tolerance, back.move_time_max, back.tf) == (req.limits, 2e-3, 2.0, 2.0)
    assert back.box == {"pc": 0.3} and back.coast_max == 0.2
    plain = request_to_msg(PlanRequest(qf=(1.0,)))
    assert (list(plain.position_min), plain.tolerance, plain.move_time_max, plain.coast_max) == \
        ([], 0.0, 0.0, 0.0)
    assert request_from_msg(plain).limits is None and request_from_msg(plain).tolerance is None


def test_limit_parameters_have_descriptions():
    d = descriptor("arm1dof.velocity_max", [4.0])
    assert "rad/s per joint" in d.description and d.read_only
    assert "rad per joint" in descriptor("scara2.position_min", [0.0, 0.0]).description
