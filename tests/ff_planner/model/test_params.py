"""Model parameters: presets match the paper's tables, YAML loading, clear errors."""
from __future__ import annotations

import math

import pytest

from ff_planner.model.friction import breakaway_torque, breaks_away, friction_torque
from ff_planner.model.params import (Arm1DofParams, ParameterError, Scara2Params, default_params,
                                     friction_scaled, load_params, n_joints, preset)


def test_presets_are_the_papers_tables():
    t2 = preset("table2")
    assert (t2.J, t2.kt, t2.n, t2.i_max, t2.pv, t2.pc, t2.pt) == (0.17, 0.0267, 54.0, 10.0, -0.05, 0.19, 0.22)
    t1 = preset("table1")
    assert (t1.pv, t1.pc, t1.pt) == (0.0, 0.19, 0.0)
    t3 = preset("table3")
    assert (t3.pc1, t3.pc2, t3.n2, t3.kt2, t3.lc2, t3.Jc2) == (0.19, 0.60, 198.0, 0.0281, 0.33, 0.178)
    assert default_params("scara2") == t3 and n_joints("scara2") == 2 and n_joints("arm1dof") == 1
    # the breakaway current of the table 2 arm: pc / (n·kt·(1 − pt)) ≈ 0.169 A
    assert breakaway_torque(t2.pc, t2.pt) / t2.torque_per_amp == pytest.approx(0.1689, abs=1e-4)


def test_replace_refuses_unknown_and_non_finite():
    p = Arm1DofParams()
    with pytest.raises(ParameterError, match="valid keys are"):
        p.replace(pc2=0.1)
    with pytest.raises(ParameterError, match="finite"):
        p.replace(pc=math.nan)
    with pytest.raises(ParameterError, match="> 0"):
        p.replace(J=0.0)
    with pytest.raises(ParameterError, match="number"):
        p.replace(pc="lots")
    assert p.pc == 0.19  # unchanged


def test_load_params_from_yaml(tmp_path):
    f = tmp_path / "arm.yaml"
    f.write_text("model: scara2\npreset: table3\nparams: {pc2: 0.7, m2: 2.0}\n")
    p = load_params(f)
    assert isinstance(p, Scara2Params) and p.pc2 == 0.7 and p.m2 == 2.0 and p.pc1 == 0.19
    f.write_text("model: arm1dof\npreset: table3\n")
    with pytest.raises(ParameterError, match="is for model 'scara2'"):
        load_params(f)
    f.write_text("model: arm1dof\nfriction: {}\n")
    with pytest.raises(ParameterError, match="unexpected key"):
        load_params(f)
    assert load_params({"model": "arm1dof"}) == preset("table2")


def test_friction_scaled():
    p = friction_scaled(preset("table2"), {"pc": 1.2, "pt": 0.5})
    assert p.pc == pytest.approx(0.228) and p.pt == pytest.approx(0.11) and p.pv == -0.05
    with pytest.raises(ParameterError):
        friction_scaled(preset("table2"), {"pc1": 1.1})


def test_eq9_branches():
    pv, pc, pt = -0.05, 0.19, 0.22
    # sliding: viscous + sign(qd) (pc + pt |T|)
    assert friction_torque(2.0, 5.0, pv, pc, pt) == pytest.approx(-0.1 + 0.19 + 1.1)
    assert friction_torque(-2.0, 5.0, pv, pc, pt) == pytest.approx(0.1 - 0.19 - 1.1)
    # sticking: friction balances a small torque exactly, saturates at pc + pt|T|
    assert friction_torque(0.0, 0.1, pv, pc, pt) == pytest.approx(0.1)
    assert friction_torque(0.0, -1.0, pv, pc, pt) == pytest.approx(-(0.19 + 0.22))
    assert friction_torque(0.0, 0.0, pv, pc, pt) == 0.0
    assert not breaks_away(0.24, pc, pt) and breaks_away(0.25, pc, pt)
