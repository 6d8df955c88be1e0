"""1-DOF planner: the compiled hot path's verification against the reference simulator, warm
starts (given starts only, honest start counts), the public solve_block entry, long moves."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model.arm1dof import derivatives
from ff_planner.model.params import preset
from ff_planner.model.profile import PlanningError, PlanRequest
from ff_planner.model.simulate import rest_position, simulate
from ff_planner.optimize.robust1d import plan_robust_1dof, solve_block, verify
from ff_planner.optimize.sample_box import FINITE_CHANGES

T2 = preset("table2")


def _q(params, prof):
    return simulate(params, prof, [0.0]).q_f[0]


def test_hot_path_verification_matches_the_reference_simulator(robust_plan_1dof):
    """The verification computed inside the compiled search = one recomputed from simulate(),
    rest_position() and derivatives() (the suite's reference entry points)."""
    prof = robust_plan_1dof.profile
    ver, fc = robust_plan_1dof.extra["verification"], robust_plan_1dof.extra["finite_change"]
    d = derivatives(T2, prof, 0.0)
    for k in ("pv", "pc", "pt"):
        p0 = getattr(T2, k)
        assert ver["exact"][k] == pytest.approx(d.dq_dp[k], abs=1e-15)
        h = 1e-6 * abs(p0)
        cen = (_q(T2.replace(**{k: p0 + h}), prof) - _q(T2.replace(**{k: p0 - h}), prof)) / (2 * h)
        assert ver["central"][k] == pytest.approx(cen, abs=1e-12)
        assert abs(cen) <= 1e-6
        fwd = (_q(T2.replace(**{k: p0 + 1e-3 * abs(p0)}), prof) - _q(T2, prof)) / (1e-3 * abs(p0))
        assert ver["forward_0.1%"][k] == pytest.approx(fwd, rel=1e-9, abs=1e-12)
        for ch in FINITE_CHANGES:
            pp = T2.replace(**{k: p0 * (1 + ch)})
            row = fc[k][f"{ch * 100:+.0f}%"]
            assert row["tf_error"] == pytest.approx(_q(pp, prof) - 1.0, abs=1e-12)
            assert row["rest_error"] == pytest.approx(rest_position(pp, prof, [0.0])[0] - 1.0,
                                                      abs=1e-12)
    pall = T2.replace(pv=T2.pv * 1.4, pc=T2.pc * 1.4, pt=T2.pt * 1.4)
    assert fc["all"]["+40%"]["tf_error"] == pytest.approx(_q(pall, prof) - 1.0, abs=1e-12)
    assert ver["q_tf"] == pytest.approx(_q(T2, prof), abs=1e-15) and ver["at_rest"]
    again = verify(T2, prof, 0.0, 1.0, ["pv", "pc", "pt"])
    assert again["robust"] and again["central"] == ver["central"]


def test_verify_refuses_what_is_not_robust():
    prof = plan_robust_1dof(PlanRequest(objective="robust-derivative", uncertain=("pc",), starts=500, seed=0)).profile
    assert verify(T2, prof, 0.0, 1.0, ["pc"])["robust"]
    assert not verify(T2, prof, 0.0, 1.1, ["pc"])["robust"]            # not at the goal
    assert not verify(T2, prof, 0.0, 1.0, ["pv"])["robust"]            # not robust to pv
    over = T2.replace(i_max=float(np.max(np.abs(prof.currents))) * 0.99)
    assert not verify(over, prof, 0.0, 1.0, ["pc"])["within_limits"]
    with pytest.raises(ValueError, match="unknown friction"):
        verify(T2, prof, 0.0, 1.0, ["mu"])


def test_warm_only_runs_exactly_the_given_starts(robust_plan_1dof):
    good = robust_plan_1dof.profile.currents          # (N, 1) as stored in a profile / motion file
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative",
                                     starts=50, seed=1), initial_currents=good, warm_only=True)
    assert r.success and r.robust and r.warm_start and r.starts_tried == 1
    assert r.extra["warm_starts"] == 1 and r.extra["warm_starts_ok"] == 1
    bad = np.full((2, 5), 0.01)           # two hopeless given starts: no random start follows
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative",
                                     starts=50, seed=1), initial_currents=bad, warm_only=True)
    assert not r.success and r.starts_tried == 2 and r.extra["warm_starts_ok"] == 0
    # several given starts: the good one after a bad one is found, and counted honestly
    both = np.vstack([bad[:1], good.reshape(1, -1)])
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative",
                                     starts=50, seed=1), initial_currents=both, warm_only=True)
    assert r.success and r.starts_tried == 2
    with pytest.raises(PlanningError, match="warm_only"):
        plan_robust_1dof(PlanRequest(objective="robust-derivative"), warm_only=True)
    patient = plan_robust_1dof(PlanRequest(objective="robust-derivative"), initial_currents=good, warm_only=True,
                               warm_settings=dict(max_iter=100, abandon_iter=100))
    assert patient.success and patient.starts_tried == 1
    with pytest.raises(PlanningError, match="warm_settings"):
        plan_robust_1dof(PlanRequest(objective="robust-derivative"), initial_currents=good, warm_settings={"zeal": 1})


def test_warm_starts_count_towards_the_requested_starts():
    bad = np.full(3, 0.01)
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative", uncertain=("pc",), qf=(7.0,), starts=5, seed=0),
                         initial_currents=bad)
    assert not r.success and r.starts_tried == 5        # 1 given + 4 random, not 1 + 5


def test_solve_block_public_entry():
    rng = np.random.default_rng(0)
    starts = rng.uniform(-3.0, 3.0, (32, 3))
    ends = solve_block(T2, 0.0, 1.0, 1.0, ("pc",), starts)
    assert len(ends) == 32 and {"currents", "ok", "status", "iterations", "residual2",
                                "kink_radius"} <= set(ends[0])
    oks = [e for e in ends if e["ok"]]
    assert oks and all(e["status"] == "ok" for e in oks)
    prof = plan_robust_1dof(PlanRequest(objective="robust-derivative", uncertain=("pc",), steps=3, starts=1),
                            initial_currents=oks[0]["currents"], warm_only=True)
    assert prof.success                     # an "ok" end point passes the full verification
    first = solve_block(T2, 0.0, 1.0, 1.0, ("pc",), starts, stop_first=True)
    assert first[-1]["ok"] and len(first) <= 32
    with pytest.raises(PlanningError):
        solve_block(T2, 0.0, 1.0, 1.0, ("pc",), np.full((2, 3), np.nan))


@pytest.mark.parametrize("name,goal", [("pc", 5.5), ("pv", 1.75), ("pt", 2.0)])
def test_long_moves_with_default_starts(name, goal):
    """Fig. 6: robust plans up to about the paper's thresholds with the default 50 starts;
    long moves saturate the middle current (held at the bound by the projected LM)."""
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative",
                                     qf=(goal,), uncertain=(name,), steps=3, starts=50, seed=0))
    assert r.success and r.robust
    assert np.max(np.abs(r.profile.currents)) <= T2.i_max


def test_beyond_the_threshold_no_robust_plan():
    r = plan_robust_1dof(PlanRequest(objective="robust-derivative",
                                     qf=(2.5,), uncertain=("pv",), steps=3, starts=200, seed=0))
    assert not r.success and r.error_code == "NO_ROBUST_PLAN" and r.best_effort
