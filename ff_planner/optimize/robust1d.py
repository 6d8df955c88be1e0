"""Robust feedforward planning for the 1-DOF arm (paper Eq. 7, section 4.1) at compiled speed.

``plan_robust_1dof(request, progress=None, initial_currents=None, grid=None, *, warm_only=False)
-> PlanResult``; ``verify(...)`` judges any plan; ``solve_block(...)`` is the public entry to the
compiled solver for other planners (robust2d's joint 1).

- objective "robust-derivative": N piecewise-constant currents (equal steps on [0, tf − coast]),
  |I| ≤ i_max, such that q(tf) = qf, the arm is at rest at tf, and every ∂q(tf)/∂p_i = 0 for the
  uncertain friction parameters. Seeded multistart of a compiled Levenberg–Marquardt solver with
  exact Jacobians (``_lm1d``). Starts are drawn 16 at a time, chunk by chunk, in a cycle
  (``chunk_spread``): a narrow box (±0.2·i_max for k ≥ 2, ±0.3·i_max for k = 1) with the first
  and last currents opposing the move (robust motions first move away from the goal, paper
  4.1.2); for k = 1 then two "far" chunks with the inner current pushing the move at 50–100 % /
  90–100 % of i_max (long moves); and a wide box (±0.8·i_max). Each chunk is ONE compiled call
  (``_lm1d.plan_chunk``: draw, solve, and verify the first success — exact derivatives, central
  differences at 1e-6, the 0.1 % quotient, the kink radius, goal, rest, |I| ≤ i_max and the
  finite-change sweep), so the hot path builds no Python objects until the result. A plan within
  0.1 % (relative parameter change) of a non-smooth point (zero crossing at a switch time,
  breakaway edge) is refused: its one-sided derivatives differ.
- objective "robust-sampled" (section 6.2): among robust plans, the one — refined by SLSQP along
  the robust set — with the least RMS error of the REST position over sampled parameter values
  (``sample_box.sample_scales``: each uncertain parameter at ±10 % and ±20 %, and the corners
  of the ±20 % box). When no derivative-robust plan is found it minimises that RMS subject to
  reaching qf at rest only.

With ``request.limits`` (position range, speed limit) every robust end point is checked against
them over the certificate's box points, the whole motion until rest (``limits1d.Limits1D``):
the first one within them is the answer; when none is, the answer has no profile and says what
to change (a plan outside the limits is never returned).

When no plan meets the tolerances the best one is returned with success=False,
best_effort=True and error_code NO_ROBUST_PLAN (or TIME_BUDGET_EXHAUSTED); the message says so.
The result's ``extra`` carries the verification: central-difference derivatives (1e-6 relative),
the 0.1 % forward quotients, the kink radius, the finite-change errors of the rest position and of
q(tf) at ±10 % and ±40 % per parameter and all together ("finite_change"), and solver statistics.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import replace as dc_replace
from typing import Callable, Optional, Sequence

import numpy as np
from scipy.optimize import minimize

from ff_planner.core.errors import PlanningError
from ff_planner.model.arm1dof import FRICTION, friction_scale
from ff_planner.model.arm1dof_derivatives import NP, Q_, VC_, hd_sim, workspace
from ff_planner.model.friction import stop_speed
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult
from ff_planner.model.simulate import simulate
from ff_planner.optimize import lm1d as _lm1d
from ff_planner.optimize.limits1d import Limits1D
from ff_planner.optimize.sample_box import FINITE_CHANGES, sample_scales

Progress = Optional[Callable[[dict], None]]

STOP_MARGIN = 1e-3      # s: the arm must be at rest this long before tf (nominal parameters)
# relative parameter change (first order) to the nearest non-smooth point — a velocity zero
# crossing at a switch time, a breakaway edge — below which a plan is refused (0.1 %): beyond
# such a point the derivatives are one-sided, so zero derivatives hold on one side only.
# Measured on the Fig. 6 sweep (N = 3, one parameter, 0.05 rad grid, 50 and 2000 starts): the
# same plans and thresholds with 1e-3 and with 0 (pv 1.80, pt 2.20 / 2.25 rad); the plans at
# the thresholds have kink radii of 0.4-2 %, so the rule costs nothing there.
MIN_KINK = 1e-3
CHUNK = 16              # starts per compiled call (the time budget is checked between calls)
SAMPLED_CANDIDATES = 4  # robust-sampled: robust plans collected, each refined by SLSQP
# LM settings per number of uncertain parameters, tuned on 3000 seeded starts of the 0 -> 1 rad,
# 1 s task (CPU time per robust plan: k = 1 ~55-90 us, k = 3 ~450 us); "spread" = random starts
# uniform in ±spread·i_max.
LM_SETTINGS = {
    1: dict(wpen=0.1, wq=1.0, lam0=1e-2, max_iter=25, abandon_iter=3, abandon_norm=1e-2,
            max_reject=3, lam_down=0.1, lam_up=5.0, spread=0.3,
            cycle=(None, ("far", 0.6, 0.5, 1.0), ("far", 0.8, 0.9, 1.0), 0.8)),
    3: dict(wpen=0.1, wq=3.0, lam0=1e-2, max_iter=25, abandon_iter=4, abandon_norm=1e-3,
            max_reject=5, lam_down=0.1, lam_up=5.0, spread=0.2, cycle=(None, 0.8)),
}
# k = 1 "cycle" (see chunk_spread): the tuned chunk first (the 0 -> 1 rad task is solved in it),
# then two "far" chunks whose inner current pushes the move at 50-100 % / 90-100 % of i_max
# (robust plans of long moves saturate it: the Fig. 6 thresholds of 1.8 rad pv, 2.3 rad pt,
# 6 rad pc come out with 50 starts), then a wide unconstrained one. Chosen on 20 seeds of the
# Fig. 6 sweep: pv robust to 1.75 rad and pc to 6.0 rad on every seed (the next grid points,
# 2.0 / 6.25 rad, have no robust plan in 20000 starts), pt to 2.0-2.25 rad (2.25 rad needs tens
# to hundreds of starts); mean starts for 0 -> 1 rad unchanged (3.8).


WIDE_SPREAD = 0.8   # unconstrained chunks of random starts use ±0.8·i_max
#: spreads of successive chunks of random starts (cycled): None = the tuned spread with the
#: first and last currents opposing the move; a number = unconstrained ±that·i_max
SPREAD_CYCLE: tuple = (None, WIDE_SPREAD)


def lm_settings(k: int) -> dict:
    """The LM settings for k uncertain parameters."""
    return LM_SETTINGS[1] if k <= 1 else LM_SETTINGS[3]


def stop_speed_bound(params: Arm1DofParams, coast: float, margin: float = STOP_MARGIN) -> float:
    """Largest coast-entry speed (rad/s) from which zero current stops the arm ``margin`` s
    before tf: ``friction.stop_speed`` with τ = coast − margin."""
    return stop_speed(params.J, params.pv, params.pc, coast - margin)


def _changes_array(changes: Sequence[float]) -> np.ndarray:
    return np.ascontiguousarray(changes, dtype=float)


_CHANGES_ARR = _changes_array(FINITE_CHANGES)


def _verification(out: np.ndarray, pscale: np.ndarray, qf: float, tol: float, i_max: float,
                  changes: Sequence[float]) -> dict:
    """The verification dict from ``_lm1d.verify_core``'s output (layout documented there)."""
    o = out.tolist()
    kink, tf_radius, t_stop = o[0], o[1], o[2]
    idx = [i for i in range(3) if pscale[i] != 0.0]
    k = len(idx)
    m = 1 + 3 * k + 2 * len(changes) * (k + (1 if k > 1 else 0))
    q = o[10:10 + m]
    v = o[10 + m:10 + 2 * m]
    q_tf, v_tf = q[0], v[0]
    exact, qd_exact, central, forward = {}, {}, {}, {}
    for r, i in enumerate(idx):
        name, sc = FRICTION[i], float(pscale[i])
        exact[name] = o[3 + i]
        qd_exact[name] = o[6 + i]
        central[name] = (q[1 + 3 * r] - q[2 + 3 * r]) / (2e-6 * sc)
        forward[name] = (q[3 + 3 * r] - q_tf) / (1e-3 * sc)
    fc: dict = {}
    j = 1 + 3 * k
    for name in [FRICTION[i] for i in idx] + (["all"] if k > 1 else []):
        row = {}
        for ch in changes:
            q_rest = q[j + 1] - qf
            row[f"{ch * 100:+.0f}%"] = {"rest_error": q_rest if math.isfinite(q_rest) else None,
                                        "tf_error": q[j] - qf, "qd_tf": v[j]}
            j += 2
        fc[name] = row
    worst = max([abs(x) for x in exact.values()] + [abs(x) for x in central.values()] + [0.0])
    at_goal = abs(q_tf - qf) <= tol
    at_rest = v_tf == 0.0
    within = o[9] <= i_max + 1e-12
    smooth = kink >= MIN_KINK
    robust = bool(worst <= tol and smooth and at_goal and at_rest and within)
    return {"robust": robust, "exact": exact, "central": central, "forward_0.1%": forward,
            "qd_exact": qd_exact, "max_abs_derivative": worst, "kink_radius": kink,
            "tf_radius": tf_radius, "t_stop": t_stop, "q_tf": q_tf, "qd_tf": v_tf,
            "at_goal": at_goal, "at_rest": at_rest, "within_limits": within,
            "finite_change": fc}


