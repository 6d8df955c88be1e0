"""Fit of the Eq. 9 friction (pv, pc, pt; optionally J) to measured runs, with 95 % intervals.

Output error: the parameters minimise Σ (q_meas − q_model)² over all samples, q_model from the
exact event-based simulator (``ff_planner.identify.sampling``) driven by each run's current, each
run's unknown start offset projected out (the model is position-invariant, so the best offset is
the run's mean residual). ``scipy.optimize.least_squares`` (trust-region reflective, bounds
pc ≥ 0, 0 ≤ pt < 1, J > 0, central-difference Jacobian) solves it, started from an equation-error
estimate (linear least squares of J·q̈ + pv·q̇ + s·pc + s·|T|·pt = T on Savitzky–Golay velocity and
acceleration of the sliding samples). Positions are the quantity an encoder measures directly;
their error (quantisation) is small and white, while differentiated signals amplify it.

Intervals (95 %), per parameter the widest of
  * the Gauss–Newton covariance s²·(JᵀJ)⁻¹, s² = SSR/(m − p − runs);
  * its Newey–West (Bartlett kernel) sandwich, which holds for correlated residuals;
  * the delete-one-run jackknife (the spread between runs, which also sees model mismatch);
with Student-t quantiles. Model adequacy: the residuals of the moving samples must be white
(Ljung–Box, 10 lags, per run, summed) and, when the encoder quantum is known, their size must
match it (χ² of SSR/σ², σ² = Δ²/12 + noise²); either failing at level ``alpha`` marks the fit
``adequate = False`` — the friction law does not describe the arm, and the intervals, which then
speak only of the best Eq. 9 approximation, are widened to ``MISMATCH_FACTOR`` times the largest
change of the estimate between fits on pairs of current levels (the levels see different speeds,
torques and positions, so a law that misses a speed- or position-dependence gives them different
best parameters), or with fewer than 3 levels by the ratio of residual to measurement rms.
Units: Nm·s/rad, Nm, fraction, kg·m², rad, s.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
from scipy import stats
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from ff_planner.core.errors import ParameterError
from ff_planner.identify.records import RunRecord
from ff_planner.identify.sampling import sample_trajectory
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile

FRICTION = ("pv", "pc", "pt")
#: typical magnitudes (table 2) that scale the parameters inside the solver
_TYPICAL = {"pv": 0.05, "pc": 0.19, "pt": 0.22, "J": 0.17}
_LOWER = {"pv": -np.inf, "pc": 0.0, "pt": 0.0, "J": 1e-9}
_UPPER = {"pv": np.inf, "pc": np.inf, "pt": 0.99, "J": np.inf}


@dataclass
class _Run:
    """A record cut to its informative part, with the input that drove it."""

    t: np.ndarray
    q: np.ndarray
    profile: CurrentProfile
    q_res: float


class IntervalBox:
    """Reading an estimate's 95 % intervals: half-widths and the relative box they span
    (``estimates`` and ``interval95`` are the subclass's fields, SI)."""

    estimates: dict[str, float]
    interval95: dict[str, tuple[float, float]]

    def half_width(self, key: str) -> float:
        """Half the 95 % interval of ``key`` (its unit)."""
        lo, hi = self.interval95[key]
        return 0.5 * (hi - lo)

    def relative_box(self, floor: float = 0.0) -> dict[str, float]:
        """Per friction parameter the fraction b with estimate·(1 ± b) ⊇ the 95 % interval
        (at least ``floor``; inf for a zero estimate)."""
        out = {}
        for k in FRICTION:
            est = self.estimates[k]
            lo, hi = self.interval95[k]
            reach = max(abs(hi - est), abs(est - lo))
            out[k] = max(floor, reach / abs(est)) if est != 0.0 else math.inf
        return out


@dataclass
class FitResult(IntervalBox):
    """Estimates, 95 % intervals (SI), adequacy tests and residuals of a friction fit."""

    keys: tuple[str, ...]
    estimates: dict[str, float]
    interval95: dict[str, tuple[float, float]]
    std: dict[str, float]
    params: Arm1DofParams
    adequate: bool
    tests: dict[str, float]
    rms: float                         # rad, residual rms
    sigma: float                       # rad, expected measurement rms (0 = unknown)
    n_samples: int
    n_runs: int
    motion_seconds: float              # s of arm motion used (profile time of all runs)
    method: str = "output-error least squares (exact simulator)"
    message: str = ""
    residuals: list[np.ndarray] = field(default_factory=list)
    times: list[np.ndarray] = field(default_factory=list)
    measured: list[np.ndarray] = field(default_factory=list)
    fitted: list[np.ndarray] = field(default_factory=list)
    covariance: Optional[np.ndarray] = None
    initial: dict[str, float] = field(default_factory=dict)


def _prepare(rec: RunRecord, tail: float = 0.02) -> _Run:
    """Keep the samples from just before the first step to shortly after the last movement."""
    rec.validate()
    moved = np.nonzero(np.diff(rec.q) != 0.0)[0]
    t_last = float(rec.t[moved[-1] + 1]) if moved.size else 0.0
    keep = (rec.t >= -0.005) & (rec.t <= t_last + tail)
    if keep.sum() < 10:
        keep = np.ones(rec.t.size, bool)
    return _Run(rec.t[keep], rec.q[keep], rec.input_profile(), rec.q_resolution)


def _theta_params(base: Arm1DofParams, keys: Sequence[str], x: np.ndarray) -> tuple[float, ...]:
    vals = {"J": float(base.J), "pv": float(base.pv), "pc": float(base.pc), "pt": float(base.pt)}
    vals.update({k: float(v) for k, v in zip(keys, x)})
    return vals["J"], vals["pv"], vals["pc"], vals["pt"]


def _model(base: Arm1DofParams, keys: Sequence[str], x: np.ndarray, run: _Run) -> tuple[np.ndarray, np.ndarray]:
    J, pv, pc, pt = _theta_params(base, keys, x)
    return sample_trajectory(J, float(base.torque_per_amp), pv, pc, pt, run.profile, float(run.q[0]), run.t)


def _residuals(base: Arm1DofParams, keys: Sequence[str], x: np.ndarray, runs: Sequence[_Run]) -> np.ndarray:
    parts = []
    for r in runs:
        e = r.q - _model(base, keys, x, r)[0]
        parts.append(e - e.mean())
    return np.concatenate(parts)


def equation_error(runs: Sequence[RunRecord], base: Arm1DofParams, fit_inertia: bool = False,
                   window: float = 0.02) -> dict[str, float]:
    """Linear least squares of Eq. 9 on filtered velocity/acceleration of the sliding samples:
    J·q̈ + pv·q̇ + s·pc + s·|T|·pt = T (s = sign q̇, T = n·kt·I commanded). A start, not the estimate."""
    rows, rhs = [], []
    c = float(base.torque_per_amp)
    for rec in runs:
        r = _prepare(rec)
        dt = float(np.median(np.diff(r.t)))
        tu = np.arange(r.t[0], r.t[-1], dt)
        if tu.size < 11:
            continue
        qu = np.interp(tu, r.t, r.q)
        w = max(5, int(round(window / dt)) | 1)
        if w >= tu.size:
            continue
        v = savgol_filter(qu, w, 2, deriv=1, delta=dt)
        a = savgol_filter(qu, w, 2, deriv=2, delta=dt)
        T = c * np.array([r.profile.current_at(x)[0] for x in tu])
        edges = np.concatenate([r.profile.step_times, [r.profile.tf]])
        far = np.min(np.abs(tu[:, None] - edges[None, :]), axis=1) > w * dt
        ok = far & (np.abs(v) > 0.15 * max(np.abs(v).max(), 1e-9)) & (tu >= 0.0)
        s = np.sign(v[ok])
        cols = [v[ok], s, s * np.abs(T[ok])]
        if fit_inertia:
            cols.append(a[ok])
            rhs.append(T[ok])
        else:
            rhs.append(T[ok] - float(base.J) * a[ok])
        rows.append(np.column_stack(cols))
    keys = ["pv", "pc", "pt"] + (["J"] if fit_inertia else [])
    if not rows or sum(x.shape[0] for x in rows) < 2 * len(keys):
        return {k: float(getattr(base, k)) for k in keys}
    A, b = np.vstack(rows), np.concatenate(rhs)
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    out = {k: float(v) for k, v in zip(keys, sol)}
    out["pc"] = max(out["pc"], 1e-4)
    out["pt"] = min(max(out["pt"], 0.0), 0.9)
    if fit_inertia and not out["J"] > 0.0:
        out["J"] = float(base.J)
    return out


def _newey_west(jac: np.ndarray, res: np.ndarray, bounds: Sequence[tuple[int, int]]) -> np.ndarray:
    """Σ over runs of the Bartlett-weighted long-run covariance of g_t = J_t·r_t (p × p)."""
    p = jac.shape[1]
    S = np.zeros((p, p))
    for lo, hi in bounds:
        g = jac[lo:hi] * res[lo:hi, None]
        n = g.shape[0]
        L = int(math.ceil(2.0 * n ** (1.0 / 3.0)))
        S += g.T @ g
        for lag in range(1, min(L, n - 1) + 1):
            G = g[lag:].T @ g[:-lag]
            S += (1.0 - lag / (L + 1.0)) * (G + G.T)
    return S


def ljung_box(x: np.ndarray, lags: int) -> float:
    """Ljung–Box statistic Q = n(n+2)·Σ_k ρ_k²/(n−k), k = 1..lags (χ²(lags) for white noise).
    Written here because scipy has no portmanteau test and statsmodels is not a dependency."""
    x = np.asarray(x, float) - np.mean(x)
    n = x.size
    den = float(x @ x)
    if n <= lags + 1 or den == 0.0:
        return 0.0
    rho = np.array([float(x[k:] @ x[:-k]) / den for k in range(1, lags + 1)])
    return float(n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, lags + 1))))


