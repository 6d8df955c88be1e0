"""The certificate over ROS says what it was computed on: a drive-exact plan's drive fields."""
from __future__ import annotations

import numpy as np

from ff_msgs.srv import PlanTrajectory
from ff_planner.model.profile import CurrentProfile, PlanResult, RobustnessCertificate
from ff_planner.optimize.drive_grid import DriveCertificate, DriveGrid
from ff_planner.ros.messages import certificate_msg, fill_response

FIELDS = dict(box={"pc": 0.2}, worst_rest_error=2e-3, worst_at={"pc": 1.2},
              per_parameter={"pc": 2e-3}, moving_at_tf=0.0, switch_timing=[1e-4, 2e-4], samples=9)


def test_drive_exact_certificate_carries_the_unit_period_and_source():
    drive = DriveGrid(quantum=0.003, period=0.01, source="config/bridge_epos4_1dof.yaml")
    msg = certificate_msg(DriveCertificate(drive=drive.to_dict(), **FIELDS))
    assert msg.certified and msg.drive_exact
    assert msg.drive_setpoint_unit == 0.003 and msg.drive_switch_period == 0.01
    assert msg.drive_source == "config/bridge_epos4_1dof.yaml"
    plain = certificate_msg(RobustnessCertificate(**FIELDS))
    assert plain.certified and not plain.drive_exact
    assert plain.drive_setpoint_unit == 0.0 and plain.drive_switch_period == 0.0
    assert not certificate_msg(None).drive_exact


def test_fill_response_sends_the_drive_fields():
    cert = DriveCertificate(drive=DriveGrid(quantum=0.001, period=0.0).to_dict(), **FIELDS)
    result = PlanResult(success=True, message="ok", profile=CurrentProfile.uniform([[1.0], [-1.0]], 1.0),
                        model="arm1dof", params=None, q0=np.zeros(1), qf=np.ones(1), uncertain=["pc"],
                        objective="robust-box", certificate=cert)
    resp = fill_response(result, PlanTrajectory.Response())
    assert resp.certificate.drive_exact and resp.certificate.drive_setpoint_unit == 0.001
    assert resp.certificate.drive_switch_period == 0.0