def _verify_out(params: Arm1DofParams, times: np.ndarray, cur: np.ndarray, tf: float,
                q0: float, pscale: np.ndarray, changes: np.ndarray) -> np.ndarray:
    k = int(np.count_nonzero(pscale))
    out = np.empty(10 + 2 * int(_lm1d.sweep_size(k, changes.shape[0])))
    _lm1d.verify_core(float(params.J), float(params.n * params.kt), float(params.pv),
                      float(params.pc), float(params.pt), times, cur, float(tf), float(q0),
                      pscale, changes, workspace(cur.shape[0]), out)
    return out


def verify(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float,
           uncertain: Sequence[str], tol: float = 1e-6, changes: Sequence[float] = FINITE_CHANGES
           ) -> dict:
    """Judge a plan by true derivatives: exact, central differences (1e-6 relative) and the
    paper's 0.1 % forward quotient; the kink radius; goal and rest at tf; |I| ≤ i_max; finite
    changes (rest position and q(tf) errors at ``changes``, one parameter at a time and all
    together). Everything runs in one compiled call (``_lm1d.verify_core``)."""
    bad = [u for u in uncertain if u not in FRICTION]
    if bad:
        raise ValueError(f"unknown friction parameter(s) {bad}; choose from {FRICTION}")
    pscale = friction_scale(params, list(uncertain))
    ch = _changes_array(changes)
    out = _verify_out(params, np.ascontiguousarray(profile.step_times, dtype=float),
                      np.ascontiguousarray(profile.currents[:, 0], dtype=float), profile.tf,
                      q0, pscale, ch)
    return _verification(out, pscale, float(qf), float(tol), float(params.i_max), list(changes))