#: a mismatched fit's half-widths are at least this many times the largest change of the
#: estimate between fits on pairs of current levels (a maximum over few subsets understates the
#: spread; 3x covers the sliding values of the Stribeck and position-dependent Coulomb arms of the
#: tests and the benchmark)
MISMATCH_FACTOR = 3.0


def _level_spread(runs: Sequence[_Run], solve: Callable[[Sequence[_Run]], np.ndarray],
                  x: np.ndarray) -> tuple[Optional[np.ndarray], str]:
    """max |θ_subset − θ| over fits on every pair of current levels (runs grouped by their largest
    |I|), or None with fewer than 3 levels. When Eq. 9 is wrong, the levels — different speeds,
    torques and positions — see different 'best' parameters; when it is right, they agree."""
    levels: dict[float, list[_Run]] = {}
    for r in runs:
        levels.setdefault(round(float(np.abs(r.profile.currents).max()), 3), []).append(r)
    groups = list(levels.values())
    if len(groups) < 3:
        return None, ""
    dev = np.zeros_like(x)
    for a, b in itertools.combinations(range(len(groups)), 2):
        try:
            dev = np.maximum(dev, np.abs(solve(groups[a] + groups[b]) - x))
        except (ValueError, np.linalg.LinAlgError):
            continue
    return dev, f"of the estimate between fits on pairs of the {len(groups)} current levels"


