"""Baseline motions of paper section 6.5 / table 4: time-optimal and energy-optimal (1-DOF arm).

Both are computed for the nominal friction model and then judged like the robust plans: their
sensitivities d q(tf)/d p by central differences through ``simulate`` (the suite's one model).

Choices, stated:

* Time-optimal: bang-bang, +I_max until t1 then −I_max until the arm reaches the goal at rest at
  t2 (closed form of the linear sliding dynamics, switch found by root finding). As a profile the
  executor can run it is two steps on [0, t2]; the rest of the move time is zero current (the arm
  sticks at the goal), i.e. it is *padded at rest* to the request's tf. The request fails with
  UNREACHABLE if t2 > tf − coast. ``extra["t_arrival"]`` = t2; the paper evaluates its table 4 at
  arrival, so ``extra`` also carries the derivatives of q(t2), q̇(t2).
* Energy-optimal: minimise the copper loss E = R ∫ I² dt over the request's tf (coasting the
  last ``coast`` seconds as every plan does), with N equal current steps (``steps``; default 100)
  and rest at tf. With the sign of the velocity fixed (monotone motion, checked afterwards by
  simulation) the final state is affine in the step currents split as I = I⁺ − I⁻, so this is a
  convex QP with two equality constraints; solved exactly through its 2-dimensional dual
  (semismooth Newton), so 100 or 1000 steps cost milliseconds.
* Motor resistance R: the paper's arm has a maxon RE 30 (60 W) motor; its 24 V winding (part
  310007, k_t = 25.9 mNm/A, the winding nearest to the paper's 26.7 mNm/A) has a terminal
  resistance of 0.611 Ω in maxon's catalogue (value quoted from the catalogue, not measured). R
  scales the energy only; it does not change the optimal profile.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np
from scipy.optimize import brentq

from ff_planner.model.params import Arm1DofParams, Params
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest, PlanResult
from ff_planner.model.simulate import rest_position, simulate
from ff_planner.model.arm1dof import track
from ff_planner.optimize.certificate import excursion_of
from ff_planner.optimize.limits1d import Limits1D

R_TERMINAL = 0.611   # Ω, maxon RE 30 60 W, 24 V winding (catalogue value), see module docstring
DEFAULT_ENERGY_STEPS = 100

Progress = Optional[Callable[[dict], None]]


# --- closed-form phases of the 1-DOF sliding dynamics (velocity sign fixed, > 0) ------------
def _phi(beta: float, t: float) -> tuple[float, float]:
    """phi1 = ∫0^t e^{-β s} ds, phi2 = ∫0^t phi1 ds (s, s²), stable for β → 0."""
    z = beta * t
    if abs(z) < 1e-6:
        return t - beta * t * t / 2.0, t * t / 2.0 - beta * t ** 3 / 6.0
    p1 = -math.expm1(-z) / beta
    return p1, (t - p1) / beta


def _phase(v0: float, c: float, beta: float, t: float) -> tuple[float, float]:
    """Distance (rad) and end velocity (rad/s) of v' = c − β v over t seconds from v0."""
    p1, p2 = _phi(beta, t)
    return v0 * p1 + c * p2, v0 * math.exp(-beta * t) + c * p1


def _stop_time(v0: float, c: float, beta: float) -> float:
    """Time (s) for v' = c − β v (c < 0) to bring v0 > 0 to rest; inf if it never does."""
    if c >= 0.0:
        return math.inf
    arg = -beta * v0 / c
    if abs(beta) < 1e-12:
        return -v0 / c
    if arg <= -1.0:
        return math.inf
    return math.log1p(arg) / beta


def _accel_brake(p: Arm1DofParams) -> tuple[float, float, float]:
    """(c_acc, c_brake, beta): v' = c − β v with +I_max and −I_max while moving forward."""
    tm = p.torque_per_amp * p.i_max
    beta = p.pv / p.J
    c_acc = (tm * (1.0 - p.pt) - p.pc) / p.J
    c_brake = (-tm * (1.0 + p.pt) - p.pc) / p.J
    return c_acc, c_brake, beta