_CFG_KEYS = ("wpen", "wq", "lam0", "tol_q", "tol_d", "min_kink", "max_iter", "abandon_iter",
             "abandon_norm", "max_reject", "lam_down", "lam_up")
#: LM settings overriding lm_settings(k) for given (warm) starts (``warm_settings=`` per call).
#: Measured on 180 neighbour continuations (goal ±0.1/0.25 rad, tf +0.1 s): patience (100
#: iterations, no abandonment) converged no more often than the tuned settings (k = 1: 99 vs 98
#: of 105 from the neighbour's own currents; k = 3: 15 of 75 either way — those runs end at a
#: kink, where the neighbour's solution branch stops) and took twice as long; what helped was
#: the rest-bound stall fix in ``_lm1d.solve_start`` (k = 1: 82 -> 99 of 105) and perturbed
#: copies of the neighbour (k = 3: 66-68 of 75 with 15 of them). So: the tuned settings.
WARM_SETTINGS: dict = {}


class _Problem:
    """The compiled solver's arguments for one request."""

    def __init__(self, request: PlanRequest, params: Arm1DofParams, n: int,
                 grid: Optional[float] = None):
        self.params = params
        self.n = n
        self.tf = float(request.tf)
        self.coast = float(request.coast)
        self.times = _step_times_cached(self.tf, self.coast, n, grid)
        self.q0 = float(request.q0[0])
        self.goal = float(request.qf[0])
        unc = [k for k in FRICTION if k in request.uncertain]
        self.umask = np.array([k in unc for k in FRICTION])
        self.pvals = np.array([params.pv, params.pc, params.pt], dtype=float)   # values
        # scales of the derivative rows (|p|, or a default where p = 0), zero if not uncertain
        self.pscale = friction_scale(params, unc)
        self.i_max = float(params.i_max)
        self.vb = stop_speed_bound(params, self.coast)
        self.W = workspace(n)
        self.tol_q = 0.1 * float(request.tol)
        self.tol_d = 0.1 * float(request.tol)
        self.settings = lm_settings(len(unc))
        self.phys = (float(params.J), float(params.n * params.kt), float(params.pv),
                     float(params.pc), float(params.pt))
        # position / speed limits over the box (None: none given)
        self.limits = Limits1D.of(getattr(request, "limits", None), params, self.q0, self.tf,
                                  unc, request.box)

    def within_limits(self, currents: np.ndarray, times: Optional[np.ndarray] = None) -> bool:
        """True when the plan keeps within the request's limits at every certificate box point
        (always, without limits)."""
        return self.limits is None or self.limits.ok(self.times if times is None else times,
                                                     currents)

    def args(self):
        p = self.params
        return (p.J, p.n * p.kt, p.pv, p.pc, p.pt, self.times, self.tf, self.q0, self.goal,
                self.umask, self.pscale, self.i_max)

    def cfg(self, **override) -> np.ndarray:
        """The LM settings as the float array ``_lm1d.plan_chunk`` takes."""
        s = dict(self.settings, tol_q=self.tol_q, tol_d=self.tol_d, min_kink=MIN_KINK)
        s.update(override)
        return np.array([float(s[k]) for k in _CFG_KEYS])

    def run(self, starts: np.ndarray, stop_first: bool):
        """LM from each row of ``starts`` (modified in place into the end points); returns
        (starts run, status, iterations, |r|², kink radius) — see ``solve_block``."""
        s = self.settings
        m = starts.shape[0]
        st = np.zeros(m, np.int64)
        it = np.zeros(m, np.int64)
        f = np.full(m, np.inf)
        kk = np.zeros(m)
        done = _lm1d.multistart(*self.args(), starts, self.W, self.vb, s["wpen"], s["wq"],  # type: ignore[call-arg]
                                s["lam0"], self.tol_q, self.tol_d, MIN_KINK, s["max_iter"],
                                s["abandon_iter"], s["abandon_norm"], s["max_reject"],
                                s["lam_down"], s["lam_up"], stop_first, st, it, f, kk)
        return done, st, it, f, kk

    def chunk(self, block: np.ndarray, cfg: np.ndarray, stop_first: bool, counts: np.ndarray,
              ver_out: np.ndarray, draw: bool = False, seed_key: int = 0, spread: float = 0.0,
              direction: float = 0.0, mid: tuple = (0.0, 0.0)):
        """One compiled call: (draw the starts,) LM from each, verify the first success."""
        m = block.shape[0]
        st = np.zeros(m, np.int64)
        it = np.zeros(m, np.int64)
        f = np.full(m, np.inf)
        kk = np.zeros(m)
        done, verified = _lm1d.plan_chunk(
            *self.phys, self.times, self.tf, self.q0, self.goal, self.umask, self.pscale,
            self.i_max, self.vb, cfg, seed_key, spread, direction, float(mid[0]),
            float(mid[1]), draw, stop_first,
            _CHANGES_ARR, block, st, it, f, kk, counts, ver_out)
        return done, verified, st, it, f

    def profile(self, currents: np.ndarray) -> CurrentProfile:
        return CurrentProfile(self.times.copy(), np.asarray(currents, float).reshape(-1, 1),
                              self.tf, self.coast)


