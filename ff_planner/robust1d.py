"""Robust feedforward planning for the 1-DOF arm (paper Eq. 7, section 4.1) at compiled speed.

``plan_robust_1dof(request, progress=None, initial_currents=None) -> PlanResult``

- objective "robust-derivative": N piecewise-constant currents (equal steps on [0, tf − coast]),
  |I| ≤ i_max, such that q(tf) = qf, the arm is at rest at tf, and every ∂q(tf)/∂p_i = 0 for the
  uncertain friction parameters. Seeded multistart of a compiled Levenberg–Marquardt solver with
  exact Jacobians (``_lm1d``); the first start that meets the tolerances with true derivatives is
  verified and returned. Starts are drawn 16 at a time: alternately from a narrow box (±0.2·i_max
  for k ≥ 2, ±0.3·i_max for k = 1) with the first and last currents opposing the move (robust
  motions first move away from the goal, paper 4.1.2), and from a wide box (±0.8·i_max). A plan within 0.1 % (relative parameter change) of a non-smooth point
  (zero crossing at a switch time, breakaway edge) is refused: its one-sided derivatives differ.
- objective "robust-sampled" (section 6.2): among robust plans, the one — refined by SLSQP along
  the robust set — with the least RMS error of the REST position over sampled parameter values
  (each uncertain parameter at ±10 % and ±20 %, and the corners of the ±20 % box). When no
  derivative-robust plan is found it minimises that RMS subject to reaching qf at rest only.

When no plan meets the tolerances the best one is returned with success=False,
best_effort=True and error_code NO_ROBUST_PLAN (or TIME_BUDGET_EXHAUSTED); the message says so.
The result's ``extra`` carries the verification: central-difference derivatives (1e-6 relative),
the 0.1 % forward quotients, the kink radius, the finite-change errors of the rest position and of
q(tf) at ±10 % and ±40 % per parameter and all together ("finite_change"), and solver statistics.
"""
from __future__ import annotations

import itertools
import math
import time
from typing import Callable, Optional, Sequence

import numpy as np

from . import _lm1d
from ._deriv1d import NP, Q_, VC_, hd_sim, workspace
from .arm1dof import FRICTION, batch_core, derivatives, friction_scale
from .params import Arm1DofParams
from .profile import CurrentProfile, PlanRequest, PlanResult, PlanningError

Progress = Optional[Callable[[dict], None]]

STOP_MARGIN = 1e-3      # s: the arm must be at rest this long before tf (nominal parameters)
MIN_KINK = 1e-3         # relative parameter change to the nearest non-smooth point (0.1 %)
CHUNK = 16              # starts per compiled call (the time budget is checked between calls)
SAMPLED_CANDIDATES = 4  # robust-sampled: robust plans collected, each refined by SLSQP
# LM settings per number of uncertain parameters, tuned on 3000 seeded starts of the 0 -> 1 rad,
# 1 s task (CPU time per robust plan: k = 1 ~55-90 us, k = 3 ~450 us); "spread" = random starts
# uniform in ±spread·i_max.
LM_SETTINGS = {
    1: dict(wpen=0.1, wq=1.0, lam0=1e-2, max_iter=25, abandon_iter=3, abandon_norm=1e-2,
            max_reject=3, lam_down=0.1, lam_up=5.0, spread=0.3),
    3: dict(wpen=0.1, wq=3.0, lam0=1e-2, max_iter=25, abandon_iter=4, abandon_norm=1e-3,
            max_reject=5, lam_down=0.1, lam_up=5.0, spread=0.2),
}


WIDE_SPREAD = 0.8   # every other chunk of random starts uses ±0.8·i_max


def lm_settings(k: int) -> dict:
    """The LM settings for k uncertain parameters."""
    return LM_SETTINGS[1] if k <= 1 else LM_SETTINGS[3]