def _bang_bang(p: Arm1DofParams, t1: float) -> tuple[float, float]:
    """Bang-bang with switch at t1: (distance at rest, arrival time t2)."""
    c_acc, c_brake, beta = _accel_brake(p)
    x1, v1 = _phase(0.0, c_acc, beta, t1)
    tau = _stop_time(v1, c_brake, beta)
    if not math.isfinite(tau):
        return math.inf, math.inf
    x2, _ = _phase(v1, c_brake, beta, tau)
    return x1 + x2, t1 + tau


def reach_1dof(p: Arm1DofParams, duration: float) -> float:
    """Upper bound (rad) on |q(tf) − q0| for any rest-to-rest move of ``duration`` s, |I| ≤ I_max.

    Bang-bang (accelerate at +I_max, brake at −I_max until rest exactly at ``duration``) is the
    farthest a monotone 1-DOF move can go; the bound ignores the zero-current coast (it lets the
    brake act through it), so it is sound, not tight. 0 if I_max cannot break the arm away.
    Cached per (arm, duration): every request is checked against it.
    """
    try:
        return _reach_cached(p, float(duration))
    except TypeError:       # an arm whose fields are not hashable
        return _reach(p, float(duration))


@functools.lru_cache(maxsize=256)
def _reach_cached(p: Arm1DofParams, duration: float) -> float:
    return _reach(p, duration)


def _reach(p: Arm1DofParams, duration: float) -> float:
    """``reach_1dof`` without the cache."""
    c_acc, _, _ = _accel_brake(p)
    if c_acc <= 0.0 or duration <= 0.0:
        return 0.0
    g = lambda t1: _bang_bang(p, t1)[1] - duration   # noqa: E731
    if g(duration) < 0.0:   # cannot happen for a finite brake; keep the bound sound anyway
        return math.inf
    t1 = brentq(g, 0.0, duration, xtol=1e-14, rtol=1e-14)
    return _bang_bang(p, t1)[0]


def bang_bang_times(p: Arm1DofParams, distance: float) -> tuple[float, float]:
    """(t1, t2) s of the time-optimal rest-to-rest move over ``distance`` rad (> 0)."""
    c_acc, _, _ = _accel_brake(p)
    if c_acc <= 0.0:
        raise PlanningError("the current limit cannot overcome static friction "
                            f"(I_max = {p.i_max} A); raise i_max", code="UNREACHABLE")
    hi = 1e-3
    while _bang_bang(p, hi)[0] < distance:
        hi *= 2.0
        if hi > 1e6:
            raise PlanningError(f"distance {distance} rad not reachable", code="UNREACHABLE")
    t1 = brentq(lambda t: _bang_bang(p, t)[0] - distance, 0.0, hi, xtol=1e-15, rtol=1e-15)
    return t1, _bang_bang(p, t1)[1]