def solve_block(params: Arm1DofParams, q0: float, qf: float, tf: float, uncertain: Sequence[str],
                starts: np.ndarray, *, coast: float = 0.05, tol: float = 1e-6,
                stop_first: bool = False) -> list[dict]:
    """Public, stable entry to the compiled robust-derivative LM (e.g. for a joint of a
    multi-joint arm): run LM from each row of ``starts`` (M, N) A, equal steps on
    [0, tf − coast], for the 1-DOF arm ``params`` moving q0 → qf (rad) in tf s.

    Returns one dict per start run (all M, or up to the first success with ``stop_first``):
    {"currents": end point (N,) A, "ok": bool (goal, zero true derivatives, rest in the coast,
    away from kinks, per the solver's tolerances 0.1·tol), "status": "ok" | "no_convergence" |
    "abandoned" | "kink" | "bad_start", "iterations", "residual2" (|r|²), "kink_radius"}.
    A result with ok=True is the solver's claim; ``verify`` judges a plan independently.
    """
    starts = np.array(starts, dtype=float, ndmin=2)
    if starts.ndim != 2 or not np.all(np.isfinite(starts)):
        raise PlanningError("starts must be a finite (M, N) array of currents (A)")
    req = PlanRequest(objective="robust-derivative", model="arm1dof", q0=(float(q0),), qf=(float(qf),), tf=float(tf),
                      uncertain=tuple(uncertain), steps=starts.shape[1], coast=float(coast),
                      params=params, tol=float(tol), starts=max(1, starts.shape[0]))
    req.validate()
    prob = _Problem(req, params, starts.shape[1])
    block = np.ascontiguousarray(np.clip(starts, -prob.i_max, prob.i_max))
    done, st, it, f, kk = prob.run(block, stop_first)
    return [{"currents": block[s].copy(), "ok": bool(st[s] == _lm1d.OK),
             "status": STATUS_NAMES[int(st[s])], "iterations": int(it[s]),
             "residual2": float(f[s]), "kink_radius": float(kk[s])} for s in range(done)]


