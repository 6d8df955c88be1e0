"""Requests for registered arms from a URDF (ff_planner.armplan.requests), without ROS: the
registry from the planner's arms.NAME.* parameters, model ids, and requests refused with one
clear message (the node test plans through the service)."""
from __future__ import annotations

from pathlib import Path

import pytest

from ff_planner.armplan.requests import (ArmRequest, arm_name, is_urdf_model, plan_registered,
                                         registry_from_parameters)
from ff_planner.core.errors import PlanningError

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"
LIMITS = dict(default_time_budget=10.0, max_time_budget=60.0, max_steps=40, max_move_time=60.0,
              coast=0.05)


def _params(*names):
    return {f"arms.{n}.{h}": str(ARMS / (f"{n}.urdf" if h == "urdf" else f"{n}.cell.yaml"))
            for n in names for h in ("urdf", "cell")}


def test_registry_from_parameters_and_its_refusals(tmp_path):
    reg = registry_from_parameters({**_params("arm3h", "vertical2"), "workers": 2}, Path)
    assert sorted(reg) == ["arm3h", "vertical2"]
    assert reg["arm3h"].urdf.name == "arm3h.urdf" and reg["arm3h"].cell.name == "arm3h.cell.yaml"
    bad = [({"arms.a.urdf": str(ARMS / "arm3h.urdf")}, "arms.a.cell is missing"),
           ({**_params("arm3h"), "arms.arm3h.mesh": "x"}, "arms.<NAME>.urdf"),
           ({"arms.3x.urdf": "a", "arms.3x.cell": "b"}, "must start with a letter"),
           ({"arms.a.urdf": str(tmp_path / "none.urdf"), "arms.a.cell": str(ARMS / "arm3h.cell.yaml")},
            "no such file"),
           ({"arms.a.urdf": "", "arms.a.cell": "x"}, "expected a file path")]
    for values, text in bad:
        with pytest.raises(ValueError, match=text.replace(".", r"\.").replace("<", ".").replace(">", ".")):
            registry_from_parameters(values, Path)


def test_model_ids():
    reg = registry_from_parameters(_params("arm3h"), Path)
    assert is_urdf_model("urdf:arm3h") and is_urdf_model("urdf:") and not is_urdf_model("scara2")
    assert arm_name("urdf:arm3h", reg) == "arm3h"
    for model, code, text in (("urdf:", "INVALID_REQUEST", "malformed"),
                              ("urdf:arm 3h", "INVALID_REQUEST", "malformed"),
                              ("urdf:arm4", "UNKNOWN_MODEL", "registered: urdf:arm3h")):
        with pytest.raises(PlanningError, match=text) as info:
            arm_name(model, reg)
        assert info.value.code == code


def test_bad_requests_come_back_as_failed_results():
    reg = registry_from_parameters(_params("arm3h"), Path)
    cases = [(ArmRequest("urdf:arm3h", [0.0], [0.5], 1.5), "INVALID_REQUEST", "need 3 values"),
             (ArmRequest("urdf:arm3h", [0.0] * 3, [0.5] * 3, 0.0), "INVALID_REQUEST", "move_time"),
             (ArmRequest("urdf:arm3h", [0.0] * 3, [0.5] * 3, 1.5, objective="time-optimal"),
              "INVALID_REQUEST", "robust-box only"),
             (ArmRequest("urdf:arm3h", [0.0] * 3, [0.5] * 3, 1.5, time_budget=1e4),
              "INVALID_REQUEST", "time_budget"),
             (ArmRequest("urdf:arm3h", [0.0] * 3, [0.5] * 3, 1.5, unsupported=("uncertain",)),
              "INVALID_REQUEST", "uncertain: not taken"),
             (ArmRequest("urdf:nope", [0.0], [0.5], 1.5), "UNKNOWN_MODEL", "no arm named 'nope'")]
    for req, code, text in cases:
        r = plan_registered(req, reg, **LIMITS)
        assert not r.success and r.error_code == code and text in r.message, (req, r.message)
        assert r.profile is None


def test_a_registered_arm_whose_cell_is_bad_is_refused_naming_the_field(tmp_path):
    cell = (ARMS / "arm3h.cell.yaml").read_text().replace("kt: 0.0267, gear: 54", "kt: -1.0, gear: 54", 1)
    (tmp_path / "bad.cell.yaml").write_text(cell)
    reg = registry_from_parameters({"arms.bad.urdf": str(ARMS / "arm3h.urdf"),
                                    "arms.bad.cell": str(tmp_path / "bad.cell.yaml")}, Path)
    r = plan_registered(ArmRequest("urdf:bad", [0.0] * 3, [0.5] * 3, 1.5), reg, **LIMITS)
    assert not r.success and r.error_code == "INVALID_REQUEST"
    assert "shoulder" in r.message and "motor.kt" in r.message, r.message