def stop_speed_bound(params: Arm1DofParams, coast: float, margin: float = STOP_MARGIN) -> float:
    """Largest coast-entry speed (rad/s) from which zero current stops the arm ``margin`` s
    before tf: |v| = (pc/J)·τ·φ1(−aτ), τ = coast − margin, a = −pv/J."""
    tau = coast - margin
    if tau <= 0.0:
        return 0.0
    a = -params.pv / params.J
    z = -a * tau
    phi1 = math.expm1(z) / z if z != 0.0 else 1.0
    return params.pc / params.J * tau * phi1


def sample_scales(uncertain: Sequence[str], levels: Sequence[float] = (0.1, 0.2),
                  corner: float = 0.2) -> np.ndarray:
    """Parameter scale factors (S, 3) for pv, pc, pt: each uncertain one at ±levels alone, and
    the corners of the ±corner box."""
    idx = [FRICTION.index(u) for u in uncertain]
    rows = []
    for i in idx:
        for lv in levels:
            for sg in (-1.0, 1.0):
                r = np.ones(NP)
                r[i] = 1.0 + sg * lv
                rows.append(r)
    if len(idx) > 1:
        for signs in itertools.product((-1.0, 1.0), repeat=len(idx)):
            r = np.ones(NP)
            for i, sg in zip(idx, signs):
                r[i] = 1.0 + sg * corner
            rows.append(r)
    return np.array(rows) if rows else np.ones((1, NP))


CHANGES = (-0.4, -0.1, 0.1, 0.4)


def finite_change(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float,
                  uncertain: Sequence[str], changes: Sequence[float] = CHANGES) -> dict:
    """Errors (rad) of the rest position and of q(tf), and q̇(tf), when friction parameters are
    off by finite relative ``changes`` — one at a time and all uncertain ones together.
    rest_error is None where the arm never stops (negative viscous friction outrunning
    Coulomb friction at that speed)."""
    return verify(params, profile, q0, qf, uncertain, changes=changes)["finite_change"]


def _sweep_rows(params: Arm1DofParams, uncertain: Sequence[str], changes: Sequence[float]):
    """Friction rows (M, 3) and rest flags (M,) for one verification sweep, with the layout:
    row 0 nominal; per uncertain p: +h, −h (central, 1e-6 of its scale), +hf (0.1 % forward);
    then per group (each p, and all together) and change: (at tf, to rest) pairs."""
    base = np.array([params.pv, params.pc, params.pt], dtype=float)
    scale = friction_scale(params, uncertain)        # |p|, or a default where p = 0
    idx = [FRICTION.index(k) for k in uncertain]
    rows = [base]
    for i in idx:
        for step in (1e-6, -1e-6, 1e-3):
            r = base.copy()
            r[i] += step * scale[i]
            rows.append(r)
    groups = [[i] for i in idx] + ([idx] if len(idx) > 1 else [])
    for g in groups:
        for ch in changes:
            r = base.copy()
            r[g] *= 1.0 + ch
            rows.append(r)
            rows.append(r)
    rest = np.zeros(len(rows), dtype=np.bool_)
    rest[1 + 3 * len(idx) + 1::2] = True
    return np.array(rows), rest, scale, groups