STATUS_NAMES = {_lm1d.OK: "ok", _lm1d.NO_CONVERGENCE: "no_convergence",
                _lm1d.ABANDONED: "abandoned", _lm1d.KINK: "kink", _lm1d.BAD_START: "bad_start"}


@functools.lru_cache(maxsize=256)
def _step_times_cached(tf: float, coast: float, n: int, grid: Optional[float]) -> np.ndarray:
    return step_times(tf, coast, n, grid)     # shared: callers must not modify it


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
    """What this planner needs beyond ``planner.check``: the 1-DOF arm, a robust objective, at
    least one uncertain parameter, a coast the arm can stop in; returns the arm's parameters."""
    params = request.resolved_params()
    if request.model != "arm1dof" or not isinstance(params, Arm1DofParams):
        raise PlanningError(f"plan_robust_1dof plans the arm1dof model, not '{request.model}'")
    if request.objective not in ("robust-derivative", "robust-sampled"):
        raise PlanningError(f"plan_robust_1dof serves robust-derivative and robust-sampled, not "
                            f"{request.objective!r}")
    if not request.uncertain:
        raise PlanningError("name at least one uncertain friction parameter (pv, pc, pt)")
    if request.coast <= STOP_MARGIN:
        raise PlanningError(f"coast must exceed {STOP_MARGIN} s so that the arm can stop in it")
    return params


