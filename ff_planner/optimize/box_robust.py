"""The robust-box objective for the 1-DOF arm: least worst-case REST error over a friction box.

Among plans with exact zero derivatives ∂q(tf)/∂p_i = 0 (the paper's condition, equalities),
q(tf) = qf and the arm at rest at tf (nominal parameters), minimise the worst |rest − qf| over
the box p_i·(1 ± f_i) (``request.box``, default ±20 % per uncertain parameter):

    min t   s.t.  −t ≤ q_rest(I; p_s) − qf ≤ t  for every sample s,
                  q(tf) − qf = 0,  ∂q(tf)/∂p_i·|p_i| = 0,  |q̇(tf − coast)| ≤ v_stop(coast),
                  |I_j| ≤ i_max

(epigraph form; SLSQP with the exact Jacobians ∂q_rest/∂I of ``hd_sim``). The samples are the
box's corners, centre and face centres; after each solve the plan is checked on a 3^k grid and
64 seeded uniform points, and the worst of those are added (exchange) until the check set adds
no more than 2 %; the LM's minimum-norm steps then put the plan back onto the robust set
exactly (SLSQP meets the equalities only to its own tolerance). Decisions: the N step currents
— the coast-entry speed is free below the stopping bound — and the coast length, chosen among
COAST_LEVELS values in [coast, coast_max] (an outer discrete choice: SLSQP with a
finite-difference coast column was measured to be misled by the model's kinks). Starts:
derivative-robust plans of the compiled LM multistart (``robust1d``); up to SCREEN_MAX of them
get a short minimax (SCREEN_ITER iterations) and the BOX_CANDIDATES best after it are refined
to convergence. Units: rad, A, s.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace as dc_replace
from typing import Callable, Optional

import numpy as np
from scipy.optimize import minimize

from ff_planner.core.errors import PlanningError
from ff_planner.model.arm1dof import FRICTION
from ff_planner.model.arm1dof_derivatives import NP, Q_, VC_, hd_sim
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import PlanRequest, PlanResult
from ff_planner.optimize import lm1d as _lm1d
from ff_planner.optimize.robust1d import (
    STOP_MARGIN,
    _no_plan,
    _Problem,
    _result,
    _seed_key,
    chunk_spread,
    verify,
)
from ff_planner.optimize.sample_box import box_check_samples, box_fractions, box_samples

Progress = Optional[Callable[[dict], None]]

COAST_LEVELS = 5        # coast lengths tried, evenly in [coast, coast_max]
SCREEN_MAX = 24         # derivative-robust LM plans screened per coast (short minimax) ...
SCREEN_ITER = 15        # ... of this many SLSQP iterations on the minimax samples
BOX_CANDIDATES = 1      # screened plans refined to convergence with exchange, per coast
SOLVE_ITER = 100        # SLSQP iterations of a full refinement
SOLVE_FTOL = 1e-5       # SLSQP tolerance on the worst error in mrad (10 nrad)
STARTS_FACTOR = 10      # LM starts per coast = STARTS_FACTOR × request.starts (~0.1 ms a start)
EXCHANGE_ROUNDS = 3     # check-set exchanges per refinement
EXCHANGE_ADD = 3        # worst check samples added per exchange
ERR_SCALE = 1e3         # the epigraph variable in mrad (SLSQP's tolerances suit O(1) values)


class _Box:
    """The minimax problem of one coast: samples, constraints and their exact Jacobians."""

    def __init__(self, prob: _Problem, scales: np.ndarray):
        self.prob = prob
        self.scales = np.ascontiguousarray(scales)
        self.memo: dict = {}

    def terms(self, I: np.ndarray):
        key = I.tobytes()
        if key not in self.memo:
            self.memo.clear()
            pr = self.prob
            p = pr.params
            I = np.ascontiguousarray(I, dtype=float)
            e, G = _lm1d.sampled_terms(p.J, p.n * p.kt, pr.pvals, self.scales, pr.times, I,
                                       pr.tf, pr.q0, pr.goal, pr.W)
            W = pr.W
            n = pr.n
            hd_sim(p.J, p.n * p.kt, p.pv, p.pc, p.pt, pr.times, I, pr.tf, pr.q0, False,
                   pr.pscale, W)
            eq = [W[Q_, 0] - pr.goal]
            jeq = [W[Q_, 4:4 + n].copy()]
            for i in range(NP):
                if pr.umask[i]:
                    eq.append(W[Q_, 1 + i] * pr.pscale[i])
                    jeq.append(W[Q_, 4 + n + i * n: 4 + n + (i + 1) * n] * pr.pscale[i])
            vc = W[VC_, 0]
            self.memo[key] = (e, G, np.array(eq), np.vstack(jeq), vc, W[VC_, 4:4 + n].copy())
        return self.memo[key]

    def worst(self, I: np.ndarray) -> float:
        e = self.terms(I)[0]
        return float(np.max(np.abs(e))) if np.all(np.isfinite(e)) else math.inf

    def solve(self, I0: np.ndarray, deadline: float, maxiter: int = SOLVE_ITER) -> np.ndarray:
        pr = self.prob
        n = pr.n
        vb = pr.vb

        def split(x):
            return np.ascontiguousarray(x[:n])

        def ineq(x):
            e, _, _, _, vc, _ = self.terms(split(x))
            return np.concatenate([x[n] - ERR_SCALE * e, x[n] + ERR_SCALE * e, [vb - abs(vc)]])

        def ineq_jac(x):
            e, G, _, _, vc, jv = self.terms(split(x))
            m = e.shape[0]
            A = np.zeros((2 * m + 1, n + 1))
            A[:m, :n] = -ERR_SCALE * G
            A[m:2 * m, :n] = ERR_SCALE * G
            A[:2 * m, n] = 1.0
            A[2 * m, :n] = -np.sign(vc) * jv
            return A

        def eq(x):
            return self.terms(split(x))[2]

        def eq_jac(x):
            J = self.terms(split(x))[3]
            return np.hstack([J, np.zeros((J.shape[0], 1))])

        def stop_at_deadline(xk):
            if time.perf_counter() > deadline:
                raise StopIteration     # SLSQP returns its current iterate

        x0 = np.concatenate([I0, [ERR_SCALE * self.worst(I0) * 1.001]])
        grad_t = np.zeros(n + 1)
        grad_t[n] = 1.0
        res = minimize(lambda x: x[n], x0, jac=lambda x: grad_t, method="SLSQP",
                       bounds=[(-pr.i_max, pr.i_max)] * n + [(0.0, None)],
                       constraints=[{"type": "eq", "fun": eq, "jac": eq_jac},
                                    {"type": "ineq", "fun": ineq, "jac": ineq_jac}],
                       options={"maxiter": int(maxiter), "ftol": SOLVE_FTOL}, callback=stop_at_deadline)
        return np.clip(np.asarray(res.x[:n], float), -pr.i_max, pr.i_max)


def _polish(prob: _Problem, I: np.ndarray) -> Optional[np.ndarray]:
    """The LM's minimum-norm steps from ``I`` back onto the robust set (SLSQP meets the
    equalities to its own tolerance only, the verification asks for 0.1·tol); None if it fails."""
    block = np.ascontiguousarray(I, dtype=float).reshape(1, -1).copy()
    done, st, _, _, _ = prob.run(block, False)
    return block[0].copy() if done and st[0] == _lm1d.OK else None


def _candidates(prob: _Problem, starts: int, seed: int, deadline: float) -> tuple[list, int, int]:
    """Derivative-robust LM plans from ``starts`` seeded starts (the tuned chunk cycle)."""
    found, tried, iters, chunk = [], 0, 0, 0
    cfg = prob.cfg()
    direction = 0.0 if prob.goal == prob.q0 else (1.0 if prob.goal > prob.q0 else -1.0)
    counts = np.zeros(5, np.int64)
    ver = np.empty(10 + 2 * int(_lm1d.sweep_size(int(prob.umask.sum()), 1)))
    while tried < starts and time.perf_counter() < deadline:
        m = min(64, starts - tried)
        frac, oppose, mid = chunk_spread(prob.settings, chunk)
        block = np.empty((m, prob.n))
        done, _, st, it, _ = prob.chunk(block, cfg, False, counts, ver, True,
                                        _seed_key(seed, chunk), frac * prob.i_max,
                                        direction if oppose else 0.0,
                                        (mid[0] * prob.i_max, mid[1] * prob.i_max))
        tried += done
        iters += int(it[:done].sum())
        chunk += 1
        found += [block[s].copy() for s in range(done) if st[s] == _lm1d.OK]
    return found, tried, iters


def plan_box_robust_1dof(request: PlanRequest, progress: Progress = None,
                         initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """Plan the robust-box objective for the 1-DOF arm (see the module docstring).

    initial_currents (N,) / (M, N) A: extra LM starts, tried first (e.g. a library neighbour).
    ``extra``: box_worst (rad, on the planner's check set), coast chosen, per-coast figures."""
    t0 = time.perf_counter()
    params = request.resolved_params()
    if request.model != "arm1dof" or not isinstance(params, Arm1DofParams):
        raise PlanningError(f"robust-box plans the arm1dof model, not '{request.model}'")
    deadline = t0 + float(request.time_budget)
    unc = [u for u in FRICTION if u in request.uncertain]
    fr = box_fractions(unc, request.box)
    base_scales = box_samples(fr, FRICTION)
    check_scales = box_check_samples(fr, FRICTION)
    lo = max(float(request.coast), 2.0 * STOP_MARGIN)
    coasts = np.unique(np.linspace(lo, max(lo, float(request.coast_max)), COAST_LEVELS))
    n = request.n_steps()
    best = None     # (worst on check set, I, prob)
    tried = iters = 0
    per_coast: list[dict] = []
    fallback = None
    for coast in coasts[::-1]:
        if per_coast and time.perf_counter() > deadline:
            break
        req_c = dc_replace(request, coast=float(coast))
        prob = _Problem(req_c, params, n)
        cands, t_, i_ = _candidates(prob, STARTS_FACTOR * int(request.starts),
                                    int(request.seed), deadline)
        if initial_currents is not None:
            init = np.array(initial_currents, dtype=float, ndmin=2).reshape(-1, n)
            out = np.ascontiguousarray(np.clip(init, -prob.i_max, prob.i_max))
            done, st, it, _, _ = prob.run(out, False)
            cands = [out[s].copy() for s in range(done) if st[s] == _lm1d.OK] + cands
            t_ += done
        tried += t_
        iters += i_
        if fallback is None:
            fallback = prob
        if not cands:
            per_coast.append({"coast": float(coast), "robust_candidates": 0})
            continue
        box = _Box(prob, base_scales)
        cands.sort(key=box.worst)
        screened = []
        for I0 in cands[:SCREEN_MAX]:     # a short minimax says more than the start's worst
            if time.perf_counter() > deadline:
                break
            try:
                I1 = box.solve(I0, deadline, SCREEN_ITER)
            except (ValueError, ArithmeticError):
                continue
            screened.append((min(box.worst(I1), box.worst(I0)), I0, I1))
        screened.sort(key=lambda x: x[0])
        row: dict = {"coast": float(coast), "robust_candidates": len(cands),
                     "screened": len(screened)}
        for _, I0, I1 in screened[:BOX_CANDIDATES]:
            if time.perf_counter() > deadline:
                break
            box = _Box(prob, base_scales)
            I = I1.copy()
            for _ in range(EXCHANGE_ROUNDS):
                try:
                    I = box.solve(I, deadline)
                except (ValueError, ArithmeticError):
                    break
                chk = _Box(prob, check_scales)
                e = chk.terms(I)[0]
                if not np.all(np.isfinite(e)):
                    break
                if np.max(np.abs(e)) <= 1.02 * box.worst(I):
                    break
                add = check_scales[np.argsort(-np.abs(e))[:EXCHANGE_ADD]]
                box = _Box(prob, np.vstack([box.scales, add]))
            for J_ in (_polish(prob, I), I, I0):   # the refined plan, on the robust set
                if J_ is None:
                    continue
                w = max(_Box(prob, base_scales).worst(J_), _Box(prob, check_scales).worst(J_))
                if best is not None and not w < best[0]:
                    continue
                ok = verify(params, prob.profile(J_), prob.q0, prob.goal, unc, request.tol)
                if ok["robust"]:
                    best = (w, J_.copy(), prob)
                    break
            if progress is not None:
                progress({"stage": f"robust-box coast {coast:.3f} s", "starts_done": tried,
                          "best": float(best[0]) if best else math.inf})
        row["best_worst"] = float(best[0]) if best and best[2] is prob else None
        per_coast.append(row)
    stats = {"n_steps": n, "box": fr, "coasts_tried": per_coast, "box_samples": int(
        base_scales.shape[0]), "box_check_samples": int(check_scales.shape[0]),
        "search_time_s": time.perf_counter() - t0}
    out_of_time = time.perf_counter() > deadline
    if best is None:
        assert fallback is not None     # the first coast always runs
        stats["stop_speed_bound"] = fallback.vb
        return _no_plan(request, fallback, None, tried, iters, False, t0, stats, out_of_time)
    w, I, prob = best
    stats.update(box_worst=w, coast=prob.coast, stop_speed_bound=prob.vb)
    req_c = dc_replace(request, coast=prob.coast)
    msg = (f"truly robust plan (zero exact derivatives) with least worst rest error over the "
           f"box: {w * 1e3:.3g} mrad on {check_scales.shape[0] + base_scales.shape[0]} samples, "
           f"coast {prob.coast:.3g} s")
    return _result(req_c, prob, I, True, msg, tried, iters, initial_currents is not None, t0,
                   stats)
