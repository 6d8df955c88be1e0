"""ff-ctl and ff-record without a running system: usage errors (exit 2), help, value parsing."""
from __future__ import annotations

import argparse

import pytest
from rcl_interfaces.msg import ParameterType

from ff_executor.ros import ctl, record
from ff_msgs_py.launch import client_ros_settings

SUBCOMMANDS = ("graph", "lifecycle", "fault-reset", "diag", "param", "plan", "execute", "record", "claim",
               "release", "enable", "status", "echo", "call")


def test_every_subcommand_has_help(capsys):
    assert ctl.main(["--help"]) == 0
    top = capsys.readouterr().out
    for sub in SUBCOMMANDS:
        assert sub in top
        assert ctl.main([sub, "--help"]) == 0
        out = capsys.readouterr().out
        assert out.startswith("usage: ff-ctl " + sub), out[:80]
    # plan and execute take ff-plan's options
    ctl.main(["execute", "--help"])
    out = capsys.readouterr().out
    assert all(opt in out for opt in ("--uncertain", "--objective", "--tolerance"))
    assert record.main(["--help"]) == 0
    assert "--duration" in capsys.readouterr().out


@pytest.mark.parametrize("argv, text", [
    (["bogus"], "invalid choice"),
    ([], "required"),
    (["lifecycle", "set", "ff_hwbridge"], "transition or state"),
    (["param", "get", "ff_executor"], "NODE NAME"),
    (["execute"], "motion file or plan options"),
    (["plan", "--coast", "0.1"], "planner node's settings"),
    (["plan", "--tf", "0.01"], "coast"),
    (["execute", "nope.json", "--qf", "1"], "not both"),
    (["graph", "--timeout", "0"], "--timeout"),
])
def test_bad_usage_exits_2_with_one_line(capsys, argv, text):
    assert ctl.main(argv) == 2
    err = capsys.readouterr().err
    assert text in err and err.count("\n") == 1, err


def test_bad_domain_and_existing_bag_folder_exit_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "x1")
    assert ctl.main(["graph"]) == 2
    assert "ROS_DOMAIN_ID" in capsys.readouterr().err
    monkeypatch.setenv("ROS_DOMAIN_ID", "300")
    assert record.main(["-o", str(tmp_path)]) == 2
    assert "0..232" in capsys.readouterr().err


