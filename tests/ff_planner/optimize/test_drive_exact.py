"""Drive-exact plans: the grid read from the bridge's own config, the profile the drive applies,
and the certificate computed on exactly that profile (checked against fresh box points)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from ff_hwbridge.drive.config import BridgeConfig
from ff_hwbridge.drive.config import load_config as load_bridge_config
from ff_hwbridge.protocol.units import DriveUnits
from ff_planner.core.errors import PlanningError
from ff_planner.model.arm1dof import FRICTION, TR_REST, track
from ff_planner.model.profile import CurrentProfile, PlanRequest
from ff_planner.optimize import drive_grid as dg
from ff_planner.optimize.certificate import certify_1dof
from ff_planner.optimize.drive_grid import (DriveCertificate, DriveConfigError, DriveGrid,
                                            drive_grid_from_config, drive_grid_from_mapping,
                                            latched_times, snap_times)
from ff_planner.optimize.planner import apply_drive_exact, check, plan

CONFIG = Path(__file__).resolve().parents[3] / "config"
SHIPPED = CONFIG / "bridge_epos4_1dof.yaml"


# --- one source: the bridge's own reading of the same file ------------------------------------
@pytest.mark.parametrize("name", ["bridge_epos4_1dof.yaml", "bridge_sim_scara2.yaml"])
def test_grid_is_what_the_bridge_reads_from_the_same_file(name):
    grid = drive_grid_from_config(CONFIG / name)
    bridge = load_bridge_config(CONFIG / name)
    assert grid.period == pytest.approx(bridge.sync_period, abs=0.0)
    for joint in bridge.joints:     # the bridge's setpoint unit: one per mille / one mA
        assert grid.quantum == pytest.approx(joint.units.current_resolution, rel=1e-12)
        raw = joint.units.amps_to_setpoint(0.6 * joint.current_limit)
        assert joint.units.setpoint_to_amps(raw) / grid.quantum == pytest.approx(raw, abs=1e-9)


def test_shipped_drive_is_3_mA_at_its_sync_period():
    grid = drive_grid_from_config(SHIPPED)
    data = yaml.safe_load(SHIPPED.read_text())
    assert grid.quantum == pytest.approx(data["joints"][0]["units"]["nominal_current"] / 1000.0)
    assert grid.quantum == pytest.approx(0.003)
    assert grid.period == data["sync_period"]


def test_defaults_mirror_the_bridges():
    assert dg.BRIDGE_SYNC_PERIOD == BridgeConfig.__dataclass_fields__["sync_period"].default
    assert dg.BRIDGE_SETPOINT_TIMING == BridgeConfig.__dataclass_fields__["setpoint_timing"].default
    assert dg.BRIDGE_NOMINAL_CURRENT == DriveUnits().nominal_current
    assert dg.BRIDGE_FAMILY == DriveUnits().family
    assert dg.EPOS2_UNIT == DriveUnits(family="epos2").current_resolution
    minimal = {"joints": [{"name": "j", "current_limit": 5.0}]}
    bridge = load_bridge_config(dict(minimal, bus={"interface": "virtual", "channel": "x"}))
    grid = drive_grid_from_mapping(minimal)
    assert (grid.quantum, grid.period) == pytest.approx(
        (bridge.joints[0].units.current_resolution, bridge.sync_period))


def test_ros_parameter_form_and_on_receipt():
    grid = drive_grid_from_config(CONFIG / "bridge_ros_params_sim_1dof.yaml")
    params = yaml.safe_load((CONFIG / "bridge_ros_params_sim_1dof.yaml").read_text())
    p = params["ff_hwbridge"]["ros__parameters"]
    assert grid.quantum == pytest.approx(p["nominal_currents"][0] / 1000.0)
    assert grid.period == p["sync_period"]
    on_receipt = drive_grid_from_mapping({"setpoint_timing": "on_receipt",
                                          "joints": [{"family": "epos2", "current_limit": 5.0}]})
    assert (on_receipt.quantum, on_receipt.period) == (0.001, 0.0)


@pytest.mark.parametrize("data, needle", [
    ({"joints": []}, "non-empty"),
    ({"sync_period": 0.01}, "names no joints"),
    ({"joints": [{"family": "epos9"}]}, "epos4 or epos2"),
    ({"joints": [{"units": {"nominal_current": -3}}]}, "nominal_current"),
    ({"sync_period": "fast", "joints": [{}]}, "sync_period"),
    ({"setpoint_timing": "sometimes", "joints": [{}]}, "setpoint_timing"),
    ({"joints": [{"units": {"nominal_current": 3.0}}, {"units": {"nominal_current": 2.0}}]},
     "differ"),
])
def test_bad_bridge_configs_say_why(data, needle):
    with pytest.raises(DriveConfigError, match=needle):
        drive_grid_from_mapping(data)


def test_missing_file_names_the_places_tried():
    with pytest.raises(DriveConfigError, match="no bridge config file"):
        drive_grid_from_config("no_such_bridge.yaml")
    assert drive_grid_from_config("bridge_epos4_1dof.yaml").period > 0.0   # the suite's folder


# --- the profile on the grid ---------------------------------------------------------------------
def test_snap_times_nearest_sync_each_step_one_period():
    prof = CurrentProfile(np.array([0.0, 0.0031, 0.0049, 0.2337, 0.9])
                          , np.ones((4, 1)), tf=1.0, coast=0.05)
    out = snap_times(prof, 0.01)
    k = out.step_times / 0.01
    assert np.allclose(k, np.rint(k), atol=1e-9) and np.all(np.diff(np.rint(k)) >= 1)
    assert np.allclose(out.step_times, [0.0, 0.01, 0.02, 0.23, 0.9])
    with pytest.raises(PlanningError, match="do not fit"):
        snap_times(CurrentProfile.uniform(np.ones(10), tf=0.1, coast=0.05), 0.01)


def test_latched_times_follow_the_bridges_rule():
    prof = CurrentProfile(np.array([0.0, 0.0095, 0.0121, 0.0139, 0.5]),
                          np.array([1.0, 2.0, 3.0, 4.0]), tf=1.0, coast=0.05)
    out = latched_times(prof, 0.01)
    # 9.5 ms -> the SYNC at 10 ms (within 10 % of a period); 12.1 and 13.9 ms -> 20 ms: the step
    # of 3.0 A is overwritten in the same cycle by the 4.0 A one and vanishes
    assert np.allclose(out.step_times, [0.0, 0.01, 0.02, 0.5])
    assert out.currents[:, 0].tolist() == [1.0, 2.0, 4.0]


# --- the must-show: the default plan for the shipped drive ------------------------------------------
@pytest.fixture(scope="module")
def shipped_plan():
    grid = drive_grid_from_config(SHIPPED)
    return grid, plan(PlanRequest(), drive=grid)


def test_default_plan_is_what_the_drive_applies(shipped_plan):
    grid, r = shipped_plan
    assert r.success and r.profile is not None
    units = load_bridge_config(SHIPPED).joints[0].units
    limit = load_bridge_config(SHIPPED).joints[0].current_limit
    for i in r.profile.currents[:, 0]:   # through the bridge's own conversion and back: unchanged
        raw = units.amps_to_setpoint(i, limit)
        assert units.setpoint_to_amps(raw) == pytest.approx(i, abs=1e-12)
    k = r.profile.step_times / grid.period
    assert np.allclose(k, np.rint(k), atol=1e-9)
    assert np.all(np.diff(np.rint(k)) >= 1)
    # the bridge's latching rule leaves a gridded profile as it is
    sent = latched_times(r.profile, grid.period)
    assert np.allclose(sent.step_times, r.profile.step_times, atol=1e-12)
    assert np.array_equal(sent.currents, r.profile.currents)
    info = r.extra["drive_exact"]
    assert info["on_grid"] and info["on_quantum"]
    assert info["current_quantum_A"] == grid.quantum and info["switch_period_s"] == grid.period


def test_certificate_is_computed_on_the_sent_profile_and_says_so(shipped_plan):
    grid, r = shipped_plan
    cert = r.certificate
    assert isinstance(cert, DriveCertificate)
    assert cert.drive["current_quantum_A"] == grid.quantum
    assert cert.drive["switch_period_s"] == grid.period
    assert "sent to the drive" in cert.drive["certified_profile"]
    assert cert.to_dict()["drive"] == cert.drive
    again = certify_1dof(r.params, r.profile, 0.0, 1.0, list(r.uncertain), None)
    assert cert.worst_rest_error == pytest.approx(again.worst_rest_error, rel=1e-12)
    assert cert.excursion is not None
    assert cert.excursion.worst_min == pytest.approx(again.excursion.worst_min)


def test_300_fresh_box_points_never_exceed_the_certificate_by_10_percent(shipped_plan):
    grid, r = shipped_plan
    rng = np.random.default_rng(20261207)
    scales = np.ones((300, 3))
    for j, u in enumerate(FRICTION):
        if u in r.uncertain:
            scales[:, j] = rng.uniform(0.8, 1.2, 300)
    sent = latched_times(r.profile, grid.period)      # exactly what the drive applies
    rest = track(r.params, sent, 0.0, scales)[:, TR_REST]
    worst = float(np.max(np.abs(rest - 1.0)))
    assert math.isfinite(worst)
    assert worst <= 1.10 * r.certificate.worst_rest_error, (worst, r.certificate.worst_rest_error)


# --- the facade's checks and the library path -------------------------------------------------------
def test_request_the_grid_cannot_serve_is_refused():
    grid = DriveGrid(quantum=0.003, period=0.01)
    with pytest.raises(PlanningError, match="differs from the drive"):
        check(PlanRequest(current_quantum=0.001), drive=grid)
    with pytest.raises(PlanningError, match="do not fit"):
        check(PlanRequest(tf=0.2, steps=30, objective="robust-derivative"), drive=grid)
    with pytest.raises(PlanningError, match="not shorter than the move time"):
        check(PlanRequest(tf=0.3, coast=0.05), drive=DriveGrid(quantum=0.003, period=0.5))
    with pytest.raises(DriveConfigError):
        DriveGrid(quantum=0.0, period=0.01)


def test_a_plan_from_elsewhere_is_made_drive_exact():
    grid = DriveGrid(quantum=0.003, period=0.01, source="test")
    req = PlanRequest(objective="time-optimal", uncertain=("pc",))
    r = plan(req)                                    # switch times anywhere, currents anywhere
    assert r.certificate is not None and not isinstance(r.certificate, DriveCertificate)
    out = apply_drive_exact(r, check(req, drive=grid))
    k = out.profile.step_times / 0.01
    assert np.allclose(k, np.rint(k), atol=1e-9)
    assert isinstance(out.certificate, DriveCertificate)
    again = certify_1dof(out.params, out.profile, 0.0, 1.0, ["pc"], None)
    assert out.certificate.worst_rest_error == pytest.approx(again.worst_rest_error, rel=1e-12)
    assert apply_drive_exact(out, check(req, drive=grid)) is out    # already drive-exact


def test_service_config_names_the_bridge_file():
    from ff_planner.service.planner_service import ServiceConfigError, config_from_mapping

    params = yaml.safe_load((CONFIG / "planner.yaml").read_text())["ff_planner"]["ros__parameters"]
    params.pop("diagnostics_period", None)          # the node's own, like its registered arms
    params = {k: v for k, v in params.items() if not k.startswith("arms.")}
    grid = config_from_mapping(params).drive()
    assert grid is not None and (grid.quantum, grid.period) == (
        drive_grid_from_config(SHIPPED).quantum, drive_grid_from_config(SHIPPED).period)
    with pytest.raises(ServiceConfigError, match="differs from the drive"):
        config_from_mapping(dict(params, current_quantum=0.001))
    with pytest.raises(ServiceConfigError, match="drive_config"):
        config_from_mapping(dict(params, drive_config="no_such_bridge.yaml"))
    assert config_from_mapping(dict(params, drive_config="")).drive() is None


def test_service_requests_carry_the_drive_to_the_worker():
    from ff_planner.service.planner_service import PlannerService, RequestFields, ServiceConfig

    svc = PlannerService(ServiceConfig(drive_config=str(SHIPPED), use_library=False,
                                       switch_grid=0.001))
    try:
        checked = svc.make_request(RequestFields(model="arm1dof", q0=[0.0], qf=[1.0],
                                                 move_time=1.0, uncertain=["pc"],
                                                 objective="robust-derivative"))
    finally:
        svc.close()
    grid = drive_grid_from_config(SHIPPED)
    assert checked.drive == DriveGrid(grid.quantum, grid.period, str(SHIPPED))
    assert getattr(checked.request, "grid", None) == grid.period      # the SYNC, not switch_grid
    r = plan(checked)                          # what a worker does with it
    assert isinstance(r.certificate, DriveCertificate)
    k = r.profile.step_times / grid.period
    assert np.allclose(k, np.rint(k), atol=1e-9)


def test_time_optimal_plan_lands_at_the_goal_as_sent():
    """Its bang-bang switch moves to the 10 ms SYNC (4.4 ms here): at 10 A that alone would put
    the rest 0.67 rad past the goal; the currents are solved again on the snapped switch."""
    from ff_planner.model.simulate import rest_position

    res = plan(PlanRequest(objective="time-optimal", uncertain=["pc"]),
               drive=DriveGrid(quantum=0.003, period=0.01, source="test"))
    info = res.extra["drive_exact"]
    assert info["max_switch_shift_s"] > 1e-3 and info["land"]["ok"]
    assert info["land"]["rest_error_snapped_rad"] > 0.1
    rest = float(rest_position(res.params, res.profile, [0.0])[0])
    assert abs(rest - 1.0) <= info["rest_error_allowed_rad"][0] and abs(rest - 1.0) < 0.01
    assert res.success and info["landing_ok"] and "solved again to land" in res.message
