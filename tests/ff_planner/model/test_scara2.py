"""2-DOF SCARA model: equations of motion, stick/slip simulation accuracy, sensitivities."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ff_planner.model import scara2
from ff_planner.model.params import Arm1DofParams, ParameterError, Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanningError

P = Scara2Params()
Q0 = np.array([-0.5, 0.0])
# a generic profile: both joints move, reverse and stick (5 stick/reverse events)
GENERIC = CurrentProfile.uniform([[3, 1], [-2, 0.5], [1, -1], [0, 0.2]], 1.0)


def test_mass_matrix_matches_kinetic_energy():
    """M from the docs equals the Hessian of the kinetic energy computed from link velocities."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(-3, 3, 2)
        w = rng.normal(size=2)
        # kinetic energy from first principles (absolute angles, COM velocities)
        v1 = P.lc1 * w[0]
        v2 = (np.array([-P.l1 * math.sin(q[0]), P.l1 * math.cos(q[0])]) * w[0]
              + np.array([-P.lc2 * math.sin(q[1]), P.lc2 * math.cos(q[1])]) * w[1])
        ke = 0.5 * (P.Jc1 + P.m1 * 0) * w[0] ** 2 + 0.5 * P.m1 * v1 ** 2 \
            + 0.5 * P.m2 * v2 @ v2 + 0.5 * P.Jc2 * w[1] ** 2
        M = scara2.mass_matrix(P, q)
        assert 0.5 * w @ M @ w == pytest.approx(ke, rel=1e-12)


def test_forward_dynamics_energy_balance():
    """Without friction, d/dt kinetic energy = motor power (checks the Coriolis terms)."""
    p = P.replace(pv1=0.0, pv2=0.0, pc1=0.0, pc2=0.0, pt1=0.0, pt2=0.0)
    rng = np.random.default_rng(1)
    for _ in range(5):
        q, w, cur = rng.uniform(-2, 2, 2), rng.uniform(-3, 3, 2), rng.uniform(-5, 5, 2)
        a = scara2.forward_dynamics(p, q, w, cur)
        A, B, C = scara2.inertia_constants(p)
        c, s = math.cos(q[0] - q[1]), math.sin(q[0] - q[1])
        M = np.array([[A, B * c], [B * c, C]])
        dM = np.array([[0, -B * s], [-B * s, 0]]) * (w[0] - w[1])
        dke = w @ M @ a + 0.5 * w @ dM @ w
        T = np.array([p.n1 * p.kt1 * cur[0], p.n2 * p.kt2 * cur[1]])
        assert dke == pytest.approx(T @ w, rel=1e-10, abs=1e-10)


def test_link2_held_is_exact_1dof_joint1():
    """Link 2 held by stiction: joint 1 follows the exact 1-DOF model with J = A (arm1dof)."""
    from ff_planner.model import arm1dof
    from ff_planner.optimize.hold_joint import joint2_hold_currents

    prof1 = CurrentProfile.uniform([[4.0], [-1.0], [-4.0]], 0.6)
    i2, frac = joint2_hold_currents(P, prof1, Q0)
    assert frac > 0.1
    prof = CurrentProfile(prof1.step_times, np.column_stack([prof1.currents[:, 0], i2]), 0.6)
    sim = scara2.simulate_detail(P, prof, Q0)
    assert sim.q_f[1] == 0.0 and sim.qd_f[1] == 0.0       # link 2 never moved
    p1 = Arm1DofParams(J=scara2.held_joint1_inertia(P), kt=P.kt1, n=P.n1, pv=P.pv1, pc=P.pc1,
                       pt=P.pt1)
    q1, v1 = arm1dof.final_state(p1, CurrentProfile(prof.step_times, prof.currents[:, :1],
                                                    prof.tf, prof.coast), Q0[0])
    assert sim.q_f[0] == pytest.approx(q1, abs=1e-12)
    assert sim.qd_f[0] == pytest.approx(v1, abs=1e-12)


def test_convergence_under_step_refinement():
    """4th-order convergence; at the default 1 ms substep the final state is within 1e-9."""
    ref = scara2.simulate_detail(P, GENERIC, Q0, h=1.25e-4)
    errs = []
    for h in (4e-3, 2e-3, 1e-3):
        s = scara2.simulate_detail(P, GENERIC, Q0, h=h)
        assert s.n_events == ref.n_events
        errs.append(np.max(np.abs(np.r_[s.q_f - ref.q_f, s.qd_f - ref.qd_f])))
    assert errs[-1] < 1e-9
    assert errs[0] > errs[1] > errs[2] or errs[0] < 1e-12