def plan_robust_1dof(request: PlanRequest, progress: Progress = None,
                     initial_currents: Optional[np.ndarray] = None,
                     grid: Optional[float] = None, *, warm_only: bool = False,
                     warm_settings: Optional[dict] = None) -> PlanResult:
    """Plan a robust rest-to-rest move of the 1-DOF arm; see the module docstring.

    initial_currents: (N,) or (N, 1) A (one start), or (M, N) (M starts): given starts tried
    first, in order, in one compiled call (e.g. a motion-library neighbour and perturbed copies
    of it), with LM settings ``WARM_SETTINGS`` updated by ``warm_settings`` (e.g.
    dict(max_iter=100, abandon_iter=100) for more patience). They count towards
    ``request.starts``: seeded random starts fill the rest, none with ``warm_only``.
    ``starts_tried`` = starts actually run (given ones included); ``extra["warm_starts_ok"]``
    says how many given starts converged.
    grid: put the switch times on this grid (s), e.g. 1e-3 for a 1 kHz drive (also read from
    ``request.grid`` when the request has that field).
    """
    t0 = time.perf_counter()
    params = _check_request(request)
    n = request.n_steps()
    if grid is None:
        grid = getattr(request, "grid", None)
    prob = _Problem(request, params, n, grid)
    warm_block = None
    if initial_currents is not None:
        init = np.array(initial_currents, dtype=float, ndmin=2)
        if init.shape == (n, 1):        # a profile's (N, 1) current column: one start
            init = init.reshape(1, n)
        if init.ndim != 2 or init.shape[1] != n or init.shape[0] < 1 \
                or not np.all(np.isfinite(init)):
            raise PlanningError(f"initial_currents needs rows of {n} finite values (A), got "
                                f"shape {np.shape(initial_currents)}")
        warm_block = np.ascontiguousarray(np.clip(init, -prob.i_max, prob.i_max))
    elif warm_only:
        raise PlanningError("warm_only needs initial_currents")
    warm = warm_block is not None
    ws = dict(WARM_SETTINGS, **(warm_settings or {}))
    bad = set(ws) - set(_CFG_KEYS)
    if bad:
        raise PlanningError(f"unknown warm_settings {sorted(bad)}; choose from {_CFG_KEYS}")
    n_warm = 0 if warm_block is None else warm_block.shape[0]
    total = 0 if warm_only else max(0, int(request.starts) - n_warm)
    sampled = request.objective == "robust-sampled"
    want = SAMPLED_CANDIDATES if sampled else 1     # robust candidates to collect
    lim = prob.limits
    # with limits every robust end point of a chunk is checked against them, not the first only
    stop_first = not sampled and lim is None
    outside: list = []       # [largest violation, I]: the robust plan nearest the limits
    rejected = 0
    found: list[np.ndarray] = []
    best_f, best_I = math.inf, None
    tried = iters = warm_ok = 0
    counts = np.zeros(5, np.int64)
    ver_out = np.empty(10 + 2 * int(_lm1d.sweep_size(int(prob.umask.sum()),
                                                     _CHANGES_ARR.shape[0])))
    verified = False
    out_of_time = False
    drawn = chunk = 0
    cfg = prob.cfg()
    direction = 0.0 if prob.goal == prob.q0 else (1.0 if prob.goal > prob.q0 else -1.0)
    seed = int(request.seed)
    while drawn < total or warm_block is not None:
        if time.perf_counter() - t0 > request.time_budget:
            out_of_time = True
            break
        if warm_block is not None:       # the warm starts run alone, first, with patience
            block, warm_block = warm_block, None
            done, verified, st, it, f = prob.chunk(block, prob.cfg(**ws),
                                                   stop_first, counts, ver_out)
            warm_ok = int(np.count_nonzero(st[:done] == _lm1d.OK))
        else:                            # seeded random starts, drawn chunk by chunk (compiled)
            m = min(CHUNK, total - drawn)
            frac, oppose, mid = chunk_spread(prob.settings, chunk)
            block = np.empty((m, n))
            done, verified, st, it, f = prob.chunk(
                block, cfg, stop_first, counts, ver_out, True, _seed_key(seed, chunk),
                frac * prob.i_max, direction if oppose else 0.0,
                (mid[0] * prob.i_max, mid[1] * prob.i_max))
            drawn += m
            chunk += 1
        tried += done
        iters += int(it[:done].sum())
        if verified and stop_first:      # robust-derivative: the first success, verified
            break
        verified = False
        for s in range(done):
            if st[s] == _lm1d.OK:
                if lim is not None:
                    over = lim.excess(prob.times, block[s])
                    if over > 0.0:
                        rejected += 1
                        if not outside or over < outside[0]:
                            outside[:] = [over, block[s].copy()]
                        continue
                found.append(block[s].copy())
            elif f[s] < best_f:
                best_f, best_I = f[s], block[s].copy()
        if progress is not None:
            progress({"starts_done": tried, "robust_found": len(found),
                      "best": float(min(best_f, 0.0 if found else best_f))})
        if len(found) >= want:
            break
    stats: dict = {"starts_ok": int(counts[_lm1d.OK]),
                   "starts_abandoned": int(counts[_lm1d.ABANDONED]),
                   "starts_unconverged": int(counts[_lm1d.NO_CONVERGENCE]),
                   "starts_at_kink": int(counts[_lm1d.KINK]), "n_steps": n,
                   "stop_speed_bound": prob.vb, "search_time_s": time.perf_counter() - t0}
    if warm:
        stats.update(warm_starts=n_warm, warm_starts_ok=warm_ok)
    if lim is not None:
        stats.update(limits=lim.describe(), robust_outside_limits=rejected)
    if verified:
        if progress is not None:
            progress({"starts_done": tried, "robust_found": 1, "best": 0.0})
        return _result(request, prob, block[done - 1].copy(), True, "", tried, iters, warm, t0,
                       stats, ver_out=ver_out)
    if sampled:
        return _finish_sampled(request, prob, found, best_I, tried, iters, warm, t0, stats,
                               out_of_time)
    if found:
        return _result(request, prob, found[0], True, "", tried, iters, warm, t0, stats)
    if lim is not None and outside:
        stats["least_violation"] = float(outside[0])     # rad or rad/s, of a robust plan
    return _no_plan(request, prob, best_I, tried, iters, warm, t0, stats, out_of_time)


