"""Learning from use: update the friction estimate (pv, pc, pt) from logged executions.

Every executed motion that starts at rest at q0 (rad) and is left alone with zero current after
tf ends at a rest position q_rest(θ) (rad) fixed by the friction θ = (pv, pc, pt) of the arm. A
measured rest position y (rad, noise σ = ``q_sigma``) is therefore one scalar observation of θ:

    y = q_rest(θ) + ε,   ε ~ N(0, σ²),   θ ~ N(μ0, P0) a priori (the current estimate).

The update is the maximum a posteriori estimate of this model, the minimiser of

    (θ − μ0)ᵀ P0⁻¹ (θ − μ0) + Σ_i (y_i − q_rest,i(θ))² / σ_i²,

found by Gauss–Newton iterations on the nonlinear model (``scipy.optimize.least_squares``,
trust-region reflective with bounds pc ≥ 0, 0 ≤ pt < 1, on the whitened residuals, with the exact
Jacobian ∂q_rest/∂θ of ``ff_planner.model.arm1dof.derivatives(to_rest=True)``: forward mode
through the event times, equal to central differences of the simulated rest position). The
posterior covariance is the linearised (Laplace) one at the optimum, P = (Hᵀ H)⁻¹ with H the
whitened Jacobian (prior rows included): the iterated extended Kalman update of all executions at
once. 95 % intervals are θ̂ ± 1.96·√diag P.

A linearisation is only as good as the rest position is linear over the parameters still in
doubt. Each execution's noise is therefore taken as σ_eff² = σ² + ω², ω² the mean squared error
of the linearisation at θ̂ over the current posterior N(θ̂, P) (at the 2n cubature points
θ̂ ± √n·chol(P)); the MAP solve and ω are repeated until θ̂ settles (posterior linearisation, as
in the iterated posterior linearisation filter). It starts from the prior: an execution whose rest
position the prior's spread moves non-linearly — a robust motion, flat to first order but curved —
is weighted by what the linearisation can say about it; as the posterior shrinks, ω → 0 and
σ_eff → σ for the informative ones.

Why robust motions teach little: the robust planner chooses the currents so that the end state,
hence the rest position, does not depend on the friction to first order — its ∂q_rest/∂θ is ~0
by design (the paper's robustness condition). Such an execution lands on target whatever the
friction is, so its rest error carries (almost) no information about θ: its Fisher information
g gᵀ/σ² is ~0. A baseline (time- or energy-optimal) motion is the opposite, its rest position
moves by 1–3 rad per Nm of Coulomb friction, so a rest error of a few mrad pins the friction
down to a fraction of a percent along the direction g. Each execution gives one direction; a
few motions of different durations and distances give several, and together with the prior they
determine all three parameters.

Per execution the result reports the sensitivities g (rad per unit), the rest position's spread
under the prior √(gᵀP0g) (rad), and the information it adds alone to the prior,
½·log₂(1 + gᵀP0g/σ_eff²) bits (0 bits: the execution cannot tell the prior's friction values apart).
A χ² test of the weighted residuals, prior term included (χ²(N) for N executions at the
optimum), says whether the executions agree with the prior, Eq. 9 and the stated noise; when they
do not, the intervals are widened by √(χ²/N) and the result says so (``--drift`` widens a prior
whose friction may have changed since it was stated). Units: rad, s, A, Nm, Nm·s/rad, pt a fraction.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence, Union

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from ff_planner.core.errors import ParameterError
from ff_planner.identify.fit import FRICTION, FitResult, IntervalBox
from ff_planner.model.arm1dof import derivatives, final_state
from ff_planner.model.params import Arm1DofParams, load_params
from ff_planner.model.profile import CurrentProfile

#: z of the two-sided 95 % normal interval
Z95 = float(stats.norm.ppf(0.975))
#: default rest-position noise (rad): a few encoder counts (2.8e-5 rad each for 4096 counts
#: behind 1:54) at the start and at rest, and the spread a switch-timing jitter of ~0.1 ms adds
DEFAULT_Q_SIGMA = 1e-4
_LOWER = np.array([-np.inf, 0.0, 0.0])
_UPPER = np.array([np.inf, np.inf, 0.99])
#: the comment line of an ff-identify parameter file that holds the covariance (SI, pv pc pt)
COV_TAG = "# covariance [pv, pc, pt] (SI):"
_COV_RE = re.compile(r"^# covariance \[pv, pc, pt\] \(SI\):\s*(\[.*\])\s*$")
_INTERVAL_RE = re.compile(r"^#\s+(pv|pc|pt):\s*\S+\s+# 95 % interval \[\s*([^,\]]+),\s*([^\]]+)\]")


@dataclass
class Prior:
    """The estimate before the update: the arm's parameters (J, kt, n, i_max and the friction
    means), the covariance of (pv, pc, pt) (SI²) and where the covariance came from."""

    params: Arm1DofParams
    cov: np.ndarray
    source: str = ""

    @property
    def mean(self) -> np.ndarray:
        return np.array([float(getattr(self.params, k)) for k in FRICTION])

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def with_drift(self, fraction: float) -> "Prior":
        """The prior widened by a drift of the friction since it was stated: independent
        (fraction·|p|)² added to each parameter's variance (a Kalman filter's process noise)."""
        if not (math.isfinite(fraction) and fraction >= 0.0):
            raise ParameterError(f"drift must be a fraction >= 0, got {fraction}")
        scale = np.array([abs(v) if v != 0.0 else 1.0 for v in self.mean])
        src = self.source + (f" + drift {fraction:g}" if fraction > 0.0 else "")
        return Prior(self.params, np.asarray(self.cov, float) + np.diag((fraction * scale) ** 2), src)

    def validate(self) -> None:
        c = np.asarray(self.cov, float)
        if c.shape != (3, 3) or not np.all(np.isfinite(c)):
            raise ParameterError("the prior covariance must be a finite 3 x 3 matrix (pv, pc, pt)")
        if not np.allclose(c, c.T, rtol=1e-9, atol=0.0):
            raise ParameterError("the prior covariance must be symmetric")
        if np.linalg.eigvalsh(c).min() <= 0.0:
            raise ParameterError("the prior covariance must be positive definite (every parameter "
                                 "needs an interval of non-zero width)")


@dataclass
class Execution:
    """One logged execution: the executed current profile, the start (at rest, rad), the measured
    rest position (rad) and its noise (rad rms)."""

    profile: CurrentProfile
    q0: float
    rest_position: float
    q_sigma: float = DEFAULT_Q_SIGMA
    name: str = ""

    def validate(self) -> None:
        self.profile.validate()
        if self.profile.n_joints != 1:
            raise ParameterError(f"execution {self.name!r}: a 1-DOF execution needs a 1-joint profile, "
                                 f"got {self.profile.n_joints}")
        for key in ("q0", "rest_position"):
            if not math.isfinite(float(getattr(self, key))):
                raise ParameterError(f"execution {self.name!r}: {key} must be a finite number (rad)")
        if not (math.isfinite(self.q_sigma) and self.q_sigma > 0.0):
            raise ParameterError(f"execution {self.name!r}: q_sigma must be > 0 rad, got {self.q_sigma}")


@dataclass
class ExecutionInfo:
    """What one execution told: rest positions predicted before/after (rad), the measured one,
    its sensitivities ∂q_rest/∂p at the update (rad per unit of p), the rest spread the prior
    allows √(gᵀP0g) (rad), the information it adds alone to the prior (bits), the normalised
    innovation (y − prediction before) / √(σ² + gᵀP0g) and the weighted residual after."""

    name: str
    measured: float
    predicted_prior: float
    predicted_posterior: float
    q_sigma: float
    sensitivity: dict[str, float]
    rest_spread_prior: float
    information_bits: float
    innovation_z: float
    residual_z: float
    linearisation: float = 0.0      # rad rms the linearisation misses over the posterior

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "measured_rest_rad": self.measured,
                "predicted_rest_prior_rad": self.predicted_prior,
                "predicted_rest_posterior_rad": self.predicted_posterior, "q_sigma_rad": self.q_sigma,
                "sensitivity": dict(self.sensitivity), "rest_spread_prior_rad": self.rest_spread_prior,
                "information_bits": self.information_bits, "innovation_z": self.innovation_z,
                "residual_z": self.residual_z, "linearisation_rad": self.linearisation}


@dataclass
class UpdateResult(IntervalBox):
    """The updated estimate: values, 95 % intervals, std and covariance (SI), the prior, what
    each execution contributed, the consistency test and the solver's figures."""

    estimates: dict[str, float]
    interval95: dict[str, tuple[float, float]]
    std: dict[str, float]
    covariance: np.ndarray
    params: Arm1DofParams
    prior: Prior
    executions: list[ExecutionInfo]
    chi2: float
    p_consistent: float
    adequate: bool
    inflation: float                 # factor applied to the intervals (1 = none)
    information_bits: float          # ½·log₂ det P0 / det P: all executions together
    iterations: int
    converged: bool
    message: str = ""
    keys: tuple[str, ...] = FRICTION
    method: str = "MAP update, Gauss-Newton on the exact rest position (linearised covariance)"