def test_client_ros_settings_honour_the_environment_and_stay_on_loopback():
    assert client_ros_settings(None, {}) == (0, {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                                                 "ROS_DOMAIN_ID": "0"})
    dom, env = client_ros_settings(None, {"ROS_DOMAIN_ID": "42"})
    assert dom == 42 and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    dom, env = client_ros_settings(7, {"ROS_DOMAIN_ID": "42", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"})
    assert dom == 7 and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"


def test_parameter_values_from_text_take_the_current_type():
    v = ctl._value_msg("25", ParameterType.PARAMETER_DOUBLE)
    assert v.type == ParameterType.PARAMETER_DOUBLE and v.double_value == 25.0
    v = ctl._value_msg("[1, 2.5]", ParameterType.PARAMETER_DOUBLE_ARRAY)
    assert v.type == ParameterType.PARAMETER_DOUBLE_ARRAY and list(v.double_array_value) == [1.0, 2.5]
    v = ctl._value_msg("true", ParameterType.PARAMETER_BOOL)
    assert v.type == ParameterType.PARAMETER_BOOL and v.bool_value is True
    v = ctl._value_msg("123", ParameterType.PARAMETER_STRING)
    assert v.type == ParameterType.PARAMETER_STRING and v.string_value == "123"


def test_plan_options_are_ff_plans():
    a = ctl.build_parser().parse_args(["plan", "--qf", "0.5", "--tf", "0.8", "--uncertain", "pc", "--set", "pc=0.2"])
    req = ctl._plan_request(a)
    assert req.model == "arm1dof" and list(req.qf) == [0.5] and req.tf == 0.8 and list(req.uncertain) == ["pc"]
    assert req.resolved_params().pc == 0.2
    assert isinstance(a, argparse.Namespace) and ctl._node_name(a.plan_service, a.namespace) == "/ff_planner/plan"
    a = ctl.build_parser().parse_args(["plan", "--qf", "0.5", "--tf", "0.8", "--namespace", "arm_a"])
    assert ctl._node_name(a.plan_service, a.namespace) == "/arm_a/ff_planner/plan"
    assert ctl._node_name("/ff_planner/plan", "arm_a") == "/ff_planner/plan"


def test_execute_prints_the_models_prediction_beside_the_measured_rest():
    from ff_executor.ros.ctl import predicted_vs_measured

    line = predicted_vs_measured([1.0022], [1.0037])
    assert "predicted rest [1.002200] rad" in line and "measured [1.003700] rad" in line
    assert "[1.500] mrad" in line
    assert "unknown" in predicted_vs_measured([], [1.0])


def _status(name: str, level: int = 0, message: str = "", **values: str):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

    return DiagnosticStatus(name=name, level=level, message=message,
                            values=[KeyValue(key=k, value=v) for k, v in values.items()])


def test_timing_notes_say_when_the_simulator_was_late_or_the_bridge_latched():
    quiet = [_status("ff_hwbridge: drive group", 0, "operation enabled"),
             _status("ff_sim_driver: drive 1", late_switches="2", late_switch_max_us="108143")]
    assert ctl.late_switches(quiet) == (2, 108143.0)
    assert ctl.late_switches([_status("ff_planner: planning", requests="3")]) == (0, 0.0)
    assert ctl.timing_notes(quiet, quiet) == []                 # nothing new during the move
    late = [quiet[0], _status("ff_sim_driver: drive 1", late_switches="5", late_switch_max_us="228138")]
    (note,) = ctl.timing_notes(quiet, late)
    assert "started 3 current change(s) late" in note and "228.1 ms" in note and "simulation" in note
    latched = [_status("ff_hwbridge: drive group", 2, "safe state: setpoint missed its SYNC cycle"), quiet[1]]
    assert ctl.timing_notes(quiet, latched) == ["ff_hwbridge: drive group: safe state: setpoint missed its SYNC cycle"]


def test_the_bridges_part_of_the_notes_comes_from_its_typed_status():
    from ff_msgs.msg import DriveGroupStatus

    quiet = [_status("ff_hwbridge: drive group", 0, "operation enabled")]
    latched = [_status("ff_hwbridge: drive group", 2, "safe state: a string nobody parses")]
    ok = DriveGroupStatus(state=DriveGroupStatus.ACTIVE, owner="/ff_executor", refused=2)
    safe = DriveGroupStatus(state=DriveGroupStatus.SAFE_STATE, latch_reason="setpoint watchdog: no fresh "
                            "setpoint", owner="/operator", claimed=True, refused=40,
                            last_refusal="setpoint refused: the drive is claimed by /operator (no token)")
    notes = ctl.timing_notes(quiet, latched, ok, safe)
    assert notes[0] == "/ff_hwbridge: safe state: setpoint watchdog: no fresh setpoint"
    assert "refused 38 command(s)" in notes[1] and "claimed by /operator" in notes[1]
    assert len(notes) == 2                      # the diagnostics string is not read as well
    assert ctl.timing_notes(quiet, quiet, ok, ok) == []


def test_plan_takes_a_tolerance_search_and_execute_keeps_its_landing_tolerance():
    p = ctl.build_parser()
    a = p.parse_args(["plan", "--tolerance", "0.002", "--tf-max", "2", "--q-min", "-0.3",
                      "--qd-max", "4"])
    req = ctl._plan_request(a)
    assert req.tolerance == 0.002 and req.move_time_max == 2.0
    assert req.limits.position_min == (-0.3,) and req.limits.velocity_max == (4.0,)
    msg = ctl.request_to_msg(req)
    assert msg.tolerance == 0.002 and list(msg.velocity_max) == [4.0]
    e = p.parse_args(["execute", "move.json", "--tolerance", "0"])
    assert e.land_tolerance == 0.0 and not hasattr(e, "tolerance")
    plain = ctl._plan_request(p.parse_args(["execute", "--qf", "1", "--tolerance", "0.1"]))
    assert plain.tolerance is None and plain.tf == 1.0       # the landing check, not a search
    with pytest.raises(ctl.UsageError, match="--tradeoff"):
        p.parse_args(["plan", "--tradeoff", "x.png"])             # ff-plan only


def test_certificate_and_excursion_are_printed(capsys):
    from ff_planner.model.limits import Excursion
    from ff_planner.model.profile import RobustnessCertificate

    class R:
        certificate = RobustnessCertificate(
            box={"pc": 0.2}, worst_rest_error=2e-3, worst_at={"pc": 1.2}, per_parameter={"pc": 2e-3},
            moving_at_tf=0.5, switch_timing=[0.0], samples=300,
            excursion=Excursion([-0.9], [1.1], [8.3], [-1.07], [1.13], [8.65]))

    ctl._print_certificate(R())
    out = capsys.readouterr().out
    assert "worst rest error 2 mrad" in out and "excursion until rest" in out and "8.6500" in out