def _seed_key(seed: int, chunk: int) -> int:
    """The uint32 seed of random-start chunk ``chunk`` for request seed ``seed``."""
    return (seed * 1_000_003 + chunk * 7919 + 0x5EED) & 0xFFFFFFFF


def chunk_spread(settings: dict, chunk: int) -> tuple[float, bool, tuple[float, float]]:
    """How random-start chunk ``chunk`` is drawn: (spread as a fraction of i_max, oppose, (mid_lo,
    mid_hi) fractions of i_max) from the cycle ``settings["cycle"]`` (default ``SPREAD_CYCLE``):

    - None: the tuned ``settings["spread"]``, the first and last currents opposing the move
      (robust motions first move away from the goal and brake at the end, paper 4.1.2);
    - a number s: unconstrained, uniform in ±s·i_max;
    - ("far", s, lo, hi): first and last currents opposing the move within s·i_max, the inner
      ones pushing it with lo..hi·i_max — long moves, whose robust plans saturate the middle.
    """
    cycle = settings.get("cycle", SPREAD_CYCLE)
    c = cycle[chunk % len(cycle)]
    if c is None:
        return float(settings["spread"]), True, (0.0, 0.0)
    if isinstance(c, tuple):
        return float(c[1]), True, (float(c[2]), float(c[3]))
    return float(c), False, (0.0, 0.0)