# --- the prior -------------------------------------------------------------------------------
def consistent_covariance(std: Sequence[float], shape_cov: Optional[np.ndarray] = None) -> np.ndarray:
    """The covariance with standard deviations ``std`` and the correlations of ``shape_cov``
    (none: uncorrelated), the correlation matrix clipped to positive definite."""
    s = np.asarray(std, float)
    R = np.eye(s.size)
    if shape_cov is not None:
        c = np.asarray(shape_cov, float)
        d = np.sqrt(np.clip(np.diag(c), 1e-300, None))
        R = c / np.outer(d, d)
        R = 0.5 * (R + R.T)
        w, V = np.linalg.eigh(R)
        R = (V * np.clip(w, 1e-6, None)) @ V.T
        d = np.sqrt(np.diag(R))
        R = R / np.outer(d, d)
    return R * np.outer(s, s)


def prior_from_fit(fit: Union[FitResult, UpdateResult]) -> Prior:
    """The prior an identification (or an earlier update) states: its estimates, and the
    covariance with the standard deviations of its 95 % intervals (half-width / 1.96) and the
    correlations of its Gauss–Newton covariance."""
    std = [fit.half_width(k) / Z95 for k in FRICTION]
    shape = None
    if fit.covariance is not None:
        idx = [list(fit.keys).index(k) for k in FRICTION]
        shape = np.asarray(fit.covariance)[np.ix_(idx, idx)]
    params = fit.params.replace(**{k: float(fit.estimates[k]) for k in FRICTION})
    return Prior(params, consistent_covariance(std, shape), "fit")


