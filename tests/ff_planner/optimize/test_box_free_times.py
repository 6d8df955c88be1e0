"""robust-box with free switch times: the compiled terms, the plans, the chosen N."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model.arm1dof import batch_core
from ff_planner.model.arm1dof_derivatives import Q_, V_, VC_, hd_sim, hd_sim_p, workspace
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import BOX_DEFAULT_STEPS, PlanRequest
from ff_planner.optimize.box_kernels import free_terms, free_values
from ff_planner.optimize.box_robust import MIN_STEP
from ff_planner.optimize.planner import plan
from ff_planner.optimize.robust1d import verify
from ff_planner.optimize.sample_box import box_corners, box_fractions

KEYS = ("pv", "pc", "pt")


def worst_over(result, scales: np.ndarray) -> float:
    """Largest |rest − 1 rad| of a 0 → 1 rad plan over friction scale factors (S, 3)."""
    p, prof = result.params, result.profile
    fr = np.ascontiguousarray(scales * np.array([p.pv, p.pc, p.pt]))
    q, _ = batch_core(p.J, p.n * p.kt, fr, np.ones(len(scales), bool), prof.step_times,
                      np.ascontiguousarray(prof.currents[:, 0]), prof.tf, 0.0)
    return float(np.max(np.abs(q - 1.0)))


def corner_worst(result) -> float:
    return worst_over(result, box_corners(box_fractions(KEYS), KEYS))


def test_parameter_rows_and_resumed_differences_repeat_the_full_simulation():
    """hd_sim_p's rows equal hd_sim's value and ∂/∂p columns; the switch-time columns of
    free_terms (resumed from the switch states) equal central differences of simulations from
    t = 0 to the last bit."""
    p = Arm1DofParams()
    nom = np.array([p.pv, p.pc, p.pt])
    times = np.array([0.0, 0.2, 0.45, 0.7, 0.9, 0.95])
    cur = np.array([-2.0, 6.0, 1.0, -5.0, 0.5])
    W, Wp = workspace(5), workspace(0)
    for to_rest in (False, True):
        k1 = hd_sim(p.J, p.n * p.kt, p.pv, p.pc, p.pt, times, cur, 1.0, 0.0, to_rest, nom, W)
        k2 = hd_sim_p(p.J, p.n * p.kt, p.pv, p.pc, p.pt, times, cur, 1.0, 0.0, to_rest, nom, Wp)
        assert k1 == k2
        for r in (Q_, V_, VC_):
            assert np.all(np.isfinite(Wp[r, :4])) and np.array_equal(W[r, :4], Wp[r, :4])
    scales = np.array([[0.8, 1.2, 1.2], [1.2, 0.8, 0.8], [1.0, 1.0, 1.0]])
    h = 1e-6
    _, Ge, _, _ = free_terms(p.J, p.n * p.kt, nom, np.abs(nom), scales, times, cur, 1.0, 0.0,
                             1.0, h, W)
    fr = np.ascontiguousarray(scales * nom)
    for j in range(1, 5):
        tp, tm = times.copy(), times.copy()
        tp[j] += h
        tm[j] -= h
        qp, _ = batch_core(p.J, p.n * p.kt, fr, np.ones(3, bool), tp, cur, 1.0, 0.0)
        qm, _ = batch_core(p.J, p.n * p.kt, fr, np.ones(3, bool), tm, cur, 1.0, 0.0)
        assert np.array_equal(Ge[:, 5 + j - 1], (qp - qm) / (2 * h))


def test_free_terms_match_the_simulator_and_its_derivatives():
    p = Arm1DofParams()
    nom = np.array([p.pv, p.pc, p.pt])
    times = np.array([0.0, 0.2, 0.45, 0.7, 0.95])
    cur = np.array([-2.0, 6.0, 1.0, -5.0])
    scales = np.array([[1.0, 1.0, 1.0], [0.8, 1.2, 0.9], [1.1, 0.85, 1.2]])
    W = workspace(4)
    e, Ge, g, Gg = free_terms(p.J, p.n * p.kt, nom, np.abs(nom), scales, times, cur, 1.0, 0.0,
                              1.0, 1e-6, W)
    e2, g2 = free_values(p.J, p.n * p.kt, nom, np.abs(nom), scales, times, cur, 1.0, 0.0, 1.0, W)
    assert np.allclose(e, e2, rtol=0, atol=1e-12) and np.array_equal(g, g2)
    q, _ = batch_core(p.J, p.n * p.kt, np.ascontiguousarray(scales * nom), np.ones(3, bool),
                      times, cur, 1.0, 0.0)
    assert np.allclose(e, q - 1.0, rtol=0, atol=1e-12)
    hd_sim(p.J, p.n * p.kt, p.pv, p.pc, p.pt, times, cur, 1.0, 0.0, False, np.abs(nom), W)
    assert g[0] == pytest.approx(W[Q_, 0] - 1.0, abs=1e-12)
    # switch-time columns against a wider central difference of the simulator
    for j in (1, 2, 3):
        h = 1e-5
        tp, tm = times.copy(), times.copy()
        tp[j] += h
        tm[j] -= h
        qp, _ = batch_core(p.J, p.n * p.kt, np.ascontiguousarray(scales * nom), np.ones(3, bool),
                           tp, cur, 1.0, 0.0)
        qm, _ = batch_core(p.J, p.n * p.kt, np.ascontiguousarray(scales * nom), np.ones(3, bool),
                           tm, cur, 1.0, 0.0)
        assert np.allclose(Ge[:, 4 + j - 1], (qp - qm) / (2 * h), rtol=1e-3, atol=1e-6)


def test_coast_column_matches_the_simulator_and_the_free_coast_stays_in_its_range():
    from ff_planner.optimize.box_kernels import end_column
    from ff_planner.optimize.box_robust import _FreeBox
    from ff_planner.optimize.robust1d import _Problem, stop_speed_bound

    p = Arm1DofParams()
    nom = np.array([p.pv, p.pc, p.pt])
    times = np.array([0.0, 0.2, 0.45, 0.7, 0.95])
    cur = np.array([-2.0, 6.0, 1.0, -5.0])
    scales = np.array([[1.0, 1.0, 1.0], [0.8, 1.2, 0.9], [1.1, 0.85, 1.2]])
    de, dg = end_column(p.J, p.n * p.kt, nom, np.abs(nom), scales, times, cur, 1.0, 0.0, 1.0,
                        1e-6, workspace(4))
    h = 1e-5
    tp, tm = times.copy(), times.copy()
    tp[4] += h
    tm[4] -= h
    fr = np.ascontiguousarray(scales * nom)
    qp, _ = batch_core(p.J, p.n * p.kt, fr, np.ones(3, bool), tp, cur, 1.0, 0.0)
    qm, _ = batch_core(p.J, p.n * p.kt, fr, np.ones(3, bool), tm, cur, 1.0, 0.0)
    assert np.allclose(de, (qp - qm) / (2 * h), rtol=1e-3, atol=1e-6)
    assert np.all(np.isfinite(dg)) and abs(dg[4]) > 0.0     # the coast-entry speed moves with t_N
    # the decision vector keeps t_N within [tf − coast_max, tf − coast] and the stopping bound
    # follows the coast
    prob = _Problem(PlanRequest(objective="robust-box", steps=4), p, 4)
    box = _FreeBox(prob, scales, (0.05, 0.2))
    x = box.start(cur, prob.times)
    assert x.shape == (2 * 4,) and x[-1] == pytest.approx(0.95)
    x[-1] = 0.5                                               # asks for a 0.5 s coast
    assert box.times(x)[4] == pytest.approx(0.8)              # held at tf − coast_max
    x[-1] = 0.85
    vb, dvb = box.stop_bound(x)
    assert vb == pytest.approx(stop_speed_bound(p, 0.15)) and dvb < 0.0


@pytest.fixture(scope="module")
def n5_plan():
    return plan(PlanRequest(objective="robust-box", steps=5, seed=0))


def test_n5_plan_with_free_step_durations_lands_within_30_mrad_over_the_box(n5_plan):
    r = n5_plan
    assert r.success and r.robust
    d = np.diff(r.profile.step_times)
    assert np.all(d >= MIN_STEP - 1e-12)
    assert r.profile.step_times[-1] == pytest.approx(1.0 - r.profile.coast, abs=1e-12)
    ver = verify(r.params, r.profile, 0.0, 1.0, KEYS)
    assert ver["robust"] and ver["max_abs_derivative"] <= 1e-6
    # equal steps at N = 5: 296 mrad at best (2000 LM starts per coast); from the equal-step LM
    # plans refined with free times 123-131 mrad; the global stage over step durations: ~24
    assert corner_worst(r) < 0.03
    rng = np.random.default_rng(778)
    sc = np.vstack([box_corners(box_fractions(KEYS), KEYS), rng.uniform(0.8, 1.2, (300, 3))])
    worst = worst_over(r, sc)
    assert worst <= 0.03 and worst <= 1.1 * r.certificate.worst_rest_error
    assert r.extra["step_durations"] == pytest.approx(d.tolist())


def test_robust_box_default_steps():
    assert PlanRequest(objective="robust-box").n_steps() == BOX_DEFAULT_STEPS
    assert PlanRequest(objective="robust-box", steps=6).n_steps() == 6
    assert PlanRequest().n_steps() == BOX_DEFAULT_STEPS          # robust-box is the default
    assert PlanRequest(objective="robust-derivative").n_steps() == 5
    assert PlanRequest(objective="robust-box", uncertain=("pc",)).n_steps() == BOX_DEFAULT_STEPS


def test_free_switch_times_go_on_a_grid():
    from ff_planner.library.gridded import on_grid
    from ff_planner.optimize.box_robust import plan_box_robust_1dof

    r = plan_box_robust_1dof(PlanRequest(objective="robust-box", steps=5, seed=1), grid=1e-3)
    assert r.success and r.robust
    assert on_grid(r.profile, 1e-3)
    assert corner_worst(r) < 0.2


def test_robust_box_chosen_steps_ladder():
    from ff_planner.optimize.planner import Route, plan_auto_1dof

    seen = []
    base = plan(PlanRequest(objective="robust-derivative", starts=200))    # a truly robust plan

    def fake(req, progress=None):
        seen.append(req.steps)
        out = base
        out.objective = "robust-box"
        out.extra = dict(base.extra, box_worst=0.004 if req.steps == 7 else 0.02)
        return out

    r = plan_auto_1dof(PlanRequest(objective="robust-box", steps=0), Route(fake, False))
    assert seen == [5, 6, 7]                     # from 2 + k up: stops within BOX_TARGET
    assert [t["steps"] for t in r.extra["auto"]["tried"]] == [5, 6, 7]
    assert r.extra["auto"]["box_target_met"] and "tried N=5" in r.message
    # steps unset (the default): N = BOX_DEFAULT_STEPS, raised only while no truly robust plan is found
    seen.clear()
    r = plan_auto_1dof(PlanRequest(objective="robust-box"), Route(fake, False))
    assert seen == [BOX_DEFAULT_STEPS] and not r.extra["auto"]["box_target_met"]


def test_continuation_in_steps_keeps_a_verified_plan_and_never_worsens(n5_plan):
    from ff_planner.optimize.box_robust import continue_steps

    req = PlanRequest(objective="robust-box", steps=5, seed=0)
    start = n5_plan.extra["box_worst"]
    r = continue_steps(req, n5_plan, n_max=6, target=0.0)
    rows = r.extra["continuation"]
    assert [row["steps"] for row in rows] == [6]
    assert rows[0]["splits_ranked"] >= 1
    assert r.success and r.robust and r.extra["box_worst"] <= start
    ver = verify(r.params, r.profile, 0.0, 1.0, KEYS)
    assert ver["robust"] and ver["max_abs_derivative"] <= 1e-6
    # the split of a step is the same profile: the continuation starts from its start's worst
    assert rows[0]["box_worst"] <= start + 1e-12
    assert corner_worst(r) <= r.extra["box_worst"] + 1e-9
    if r.profile.n_steps == 6:
        assert np.all(np.diff(r.profile.step_times) >= MIN_STEP - 1e-12)
