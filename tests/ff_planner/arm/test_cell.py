"""An arm from a URDF plus a cell file: what is refused (one line naming the joint and the field)
and what the shipped arms are."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from ff_planner.arm.cell import cell_from_mapping, load_cell
from ff_planner.arm.errors import ArmConfigError
from ff_planner.arm.model import load_arm
from ff_planner.model.params import Scara2Params
from ff_planner.model.scara2 import inertia_constants

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"


def _scara_cell() -> dict:
    return yaml.safe_load((ARMS / "scara2.cell.yaml").read_text())


def _write(tmp_path: Path, cell: dict, urdf_text: str | None = None) -> Path:
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(urdf_text if urdf_text is not None else (ARMS / "scara2.urdf").read_text())
    cell = dict(cell, urdf=str(urdf))
    p = tmp_path / "arm.cell.yaml"
    p.write_text(yaml.safe_dump(cell))
    return p


def _refused(path: Path) -> ArmConfigError:
    with pytest.raises(ArmConfigError) as info:
        load_arm(path)
    msg = str(info.value)
    assert "\n" not in msg
    return info.value


def test_shipped_scara_has_the_papers_mass_matrix():
    arm = load_arm(ARMS / "scara2.cell.yaml")
    A, B, C = inertia_constants(Scara2Params())
    assert arm.joints == ("joint1", "joint2")
    np.testing.assert_allclose(arm.constants.Za, [[A, B], [B, C]], rtol=1e-12)
    np.testing.assert_allclose(arm.constants.Zb, 0.0, atol=1e-12)
    np.testing.assert_allclose(arm.constants.Ga, 0.0, atol=1e-12)
    # motor 2 drives the absolute angle: θ2 = q1 + q2
    np.testing.assert_array_equal(arm.E, [[1.0, 0.0], [1.0, 1.0]])
    th = np.array([0.3, -1.1])
    M = arm.constants.mass_matrix(th)
    c = np.cos(th[0] - th[1])
    np.testing.assert_allclose(M, [[A, B * c], [B * c, C]], rtol=1e-12)


def test_shipped_1dof_arm():
    arm = load_arm(ARMS / "arm1dof.cell.yaml")
    np.testing.assert_allclose(arm.constants.mass_matrix(np.array([0.7])), [[0.17]], rtol=1e-12)
    np.testing.assert_allclose(arm.torque_per_amp, [54 * 0.0267])


@pytest.mark.parametrize("path, value, joint, field", [
    (("joint2", "motor", "kt"), -1.0, "joint2", "motor.kt"),
    (("joint1", "motor", "i_max"), 0.0, "joint1", "motor.i_max"),
    (("joint1", "friction", "pt"), 1.5, "joint1", "friction.pt"),
    (("joint1", "friction", "pc"), "lots", "joint1", "friction.pc"),
    (("joint2", "box", "pc"), 2.0, "joint2", "box.pc"),
    (("joint2", "limits", "velocity_max"), -3.0, "joint2", "limits.velocity_max"),
    (("joint2", "angle"), "sideways", "joint2", "angle"),
    (("joint1", "motor", "torque"), 1.0, "joint1", "motor.torque"),
])
def test_bad_cell_values_name_joint_and_field(tmp_path, path, value, joint, field):
    cell = _scara_cell()
    d = cell["joints"]
    for k in path[:-1]:
        d = d.setdefault(k, {})
    d[path[-1]] = value
    err = _refused(_write(tmp_path, cell))
    assert err.joint == joint and err.field == field
    assert f"joint '{joint}'" in str(err) and field in str(err)


def test_missing_motor_value(tmp_path):
    cell = _scara_cell()
    del cell["joints"]["joint1"]["motor"]["gear"]
    err = _refused(_write(tmp_path, cell))
    assert (err.joint, err.field) == ("joint1", "motor.gear") and "missing" in str(err)


def test_joint_names_must_match(tmp_path):
    cell = _scara_cell()
    cell["joints"]["elbow"] = cell["joints"].pop("joint2")
    err = _refused(_write(tmp_path, cell))
    assert err.joint == "elbow" and "is not a joint of arm.urdf" in str(err)
    cell = _scara_cell()
    del cell["joints"]["joint2"]
    err = _refused(_write(tmp_path, cell))
    assert err.joint == "joint2" and "is missing" in str(err)


def test_prismatic_moving_joint_refused(tmp_path):
    text = (ARMS / "scara2.urdf").read_text().replace(
        '<joint name="joint2" type="revolute">', '<joint name="joint2" type="prismatic">')
    err = _refused(_write(tmp_path, _scara_cell(), text))
    assert (err.joint, err.field) == ("joint2", "type") and "prismatic" in str(err)


def test_missing_inertial_refused(tmp_path):
    text = (ARMS / "scara2.urdf").read_text()
    start = text.index('<link name="link2">')
    end = text.index("</link>", start) + len("</link>")
    text = text[:start] + '<link name="link2"/>' + text[end:]
    err = _refused(_write(tmp_path, _scara_cell(), text))
    assert err.joint == "joint2" and "<inertial>" in err.field


def test_non_parallel_axes_refused(tmp_path):
    text = (ARMS / "scara2.urdf").read_text()
    i = text.index('<joint name="joint2"')
    text = text[:i] + text[i:].replace('<axis xyz="0 0 1"/>', '<axis xyz="0 1 0"/>', 1)
    err = _refused(_write(tmp_path, _scara_cell(), text))
    assert (err.joint, err.field) == ("joint2", "axis") and "not parallel" in str(err)


def test_held_joint_is_locked(tmp_path):
    cell = _scara_cell()
    cell["joints"]["joint2"] = {"hold": "brake", "position": 0.5}
    arm = load_arm(_write(tmp_path, cell))
    assert arm.joints == ("joint1",) and arm.held == ("joint2",)
    A, B, C = inertia_constants(Scara2Params())
    # link 2 locked at 0.5 rad relative: J = A + C + 2·B·cos(0.5)
    np.testing.assert_allclose(arm.constants.mass_matrix(np.array([0.2])),
                               [[A + C + 2 * B * np.cos(0.5)]], rtol=1e-12)


def test_cell_file_errors_are_one_line(tmp_path):
    with pytest.raises(ArmConfigError, match="cannot be read"):
        load_cell(tmp_path / "nope.yaml")
    with pytest.raises(ArmConfigError) as info:
        cell_from_mapping({"joints": {"j": {"hold": "glue", "position": 0}}}, "c.yaml")
    assert (info.value.joint, info.value.field) == ("j", "hold")
    with pytest.raises(ArmConfigError) as info:
        cell_from_mapping({"joints": {"j": {"hold": "brake", "position": 0}}}, "c.yaml")
    assert "no moving joint" in str(info.value)