def prior_from_box(params: Arm1DofParams, box: Mapping[str, float]) -> Prior:
    """A prior from a relative box b per parameter read as a 95 % interval p·(1 ± b): σ = b·|p|/1.96,
    uncorrelated (a parameter with value 0 takes b as an absolute half-width)."""
    missing = [k for k in FRICTION if k not in box]
    if missing:
        raise ParameterError(f"the prior box needs {', '.join(FRICTION)}; missing {', '.join(missing)}")
    bad = [k for k in box if k not in FRICTION]
    if bad:
        raise ParameterError(f"the prior box names unknown parameter(s) {bad}; use {', '.join(FRICTION)}")
    std = []
    for k in FRICTION:
        b = float(box[k])
        if not (math.isfinite(b) and b > 0.0):
            raise ParameterError(f"prior box {k} must be > 0 (a fraction), got {box[k]}")
        v = abs(float(getattr(params, k)))
        std.append(b * (v if v > 0.0 else 1.0) / Z95)
    return Prior(params, consistent_covariance(std), "box")


def load_prior(path: Union[str, Path], box: Optional[Mapping[str, float]] = None) -> Prior:
    """The prior of an ff-identify parameter file.

    Its values are the means; the covariance is the file's ``# covariance`` line when it has one
    (written by ff-identify), else a diagonal one from its ``# 95 % interval`` lines (σ = half-width
    / 1.96: the correlations are lost). ``box`` (fractions, as ``prior_from_box``) replaces both; a
    file with neither (e.g. a plain load_params file) needs it."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParameterError(f"cannot read {str(p)!r}: {exc.strerror or exc}") from None
    try:
        params = load_params(p)
    except ParameterError as exc:
        raise ParameterError(f"{p}: {exc}") from None
    except Exception as exc:        # a YAML syntax error
        raise ParameterError(f"{p} is not a parameter file: {str(exc).splitlines()[0]}") from None
    if not isinstance(params, Arm1DofParams):
        raise ParameterError(f"{p}: learning from use supports model 'arm1dof' only, got '{params.model}'")
    if box is not None:
        return prior_from_box(params, box)
    cov, intervals = None, {}
    for line in text.splitlines():
        m = _COV_RE.match(line)
        if m:
            try:
                cov = np.array(json.loads(m.group(1)), float)
            except (ValueError, TypeError):
                raise ParameterError(f"{p}: unreadable covariance line {line!r}") from None
        m = _INTERVAL_RE.match(line)
        if m:
            try:
                intervals[m.group(1)] = (float(m.group(2)), float(m.group(3)))
            except ValueError:
                raise ParameterError(f"{p}: unreadable interval line {line!r}") from None
    if cov is not None:
        prior = Prior(params, cov, "covariance")
    elif set(intervals) == set(FRICTION):
        std = [0.5 * (intervals[k][1] - intervals[k][0]) / Z95 for k in FRICTION]
        prior = Prior(params, consistent_covariance(std), "intervals (diagonal: no correlations)")
    else:
        raise ParameterError(f"{p} states no uncertainty (no ff-identify covariance or 95 % interval "
                             f"lines): give the prior box, e.g. --prior-box pv=0.3 --prior-box pc=0.1 "
                             f"--prior-box pt=0.1")
    prior.validate()
    return prior


# --- the executions file ---------------------------------------------------------------------
#: reads a motion (a path, or an inline mapping) into (profile, planned q0 rad or None)
MotionLoader = Callable[[Union[str, Mapping[str, Any]], Path], tuple[CurrentProfile, Optional[float]]]


def profile_from_record(d: Mapping[str, Any]) -> tuple[CurrentProfile, Optional[float]]:
    """A CurrentProfile-like record ``{step_times: [s], currents: [A] or [[A]], tf: s, coast: s
    [, q0: rad or [rad]]}`` as (profile, q0 or None)."""
    try:
        cur = np.asarray(d["currents"], float)
        prof = CurrentProfile(np.asarray(d["step_times"], float), cur.reshape(-1, 1) if cur.ndim == 1 else cur,
                              float(d["tf"]), float(d.get("coast", 0.0)))
    except KeyError as exc:
        raise ParameterError(f"an inline profile needs step_times, currents, tf (and coast): missing {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"bad inline profile: {exc}") from None
    q0 = d.get("q0")
    if q0 is not None:
        q0 = float(np.atleast_1d(np.asarray(q0, float))[0])
    return prof, q0


def _default_loader(motion: Union[str, Mapping[str, Any]], folder: Path) -> tuple[CurrentProfile, Optional[float]]:
    if isinstance(motion, Mapping) and "format" not in motion:
        return profile_from_record(motion)
    raise ParameterError("reading ff-motion/1 files needs a motion loader (the ff-identify CLI has one)")


def _number(x: Any, what: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(float(x)):
        raise ParameterError(f"{what} must be a finite number, got {x!r}")
    return float(x)


def parse_executions(data: Any, folder: Union[str, Path] = ".", loader: Optional[MotionLoader] = None,
                     q_sigma: float = DEFAULT_Q_SIGMA, source: str = "executions") -> list[Execution]:
    """Executions from the parsed JSON of an executions file: a list (or ``{"executions": [...]}``)
    of ``{motion: path or inline profile, rest_position: rad [, q_sigma: rad] [, q0: rad]
    [, name]}``. Paths are relative to ``folder``; ``q0`` (the measured start) defaults to the
    motion's own; ``q_sigma`` to the given default."""
    if isinstance(data, Mapping) and "executions" in data:
        data = data["executions"]
    if not isinstance(data, list) or not data:
        raise ParameterError(f"{source}: needs a non-empty JSON list of {{motion, rest_position[, q_sigma]}}")
    load = loader or _default_loader
    out = []
    for i, e in enumerate(data):
        where = f"{source}[{i}]"
        if not isinstance(e, Mapping):
            raise ParameterError(f"{where}: must be an object {{motion, rest_position[, q_sigma]}}, got {e!r}")
        if "motion" not in e or "rest_position" not in e:
            raise ParameterError(f"{where}: needs keys motion and rest_position, got {sorted(e)}")
        motion = e["motion"]
        if not isinstance(motion, (str, Mapping)):
            raise ParameterError(f"{where}: motion must be a file path or an inline profile object")
        try:
            prof, q0_planned = load(motion, Path(folder))
        except ParameterError as exc:
            raise ParameterError(f"{where}: {exc}") from None
        except ValueError as exc:      # a motion file's own error (MotionFileError)
            raise ParameterError(f"{where}: {str(exc).splitlines()[0]}") from None
        if q0_planned is None and "q0" not in e:
            raise ParameterError(f"{where}: an inline profile without q0 needs the execution's q0 (rad)")
        rest = e["rest_position"]
        if isinstance(rest, list) and len(rest) == 1:
            rest = rest[0]
        ex = Execution(prof, _number(e.get("q0", q0_planned), f"{where}: q0"),
                       _number(rest, f"{where}: rest_position"),
                       _number(e.get("q_sigma", q_sigma), f"{where}: q_sigma"),
                       str(e.get("name", motion if isinstance(motion, str) else f"#{i}")))
        try:
            ex.validate()
        except ValueError as exc:
            raise ParameterError(f"{where}: {str(exc).splitlines()[0]}") from None
        out.append(ex)
    return out


