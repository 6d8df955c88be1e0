"""2-DOF tasks in which link 2 must move: the least-worst-case-error plan, labelled best_effort.

No truly derivative-robust plan is known for these tasks (docs/scara2-model.md). This module
minimises, by least squares with complex-step Jacobians through the full 2-DOF simulation, the
final-position errors at nominal friction (weighted, so the goal is met) and at each friction
parameter changed by ±SAMPLE_FRACTION one at a time, plus the final velocities (rest at tf).
Units: rad, A, s.
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable, Optional

import numpy as np
from scipy.optimize import least_squares

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest, PlanResult
from ff_planner.optimize.sample_box import SAMPLE_LEVELS, one_at_a_time

SAMPLE_FRACTION = SAMPLE_LEVELS[0]   # each uncertain parameter at ±10 % alone
_W_NOMINAL = 10.0


class _Timeout(Exception):
    pass


class _Sampled:
    def __init__(self, p: Scara2Params, req: PlanRequest):
        self.p = p
        self.q0 = np.asarray(req.q0, float)
        self.qf = np.asarray(req.qf, float)
        self.N = req.n_steps()
        self.times = np.linspace(0.0, req.tf - req.coast, self.N + 1)
        self.prof = CurrentProfile(self.times, np.zeros((self.N, 2)), req.tf, req.coast)
        base = scara2._pack(p)
        idx = {"pv1": 0, "pv2": 1, "pc1": 2, "pc2": 3, "pt1": 4, "pt2": 5}
        self.Ps = [base]
        for n, change in one_at_a_time(req.uncertain, (SAMPLE_FRACTION,), signs=(1.0, -1.0)):
            P = base.copy()
            P[idx[n]] *= 1.0 + change
            self.Ps.append(P)
        self.y0 = np.concatenate([self.q0, np.zeros(2)]).astype(np.complex128)
        self.imax = np.array([p.i_max1, p.i_max2])

    def _final(self, P, cur):
        r = scara2._run(P, self.prof, self.y0, scara2.DEFAULT_H, currents=cur)
        return r[0]

    deadline = math.inf
    best_x = None
    best_score = math.inf

    def residuals(self, x: np.ndarray, jac: bool = False):
        if time.perf_counter() > self.deadline:
            raise _Timeout
        cur = x.reshape(self.N, 2)
        res = []
        J = []
        for k, P in enumerate(self.Ps):
            y = self._final(P, cur.astype(np.complex128))
            w = _W_NOMINAL if k == 0 else 1.0
            res.extend(w * (y[:2].real - self.qf))
            res.extend(y[2:].real)
            if jac:
                if time.perf_counter() > self.deadline:
                    raise _Timeout
                rows = np.zeros((4, x.size))
                for i in range(x.size):
                    c = cur.astype(np.complex128).ravel()
                    c[i] += 1e-30j
                    yi = self._final(P, c.reshape(self.N, 2))
                    d = yi.imag / 1e-30
                    rows[:2, i] = w * d[:2]
                    rows[2:, i] = d[2:]
                J.append(rows)
        if jac:
            return np.array(res), np.vstack(J)
        r = np.array(res)
        score = float(np.sum(r ** 2))
        if score < self.best_score:
            self.best_score, self.best_x = score, x.copy()
        return r

    def jac(self, x):
        return self.residuals(x, jac=True)[1]

    def start(self, rng) -> np.ndarray:
        """Bang-bang-like guess: accelerate for the first half, decelerate for the second."""
        A, B, C = scara2.inertia_constants(self.p)
        K = np.array([self.p.n1 * self.p.kt1, self.p.n2 * self.p.kt2])
        T = self.times[-1]
        dq = self.qf - self.q0
        acc = 4.0 * dq / T ** 2
        tq = np.array([A, C]) * acc
        x = np.zeros((self.N, 2))
        half = self.N // 2
        x[:half] = tq / K
        x[half:] = -tq / K
        x += rng.normal(0.0, 0.5, x.shape)
        return np.clip(x, -self.imax, self.imax).ravel()


def plan_least_worst(request: PlanRequest, p: Scara2Params, progress: Optional[Callable],
                     t_start: float) -> PlanResult:
    """Least worst-case-error plan for a task that moves link 2 (never labelled robust unless it
    truly is: the 12 complex-step derivatives are checked)."""
    prob = _Sampled(p, request)
    rng = np.random.default_rng(request.seed)
    deadline = t_start + float(request.time_budget)
    lb = -np.tile(prob.imax, prob.N)
    best = None
    starts = iters = 0
    while starts < min(request.starts, 20) and time.perf_counter() < deadline:
        starts += 1
        x0 = prob.start(rng)
        prob.deadline = deadline
        prob.best_x, prob.best_score = None, math.inf
        try:
            sol = least_squares(prob.residuals, x0, jac=prob.jac, bounds=(lb, -lb),
                                method="trf", max_nfev=40, xtol=1e-12, ftol=1e-12)
            iters += sol.nfev
            xs = sol.x
        except _Timeout:
            if prob.best_x is None:
                break
            xs = prob.best_x
        prob.deadline = math.inf
        r = prob.residuals(xs)
        nominal_err = float(np.max(np.abs(r[:2]))) / _W_NOMINAL
        worst = float(np.max(np.abs(r.reshape(-1, 4)[1:, :2]))) if len(prob.Ps) > 1 else 0.0
        score = worst + 10.0 * nominal_err + float(np.max(np.abs(r[2:4])))
        if best is None or score < best[0]:
            best = (score, xs.copy(), nominal_err, worst)
        if progress:
            progress({"stage": "least-worst", "starts_done": starts, "best": best[0],
                      "elapsed": time.perf_counter() - t_start})
    elapsed = time.perf_counter() - t_start
    common: dict[str, Any] = dict(model="scara2", params=p, q0=np.asarray(request.q0, float),
                  qf=np.asarray(request.qf, float), uncertain=list(request.uncertain),
                  objective=request.objective, starts_tried=starts, iterations=iters,
                  solve_time=elapsed)
    if best is None:
        return PlanResult(success=False, message="time budget too short for a 2-DOF plan",
                          profile=None, error_code="TIME_BUDGET_EXHAUSTED", **common)
    _, x, nominal_err, worst = best
    profile = CurrentProfile(prob.times, x.reshape(prob.N, 2), request.tf, request.coast)
    sim = scara2._simulate_raw(p, profile, prob.q0, np.zeros(2))
    sens = scara2.sensitivities_scara2(p, profile, prob.q0, request.uncertain)
    sens = {k: v for k, v in sens.items() if k.startswith("q") and not k.startswith("qd")}
    smax = max(abs(v) for v in sens.values()) if sens else 0.0
    err = float(np.max(np.abs(sim.q_f - prob.qf)))
    robust = smax <= request.tol and err <= request.tol and all(sim.stuck_tf)
    msg = (f"link 2 must move: no truly robust plan is known for such tasks; returning the "
           f"least-worst-case plan (nominal error {err:.2g} rad, worst error at ±"
           f"{int(SAMPLE_FRACTION * 100)} % one-at-a-time {worst:.2g} rad, max |dq/dp| "
           f"{smax:.2g}) — NOT derivative-robust")
    if robust:
        msg = "robust plan (link 2 moving)"
    return PlanResult(success=robust, robust=robust, best_effort=not robust,
                      error_code="OK" if robust else "NO_ROBUST_PLAN", message=msg,
                      profile=profile, q_final=sim.q_f, qd_final=sim.qd_f, sensitivities=sens,
                      extra={"method": "least-worst-sampled", "nominal_error": err,
                             "worst_sampled_error": worst, "sample_fraction": SAMPLE_FRACTION,
                             "max_sensitivity": smax}, **common)


#: pv1 pc1 pt1 pv2 pc2 pt2 in scara2's packed parameter vector
_FRICTION_SLOTS = (0, 2, 4, 1, 3, 5)


def _robust_residual(base: np.ndarray, prof: CurrentProfile, cur: np.ndarray, y0: np.ndarray,
                     qf: np.ndarray, step: float) -> np.ndarray:
    """[10·(q(tf) − qf) (rad), q̇(tf) (rad/s), ∂q_j(tf)/∂p_i · p_i (rad, 12)] of ``prof`` with
    the currents ``cur`` (complex, A) from ``y0``, simulated at substep ``step`` (s); the
    sensitivities by complex steps of each friction parameter of the packed vector ``base``."""
    y = scara2._run(base, prof, y0, step, currents=cur)[0]
    r = [10 * (y[0].real - qf[0]), 10 * (y[1].real - qf[1]), y[2].real, y[3].real]
    for i in _FRICTION_SLOTS:
        Pc = base.copy()
        d = 1e-30 * abs(Pc[i].real)
        Pc[i] += 1j * d
        yc = scara2._run(Pc, prof, y0, step, currents=cur)[0]
        r += [yc[0].imag / d * Pc[i].real, yc[1].imag / d * Pc[i].real]
    return np.array(r)


def _forward_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                      eps: float = 1e-6) -> np.ndarray:
    """∂fun/∂x by forward differences of step ``eps`` (x's unit)."""
    f0 = fun(x)
    J = np.zeros((f0.size, x.size))
    for k in range(x.size):
        xp = x.copy()
        xp[k] += eps
        J[:, k] = (fun(xp) - f0) / eps
    return J


def derivative_search(p: Scara2Params, q0, qf, tf: float, n_steps: int, seconds: float,
                      seed: int = 0, coast: float = 0.05) -> dict:
    """Evidence search for a derivative-robust plan of a task that moves link 2: multistart least
    squares on [10·(q(tf) − qf), q̇(tf), ∂q_j(tf)/∂p_i · p_i (12)] over 2·n_steps free currents,
    complex-step derivatives through the full model, finite-difference Jacobian. Returns the best
    residual found (0 would mean a truly robust plan) and how many starts ran."""
    q0 = np.asarray(q0, float)
    qf = np.asarray(qf, float)
    times = np.linspace(0.0, tf - coast, n_steps + 1)
    prof = CurrentProfile(times, np.zeros((n_steps, 2)), tf, coast)
    base = scara2._pack(p)
    y0 = np.r_[q0, 0.0, 0.0].astype(np.complex128)

    def res(x: np.ndarray) -> np.ndarray:
        cur = x.reshape(n_steps, 2).astype(np.complex128)
        return _robust_residual(base, prof, cur, y0, qf, scara2.DEFAULT_H)

    def jac(x: np.ndarray) -> np.ndarray:
        return _forward_jacobian(res, x)

    rng = np.random.default_rng(seed)
    lim = np.tile([p.i_max1, p.i_max2], n_steps)
    best, starts, t0 = math.inf, 0, time.perf_counter()
    best_x = None
    while time.perf_counter() - t0 < seconds:
        starts += 1
        try:
            sol = least_squares(res, rng.uniform(-3, 3, 2 * n_steps), jac=jac, bounds=(-lim, lim),
                                method="trf", max_nfev=60, xtol=1e-12, ftol=1e-12)
        except Exception:
            continue
        m = float(np.max(np.abs(sol.fun)))
        if m < best:
            best, best_x = m, sol.x.copy()
    return {"task": [q0.tolist(), qf.tolist()], "tf": tf, "n_steps": n_steps,
            "seconds": seconds, "starts": starts, "best_max_scaled_residual": best,
            "best_currents": None if best_x is None else best_x.reshape(n_steps, 2).tolist()}


def robust_search(p: Scara2Params, q0, qf, tf: float, n_steps: int, seconds: float, *,
                  seed: int = 0, coast: float = 0.05, free_times: bool = False,
                  h: float = 2e-3, max_nfev: int = 40, spread: float = 3.0,
                  initial: Optional[list] = None) -> dict:
    """Evidence search for a truly robust plan of a task that moves link 2, as
    ``derivative_search`` but with optional free (unequal) step durations: the N durations are
    (tf − coast)·softmax(u), u ∈ [−2, 2]^N (ratios up to e^4 between steps). Multistart least
    squares on [10·(q(tf) − qf), q̇(tf), ∂q_j(tf)/∂p_i · p_i (12)] over the 2N currents (and u),
    complex-step sensitivities through the full model at substep ``h`` (s), forward-difference
    Jacobian, until ``seconds`` have passed (at least one start). ``best_first_order_optimality``:
    ‖Jᵀr‖∞ at the best point (≈ 0 with a residual ≠ 0: a local minimum that is not a robust plan).
    The best point is re-simulated at the default substep:
    its largest |scaled residual| (0 for a truly robust plan), goal error (rad), final speeds
    (rad/s), largest |∂q/∂p| (rad per unit) and whether both links are at rest at tf.
    ``initial``: start points (the search vector: 2N currents row-major, then u with free
    times) tried before the random ones, e.g. for a continuation from a neighbouring task."""
    q0 = np.asarray(q0, float)
    qf = np.asarray(qf, float)
    span = float(tf - coast)
    base = scara2._pack(p)
    y0 = np.r_[q0, 0.0, 0.0].astype(np.complex128)
    nc = 2 * n_steps

    def profile_of(x: np.ndarray) -> CurrentProfile:
        if free_times:
            w = np.exp(x[nc:] - np.max(x[nc:]))
            times = np.r_[0.0, np.cumsum(w / w.sum())] * span
            times[-1] = span
        else:
            times = np.linspace(0.0, span, n_steps + 1)
        return CurrentProfile(times, x[:nc].reshape(n_steps, 2), tf, coast)

    def res(x: np.ndarray, step: float = h) -> np.ndarray:
        prof = profile_of(x)
        return _robust_residual(base, prof, prof.currents.astype(np.complex128), y0, qf, step)

    def jac(x: np.ndarray) -> np.ndarray:
        return _forward_jacobian(res, x)

    rng = np.random.default_rng(seed)
    lim = np.tile([p.i_max1, p.i_max2], n_steps)
    lo, hi = -lim, lim
    if free_times:
        lo = np.r_[lo, np.full(n_steps, -2.0)]
        hi = np.r_[hi, np.full(n_steps, 2.0)]
    best, starts, t0 = math.inf, 0, time.perf_counter()
    best_x: Optional[np.ndarray] = None
    best_opt = math.nan
    queue = [np.asarray(x, dtype=float) for x in (initial or [])]
    while starts == 0 or time.perf_counter() - t0 < seconds:
        starts += 1
        if queue:
            x0 = np.clip(queue.pop(0), lo, hi)
        else:
            x0 = rng.uniform(-spread, spread, nc)
            if free_times:
                x0 = np.r_[x0, np.zeros(n_steps)]
        try:
            sol = least_squares(res, x0, jac=jac, bounds=(lo, hi), method="trf",
                                max_nfev=max_nfev, xtol=1e-12, ftol=1e-12)
        except (PlanningError, ValueError, ArithmeticError):
            continue
        m = float(np.max(np.abs(sol.fun)))
        if m < best:
            best, best_x, best_opt = m, sol.x.copy(), float(sol.optimality)
    out: dict = {"task": [q0.tolist(), qf.tolist()], "tf": tf, "coast": coast,
                 "n_steps": n_steps, "free_times": free_times, "seconds": seconds,
                 "starts": starts,
                 "best_max_scaled_residual": best if math.isfinite(best) else None,
                 "best_first_order_optimality": best_opt}
    if best_x is not None:
        prof = profile_of(best_x)
        r = res(best_x, scara2.DEFAULT_H)
        sim = scara2.simulate_detail(p, prof, q0)
        out.update(best_max_scaled_residual_1ms=float(np.max(np.abs(r))),
                   goal_error_rad=float(np.max(np.abs(sim.q_f - qf))),
                   final_speed_rad_s=[float(v) for v in sim.qd_f],
                   max_abs_sensitivity=float(np.max(np.abs(r[4:].reshape(6, 2) / np.array(
                       [[float(base[i].real)] for i in _FRICTION_SLOTS])))),
                   at_rest_tf=bool(all(sim.stuck_tf)),
                   step_times_s=[float(t) for t in prof.step_times], best_x=best_x.tolist(),
                   currents_A=prof.currents.tolist())
    return out
