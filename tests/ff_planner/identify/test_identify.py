"""Friction identification on simulated measurements: excitation, fit, intervals, mismatch flag."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ff_planner.core.errors import ParameterError
from ff_planner.identify import Envelope, RunRecord, design_excitation, fit_friction, load_records, save_records
from ff_planner.identify.fit import ljung_box
from ff_planner.identify.measure import FrictionMismatch, Sensors, measure_runs, record_trajectory, simulate_mismatch
from ff_planner.identify.output import params_yaml, summary, write_report
from ff_planner.identify.sampling import sample_params
from ff_planner.model.arm1dof import advance_core
from ff_planner.model.params import Arm1DofParams, load_params
from ff_planner.model.profile import CurrentProfile

BASE = Arm1DofParams()                     # table 2: the guess the user starts from
ENV = Envelope(q_min=-1.0, q_max=1.0, v_max=3.0)


@pytest.fixture(scope="module")
def excitation():
    return design_excitation(BASE, ENV, 0.0)


def _true(rng: np.random.Generator) -> Arm1DofParams:
    f = 1.0 + rng.uniform(-0.3, 0.3, 3)
    return BASE.replace(pv=BASE.pv * f[0], pc=BASE.pc * f[1], pt=BASE.pt * f[2])


def test_excitation_stays_in_envelope_and_ends_at_rest(excitation):
    runs = excitation.runs
    levels = sorted({round(r.level, 9) for r in runs})
    assert len(levels) == 4 and levels[-1] == pytest.approx(BASE.i_max)
    assert {r.direction for r in runs} == {1, -1}
    # currents both aid and oppose the motion within a run; each run ends with a zero-current coast
    for r in runs:
        assert r.profile.currents[0, 0] == -r.profile.currents[1, 0]
        assert r.profile.coast > 0.0
    # the runs chain (each starts where the previous stopped) and every corner of ±30 % stays inside
    q = 0.0
    for true in (BASE, BASE.replace(pc=0.7 * BASE.pc, pt=0.7 * BASE.pt, pv=1.3 * BASE.pv),
                 BASE.replace(pc=1.3 * BASE.pc, pt=1.3 * BASE.pt, pv=0.7 * BASE.pv)):
        q = 0.0
        for r in runs:
            t = np.linspace(0.0, r.profile.tf, 2000)
            qs, vs = sample_params(true, r.profile, q, t)
            assert ENV.q_min <= qs.min() and qs.max() <= ENV.q_max
            assert np.abs(vs).max() <= ENV.v_max
            assert vs[-1] == 0.0                     # at rest at the end of the run
            q = float(qs[-1])


def test_timing_margin_keeps_late_switches_inside():
    env = Envelope(-1.0, 1.0, 3.0, i_max=3.0)
    ex = design_excitation(BASE, env, 0.0, timing_margin=0.02)
    fast = BASE.replace(pc=0.7 * BASE.pc, pt=0.7 * BASE.pt, pv=1.3 * BASE.pv)     # least friction
    q = 0.0
    for r in ex.runs:
        st = r.profile.step_times.copy()
        st[1:] += 0.02                                      # the brake and the final zero 20 ms late
        late = CurrentProfile(st, r.profile.currents, r.profile.tf + 0.02, r.profile.coast)
        qs, vs = sample_params(fast, late, q, np.linspace(0.0, late.tf, 2000))
        assert env.q_min <= qs.min() and qs.max() <= env.q_max and np.abs(vs).max() <= env.v_max
        q = float(qs[-1])


def test_excitation_refuses_small_envelope():
    with pytest.raises(ParameterError, match="envelope too small"):
        design_excitation(BASE, Envelope(-0.01, 0.01, 3.0), 0.0)
    with pytest.raises(ParameterError, match="outside the envelope"):
        design_excitation(BASE, ENV, 2.0)
    with pytest.raises(ParameterError, match="breakaway"):
        design_excitation(BASE, Envelope(-1, 1, 3.0, i_max=0.2), 0.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fit_recovers_friction_with_honest_intervals(excitation, seed):
    rng = np.random.default_rng(seed)
    true = _true(rng)
    records = measure_runs(true, excitation.profiles, 0.0, Sensors(), rng)
    fit = fit_friction(records, BASE)
    assert fit.adequate, fit.message
    for k, tol in (("pc", 0.03), ("pt", 0.03), ("pv", 0.10)):
        tv = getattr(true, k)
        assert abs(fit.estimates[k] / tv - 1.0) < tol
        lo, hi = fit.interval95[k]
        assert lo <= tv <= hi
        assert lo < fit.estimates[k] < hi
    # the residual is the encoder's quantisation noise, nothing more
    assert fit.rms == pytest.approx(fit.sigma, rel=0.1)


def test_fit_with_inertia_free(excitation):
    rng = np.random.default_rng(7)
    true = _true(rng).replace(J=0.19)
    records = measure_runs(true, excitation.profiles, 0.0, Sensors(), rng)
    fit = fit_friction(records, BASE, fit_inertia=True)
    assert fit.adequate, fit.message
    assert abs(fit.estimates["J"] / 0.19 - 1.0) < 0.01
    for k in ("pv", "pc", "pt", "J"):       # one draw: within 3 standard errors (coverage below)
        assert abs(fit.estimates[k] - getattr(true, k)) < 3.0 * fit.std[k]


def test_interval_coverage_over_trials(excitation):
    """16 arms drawn within ±30 % of table 2: each 95 % interval may miss rarely, not often."""
    misses = dict.fromkeys(("pv", "pc", "pt"), 0)
    for seed in range(16):
        rng = np.random.default_rng(1000 + seed)
        true = _true(rng)
        fit = fit_friction(measure_runs(true, excitation.profiles, 0.0, Sensors(), rng), BASE)
        for k in misses:
            lo, hi = fit.interval95[k]
            misses[k] += not lo <= getattr(true, k) <= hi
    assert max(misses.values()) <= 2, misses


def _cogging_sim(true: Arm1DofParams, profile, q0: float, t: np.ndarray, depth: float) -> np.ndarray:
    """This test's own plant: Coulomb level pc·(1 + depth·sin(2π q / 0.25 rad)), held for 0.1 ms
    steps of the exact closed-form motion (depth 0 reproduces Eq. 9)."""
    c = true.torque_per_amp
    q, v, tt = q0, 0.0, 0.0
    out = np.full(t.size, q0)
    switches = sorted(float(s) for s in profile.step_times[1:]) + [math.inf]
    nxt = 0                                   # switches[nxt]: the first one after tt
    for k in np.nonzero(t > 0.0)[0]:
        while tt < t[k] - 1e-12:
            while switches[nxt] <= tt + 1e-12:
                nxt += 1
            tn = min(t[k], tt + 1e-4, switches[nxt])
            pc = true.pc * (1.0 + depth * math.sin(2.0 * math.pi * q / 0.25))
            q, v = advance_core(true.J, c, true.pv, pc, true.pt, q, v, profile.current_at(tt)[0], tn - tt)
            tt = tn
        out[k] = q
    return out


def _cogging_records(excitation, depth: float, rng):
    sens, out, q = Sensors(), [], 0.0
    for prof in excitation.profiles[:4]:
        t = np.arange(-sens.pre, prof.tf + 1e-12, sens.sample_period)
        qt = _cogging_sim(BASE, prof, q, t, depth)
        out.append(record_trajectory(t, qt, prof, BASE, sens, rng))
        q = float(qt[-1])
    return out


def test_model_mismatch_is_flagged(excitation):
    rng = np.random.default_rng(5)
    same = fit_friction(_cogging_records(excitation, 0.0, rng), BASE)     # the plant itself is fine
    assert same.adequate, same.message
    fit = fit_friction(_cogging_records(excitation, 0.2, rng), BASE)
    assert not fit.adequate
    assert "MODEL MISMATCH" in fit.message
    assert fit.tests["p_white"] < 1e-3 and fit.tests["p_chi2"] < 1e-3
    # no tight intervals claimed: wider than the well-modelled fit's by far
    for k in ("pv", "pc", "pt"):
        assert fit.half_width(k) > 20 * same.half_width(k)


def test_ljung_box_separates_white_from_correlated():
    rng = np.random.default_rng(0)
    white = rng.standard_normal(2000)
    walk = np.cumsum(white)
    assert ljung_box(white, 10) < 30.0 < ljung_box(walk, 10)


def test_outputs_round_trip(excitation, tmp_path):
    rng = np.random.default_rng(11)
    true = _true(rng)
    records = measure_runs(true, excitation.profiles[:4], 0.0, Sensors(), rng)
    path = tmp_path / "runs.json"
    save_records(path, records, BASE, {"truth": true.to_dict()})
    loaded, params, meta = load_records(path)
    assert len(loaded) == 4 and params == BASE and meta["truth"]["pc"] == true.pc
    np.testing.assert_array_equal(loaded[2].q, records[2].q)
    fit = fit_friction(loaded, params)
    d = summary(fit)
    json.dumps(d)
    assert set(d["estimates"]) == {"pv", "pc", "pt"} and len(d["interval95"]["pc"]) == 2
    assert all(b >= 0.02 for b in d["box"].values())
    yml = tmp_path / "params.yaml"
    yml.write_text(params_yaml(fit))
    p = load_params(yml)
    assert p.pc == pytest.approx(fit.estimates["pc"]) and p.J == BASE.J
    assert "uncertainty box" in yml.read_text()
    files = write_report(fit, tmp_path / "rep", truth=true.to_dict())
    assert files[1].stat().st_size > 10_000 and "95 % interval" in files[0].read_text()


def test_bad_records_are_refused(tmp_path):
    with pytest.raises(ParameterError, match="same length"):
        RunRecord(np.arange(20.0), np.zeros(19), np.zeros(20)).validate()
    bad = tmp_path / "x.json"
    bad.write_text("{}")
    with pytest.raises(ParameterError, match="ff-identify-records/1"):
        load_records(bad)


def test_mismatch_plant_steps_reproduce_eq9_when_switched_off(excitation):
    prof = excitation.profiles[0]
    t = np.linspace(0.0, prof.tf, 500)
    exact, _ = sample_params(BASE, prof, 0.1, t)
    stepped = simulate_mismatch(BASE, prof, 0.1, t, FrictionMismatch(step=1e-3))
    np.testing.assert_allclose(stepped, exact, atol=1e-9)
    # a Stribeck rise holds the arm longer at breakaway and stops it sooner
    strib = simulate_mismatch(BASE, prof, 0.1, t, FrictionMismatch(stribeck=0.5, step=1e-3))
    assert abs(strib[-1] - 0.1) < abs(exact[-1] - 0.1) - 1e-3


def test_stribeck_friction_is_flagged_and_no_tight_interval_is_claimed(excitation):
    rng = np.random.default_rng(8)
    good = fit_friction(measure_runs(BASE, excitation.profiles, 0.0, Sensors(), rng), BASE)
    assert good.adequate, good.message
    recs = measure_runs(BASE, excitation.profiles, 0.0, Sensors(), rng, mismatch=FrictionMismatch(stribeck=0.3))
    fit = fit_friction(recs, BASE)
    assert not fit.adequate and "MODEL MISMATCH" in fit.message and "widened" in fit.message
    assert fit.tests["p_white"] < 1e-3 and fit.tests["p_chi2"] < 1e-3
    for k in ("pv", "pc", "pt"):
        # Eq. 9 cannot match the arm; the estimate is off by more than the well-modelled fit's
        # interval, and the intervals say so: wide enough to hold the arm's sliding friction
        assert abs(fit.estimates[k] - getattr(BASE, k)) > 10 * good.half_width(k)
        lo, hi = fit.interval95[k]
        assert lo <= getattr(BASE, k) <= hi
        assert fit.half_width(k) > 100 * good.half_width(k)
    assert "WARNING" in params_yaml(fit)
