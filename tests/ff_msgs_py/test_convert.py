"""Round trips between ff_msgs messages and the planner's dataclasses / numpy."""
from __future__ import annotations

import numpy as np
import pytest

from ff_msgs.msg import CurrentProfile as CurrentProfileMsg
from ff_msgs.srv import PlanTrajectory
from ff_msgs_py import convert
from ff_planner.core.errors import ERROR_NAMES
from ff_planner.model.params import ParameterError, default_params
from ff_planner.model.profile import BOX_DEFAULT_STEPS, CurrentProfile, PlanningError, PlanRequest, PlanResult


def test_profile_round_trip_2dof():
    prof = CurrentProfile.uniform([[1.0, -2.0], [3.5, 4.0], [-5.0, 0.25]], tf=1.2, coast=0.05)
    msg = convert.profile_to_msg(prof, "scara2", [-0.5, 0.0], [0.5, 0.0])
    assert msg.joint_names == ["joint1", "joint2"] and msg.n_steps == 3
    back = convert.msg_to_profile(msg)
    np.testing.assert_array_equal(back.currents, prof.currents)
    np.testing.assert_array_equal(back.step_times, prof.step_times)
    assert back.tf == 1.2 and back.coast == 0.05
    # the id is a content hash: same motion, same id; different currents, different id
    assert msg.profile_id == convert.profile_to_msg(prof, "scara2", [-0.5, 0.0], [0.5, 0.0]).profile_id
    prof.currents[0, 0] += 1e-3
    assert msg.profile_id != convert.profile_to_msg(prof, "scara2", [-0.5, 0.0], [0.5, 0.0]).profile_id