def load_executions(path: Union[str, Path], loader: Optional[MotionLoader] = None,
                    q_sigma: float = DEFAULT_Q_SIGMA) -> list[Execution]:
    """``parse_executions`` of a JSON file (motion paths relative to its folder)."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ParameterError(f"cannot read {str(p)!r}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ParameterError(f"{p} is not JSON: {exc.msg} at line {exc.lineno}") from None
    return parse_executions(data, p.parent, loader, q_sigma, str(p))


# --- the update ------------------------------------------------------------------------------
def rest_and_gradient(params: Arm1DofParams, ex: Execution) -> tuple[float, np.ndarray]:
    """(q_rest rad, ∂q_rest/∂(pv, pc, pt)) of one execution under ``params`` (exact forward mode)."""
    d = derivatives(params, ex.profile, float(ex.q0), to_rest=True)
    g = np.array([d.dq_dp[k] for k in FRICTION])
    if not (math.isfinite(d.q) and np.all(np.isfinite(g))):
        raise ParameterError(f"execution {ex.name!r}: the arm does not come to rest under "
                             f"pv={params.pv:.4g}, pc={params.pc:.4g}, pt={params.pt:.4g}")
    return float(d.q), g


def rest_gradient_central(params: Arm1DofParams, ex: Execution, rel_step: float = 1e-6) -> np.ndarray:
    """∂q_rest/∂(pv, pc, pt) by central differences of the simulated rest position (a check)."""
    out = []
    for k in FRICTION:
        v = float(getattr(params, k))
        h = rel_step * (abs(v) if v != 0.0 else 1.0)
        qp = final_state(params.replace(**{k: v + h}), ex.profile, ex.q0, to_rest=True)[0]
        qm = final_state(params.replace(**{k: v - h}), ex.profile, ex.q0, to_rest=True)[0]
        out.append((qp - qm) / (2.0 * h))
    return np.array(out)


def _with(params: Arm1DofParams, x: np.ndarray) -> Arm1DofParams:
    return params.replace(**{k: float(v) for k, v in zip(FRICTION, x)})


def _linearisation_var(params: Arm1DofParams, executions: Sequence[Execution], x: np.ndarray, P: np.ndarray,
                       r: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Per execution the variance (rad²) of what the linearisation r(θ̂) + g·(θ − θ̂) misses over
    θ ~ N(θ̂, P): the mean squared error at the 2n cubature points θ̂ ± √n·(columns of chol P),
    clipped to the parameter bounds (a point where the arm never stops counts as (0.1 rad)²)."""
    L = np.linalg.cholesky(P)
    n = x.size
    err = np.zeros((len(executions), 2 * n))
    j = 0
    for col in range(n):
        for sgn in (1.0, -1.0):
            pt = np.clip(x + sgn * math.sqrt(n) * L[:, col], _LOWER, _UPPER)
            p = _with(params, pt)
            for i, ex in enumerate(executions):
                q = final_state(p, ex.profile, float(ex.q0), to_rest=True)[0]
                err[i, j] = (q - r[i] - G[i] @ (pt - x)) if math.isfinite(q) else 0.1
            j += 1
    return np.mean(err ** 2, axis=1)