def _no_plan(request, prob, best_I, tried, iters, warm, t0, stats, out_of_time,
             limits: Optional[Limits1D] = None) -> PlanResult:
    """The answer without a robust plan: the best effort ``best_I`` labelled, or no profile at
    all. With ``limits`` (or the problem's) a best effort outside them is dropped: the answer
    then has no profile and says what to change."""
    limits = limits if limits is not None else getattr(prob, "limits", None)
    if limits is not None and best_I is not None and not limits.ok(prob.times, best_I):
        best_I = None
    if limits is not None and best_I is None:
        res = PlanResult(False, f"{limits.advice()} (N = {prob.n}, {tried} start(s))", None,
                         "arm1dof", prob.params, np.array([prob.q0]), np.array([prob.goal]),
                         list(request.uncertain), request.objective,
                         error_code="TIME_BUDGET_EXHAUSTED" if out_of_time else "NO_ROBUST_PLAN",
                         starts_tried=tried, iterations=iters,
                         solve_time=time.perf_counter() - t0, warm_start=warm, extra=stats)
        return res
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
            code="OK", extra=None, ver_out=None) -> PlanResult:
    """The PlanResult of ``currents``, judged by the verification (computed here unless the
    compiled search already verified exactly these currents: ``ver_out``)."""
    prof = prob.profile(currents)
    if ver_out is None:
        ver_out = _verify_out(prob.params, prob.times, np.ascontiguousarray(currents, float),
                              prob.tf, prob.q0, prob.pscale, _CHANGES_ARR)
    check = _verification(ver_out, prob.pscale, prob.goal, float(request.tol), prob.i_max,
                          FINITE_CHANGES)
    robust = check.pop("robust")
    fc = check.pop("finite_change")
    check["robust"] = robust
    if success and not robust:    # the compiled solver's claim did not survive verification
        success, code = False, "NO_ROBUST_PLAN"
        message = "best plan failed the true-derivative verification"
    if success and not message:
        message = (f"truly robust plan: max |dq(tf)/dp| = {check['max_abs_derivative']:.1e} "
                   f"(exact and central differences), |q(tf) - qf| = "
                   f"{abs(check['q_tf'] - prob.goal):.1e} rad, at rest at tf")
    ex = stats
    ex["verification"] = check
    ex["finite_change"] = fc
    if extra:
        ex.update(extra)
    q_tf, v_tf = check["q_tf"], check["qd_tf"]
    return PlanResult(
        success=bool(success), message=message, profile=prof, model="arm1dof",
        params=prob.params, q0=np.array([prob.q0]), qf=np.array([prob.goal]),
        uncertain=list(request.uncertain), objective=request.objective,
        q_final=np.array([q_tf]), qd_final=np.array([v_tf]), sensitivities=dict(check["exact"]),
        robust=bool(robust), error_code=code, best_effort=not success, starts_tried=tried,
        iterations=iters, solve_time=time.perf_counter() - t0, warm_start=warm, extra=ex)


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
    scales = sample_scales(request.uncertain, FRICTION)
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
        if (ok["robust"] if with_derivs else (ok["at_goal"] and ok["at_rest"])) \
                and prob.within_limits(I1):
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
    plan_robust_1dof(PlanRequest(objective="robust-derivative", starts=200, seed=0, uncertain=("pc",)))
    plan_robust_1dof(PlanRequest(objective="robust-sampled", starts=200, seed=0,
                                 uncertain=("pc",)))
    simulate(Arm1DofParams(), CurrentProfile.uniform([[1.0], [-1.0]], 1.0), [0.0], trajectory=True)
    return time.perf_counter() - t0


def smallest_robust_steps(request: PlanRequest, n_max: int = 12,
                          progress: Progress = None) -> tuple[Optional[PlanResult], list[dict]]:
    """The smallest N (from 2 + k up to ``n_max``) that admits a truly robust plan.

    Returns (the first robust PlanResult or None, evidence): one row per N tried with the starts
    run, whether a robust plan was found, and the best residual seen — so that "no robust plan
    with N steps" is stated with what was tried. Each N gets ``request.starts`` starts and
    ``request.time_budget`` seconds.
    """
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
