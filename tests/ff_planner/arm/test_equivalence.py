"""The shipped 1-DOF and SCARA URDFs (config/arms/) reproduce the hand-written models
(``arm1dof``: closed form; ``scara2``: its own compiled integrator) on the paper's section 4 plans:
trajectories, final states and rest positions to 1e-9 rad, rest-position sensitivities to the
friction parameters likewise (relative to their size)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ff_planner.arm import sim
from ff_planner.arm.model import load_arm
from ff_planner.model import arm1dof, scara2
from ff_planner.model.params import Arm1DofParams, Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanRequest
from ff_planner.optimize.planner import plan

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"
TOL = 1e-9
SIX = ("pv1", "pc1", "pt1", "pv2", "pc2", "pt2")


@pytest.fixture(scope="module")
def plans_1dof() -> list[CurrentProfile]:
    """Section 4.1: 0 -> 1 rad in 1 s, robust-derivative (N = 5) and robust-box plans."""
    out = []
    for objective in ("robust-derivative", "robust-box"):
        r = plan(PlanRequest(objective=objective, model="arm1dof", q0=(0.0,), qf=(1.0,), tf=1.0))
        assert r.profile is not None
        out.append(r.profile)
    return out


@pytest.fixture(scope="module")
def plan_scara() -> CurrentProfile:
    """Section 4.2: [-0.5, 0] -> [0.5, 0] rad in 1 s, all six parameters, N = 8."""
    r = plan(PlanRequest(objective="robust-derivative", model="scara2", q0=(-0.5, 0.0),
                         qf=(0.5, 0.0), tf=1.0, uncertain=SIX, starts=32, seed=0, time_budget=60))
    assert r.profile is not None and r.success
    return r.profile


def _moving_scara_profile() -> CurrentProfile:
    """A profile that moves both links, with stick/slip events on both joints."""
    cur = np.array([[1.04, 0.30], [1.04, 0.30], [-0.61, 0.04], [-0.61, 0.04], [0.3, -0.2]])
    return CurrentProfile.uniform(cur, 1.0, 0.05)


def test_1dof_urdf_reproduces_arm1dof(plans_1dof):
    arm = load_arm(ARMS / "arm1dof.cell.yaml")
    p = Arm1DofParams()
    for prof in plans_1dof:
        s = sim.simulate(arm, prof, [0.0], record=True)
        ref = arm1dof.simulate_arm1dof(p, prof, 0.0)
        assert abs(s.q_f[0] - ref.q_f[0]) < TOL and abs(s.qd_f[0] - ref.qd_f[0]) < TOL
        rest = arm1dof.rest_position_arm1dof(p, prof, 0.0)
        assert s.q_rest is not None and abs(s.q_rest[0] - rest[0]) < TOL
        # the trajectory at every substep and event of the URDF arm, against the exact segments
        assert s.t is not None and s.q is not None
        times = np.ascontiguousarray(prof.step_times, float)
        cur = np.ascontiguousarray(prof.currents[:, 0], float)
        cap = 3 * (len(cur) + 3) + 4
        seg = np.zeros((cap, 7))
        _, _, nseg, _ = arm1dof.sim_core(p.J, p.n * p.kt, p.pv, p.pc, p.pt, times, cur, prof.tf,
                                         0.0, 0.0, False, seg, np.zeros((0, 3)))
        inside = s.t <= prof.tf
        q_exact, _ = arm1dof.eval_segments(seg, min(nseg, cap), s.t[inside])
        assert inside.sum() > 900
        assert np.max(np.abs(s.q[inside, 0] - q_exact)) < TOL
        # rest-position sensitivities: complex step through the URDF arm vs the exact forward mode
        d = arm1dof.derivatives(p, prof, 0.0, to_rest=True)
        S = sim.rest_sensitivities(arm, prof, [0.0])
        for k_, name in enumerate(("pv", "pc", "pt")):
            assert abs(S[0, 0, k_] - d.dq_dp[name]) <= TOL * max(1.0, abs(d.dq_dp[name]))


@pytest.mark.parametrize("which", ["planned", "both-moving"])
def test_scara_urdf_reproduces_scara2(plan_scara, which):
    arm = load_arm(ARMS / "scara2.cell.yaml")
    p = Scara2Params()
    prof, q0 = (plan_scara, [-0.5, 0.0]) if which == "planned" else (_moving_scara_profile(), [0.0, 0.0])
    s = sim.simulate(arm, prof, q0, record=True)
    ref = scara2.simulate_detail(p, prof, q0, trajectory=True, settle=True)
    assert s.n_events == ref.n_events
    assert np.max(np.abs(s.q_f - ref.q_f)) < TOL and np.max(np.abs(s.qd_f - ref.qd_f)) < TOL
    assert s.q_rest is not None and ref.q_rest is not None
    assert np.max(np.abs(s.q_rest - ref.q_rest)) < TOL
    assert s.t is not None and s.q is not None and ref.t is not None and ref.q is not None
    assert s.t.shape == ref.t.shape and np.max(np.abs(s.t - ref.t)) < 1e-12
    assert np.max(np.abs(s.q - ref.q)) < TOL
    if which == "planned":
        sens = scara2.sensitivities_scara2(p, prof, q0, SIX, rest=True)
        S = sim.rest_sensitivities(arm, prof, q0)
        for j in range(2):
            for k, name in enumerate(("pv", "pc", "pt")):
                key = f"{name}{j + 1}"
                for i in range(2):
                    want = sens[f"qrest{i + 1}/{key}"]
                    assert abs(S[i, j, k] - want) <= TOL * max(1.0, abs(want)), (i, key)