def update_from_executions(prior: Prior, executions: Sequence[Execution], *, alpha: float = 1e-3,
                           max_nfev: int = 100, max_outer: int = 12) -> UpdateResult:
    """The MAP estimate of (pv, pc, pt) given the prior and the executions' rest positions, its
    linearised covariance and 95 % intervals, and what each execution contributed (module doc).
    ``alpha``: level of the χ² consistency test; ``max_outer``: re-linearisations at most."""
    if not executions:
        raise ParameterError("no executions to learn from")
    prior.validate()
    for ex in executions:
        ex.validate()
    mu0, P0 = prior.mean, np.asarray(prior.cov, float)
    Linv = np.linalg.cholesky(np.linalg.inv(P0))       # P0⁻¹ = L Lᵀ: prior rows Lᵀ(θ − μ0)
    y = np.array([ex.rest_position for ex in executions])
    sig = np.array([ex.q_sigma for ex in executions])
    cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def model(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = x.tobytes()
        if key not in cache:
            p = _with(prior.params, x)
            r, G = np.empty(len(executions)), np.zeros((len(executions), 3))
            for i, ex in enumerate(executions):
                try:
                    r[i], G[i] = rest_and_gradient(p, ex)
                except ParameterError:     # a trial step where the arm never stops
                    r[i] = math.nan
            cache[key] = (r, G)
        return cache[key]

    def solve(x_start: np.ndarray, s_eff: np.ndarray):
        def fun(x: np.ndarray) -> np.ndarray:
            r, _ = model(x)
            e = np.where(np.isfinite(r), (y - r) / s_eff, 1e8)     # such a step is rejected
            return np.concatenate([e, Linv.T @ (x - mu0)])

        def jac(x: np.ndarray) -> np.ndarray:
            return np.vstack([-model(x)[1] / s_eff[:, None], Linv.T])

        sol = least_squares(fun, x_start, jac=jac, bounds=(_LOWER, _UPPER), x_scale=np.sqrt(np.diag(P0)),
                            method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)
        H = jac(sol.x)
        P = np.linalg.inv(H.T @ H)
        return sol, 0.5 * (P + P.T)

    x0 = np.clip(mu0, _LOWER + 1e-12, _UPPER - 1e-12)
    x, P = x0, P0
    nfev, settled = 0, False
    r0, G0 = model(x0)
    if not np.all(np.isfinite(r0)):
        rest_and_gradient(prior.params, executions[int(np.argmin(np.isfinite(r0)))])   # raises, names it
    for _ in range(max_outer):
        r, G = model(x)
        s_eff = np.sqrt(sig ** 2 + _linearisation_var(prior.params, executions, x, P, r, G))
        sol, P_new = solve(x, s_eff)
        nfev += int(sol.nfev)
        step = np.abs(sol.x - x) / np.sqrt(np.diag(P_new))
        x, P = sol.x, P_new
        if step.max() < 1e-3:
            settled = True
            break
    for ex in executions:       # the estimate itself must let every execution come to rest
        rest_and_gradient(_with(prior.params, x), ex)
    r_post, G_post = model(x)
    lin = _linearisation_var(prior.params, executions, x, P, r_post, G_post)
    n = len(executions)
    chi2 = float(np.sum(((y - r_post) / s_eff) ** 2) + np.sum((Linv.T @ (x - mu0)) ** 2))
    p_cons = float(stats.chi2.sf(chi2, n))
    adequate = p_cons >= alpha
    inflation = 1.0 if adequate else math.sqrt(chi2 / n)
    P_out = P * inflation ** 2
    std = np.sqrt(np.diag(P_out))
    infos = []
    for i, ex in enumerate(executions):
        spread2 = float(G0[i] @ P0 @ G0[i])
        infos.append(ExecutionInfo(
            ex.name, float(y[i]), float(r0[i]), float(r_post[i]), float(sig[i]),
            {k: float(v) for k, v in zip(FRICTION, G_post[i])}, math.sqrt(spread2),
            0.5 * math.log2(1.0 + spread2 / s_eff[i] ** 2),
            float((y[i] - r0[i]) / math.sqrt(s_eff[i] ** 2 + spread2)),
            float((y[i] - r_post[i]) / s_eff[i]), float(math.sqrt(lin[i]))))
    bits = 0.5 * math.log2(float(np.linalg.det(P0) / np.linalg.det(P)))
    est = {k: float(v) for k, v in zip(FRICTION, x)}
    if adequate:
        msg = (f"updated from {n} execution(s): {bits:.1f} bits; the rest positions agree with Eq. 9 and "
               f"their noise (chi2 = {chi2:.3g} on {n} dof, p = {p_cons:.2g})")
    else:
        msg = (f"INCONSISTENT: the {n} rest positions disagree with the updated estimate and their "
               f"stated noise (chi2 = {chi2:.3g} on {n} dof, p = {p_cons:.2g}); intervals widened "
               f"{inflation:.3g}x — q_sigma may be too small, or the friction changed more than the prior "
               f"allows (--drift) or does not follow Eq. 9")
    if not (sol.success and settled):
        msg += "; the iterations did not settle"
    return UpdateResult(
        estimates=est, interval95={k: (float(v - Z95 * s), float(v + Z95 * s)) for k, v, s in zip(FRICTION, x, std)},
        std={k: float(s) for k, s in zip(FRICTION, std)}, covariance=P_out, params=_with(prior.params, x),
        prior=prior, executions=infos, chi2=chi2, p_consistent=p_cons, adequate=adequate, inflation=inflation,
        information_bits=bits, iterations=nfev, converged=bool(sol.success and settled), message=msg)


def update_summary(res: UpdateResult, box_floor: float = 0.02,
                   extra: Optional[Mapping[str, Any]] = None) -> dict[str, Any]:
    """The ``--json`` dict of an update: estimates, interval95, std, box, the prior, per-execution
    information and the consistency test (SI units)."""
    box = res.relative_box(box_floor)
    pr = res.prior
    out: dict[str, Any] = {
        "estimates": dict(res.estimates),
        "interval95": {k: [lo, hi] for k, (lo, hi) in res.interval95.items()},
        "std": dict(res.std), "box": box, "adequate": res.adequate, "message": res.message,
        "covariance": res.covariance.tolist(),
        "prior": {"estimates": {k: float(v) for k, v in zip(FRICTION, pr.mean)},
                  "std": {k: float(v) for k, v in zip(FRICTION, pr.std)},
                  "interval95": {k: [float(m - Z95 * s), float(m + Z95 * s)]
                                 for k, m, s in zip(FRICTION, pr.mean, pr.std)},
                  "covariance_from": pr.source},
        "information_bits": res.information_bits,
        "std_ratio": {k: res.std[k] / float(s) for k, s in zip(FRICTION, pr.std)},
        "executions": [e.to_dict() for e in res.executions],
        "tests": {"chi2": res.chi2, "chi2_dof": len(res.executions), "p_consistent": res.p_consistent,
                  "inflation": res.inflation},
        "iterations": res.iterations, "converged": res.converged, "method": res.method,
        "units": {"pv": "Nm·s/rad", "pc": "Nm", "pt": "fraction", "sensitivity": "rad per unit of p"},
        "ff_plan_box_args": " ".join(f"--box {k}={box[k]:.4g}" for k in FRICTION),
    }
    out.update(dict(extra or {}))
    return out

