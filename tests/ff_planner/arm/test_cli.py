"""ff-plan --cell (ff_planner.cli.plan hands it to ff_planner.cli.plan_urdf): a plan for the
1-DOF arm from its URDF, and one-line refusals of bad input."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from ff_planner.arm import sim
from ff_planner.arm.model import load_arm
from ff_planner.cli.plan_urdf import main
from ff_planner.model import arm1dof
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"


def test_plans_the_1dof_arm_from_its_urdf(tmp_path):
    out = tmp_path / "plan.json"
    rc = main(["--cell", str(ARMS / "arm1dof.cell.yaml"), "--q0", "0", "--qf", "1", "--tf", "1",
               "--time-budget", "30", "-o", str(out)])
    assert rc == 0
    d = json.loads(out.read_text())
    assert d["joints"] == ["joint1"] and d["label"] == "zero-derivative"
    cert = d["certificate"]
    assert len(cert["worst_per_joint"]) == 1 and cert["samples"] >= 8 + 1 + 6 + 128
    prof = CurrentProfile(np.array(d["step_times"]), np.array(d["currents"]), d["tf"], d["coast"])
    # the hand-written 1-DOF model agrees on the plan's rest position (the goal) and on its
    # certified worst case at the box corner the certificate names
    p = Arm1DofParams()
    assert abs(arm1dof.rest_position_arm1dof(p, prof, 0.0)[0] - 1.0) < 1e-6
    at = cert["worst_at"]
    pw = p.replace(pv=p.pv * at["pv@joint1"], pc=p.pc * at["pc@joint1"], pt=p.pt * at["pt@joint1"])
    worst_1dof = abs(arm1dof.rest_position_arm1dof(pw, prof, 0.0)[0] - 1.0)
    assert abs(worst_1dof - cert["worst_rest_error"]) < 1e-8
    arm = load_arm(ARMS / "arm1dof.cell.yaml")
    assert abs(sim.rest_position(arm, prof, [0.0])[0] - 1.0) < 1e-6


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "bad.cell.yaml"
    text = (ARMS / "arm1dof.cell.yaml").read_text().replace("i_max: 10.0", "i_max: -3")
    bad.write_text(text.replace("urdf: arm1dof.urdf", f"urdf: {ARMS / 'arm1dof.urdf'}"))
    proc = subprocess.run([sys.executable, "-m", "ff_planner.cli.plan", "--cell", str(bad),
                           "--q0", "0", "--qf", "1"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "joint 'joint1'" in lines[0] and "motor.i_max" in lines[0]
    proc = subprocess.run([sys.executable, "-m", "ff_planner.cli.plan", "--cell",
                           str(ARMS / "arm1dof.cell.yaml"), "--q0", "0,0", "--qf", "1"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