def verify(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float,
           uncertain: Sequence[str], tol: float = 1e-6, changes: Sequence[float] = CHANGES
           ) -> dict:
    """Judge a plan by true derivatives: exact, central differences (1e-6 relative) and the
    paper's 0.1 % forward quotient; the kink radius; goal and rest at tf; finite changes
    (rest position and q(tf) errors at ``changes``, one parameter at a time and all together).
    All simulations run in one compiled call."""
    uncertain = list(uncertain)
    d = derivatives(params, profile, q0, uncertain=uncertain)
    rows, rest, scale, groups = _sweep_rows(params, uncertain, changes)
    q, v = batch_core(float(params.J), float(params.n * params.kt), rows, rest,
                      np.ascontiguousarray(profile.step_times, dtype=float),
                      np.ascontiguousarray(profile.currents[:, 0], dtype=float),
                      float(profile.tf), float(q0))
    q_tf, v_tf = float(q[0]), float(v[0])
    central, forward = {}, {}
    for m, k in enumerate(uncertain):
        sc = scale[FRICTION.index(k)]
        central[k] = float((q[1 + 3 * m] - q[2 + 3 * m]) / (2e-6 * sc))
        forward[k] = float((q[3 + 3 * m] - q_tf) / (1e-3 * sc))
    fc: dict = {}
    j = 1 + 3 * len(uncertain)
    for g in groups:
        name = FRICTION[g[0]] if len(g) == 1 else "all"
        row = {}
        for ch in changes:
            q_rest = float(q[j + 1] - qf)
            row[f"{ch * 100:+.0f}%"] = {"rest_error": q_rest if math.isfinite(q_rest) else None,
                                        "tf_error": float(q[j] - qf), "qd_tf": float(v[j])}
            j += 2
        fc[name] = row
    exact = {k: d.dq_dp[k] for k in uncertain}
    worst = max([abs(x) for x in exact.values()] + [abs(x) for x in central.values()] + [0.0])
    at_goal = abs(q_tf - qf) <= tol
    at_rest = v_tf == 0.0
    within = bool(np.all(np.abs(profile.currents) <= params.i_max + 1e-12))
    robust = bool(worst <= tol and d.smooth and at_goal and at_rest and within)
    return {"robust": robust, "exact": exact, "central": central, "forward_0.1%": forward,
            "qd_exact": {k: d.dqd_dp[k] for k in uncertain}, "max_abs_derivative": worst,
            "kink_radius": d.kink_radius, "tf_radius": d.tf_radius, "t_stop": d.t_stop,
            "q_tf": q_tf, "qd_tf": v_tf, "at_goal": at_goal, "at_rest": at_rest,
            "within_limits": within, "finite_change": fc}


class _Problem:
    """The compiled solver's arguments for one request."""

    def __init__(self, request: PlanRequest, params: Arm1DofParams, n: int,
                 grid: Optional[float] = None):
        self.params = params
        self.n = n
        self.tf = float(request.tf)
        self.coast = float(request.coast)
        self.times = step_times(self.tf, self.coast, n, grid)
        self.q0 = float(request.q0[0])
        self.goal = float(request.qf[0])
        self.umask = np.array([k in request.uncertain for k in FRICTION])
        self.pvals = np.array([params.pv, params.pc, params.pt], dtype=float)   # values
        # scales of the derivative rows (|p|, or a default where p = 0), zero if not uncertain
        self.pscale = friction_scale(params, [k for k in FRICTION if k in request.uncertain])
        self.i_max = float(params.i_max)
        self.vb = stop_speed_bound(params, self.coast)
        self.W = workspace(n)
        self.tol_q = 0.1 * float(request.tol)
        self.tol_d = 0.1 * float(request.tol)
        self.settings = lm_settings(int(self.umask.sum()))

    def args(self):
        p = self.params
        return (p.J, p.n * p.kt, p.pv, p.pc, p.pt, self.times, self.tf, self.q0, self.goal,
                self.umask, self.pscale, self.i_max)

    def run(self, starts: np.ndarray, stop_first: bool):
        s = self.settings
        m = starts.shape[0]
        st = np.zeros(m, np.int64)
        it = np.zeros(m, np.int64)
        f = np.full(m, np.inf)
        kk = np.zeros(m)
        done = _lm1d.multistart(*self.args(), starts, self.W, self.vb, s["wpen"], s["wq"],
                                s["lam0"], self.tol_q, self.tol_d, MIN_KINK, s["max_iter"],
                                s["abandon_iter"], s["abandon_norm"], s["max_reject"],
                                s["lam_down"], s["lam_up"], stop_first, st, it, f, kk)
        return done, st, it, f, kk

    def profile(self, currents: np.ndarray) -> CurrentProfile:
        return CurrentProfile(self.times.copy(), np.asarray(currents, float).reshape(-1, 1),
                              self.tf, self.coast)