def fit_friction(records: Sequence[RunRecord], base: Arm1DofParams, *, fit_inertia: bool = False,
                 initial: Optional[dict[str, float]] = None, q_noise: float = 0.0,
                 alpha: float = 1e-3, jackknife: bool = True, lags: int = 10) -> FitResult:
    """Fit pv, pc, pt (and J with ``fit_inertia``) of ``base`` to the runs; see the module doc.

    ``q_noise``: rad rms of position noise besides quantisation (for the χ² test); ``alpha``: level
    of the adequacy tests.
    """
    if not records:
        raise ParameterError("no runs to fit")
    runs = [_prepare(r) for r in records]
    keys = FRICTION + (("J",) if fit_inertia else ())
    start = dict(initial) if initial else equation_error(records, base, fit_inertia)
    x0 = np.array([float(start.get(k, getattr(base, k))) for k in keys])
    lower = np.array([_LOWER[k] for k in keys])
    upper = np.array([_UPPER[k] for k in keys])
    x0 = np.clip(x0, lower + 1e-9, upper - 1e-9)
    scale = np.array([max(abs(v), 0.1 * _TYPICAL[k]) for k, v in zip(keys, x0)])

    def solve(sel: Sequence[_Run], x_start: np.ndarray):
        return least_squares(lambda x: _residuals(base, keys, x, sel), x_start, jac="3-point",
                             bounds=(lower, upper), x_scale=scale, diff_step=1e-5, method="trf",
                             xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)

    sol = solve(runs, x0)
    x = sol.x
    res = sol.fun
    jac = sol.jac
    m, p, R = res.size, len(keys), len(runs)
    dof = max(m - p - R, 1)
    ssr = float(res @ res)
    s2 = ssr / dof
    A = jac.T @ jac
    try:
        Ainv = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        raise ParameterError("the runs do not determine the parameters (singular Jacobian); "
                             "add runs at other current levels") from None
    bounds_idx, lo = [], 0
    for r in runs:
        bounds_idx.append((lo, lo + r.t.size))
        lo += r.t.size
    cov = s2 * Ainv
    cov_nw = Ainv @ _newey_west(jac, res, bounds_idx) @ Ainv * (m / dof)
    t_q = float(stats.t.ppf(0.975, dof))
    half = t_q * np.sqrt(np.maximum(np.diag(cov), np.diag(cov_nw)))
    if jackknife and R >= 3:
        xs = np.array([solve([r for j, r in enumerate(runs) if j != i], x).x for i in range(R)])
        var_jk = (R - 1) / R * np.sum((xs - xs.mean(axis=0)) ** 2, axis=0)
        half = np.maximum(half, float(stats.t.ppf(0.975, R - 1)) * np.sqrt(var_jk))

    # adequacy: whiteness of the moving samples' residuals, size against the encoder quantum
    q_res = max(r.q_res for r in runs)
    sigma = math.sqrt(q_res ** 2 / 12.0 + q_noise ** 2)
    Q, n_lb = 0.0, 0
    residuals, fitted = [], []
    for (a, b), r in zip(bounds_idx, runs):
        e = res[a:b]
        qm, vm = _model(base, keys, x, r)
        fitted.append(qm + (r.q - qm - e).mean())
        residuals.append(e)
        dt = float(np.median(np.diff(r.t)))
        moving = np.abs(vm) > max(5.0 * q_res / dt, 1e-3)
        if moving.sum() > 2 * lags:
            Q += ljung_box(e[moving], lags)
            n_lb += lags
    p_white = float(stats.chi2.sf(Q, n_lb)) if n_lb else 1.0
    tests = {"ljung_box_q": Q, "ljung_box_dof": float(n_lb), "p_white": p_white,
             "chi2": math.nan, "chi2_dof": float(dof), "p_chi2": math.nan, "alpha": alpha}
    adequate = p_white >= alpha
    reasons = [] if p_white >= alpha else [f"residuals not white (Ljung-Box p = {p_white:.2g})"]
    if sigma > 0.0:
        chi2 = ssr / sigma ** 2
        p_chi2 = float(stats.chi2.sf(chi2, dof))
        tests.update(chi2=chi2, p_chi2=p_chi2)
        if p_chi2 < alpha:
            adequate = False
            reasons.append(f"residual rms {math.sqrt(ssr / m):.3g} rad is {math.sqrt(chi2 / dof):.2g}x "
                           f"the measurement's {sigma:.3g} rad (chi2 p = {p_chi2:.2g})")
    if not adequate:        # no tight claim: widen to the estimate's dependence on the data
        spread, how = _level_spread(runs, lambda sel: solve(sel, x).x, x)
        tests["mismatch_spread_factor"] = MISMATCH_FACTOR
        if spread is not None:
            half = np.maximum(half, MISMATCH_FACTOR * spread)
            reasons.append(f"intervals widened to {MISMATCH_FACTOR:g}x the spread {how}")
        else:
            birge = math.sqrt(s2) / sigma if sigma > 0.0 else 1.0
            half = half * max(1.0, birge)
            reasons.append(f"intervals widened {max(1.0, birge):.3g}x (residual rms over the measurement's)")
    est = {k: float(v) for k, v in zip(keys, x)}
    params = base.replace(**est)
    msg = ("the friction law fits the runs within the measurement noise" if adequate else
           "MODEL MISMATCH: " + "; ".join(reasons) +
           " — Eq. 9 does not describe this arm; the intervals bound the best Eq. 9 approximation only")
    return FitResult(
        keys=keys, estimates=est,
        interval95={k: (float(v - h), float(v + h)) for k, v, h in zip(keys, x, half)},
        std={k: float(h / t_q) for k, h in zip(keys, half)}, params=params, adequate=adequate,
        tests=tests, rms=math.sqrt(ssr / m), sigma=sigma, n_samples=m, n_runs=R,
        motion_seconds=float(sum(r.profile.tf for r in runs)), message=msg, residuals=residuals,
        times=[r.t for r in runs], measured=[r.q for r in runs], fitted=fitted,
        covariance=np.maximum(cov, cov_nw), initial={k: float(v) for k, v in zip(keys, x0)})