def test_sticking_and_breakaway_thresholds():
    """A joint alone below its breakaway current stays put; above it moves (Eq. 9)."""
    brk2 = P.pc2 / (1 - P.pt2) / (P.n2 * P.kt2)    # A
    for frac, moves in ((0.95, False), (1.05, True)):
        prof = CurrentProfile.uniform([[0.0, frac * brk2]], 0.2, coast=0.0)
        s = scara2.simulate_detail(P, prof, Q0)
        assert (abs(s.q_f[1]) > 0) == moves
        # joint 1 alone is pushed by the reaction of link 2 only when that exceeds its stiction
    # a stuck joint 1 feels link 2's reaction: huge motor-2 current breaks joint 1 loose
    s = scara2.simulate_detail(P, CurrentProfile.uniform([[0.0, 10.0]], 0.2, coast=0.0),
                               np.array([0.0, 0.0]))
    assert abs(s.q_f[0]) > 1e-3


def test_complex_step_matches_central_differences():
    cs = scara2.sensitivities_scara2(P, GENERIC, Q0, method="complex")
    fd = scara2.sensitivities_scara2(P, GENERIC, Q0, method="central", rel_step=1e-5)
    assert set(cs) == set(fd)
    assert len([k for k in cs if k.startswith("q") and not k.startswith("qd")]) == 12
    for k in cs:
        assert cs[k] == pytest.approx(fd[k], abs=1e-6 + 1e-6 * abs(cs[k])), k
    assert max(abs(v) for v in cs.values()) > 0.1       # a non-robust profile: nonzero


def test_advance_matches_simulation():
    """advance() in 1 ms pieces reproduces the whole-profile simulation (same model)."""
    prof = CurrentProfile.uniform([[3, 1], [-2, 0.5]], 0.2, coast=0.0)
    q, qd = Q0.copy(), np.zeros(2)
    for k in range(200):
        t = k * 1e-3
        q, qd = scara2.advance(P, q, qd, prof.current_at(t + 1e-9), 1e-3)
    s = scara2.simulate_detail(P, prof, Q0)
    assert np.allclose(q, s.q_f, atol=1e-9) and np.allclose(qd, s.qd_f, atol=1e-8)


def test_simulate_dispatch_and_rest_position():
    from ff_planner.core.results import SimResult
    from ff_planner.model.simulate import rest_position, simulate

    r = simulate(P, GENERIC, Q0, trajectory=True)
    assert isinstance(r, SimResult) and r.q.shape[1] == 2 and r.t[0] == 0.0
    assert any(kind.startswith("stick") for _, kind in r.events)
    rest = rest_position(P, GENERIC, Q0)
    assert rest.shape == (2,) and np.all(np.isfinite(rest))
    assert abs(rest[0] - r.q_f[0]) > 1e-3          # still moving at tf: rests later


def test_bad_input_is_refused_clearly():
    with pytest.raises(PlanningError, match="2 joints"):
        scara2.simulate_scara2(P, CurrentProfile.uniform([1.0], 1.0), Q0)
    with pytest.raises(PlanningError, match="finite"):
        scara2.simulate_scara2(P, GENERIC, [math.nan, 0.0])
    with pytest.raises(ParameterError, match="unknown friction"):
        scara2.sensitivities_scara2(P, GENERIC, Q0, names=["pq1"])
    with pytest.raises(PlanningError, match="dt"):
        scara2.advance(P, Q0, [0, 0], [0, 0], -1.0)


def test_held_link2_derivatives_match_exact_1dof():
    """Complex-step derivatives through the 2-DOF integrator equal arm1dof's exact forward-mode
    derivatives of joint 1 (link 2 held), w.r.t. friction and currents."""
    from ff_planner.model import arm1dof
    from ff_planner.optimize.hold_joint import joint1_params, joint2_hold_currents

    prof1 = CurrentProfile.uniform([[4.0], [-1.0], [-4.0]], 0.6)
    i2, frac = joint2_hold_currents(P, prof1, Q0)
    prof = CurrentProfile(prof1.step_times, np.column_stack([prof1.currents[:, 0], i2]), 0.6)
    cs = scara2.sensitivities_scara2(P, prof, Q0, names=("pv1", "pc1", "pt1"))
    d = arm1dof.derivatives(joint1_params(P), prof1, Q0[0])
    for k in ("pv", "pc", "pt"):
        assert cs[f"q1/{k}1"] == pytest.approx(d.dq_dp[k], rel=1e-8, abs=1e-11)
        assert cs[f"q2/{k}1"] == 0.0
    # w.r.t. the joint-1 currents: complex step through the full model
    dI = scara2.current_sensitivities_scara2(P, prof, Q0)
    for i in range(prof.n_steps):
        assert dI[i, 0, 0] == pytest.approx(d.dq_dI[i], rel=1e-8, abs=1e-11)
