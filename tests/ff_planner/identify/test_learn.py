"""Learning from use: the friction update from the rest positions of executed motions (no ROS)."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.core.errors import ParameterError
from ff_planner.identify import Envelope, design_excitation, fit_friction
from ff_planner.identify.learn import (
    Execution,
    Prior,
    load_prior,
    parse_executions,
    prior_from_box,
    prior_from_fit,
    rest_and_gradient,
    rest_gradient_central,
    update_from_executions,
)
from ff_planner.identify.measure import Sensors, measure_rest, measure_runs
from ff_planner.identify.output import params_yaml
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize import plan

BASE = Arm1DofParams()                               # table 2: the current estimate
KEYS = ("pv", "pc", "pt")
#: a prior as wide as an identification on the loaded stack gives (pv ±30 %, pc and pt ±5 %)
PRIOR = prior_from_box(BASE, {"pv": 0.3, "pc": 0.05, "pt": 0.05})
#: (objective, q0 rad, qf rad, tf s) of the executed baseline motions
BASELINES = [("energy-optimal", 0.0, 1.0, 1.0), ("energy-optimal", 1.0, 0.2, 0.6),
             ("time-optimal", 0.2, -0.6, 0.8), ("energy-optimal", -0.6, 0.9, 1.5),
             ("time-optimal", 0.9, 0.0, 0.5)]
ROBUST = [(0.0, 1.0, 1.0), (0.2, -0.6, 0.8), (-0.6, 0.9, 1.5)]
NOISE = 8e-5                                          # rad rms besides the encoder quantum


def _profile(objective: str, q0: float, qf: float, tf: float):
    res = plan(PlanRequest(q0=(q0,), qf=(qf,), tf=tf, objective=objective, starts=10, params=BASE))
    assert res.profile is not None and res.success, res.message
    return res


@pytest.fixture(scope="module")
def baseline_profiles():
    return [(_profile(o, q0, qf, tf).profile, q0, f"{o} {q0}->{qf}") for o, q0, qf, tf in BASELINES]


@pytest.fixture(scope="module")
def robust_profiles():
    out = []
    for q0, qf, tf in ROBUST:
        res = _profile("robust-derivative", q0, qf, tf)
        assert res.robust
        out.append((res.profile, q0, f"robust {q0}->{qf}"))
    return out


def _executions(true: Arm1DofParams, profiles, rng) -> list[Execution]:
    return [Execution(prof, q0, measure_rest(true, prof, q0, rng, Sensors(), NOISE), 1e-4, name)
            for prof, q0, name in profiles]


def test_rest_sensitivities_are_the_simulated_rest_positions_derivatives(baseline_profiles):
    for prof, q0, name in baseline_profiles:
        ex = Execution(prof, q0, 0.0, 1e-4, name)
        _, g = rest_and_gradient(BASE, ex)
        np.testing.assert_allclose(g, rest_gradient_central(BASE, ex), rtol=1e-4, atol=1e-7)
        assert np.abs(g).max() > 0.3                 # a baseline's rest position moves with friction


def test_update_moves_a_biased_prior_to_the_truth(baseline_profiles):
    true = BASE.replace(pv=1.15 * BASE.pv, pc=1.03 * BASE.pc, pt=0.97 * BASE.pt)   # 1-1.2 sigma off
    res = update_from_executions(PRIOR, _executions(true, baseline_profiles, np.random.default_rng(4)))
    assert res.adequate and res.converged, res.message
    for i, k in enumerate(KEYS):
        tv = getattr(true, k)
        assert abs(res.estimates[k] - tv) < 0.2 * abs(PRIOR.mean[i] - tv)
        lo, hi = res.interval95[k]
        assert lo <= tv <= hi
        assert res.std[k] < 0.2 * PRIOR.std[i]
    assert all(e.information_bits > 3.0 for e in res.executions)
    assert all(abs(e.residual_z) < 4.0 for e in res.executions)
    assert res.information_bits > 15.0


def test_intervals_cover_the_truth_over_trials(baseline_profiles):
    """20 arms drawn from the prior: each 95 % interval may miss now and then, not often."""
    rng = np.random.default_rng(11)
    misses = dict.fromkeys(KEYS, 0)
    for _ in range(20):
        x = rng.multivariate_normal(PRIOR.mean, PRIOR.cov)
        true = BASE.replace(**dict(zip(KEYS, x)))
        res = update_from_executions(PRIOR, _executions(true, baseline_profiles, rng))
        for k in KEYS:
            lo, hi = res.interval95[k]
            misses[k] += not lo <= getattr(true, k) <= hi
    assert max(misses.values()) <= 3, misses


@pytest.mark.parametrize("scale", [(1.02, 0.995, 1.004), (1.15, 0.975, 1.025)])    # 0.1 and ~1 sigma off
def test_robust_motions_carry_almost_no_information(robust_profiles, baseline_profiles, scale):
    true = BASE.replace(pv=scale[0] * BASE.pv, pc=scale[1] * BASE.pc, pt=scale[2] * BASE.pt)
    rng = np.random.default_rng(5)
    res = update_from_executions(PRIOR, _executions(true, robust_profiles, rng))
    assert all(e.information_bits < 0.01 for e in res.executions)
    assert all(max(abs(v) for v in e.sensitivity.values()) < 1e-3 for e in res.executions)
    for i, k in enumerate(KEYS):               # the estimate stays where it was, as uncertain
        assert abs(res.estimates[k] - PRIOR.mean[i]) < 0.05 * PRIOR.std[i]
        assert res.std[k] > 0.95 * PRIOR.std[i]
    base = update_from_executions(PRIOR, _executions(true, baseline_profiles[:3], rng))
    assert min(e.information_bits for e in base.executions) > 100 * max(e.information_bits for e in res.executions)


def test_prior_from_an_identification_file_round_trips(tmp_path):
    ex = design_excitation(BASE, Envelope(-1.0, 1.0, 3.0), 0.0, n_levels=2)
    rng = np.random.default_rng(2)
    fit = fit_friction(measure_runs(BASE.replace(pc=0.2), ex.profiles, 0.0, Sensors(), rng), BASE)
    path = tmp_path / "p.yaml"
    path.write_text(params_yaml(fit))
    prior = load_prior(path)
    assert prior.source == "covariance"
    np.testing.assert_allclose(prior.mean, [fit.estimates[k] for k in KEYS], rtol=1e-12)
    # the written covariance states the fit's 95 % intervals
    np.testing.assert_allclose(1.96 * prior.std, [fit.half_width(k) for k in KEYS], rtol=2e-3)
    np.testing.assert_allclose(prior.cov, prior_from_fit(fit).cov, rtol=1e-5, atol=1e-30)
    # without the covariance line: the interval lines give a diagonal covariance
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("# covariance")]
    path.write_text("\n".join(lines) + "\n")
    diag = load_prior(path)
    assert diag.source.startswith("intervals")
    np.testing.assert_allclose(np.diag(diag.cov), np.diag(prior.cov), rtol=1e-4)
    assert np.count_nonzero(diag.cov - np.diag(np.diag(diag.cov))) == 0


def test_a_file_without_uncertainty_needs_a_box(tmp_path):
    path = tmp_path / "plain.yaml"
    path.write_text("model: arm1dof\npreset: table2\nparams: {pc: 0.2}\n")
    with pytest.raises(ParameterError, match="--prior-box"):
        load_prior(path)
    prior = load_prior(path, {"pv": 0.3, "pc": 0.1, "pt": 0.1})
    assert prior.mean[1] == 0.2 and prior.std[1] == pytest.approx(0.1 * 0.2 / 1.959964)
    with pytest.raises(ParameterError, match="missing pt"):
        prior_from_box(BASE, {"pv": 0.3, "pc": 0.1})
    with pytest.raises(ParameterError, match="positive definite"):
        Prior(BASE, np.diag([1e-4, 0.0, 1e-4])).validate()


@pytest.mark.parametrize("data, msg", [
    ([], "non-empty JSON list"),
    ({"runs": []}, "non-empty JSON list"),
    ([{"motion": {"step_times": [0, 0.5], "currents": [1.0], "tf": 0.6, "q0": 0}}], "rest_position"),
    ([{"motion": {"step_times": [0, 0.5], "currents": [1.0], "tf": 0.6, "q0": 0}, "rest_position": "x"}],
     "rest_position must be a finite number"),
    ([{"motion": {"step_times": [0, 0.5], "currents": [1.0], "tf": 0.6, "q0": 0}, "rest_position": 0.1,
       "q_sigma": -1}], "q_sigma must be > 0"),
    ([{"motion": {"step_times": [0, 0.5], "currents": [1.0], "tf": 0.6}, "rest_position": 0.1}],
     "needs the execution's q0"),
    ([{"motion": {"currents": [1.0], "tf": 0.6, "q0": 0}, "rest_position": 0.1}], "missing 'step_times'"),
    ([{"motion": "m.json", "rest_position": 0.1}], "motion loader"),
    ([3], "must be an object"),
])
def test_malformed_executions_are_refused_clearly(data, msg):
    with pytest.raises(ParameterError, match=msg) as info:
        parse_executions(data)
    assert len(str(info.value).splitlines()) == 1


def test_inline_profile_execution_is_used_as_given():
    data = [{"motion": {"step_times": [0.0, 0.3, 0.6], "currents": [[3.0], [-3.0]], "tf": 0.8, "coast": 0.2},
             "q0": 0.1, "rest_position": 0.2, "name": "manual"}]
    (ex,) = parse_executions(data, q_sigma=2e-4)
    assert ex.q0 == 0.1 and ex.q_sigma == 2e-4 and ex.name == "manual" and ex.profile.n_steps == 2