def test_inconsistent_profile_msg_is_refused():
    msg = CurrentProfileMsg(joint_names=["j"], n_steps=3, currents=[1.0, 2.0], step_times=[0, 0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="currents"):
        convert.msg_to_profile(msg)
    msg = CurrentProfileMsg(joint_names=["j"], n_steps=2, currents=[1.0, 2.0], step_times=[0, 0.1])
    with pytest.raises(ValueError, match="step times"):
        convert.msg_to_profile(msg)


def test_time_round_trip():
    for ns in (0, 1, 999_999_999, 1_000_000_000, 1_732_000_123_456_789):
        assert convert.time_to_ns(convert.ns_to_time(ns)) == ns
    with pytest.raises(ValueError):
        convert.ns_to_time(-1)


def test_setpoint_round_trip():
    msg = convert.setpoint_msg(5_000_000_123, [1.5, -2.0], 7, "abc", last=True)
    stamp, cur, seq, pid, last = convert.setpoint_to_tuple(msg)
    assert stamp == 5_000_000_123 and seq == 7 and pid == "abc" and last
    np.testing.assert_array_equal(cur, [1.5, -2.0])


def _node_request(msg, config=None):
    """What the planner node makes of a PlanTrajectory request (its message decoding and checks)."""
    from ff_planner.ros.messages import fields_from_msg
    from ff_planner.service.planner_service import PlannerService, ServiceConfig

    service = PlannerService(config or ServiceConfig(library_path="", warmup=False))
    return service.make_request(fields_from_msg(msg)).request


def test_request_round_trip_with_overrides():
    params = default_params("arm1dof").replace(pc=0.25, J=0.2)
    req = PlanRequest(model="arm1dof", q0=[0.1], qf=[1.1], tf=0.9, uncertain=["pc"],
                      objective="robust-sampled", steps=4, starts=12, seed=3, time_budget=2.5,
                      params=params)
    msg = convert.request_to_msg(req)
    assert sorted(msg.override_names) == ["J", "pc"]
    back = _node_request(msg)
    assert back.params == params
    assert (back.model, list(back.q0), list(back.qf), back.tf) == ("arm1dof", [0.1], [1.1], 0.9)
    assert (back.objective, back.steps, back.starts, back.seed, back.time_budget) == (
        "robust-sampled", 4, 12, 3, 2.5)
    back.validate()


def test_request_defaults_and_bad_override():
    msg = PlanTrajectory.Request(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pc"])
    from ff_planner.service.planner_service import ServiceConfig
    req = _node_request(msg, ServiceConfig(library_path="", warmup=False, default_starts=7, default_time_budget=4.0))
    assert req.steps is None and req.starts == 7 and req.time_budget == 4.0
    assert req.objective == "robust-box" and req.n_steps() == BOX_DEFAULT_STEPS       # the planner's defaults
    msg.objective = "robust-derivative"
    assert _node_request(msg).n_steps() == 3                 # 2 + k for one parameter
    msg.override_names, msg.override_values = ["nope"], [1.0]
    with pytest.raises(ParameterError, match="nope"):
        _node_request(msg)
    msg.override_names, msg.override_values = ["pc"], []
    with pytest.raises(PlanningError, match="override"):
        _node_request(msg)


def test_result_to_response():
    prof = CurrentProfile.uniform([1.0, -1.0, 0.5], tf=1.0)
    result = PlanResult(success=False, message="no robust plan", profile=prof, model="arm1dof",
                        params=default_params("arm1dof"), q0=np.array([0.0]), qf=np.array([1.0]),
                        uncertain=["pc"], objective="robust-derivative", q_final=np.array([0.99]),
                        qd_final=np.array([0.0]), sensitivities={"pc": 1e-3}, error_code="NO_ROBUST_PLAN",
                        best_effort=True, starts_tried=5, iterations=40, solve_time=0.01)
    res = convert.result_to_response(result, PlanTrajectory.Response())
    assert not res.success and res.error_code == PlanTrajectory.Response.NO_ROBUST_PLAN
    assert list(res.sensitivity_names) == ["pc"] and list(res.sensitivity_values) == [1e-3]
    assert list(res.q_final) == [0.99] and res.profile.n_steps == 3 and not res.robust
    np.testing.assert_array_equal(convert.msg_to_profile(res.profile).currents, prof.currents)
    # every error name maps onto the service's constant of the same name
    for name, value in convert.ERROR_CODES.items():
        assert getattr(PlanTrajectory.Response, name) == value


def _interface_error_constants() -> dict[str, int]:
    """The integer constants of the generated PlanTrajectory.Response class (uint8 error codes)."""
    cls = PlanTrajectory.Response
    return {n: getattr(cls, n) for n in dir(cls)
            if n.isupper() and isinstance(getattr(cls, n), int) and not isinstance(getattr(cls, n), bool)}


def test_error_names_are_exactly_the_interface_constants():
    constants = _interface_error_constants()
    assert set(ERROR_NAMES) == set(constants)
    assert len(set(constants.values())) == len(constants), "two error names share a code"
    assert sorted(constants, key=constants.__getitem__) == list(ERROR_NAMES)   # ERROR_NAMES in code order
    assert convert.ERROR_CODES == constants


def test_predicted_rest_travels_with_the_profile_and_the_plan_answer():
    prof = CurrentProfile.uniform([1.0, -1.0], 1.0)
    profile_to_msg, predicted_rest_of = convert.profile_to_msg, convert.predicted_rest_of
    msg = profile_to_msg(prof, "arm1dof", [0.0], [0.5], predicted_rest=[0.4999])
    assert list(msg.predicted_rest) == [0.4999] and predicted_rest_of(msg) == [0.4999]
    # unknown, wrong length or not finite: empty
    assert list(profile_to_msg(prof, "arm1dof", [0.0], [0.5]).predicted_rest) == []
    assert list(profile_to_msg(prof, "arm1dof", [0.0], [0.5], predicted_rest=[1.0, 2.0]).predicted_rest) == []
    assert list(profile_to_msg(prof, "arm1dof", [0.0], [0.5], predicted_rest=[float("nan")]).predicted_rest) == []
    result = PlanResult(success=True, message="ok", profile=prof, model="arm1dof", params=None,
                        q0=np.zeros(1), qf=np.full(1, 0.5), uncertain=[], objective="energy-optimal",
                        extra={"predicted_rest": [0.501]})
    res = convert.result_to_response(result, PlanTrajectory.Response())
    assert list(res.profile.predicted_rest) == [0.501]
    back = convert.response_to_result(res, PlanRequest(model="arm1dof", q0=[0.0], qf=[0.5], tf=1.0))
    assert back.extra["predicted_rest"] == [0.501]


def test_drive_exact_certificate_round_trips_with_its_drive_fields():
    """A drive-exact certificate comes back from its message with the drive's unit, period and
    source; a plain one comes back plain with the drive fields left at false / 0 / ""."""
    from ff_planner.model.limits import Excursion
    from ff_planner.model.profile import RobustnessCertificate
    from ff_planner.optimize.drive_grid import DriveCertificate, DriveGrid

    common = dict(box={"pv": 0.2, "pc": 0.2}, worst_rest_error=5.3e-3,
                  worst_at={"pv": 0.8, "pc": 1.2}, per_parameter={"pv": 1e-3, "pc": 4e-3},
                  moving_at_tf=0.25, switch_timing=[1e-4, -2e-4], samples=283,
                  excursion=Excursion([-0.9], [1.1], [8.3], [-1.07], [1.13], [8.65]))
    grid = DriveGrid(0.003, 0.01, "config/bridge_epos4_1dof.yaml")
    cert = DriveCertificate(drive=grid.to_dict(), **common)
    msg = convert.certificate_to_msg(cert)
    assert msg.drive_exact and msg.drive_setpoint_unit == 0.003 and msg.drive_switch_period == 0.01
    assert msg.drive_source == "config/bridge_epos4_1dof.yaml"
    back = convert.certificate_from_msg(msg)
    assert isinstance(back, DriveCertificate)
    assert back.drive == {"current_quantum_A": 0.003, "switch_period_s": 0.01,
                          "source": "config/bridge_epos4_1dof.yaml"}
    assert back == cert
    assert back.to_dict()["drive"] == cert.to_dict()["drive"]
    # on receipt (period 0) keeps its zero period and stays drive-exact
    on_receipt = DriveCertificate(drive=DriveGrid(0.001, 0.0, "bridge.yaml").to_dict(), **common)
    back = convert.certificate_from_msg(convert.certificate_to_msg(on_receipt))
    assert isinstance(back, DriveCertificate) and back.drive["switch_period_s"] == 0.0
    assert back == on_receipt
    plain = RobustnessCertificate(**common)
    pmsg = convert.certificate_to_msg(plain)
    assert not pmsg.drive_exact and pmsg.drive_setpoint_unit == 0.0 and pmsg.drive_source == ""
    pback = convert.certificate_from_msg(pmsg)
    assert type(pback) is RobustnessCertificate and pback == plain


def test_a_drive_exact_answer_writes_its_drive_into_the_motion_file(tmp_path):
    """ff-ctl plan -o: a drive-exact plan's certificate comes back from the service's answer with
    the drive it is for, and the motion file written from it says so."""
    import json

    from ff_planner.export.motion_file import write_motion
    from ff_planner.model.profile import RobustnessCertificate
    from ff_planner.optimize.drive_grid import DriveCertificate, DriveGrid

    prof = CurrentProfile.uniform([[1.0], [-1.0], [0.5]], tf=1.0, coast=0.1)
    cert = DriveCertificate(
        drive=DriveGrid(0.003, 0.01, "config/bridge_epos4_1dof.yaml").to_dict(),
        **vars(RobustnessCertificate(box={"pc": 0.2}, worst_rest_error=4e-3, worst_at={"pc": 0.8},
                                     per_parameter={"pc": 4e-3}, moving_at_tf=0.0,
                                     switch_timing=[0.0, 0.0, 0.0], samples=50)))
    result = PlanResult(success=True, message="ok", profile=prof, model="arm1dof",
                        params=default_params("arm1dof"), q0=np.zeros(1), qf=np.ones(1),
                        uncertain=["pc"], objective="robust-box", q_final=np.ones(1),
                        qd_final=np.zeros(1), certificate=cert)
    res = convert.result_to_response(result, PlanTrajectory.Response())
    assert res.certificate.drive_exact and res.certificate.drive_switch_period == 0.01
    back = convert.response_to_result(res, PlanRequest(uncertain=("pc",)))
    assert isinstance(back.certificate, DriveCertificate) and back.certificate == cert
    path = tmp_path / "m.json"
    write_motion(path, back)
    drive = json.loads(path.read_text())["certificate"]["drive"]
    assert drive == {"current_quantum_A": 0.003, "switch_period_s": 0.01,
                     "source": "config/bridge_epos4_1dof.yaml"}