def step_times(tf: float, coast: float, n: int, grid: Optional[float] = None) -> np.ndarray:
    """N+1 step boundaries (s) on [0, tf − coast]: equal steps, or with ``grid`` (s, e.g. the
    drive's 1 ms cycle) each boundary rounded to the grid, the last one at or before tf − coast,
    so that the executed profile is exactly the optimised one."""
    end = tf - coast
    if grid is None:
        return np.linspace(0.0, end, n + 1)
    if not (math.isfinite(grid) and grid > 0.0):
        raise PlanningError(f"grid must be a positive number of seconds, got {grid}")
    cells = math.floor(end / grid + 1e-9)
    if cells < n:
        raise PlanningError(f"{n} steps do not fit on a {grid} s grid within tf - coast = "
                            f"{end} s; use fewer steps or a finer grid")
    k = np.round(np.linspace(0, cells, n + 1)).astype(np.int64)
    return k * grid


def _check_request(request: PlanRequest) -> Arm1DofParams:
    request.validate()
    if request.model != "arm1dof":
        raise PlanningError(f"plan_robust_1dof plans the arm1dof model, not '{request.model}'")
    if request.objective not in ("robust-derivative", "robust-sampled"):
        raise PlanningError(f"plan_robust_1dof serves robust-derivative and robust-sampled, not "
                            f"{request.objective!r}")
    if not request.uncertain:
        raise PlanningError("name at least one uncertain friction parameter (pv, pc, pt)")
    if request.coast <= STOP_MARGIN:
        raise PlanningError(f"coast must exceed {STOP_MARGIN} s so that the arm can stop in it")
    return request.resolved_params()