# --- sensitivities through the shared simulation --------------------------------------------
def finite_differences(params: Params, profile: CurrentProfile, q0: Sequence[float],
                       names: Sequence[str], *, rel_step: float = 1e-6,
                       scheme: str = "central") -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{name: (d q(tf)/d p, d q̇(tf)/d p)} by finite differences through ``simulate``.

    scheme "central" (true derivative where it exists), "forward" or "backward" (one-sided;
    the paper's method is forward with rel_step = 1e-3). Units: rad (rad/s) per parameter unit.
    """
    base = None if scheme == "central" else simulate(params, profile, q0)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name in names:
        p0 = float(getattr(params, name))
        h = rel_step * max(abs(p0), 1e-3)
        if scheme == "central":
            a = simulate(params.replace(**{name: p0 + h}), profile, q0)
            b = simulate(params.replace(**{name: p0 - h}), profile, q0)
            dq = (np.asarray(a.q_f) - np.asarray(b.q_f)) / (2 * h)
            dqd = (np.asarray(a.qd_f) - np.asarray(b.qd_f)) / (2 * h)
        elif scheme in ("forward", "backward") and base is not None:
            sgn = 1.0 if scheme == "forward" else -1.0
            a = simulate(params.replace(**{name: p0 + sgn * h}), profile, q0)
            dq = sgn * (np.asarray(a.q_f) - np.asarray(base.q_f)) / h
            dqd = sgn * (np.asarray(a.qd_f) - np.asarray(base.qd_f)) / h
        else:
            raise ValueError(f"unknown scheme {scheme!r}; use central, forward or backward")
        out[name] = (dq, dqd)
    return out


# --- the two baselines -----------------------------------------------------------------------
@dataclass
class Baseline:
    """A baseline profile and its figures (1-DOF). Units: s, A, J."""

    profile: CurrentProfile
    energy: float          # J, R ∫ I² dt
    t_arrival: float       # s, when the arm reaches the goal (time-optimal) or tf
    R: float               # Ω, resistance assumed


def time_optimal_1dof(p: Arm1DofParams, q0: float, qf: float, tf: float, coast: float,
                      R: float = R_TERMINAL) -> Baseline:
    """Bang-bang profile reaching qf at rest as early as possible, padded at rest to tf."""
    dist = qf - q0
    s = 1.0 if dist >= 0 else -1.0
    if abs(dist) < 1e-12:
        raise PlanningError("q0 equals qf: the time-optimal move is no move", code="INVALID_REQUEST")
    t1, t2 = bang_bang_times(p, abs(dist))
    if t2 > tf - coast + 1e-12:
        raise PlanningError(f"the time-optimal move over {abs(dist):.4g} rad needs {t2:.4g} s of "
                            f"current, more than tf - coast = {tf - coast:.4g} s; raise tf",
                            code="UNREACHABLE")
    prof = CurrentProfile(np.array([0.0, t1, t2]), np.array([[s * p.i_max], [-s * p.i_max]]),
                          tf, coast)
    energy = R * p.i_max ** 2 * t2
    return Baseline(prof, energy, t2, R)


def _affine_final_state(p: Arm1DofParams, h: float, n: int, coast: float):
    """Matrix M (2 × n) and offset m0 with [x(tf), v(tf)] = M @ c + m0 for step accelerations c
    (rad/s²) on n steps of h seconds, then coasting with c = −pc/J (forward motion)."""
    beta = p.pv / p.J
    p1, p2 = _phi(beta, h)
    cp1, cp2 = _phi(beta, coast)
    ce = math.exp(-beta * coast)
    # propagate each unit acceleration through the remaining steps (linear, v0 = 0)
    M = np.zeros((2, n))
    for k in range(n):
        x, v = p2, p1                        # after step k with c_k = 1
        m = n - k - 1                        # full steps left with c = 0
        if m:
            pm1, _ = _phi(beta, m * h)
            x, v = x + v * pm1, v * math.exp(-beta * m * h)
        x, v = x + v * cp1, v * ce           # coast contribution of the carried velocity
        M[:, k] = (x, v)
    c_coast = -p.pc / p.J
    m0 = np.array([c_coast * cp2, c_coast * cp1])
    return M, m0


def box_least_norm(A: np.ndarray, b: np.ndarray, h: float, hi: float,
                    max_iter: int = 100) -> Optional[np.ndarray]:
    """argmin h‖x‖² subject to A x = b, 0 ≤ x ≤ hi (A: m × n, m small), by its m-dimensional
    dual: x(λ) = clip(Aᵀλ / 2h, 0, hi) and a semismooth Newton step on A x(λ) = b with
    backtracking. None if the box makes A x = b infeasible."""
    lam = 2.0 * h * np.linalg.lstsq(A @ A.T, b, rcond=None)[0]

    def x_of(l):
        return np.clip(A.T @ l / (2.0 * h), 0.0, hi)

    x = x_of(lam)
    r = A @ x - b
    for _ in range(max_iter):
        nr = float(np.linalg.norm(r))
        if nr <= 1e-13 * max(1.0, float(np.linalg.norm(b))):
            return x
        free = (A.T @ lam > 0.0) & (A.T @ lam < 2.0 * h * hi)
        H = (A[:, free] @ A[:, free].T) / (2.0 * h)
        try:
            step = np.linalg.solve(H + 1e-14 * np.trace(H) * np.eye(len(b)), -r)
        except np.linalg.LinAlgError:
            step = -r
        t = 1.0
        while t > 1e-12:
            lam_new = lam + t * step
            x_new = x_of(lam_new)
            r_new = A @ x_new - b
            if np.linalg.norm(r_new) < (1.0 - 1e-4 * t) * nr:
                lam, x, r = lam_new, x_new, r_new
                break
            t *= 0.5
        else:
            return None
    return x if np.linalg.norm(r) <= 1e-9 * max(1.0, float(np.linalg.norm(b))) else None


def energy_optimal_1dof(p: Arm1DofParams, q0: float, qf: float, tf: float, coast: float,
                        steps: int = DEFAULT_ENERGY_STEPS, R: float = R_TERMINAL) -> Baseline:
    """Minimum copper-loss rest-to-rest profile with ``steps`` equal current steps on [0, tf−coast]."""
    dist = qf - q0
    s = 1.0 if dist >= 0 else -1.0
    if abs(dist) < 1e-12:
        raise PlanningError("q0 equals qf: the energy-optimal move is no move", code="INVALID_REQUEST")
    n = int(steps)
    h = (tf - coast) / n
    M, m0 = _affine_final_state(p, h, n, coast)
    g = p.torque_per_amp / p.J
    # c_k = g (1-pt) I+_k − g (1+pt) I-_k − pc/J ; decision x = [I+, I-] >= 0
    A = np.hstack([M * g * (1.0 - p.pt), -M * g * (1.0 + p.pt)])
    b = np.array([abs(dist), 0.0]) - m0 - M @ np.full(n, -p.pc / p.J)
    x = box_least_norm(A, b, h, p.i_max)
    if x is None or np.max(np.abs(A @ x - b)) > 1e-9 * max(1.0, abs(dist)):
        raise PlanningError(f"energy-optimal solve failed: no current profile within ±I_max = "
                            f"{p.i_max} A reaches the goal at rest in tf = {tf} s", code="UNREACHABLE")
    cur = s * (x[:n] - x[n:])
    prof = CurrentProfile(np.linspace(0.0, tf - coast, n + 1), cur.reshape(-1, 1), tf, coast)
    return Baseline(prof, R * float(np.sum(cur ** 2)) * h, tf, R)


def _check_limits(request: PlanRequest, p: Arm1DofParams, bl: Baseline, q0: float) -> None:
    """Refuse a baseline that leaves the request's limits anywhere along its motion (until rest)
    at any of the certificate's box points (``limits1d.Limits1D``): a baseline is fixed by its
    definition (bang-bang, least copper loss at the nominal friction) and has no freedom left
    to honour them. PlanningError (UNREACHABLE) saying what to change."""
    lim = Limits1D.of(getattr(request, "limits", None), p, q0, float(request.tf),
                      [u for u in ("pv", "pc", "pt") if u in request.uncertain], request.box)
    if lim is None:
        return
    if lim.excess(bl.profile.step_times, bl.profile.currents[:, 0]) > 0.0:
        tr = track(p, bl.profile, q0, np.vstack([np.ones((1, 3)), lim.design]))
        bad = excursion_of(tr[1:], tr[0]).violations(request.limits)
        nominal = lim.excess(bl.profile.step_times, bl.profile.currents[:, 0], np.ones((1, 3)))
        where = "at the nominal friction" if nominal > 0.0 else "over the friction box"
        raise PlanningError(
            f"the {request.objective} baseline leaves the limits {where} ({'; '.join(bad)}, "
            f"until rest); it is fixed by its definition and cannot honour them: widen the "
            f"limits, give a longer move time, a smaller box, or use the robust-box objective",
            code="UNREACHABLE")


def plan_baseline(request: PlanRequest, progress: Progress = None, *,
                  R: float = R_TERMINAL) -> PlanResult:
    """Time-optimal or energy-optimal plan for a validated 1-DOF request, with its sensitivities.

    ``steps``: the energy-optimal grid (default 100 when the request leaves it unset); ignored by
    the time-optimal plan. Sensitivities are central differences of q(tf) for ``uncertain``.
    """
    t_start = time.perf_counter()
    p = request.resolved_params()
    if request.model != "arm1dof" or not isinstance(p, Arm1DofParams):
        raise PlanningError(f"the {request.objective} baseline is implemented for arm1dof only "
                            f"(paper section 6.5); got model '{request.model}'",
                            code="INVALID_REQUEST")
    q0, qf = float(request.q0[0]), float(request.qf[0])
    if request.objective == "time-optimal":
        bl = time_optimal_1dof(p, q0, qf, request.tf, request.coast, R)
    elif request.objective == "energy-optimal":
        steps = int(request.steps) if request.steps else DEFAULT_ENERGY_STEPS
        bl = energy_optimal_1dof(p, q0, qf, request.tf, request.coast, steps, R)
    else:
        raise PlanningError(f"plan_baseline serves time-optimal and energy-optimal, not "
                            f"{request.objective!r}", code="INVALID_REQUEST")
    _check_limits(request, p, bl, q0)
    sim = simulate(p, bl.profile, [q0])
    names = list(request.uncertain) or list(p.friction_keys)
    fd = finite_differences(p, bl.profile, [q0], names)
    sens = {k: float(v[0][0]) for k, v in fd.items()}
    extra = {
        "energy_J": bl.energy, "R_ohm": bl.R, "t_arrival": bl.t_arrival,
        "sensitivities_qd": {k: float(v[1][0]) for k, v in fd.items()},
        "relative_sensitivities": {k: float(v[0][0]) * float(getattr(p, k)) for k, v in fd.items()},
        "rest_position": np.asarray(rest_position(p, bl.profile, [q0]), dtype=float).tolist(),
    }
    if request.objective == "time-optimal":
        arr = CurrentProfile(bl.profile.step_times, bl.profile.currents, bl.t_arrival, 0.0)
        fa = finite_differences(p, arr, [q0], names)
        extra["at_arrival"] = {k: {"dq": float(v[0][0]), "dqd": float(v[1][0])} for k, v in fa.items()}
    err = abs(float(sim.q_f[0]) - qf)
    ok = err <= 1e-6 and abs(float(sim.qd_f[0])) <= 1e-6
    robust = ok and all(abs(v) <= request.tol for v in sens.values())
    if progress is not None:
        progress({"objective": request.objective, "final_error": err})
    return PlanResult(
        success=ok, message=(f"{request.objective} baseline: reaches the goal to {err:.2e} rad; "
                             f"not designed for robustness" if ok else
                             f"{request.objective} baseline misses the goal by {err:.3e} rad"),
        profile=bl.profile, model=request.model, params=p, q0=np.array([q0]), qf=np.array([qf]),
        uncertain=names, objective=request.objective, q_final=np.asarray(sim.q_f, dtype=float),
        qd_final=np.asarray(sim.qd_f, dtype=float), sensitivities=sens, robust=robust,
        error_code="OK" if ok else "INTERNAL_ERROR", best_effort=not ok, starts_tried=1,
        iterations=1, solve_time=time.perf_counter() - t_start, extra=extra)