def plan_robust_1dof(request: PlanRequest, progress: Progress = None,
                     initial_currents: Optional[np.ndarray] = None,
                     grid: Optional[float] = None) -> PlanResult:
    """Plan a robust rest-to-rest move of the 1-DOF arm; see the module docstring.

    initial_currents: (N,) A, a warm start tried first (e.g. a motion-library neighbour).
    grid: put the switch times on this grid (s), e.g. 1e-3 for a 1 kHz drive (also read from
    ``request.grid`` when the request has that field).
    """
    t0 = time.perf_counter()
    params = _check_request(request)
    n = request.n_steps()
    if grid is None:
        grid = getattr(request, "grid", None)
    prob = _Problem(request, params, n, grid)
    rng = np.random.default_rng(request.seed)
    spread = prob.settings["spread"] * prob.i_max
    total = int(request.starts)
    warm_block = None
    if initial_currents is not None:
        init = np.asarray(initial_currents, dtype=float).reshape(-1)
        if init.shape != (n,) or not np.all(np.isfinite(init)):
            raise PlanningError(f"initial_currents needs {n} finite values, got {init.size}")
        warm_block = np.clip(init, -prob.i_max, prob.i_max).reshape(1, n)
    warm = warm_block is not None
    sampled = request.objective == "robust-sampled"
    want = SAMPLED_CANDIDATES if sampled else 1     # robust candidates to collect
    found: list[np.ndarray] = []
    best_f, best_I = math.inf, None
    tried = iters = 0
    counts = np.zeros(5, np.int64)
    out_of_time = False
    drawn = 0
    while drawn < total or warm_block is not None:
        if time.perf_counter() - t0 > request.time_budget:
            out_of_time = True
            break
        if warm_block is not None:       # the warm start runs alone, first
            block, warm_block = warm_block, None
        else:                            # seeded random starts, drawn chunk by chunk
            m = min(CHUNK, total - drawn)
            # even chunks: the spread tuned on the paper's task, signs as below; odd chunks:
            # a wide, unconstrained one, which finds plans sooner for longer or slower moves
            wide = (drawn // CHUNK) % 2 == 1
            s_c = WIDE_SPREAD * prob.i_max if wide else spread
            block = rng.uniform(-s_c, s_c, (m, n))
            if not wide and n >= 2 and prob.goal != prob.q0:
                # robust motions first move away from the goal (paper section 4.1.2) and brake
                # at the end: the first and last currents oppose the move on these chunks
                d = 1.0 if prob.goal > prob.q0 else -1.0
                block[:, 0] = -d * np.abs(block[:, 0])
                block[:, -1] = -d * np.abs(block[:, -1])
            drawn += m
        done, st, it, f, kk = prob.run(block, stop_first=not sampled)
        tried += done
        iters += int(it[:done].sum())
        counts += np.bincount(st[:done], minlength=5)
        for s in range(done):
            if st[s] == _lm1d.OK:
                found.append(block[s].copy())
            elif f[s] < best_f:
                best_f, best_I = f[s], block[s].copy()
        if progress is not None:
            progress({"starts_done": tried, "robust_found": len(found),
                      "best": float(min(best_f, 0.0 if found else best_f))})
        if len(found) >= want:
            break
    stats = {"starts_ok": int(counts[_lm1d.OK]), "starts_abandoned": int(counts[_lm1d.ABANDONED]),
             "starts_unconverged": int(counts[_lm1d.NO_CONVERGENCE]),
             "starts_at_kink": int(counts[_lm1d.KINK]), "n_steps": n,
             "stop_speed_bound": prob.vb, "search_time_s": time.perf_counter() - t0}

    if sampled:
        return _finish_sampled(request, prob, found, best_I, tried, iters, warm, t0, stats,
                               out_of_time)
    if found:
        return _result(request, prob, found[0], True, "", tried, iters, warm, t0, stats)
    return _no_plan(request, prob, best_I, tried, iters, warm, t0, stats, out_of_time)


def _no_plan(request, prob, best_I, tried, iters, warm, t0, stats, out_of_time) -> PlanResult:
    code = "TIME_BUDGET_EXHAUSTED" if out_of_time else "NO_ROBUST_PLAN"
    k = len(request.uncertain)
    why = (f"no truly robust plan with N = {prob.n} steps for k = {k} uncertain parameter(s) "
           f"in {tried} start(s)")
    if out_of_time:
        why += f" within the time budget of {request.time_budget} s"
    elif prob.n < k + 2:
        why += f" (N = 2 + k = {k + 2} steps are needed for the equations to be solvable)"
    else:
        why += "; try more steps (longer moves need more) or a longer move time"
    if best_I is None:
        res = PlanResult(False, why, None, "arm1dof", prob.params, np.array([prob.q0]),
                         np.array([prob.goal]), list(request.uncertain), request.objective,
                         error_code=code, starts_tried=tried, iterations=iters,
                         solve_time=time.perf_counter() - t0, warm_start=warm, extra=stats)
        return res
    return _result(request, prob, best_I, False, why, tried, iters, warm, t0, stats, code=code)


def _result(request, prob, currents, success, message, tried, iters, warm, t0, stats,
            code="OK", extra=None) -> PlanResult:
    prof = prob.profile(currents)
    uncertain = list(request.uncertain)
    check = verify(prob.params, prof, prob.q0, prob.goal, uncertain, request.tol)
    robust = check["robust"]
    if success and not robust:    # the compiled solver's claim did not survive verification
        success, code = False, "NO_ROBUST_PLAN"
        message = "best plan failed the true-derivative verification"
    if success and not message:
        message = (f"truly robust plan: max |dq(tf)/dp| = {check['max_abs_derivative']:.1e} "
                   f"(exact and central differences), |q(tf) - qf| = "
                   f"{abs(check['q_tf'] - prob.goal):.1e} rad, at rest at tf")
    ex = dict(stats)
    ex.update(verification={k: v for k, v in check.items() if k != "finite_change"},
              finite_change=check["finite_change"])
    if extra:
        ex.update(extra)
    q_tf, v_tf = check["q_tf"], check["qd_tf"]
    res = PlanResult(
        success=bool(success), message=message, profile=prof, model="arm1dof",
        params=prob.params, q0=np.array([prob.q0]), qf=np.array([prob.goal]),
        uncertain=uncertain, objective=request.objective, q_final=np.array([q_tf]),
        qd_final=np.array([v_tf]), sensitivities=dict(check["exact"]), robust=bool(robust),
        error_code=code, best_effort=not success, starts_tried=tried, iterations=iters,
        solve_time=time.perf_counter() - t0, warm_start=warm, extra=ex)
    return res


# --- robust-sampled -----------------------------------------------------------------------------
def _sampled_terms(prob: _Problem, I: np.ndarray, scales: np.ndarray):
    """Rest-position errors at the sampled parameters and their Jacobian w.r.t. I."""
    p = prob.params
    return _lm1d.sampled_terms(p.J, p.n * p.kt, prob.pvals, np.ascontiguousarray(scales),
                               prob.times, np.ascontiguousarray(I, dtype=float), prob.tf,
                               prob.q0, prob.goal, prob.W)


def _constraints(prob: _Problem, I: np.ndarray, with_derivs: bool):
    """Equalities [q(tf) − qf, scaled ∂q/∂p_i] and inequality vb − |v_coast| with Jacobians."""
    p = prob.params
    W = prob.W
    pw = prob.pscale
    hd_sim(p.J, p.n * p.kt, p.pv, p.pc, p.pt, prob.times, I, prob.tf, prob.q0, False, pw, W)
    n = prob.n
    eq = [W[Q_, 0] - prob.goal]
    jeq = [W[Q_, 4:4 + n].copy()]
    if with_derivs:
        base = 4 + n
        for i in range(NP):
            if prob.umask[i]:
                eq.append(W[Q_, 1 + i] * prob.pscale[i])
                jeq.append(W[Q_, base + i * n: base + (i + 1) * n] * prob.pscale[i])
    vc = W[VC_, 0]
    ineq = prob.vb * 0.98 - abs(vc)
    jin = -np.sign(vc) * W[VC_, 4:4 + n]
    return np.array(eq), np.array(jeq), ineq, jin


def _refine_sampled(prob: _Problem, I0: np.ndarray, scales: np.ndarray, with_derivs: bool,
                    budget: float) -> tuple[np.ndarray, float]:
    """SLSQP on the sampled RMS from I0, keeping the equalities (exact Jacobians)."""
    from scipy.optimize import minimize

    m = scales.shape[0]

    def fun(I):
        e, G = _sampled_terms(prob, I, scales)
        return float(e @ e / m), 2.0 * (G.T @ e) / m

    memo: dict = {}

    def con(I):
        key = I.tobytes()
        if key not in memo:
            memo.clear()
            memo[key] = _constraints(prob, np.ascontiguousarray(I, dtype=float), with_derivs)
        return memo[key]

    cons = [{"type": "eq", "fun": lambda I: con(I)[0], "jac": lambda I: con(I)[1]},
            {"type": "ineq", "fun": lambda I: np.array([con(I)[2]]),
             "jac": lambda I: con(I)[3].reshape(1, -1)}]
    bounds = [(-prob.i_max, prob.i_max)] * prob.n
    deadline = time.perf_counter() + budget

    def stop_at_deadline(xk):
        if time.perf_counter() > deadline:
            raise StopIteration     # SLSQP returns its current iterate

    res = minimize(fun, I0, jac=True, method="SLSQP", bounds=bounds, constraints=cons,
                   options={"maxiter": 200, "ftol": 1e-12}, callback=stop_at_deadline)
    return np.asarray(res.x, float), float(math.sqrt(max(res.fun, 0.0)))


def _rms(prob: _Problem, I: np.ndarray, scales: np.ndarray) -> float:
    e, _ = _sampled_terms(prob, I, scales)
    return float(np.sqrt(np.mean(e * e))) if np.all(np.isfinite(e)) else math.inf


def _finish_sampled(request, prob, found, best_I, tried, iters, warm, t0, stats, out_of_time):
    scales = sample_scales(request.uncertain)
    with_derivs = bool(found)
    cands = found if found else ([best_I] if best_I is not None else [])
    best, best_rms = None, math.inf
    for I0 in cands:
        rms0 = _rms(prob, I0, scales)
        if rms0 < best_rms:
            best, best_rms = I0, rms0
    if best is None:
        return _no_plan(request, prob, None, tried, iters, warm, t0, stats, out_of_time)
    rms_before = best_rms
    # refine each candidate along the robust set (SLSQP, exact Jacobians); keep the best that
    # still verifies, within the time budget
    for I0 in sorted(cands, key=lambda c: _rms(prob, c, scales)):
        if time.perf_counter() - t0 > request.time_budget:
            break
        try:
            left = request.time_budget - (time.perf_counter() - t0)
            I1, _ = _refine_sampled(prob, I0.copy(), scales, with_derivs, left)
        except (ValueError, ArithmeticError):
            continue
        rms1 = _rms(prob, I1, scales)
        if not rms1 < best_rms:
            continue
        ok = verify(prob.params, prob.profile(I1), prob.q0, prob.goal, request.uncertain,
                    request.tol)
        if ok["robust"] if with_derivs else (ok["at_goal"] and ok["at_rest"]):
            best, best_rms = I1, rms1
    extra = {"sampled_rms": best_rms, "sampled_rms_before_refine": rms_before,
             "sampled_points": scales.tolist(), "sampled_worst": float(
                 np.max(np.abs(_sampled_terms(prob, best, scales)[0])))}
    if with_derivs:
        return _result(request, prob, best, True,
                       f"robust plan with least sampled rest-position RMS {best_rms:.2e} rad "
                       f"over {len(scales)} parameter samples", tried, iters, warm, t0, stats,
                       extra=extra)
    check = verify(prob.params, prob.profile(best), prob.q0, prob.goal, request.uncertain,
                   request.tol)
    if check["at_goal"] and check["at_rest"]:
        res = _result(request, prob, best, False, "", tried, iters, warm, t0, stats,
                      code="NO_ROBUST_PLAN", extra=extra)
        res.message = (f"no derivative-robust plan found with N = {prob.n}; returning the plan "
                       f"with least sampled rest-position RMS {best_rms:.2e} rad (NOT "
                       f"derivative-robust)")
        return res
    return _no_plan(request, prob, best, tried, iters, warm, t0, stats, out_of_time)


def warmup() -> float:
    """Compile (or load from numba's on-disk cache) every 1-DOF kernel; returns seconds taken.

    Call it at install or node start so that no user request pays for compilation (cold compile
    ~10–25 s on a 2-core machine, cached load ~0.3 s)."""
    t0 = time.perf_counter()
    plan_robust_1dof(PlanRequest(starts=200, seed=0, uncertain=("pc",)))
    plan_robust_1dof(PlanRequest(objective="robust-sampled", starts=200, seed=0,
                                 uncertain=("pc",)))
    from .simulate import simulate

    simulate(Arm1DofParams(), CurrentProfile.uniform([1.0, -1.0], 1.0), [0.0], trajectory=True)
    return time.perf_counter() - t0


def smallest_robust_steps(request: PlanRequest, n_max: int = 12,
                          progress: Progress = None) -> tuple[Optional[PlanResult], list[dict]]:
    """The smallest N (from 2 + k up to ``n_max``) that admits a truly robust plan.

    Returns (the first robust PlanResult or None, evidence): one row per N tried with the starts
    run, whether a robust plan was found, and the best residual seen — so that "no robust plan
    with N steps" is stated with what was tried. Each N gets ``request.starts`` starts and
    ``request.time_budget`` seconds.
    """
    from dataclasses import replace as dc_replace

    evidence = []
    k = len(request.uncertain)
    for n in range(max(1, k + 2 if request.steps is None else request.steps), n_max + 1):
        r = plan_robust_1dof(dc_replace(request, steps=n), progress)
        evidence.append({"steps": n, "robust": bool(r.robust and r.success),
                         "starts_tried": r.starts_tried, "solve_time_s": r.solve_time,
                         "error_code": r.error_code,
                         "max_abs_derivative": (r.extra.get("verification") or {}).get(
                             "max_abs_derivative")})
        if r.success and r.robust:
            return r, evidence
    return None, evidence


def warmup_main() -> None:
    """Console entry point: compile/cache the 1-DOF kernels now and print how long it took."""
    print(f"ff_planner 1-DOF kernels ready in {warmup():.2f} s")
