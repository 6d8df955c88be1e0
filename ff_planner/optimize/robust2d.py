"""Robust rest-to-rest plans for the 2-DOF SCARA arm (paper section 4.2), in seconds, not hours.

Method ("hold link 2, solve joint 1 exactly"): when the task leaves link 2's absolute angle
unchanged (q2f = q20, as in the paper's [-0.5, 0] → [0.5, 0] task), motor 2 can cancel the
reaction of link 1 step by step so that joint 2 never leaves stiction. Then

* q2(t) ≡ q20 for every friction value near nominal, so ∂q2(tf)/∂p = 0 exactly and joint 1
  does not feel pv2, pc2, pt2 (∂q1/∂p2 = 0 exactly);
* joint 1 is EXACTLY the 1-DOF arm with inertia A = Jc1 + m1·lc1² + m2·l1² and joint-1 friction,
  solved with the suite's exact 1-DOF simulator (``ff_planner.model.arm1dof``): multistart
  least-squares on [q1(tf) − q1f, ∂q1(tf)/∂p_i] with the final stop kept strictly inside the
  zero-current coast (rest at tf that survives parameter changes, no kink at the nominal point);
* motor 2's current on each step is the midpoint of the reaction torque's range on that step,
  which maximises the stiction margin; the plan records how far joint-2 friction may drop before
  link 2 would slip (``extra['hold_fraction']``).

Every plan is then verified on the FULL 2-DOF simulation (``ff_planner.model.scara2``): final error,
both joints at rest at tf, and all 12 sensitivities by complex step (exact derivatives). Tasks in
which link 2 must move have no known truly robust plan (see docs/scara2-model.md): the planner
says so (NO_ROBUST_PLAN) and returns its least-worst-case-error plan labelled best_effort.

Limits (``request.limits``): with link 2 held, joint 1's excursion is the held 1-DOF arm's, so
every verified candidate is checked against joint 1's position range and speed limit at the
certificate's box points of the uncertain joint-1 parameters (``limits2d.joint1_limits``,
exact); a held plan outside them is continued into them (a second continuation with
``Joint1Problem``'s limit rows at the box corners, so that the first keeps its success rate). A
candidate within them is also simulated on the full 2-DOF model at the corners of the whole box
(``limits2d.corner_excess_2dof``: both joints, link 2 free to slip) before it is taken. The search
goes on past a robust plan outside them and answers one only when no robust plan within them was
found, labelled (not a success, ``extra["limits_joint1_excess"]``). Tasks that move link 2: the
one-joint-at-a-time plans hold each phase's moving joint within its limits
(``robust2d_sequential``); the least-worst plan does not search under limits. The facade checks
the 2-DOF certificate's excursion against the limits and labels a plan that leaves them.

Units: rad, A, s. No rclpy here.
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable, Optional

import numpy as np

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest, PlanResult
from ff_planner.optimize.hold_joint import Joint1Problem, joint1_params, joint2_hold_currents
from ff_planner.optimize.limits2d import corner_excess_2dof, joint1_limits
from ff_planner.optimize.robust1d import solve_block
from ff_planner.optimize.robust2d_least_worst import plan_least_worst
from ff_planner.optimize.robust2d_refine import refine_sampled
from ff_planner.optimize.robust2d_sequential import plan_sequential
from ff_planner.optimize.sample_box import FINITE_FRACTIONS, one_at_a_time

Progress = Optional[Callable[[dict], None]]

HOLD_FALLBACK = 0.1      # accepted when HOLD_MIN cannot be reached from a start
HOLD_LEVELS = (HOLD_FALLBACK,)   # margins asked for in turn by the continuation
STAGE2_NFEV = 40         # evaluations per continuation attempt (then abandon)
CHUNK = 16               # joint-1 starts per compiled call (budget checked between calls)


def _is_pos(key: str) -> bool:
    """'q1/pc2' (position sensitivity), not 'qd1/pc2'."""
    return key.startswith("q") and not key.startswith("qd")


# ----------------------------------------------------------------------------------------------
# verification on the full model


def verify_plan(p: Scara2Params, profile: CurrentProfile, q0, qf, names=scara2.FRICTION_NAMES,
                finite=FINITE_FRACTIONS) -> dict:
    """Full 2-DOF check of a plan: final state, 12 complex-step sensitivities, and the final
    (rest) position error when each friction parameter is off by ±finite fractions."""
    q0 = np.asarray(q0, float)
    qf = np.asarray(qf, float)
    sim = scara2._simulate_raw(p, profile, q0, np.zeros(2), settle=True)
    sens = scara2.sensitivities_scara2(p, profile, q0, names, method="complex")
    worst = {}
    for f in finite:
        w = 0.0
        for n, change in one_at_a_time(names, (f,), signs=(1.0, -1.0)):
            pp = p.replace(**{n: getattr(p, n) * (1.0 + change)})
            r = scara2._simulate_raw(pp, profile, q0, np.zeros(2), settle=True)
            w = max(w, float(np.max(np.abs(r.q_rest - qf))))
        worst[f"{int(round(f * 100))}%"] = w
    return {
        "q_final": sim.q_f, "qd_final": sim.qd_f, "q_rest": sim.q_rest,
        "error": float(np.max(np.abs(sim.q_f - qf))),
        "at_rest": bool(sim.stuck_tf[0] and sim.stuck_tf[1]),
        "sensitivities": {k: v for k, v in sens.items() if _is_pos(k)},
        "max_sensitivity": max(abs(v) for k, v in sens.items() if _is_pos(k)),
        "worst_rest_error_one_at_a_time": worst,
    }


# ----------------------------------------------------------------------------------------------
# the planner


def _result(request: PlanRequest, p: Scara2Params, **kw: Any) -> PlanResult:
    base: dict[str, Any] = dict(success=False, message="", profile=None, model="scara2", params=p,
                q0=np.asarray(request.q0, float), qf=np.asarray(request.qf, float),
                uncertain=list(request.uncertain), objective=request.objective)
    base.update(kw)
    return PlanResult(**base)


def plan_robust_scara2(request: PlanRequest, progress: Progress = None) -> PlanResult:
    """Robust 2-DOF plan: every |∂q_j(tf)/∂p_i| ≤ tol (true derivatives), |q(tf) − qf| ≤ tol,
    both joints at rest at tf; verified on the full 2-DOF simulation.

    Returns success with the plan, or NO_ROBUST_PLAN / TIME_BUDGET_EXHAUSTED with the best plan
    found labelled ``best_effort``. ``progress`` gets dicts like {"stage": "joint1",
    "starts_done": 12, "best": 3e-4, "elapsed": 0.4}. ``request.starts`` bounds the number of
    continuations (the costly step); joint-1 starts are cheap and run within the time budget.
    """
    t_start = time.perf_counter()
    p = request.resolved_params()
    if not isinstance(p, Scara2Params):
        raise PlanningError("plan_robust_scara2 needs a scara2 request")
    q0 = np.asarray(request.q0, float)
    qf = np.asarray(request.qf, float)
    tol = float(request.tol)
    N = request.n_steps()
    deadline = t_start + float(request.time_budget)
    names = tuple(request.uncertain)

    if abs(qf[1] - q0[1]) > 0.0:
        return _plan_link2_moving(request, p, progress, t_start)

    names1 = tuple(n[:-1] for n in names if n.endswith("1"))
    p1 = joint1_params(p)
    args = (p1, float(q0[0]), float(qf[0]), float(request.tf), float(request.coast), N, names1)
    # stage 1: joint 1 robust with rest in the coast (robust1d's compiled LM, ``solve_block``);
    # stage 2: continuation along that solution set until link 2 is held with margin
    times = np.linspace(0.0, request.tf - request.coast, N + 1)
    lim = joint1_limits(request, p)
    holds = [Joint1Problem(*args, p2=p, q2=float(q0[1]), hold_min=h) for h in HOLD_LEVELS]
    holds_lim = [Joint1Problem(*args, p2=p, q2=float(q0[1]), hold_min=h, limits=lim)
                 for h in HOLD_LEVELS] if lim is not None else []
    rng = np.random.default_rng(request.seed)
    best = None          # (score, profile, verification)
    best_cost = math.inf
    starts = 0
    iters = 0
    candidates = 0
    found = False
    # request.starts bounds the expensive part, the continuations from joint-1 robust solutions
    # (each a "start" of the 2-DOF search); cheap joint-1 starts (CHUNK per compiled call, full
    # current range) run until the time budget
    while candidates < request.starts and time.perf_counter() < deadline and not found:
        block = rng.uniform(-p1.i_max, p1.i_max, (CHUNK, N))
        ends = solve_block(p1, float(q0[0]), float(qf[0]), float(request.tf), names1, block,
                           coast=float(request.coast), tol=tol)
        starts += len(ends)
        iters += sum(e["iterations"] for e in ends)
        best_cost = min([best_cost] + [e["residual2"] for e in ends])
        xs = [e["currents"] for e in ends if e["ok"]]
        if progress:
            progress({"stage": "joint1", "starts_done": starts, "best": best_cost,
                      "candidates": candidates + len(xs),
                      "elapsed": time.perf_counter() - t_start})
        for x in xs:
            if time.perf_counter() >= deadline or candidates >= request.starts:
                break
            candidates += 1
            # continuation along the solution set (4 spare dimensions at N = 8) until motor 2 can
            # hold link 2 with margin: first asking for HOLD_MIN, else HOLD_FALLBACK
            for hp in holds:
                x2, fun2, nfev2 = hp.solve(x, max_nfev=STAGE2_NFEV)
                iters += nfev2
                if float(np.max(np.abs(fun2))) <= 0.1 * tol:
                    x = x2
                    break
            # then, from a held plan outside joint 1's limits, on along the set into them
            if lim is not None and lim.excess(times, np.ascontiguousarray(x)) > 0.0:
                for hp in holds_lim:
                    x2, fun2, nfev2 = hp.solve(x, max_nfev=STAGE2_NFEV)
                    iters += nfev2
                    if float(np.max(np.abs(fun2))) <= 0.1 * tol:
                        x = x2
                        break
            prof1 = CurrentProfile(times, x.reshape(-1, 1), request.tf, request.coast)
            I2, frac = joint2_hold_currents(p, prof1, q0)
            profile = CurrentProfile(times, np.column_stack([x, I2]), request.tf, request.coast)
            if frac <= 0.0:
                continue
            sim = scara2._simulate_raw(p, profile, q0, np.zeros(2))
            sens = scara2.sensitivities_scara2(p, profile, q0, names, method="complex")
            smax = max(abs(v) for k, v in sens.items() if _is_pos(k))
            err = float(np.max(np.abs(sim.q_f - qf)))
            ok = err <= tol and smax <= tol and sim.stuck_tf[0] and sim.stuck_tf[1]
            excess = lim.excess(times, np.ascontiguousarray(x, dtype=float)) if lim else 0.0
            if ok and excess <= 0.0:     # and on the full model at the corners of the box
                excess = corner_excess_2dof(request, p, profile)
            ok_in = ok and excess <= 0.0
            # robust within the limits, then robust nearest the limits, then least residual
            score = ((0, -frac) if ok_in else (1, excess) if ok else (2, smax + err))
            if best is None or score < best[0]:
                best = (score, profile, sim, sens, frac, excess)
            if progress:
                progress({"stage": "verify", "starts_done": starts, "robust": ok,
                          "hold_fraction": frac, "max_sensitivity": smax, "error": err,
                          "elapsed": time.perf_counter() - t_start})
            if ok_in:   # frac >= HOLD_FALLBACK > 0 here: first verified robust plan wins
                found = True
                break
    elapsed = time.perf_counter() - t_start
    if best is None:
        code = "TIME_BUDGET_EXHAUSTED" if time.perf_counter() >= deadline else "NO_ROBUST_PLAN"
        return _result(request, p, message=(
            f"no robust plan with N = {N} steps per joint after {starts} joint-1 starts and "
            f"{candidates} continuations (best joint-1 residual {best_cost:.3g}); "
            + (f"{lim.advice()}" if lim is not None else
               "try a larger time budget, more starts, more steps or a longer tf")),
            error_code=code, starts_tried=starts, iterations=iters, solve_time=elapsed)
    (rank, _), profile, sim, sens, frac, excess = best
    robust = rank == 0
    outside = rank == 1      # robust, but joint 1 leaves its limits
    refined = None
    if robust and request.objective == "robust-sampled" and names1:
        refined = _refine(request, p, holds[0], profile, names, names1, deadline, progress,
                          t_start)
        if refined is not None and lim is not None and not lim.ok(
                times, np.ascontiguousarray(refined[0].currents[:, 0])):
            refined = None       # the refinement left joint 1's limits: keep the plan within
        if refined is not None:
            profile, sim, sens, frac = refined
    elapsed = time.perf_counter() - t_start
    msg = (f"robust plan: joint 2 held by stiction (holds down to {100 * (1 - frac):.0f} % "
           f"of nominal joint-2 friction), max |dq/dp| = "
           f"{max(abs(v) for k, v in sens.items() if _is_pos(k)):.2g}")
    if outside:
        advice = (lim.advice() if lim is not None else "widen the limits or give a longer "
                  "move time")
        msg = (f"robust plan found, but it leaves the limits by {excess:.3g} rad (rad/s) over "
               f"the box: {advice}; " + msg.split(": ", 1)[1])
    elif not robust:
        msg = "best plan found is NOT robust to the tolerance: " + msg.split(": ", 1)[1]
    limit_extra = {} if lim is None else {"limits_joint1_excess": float(excess)}
    return _result(
        request, p, success=robust, robust=robust or outside, best_effort=not robust,
        error_code="OK" if robust else "NO_ROBUST_PLAN", message=msg, profile=profile,
        q_final=sim.q_f, qd_final=sim.qd_f,
        sensitivities={k: v for k, v in sens.items() if _is_pos(k)},
        starts_tried=starts, iterations=iters, solve_time=elapsed,
        extra={"method": "hold-link2", "hold_fraction": frac, "candidates": candidates,
               "joint1_inertia": p1.J, "sampled_refinement": refined is not None,
               **limit_extra})


def _refine(request, p, hp, profile, names, names1, deadline, progress, t_start):
    """robust-sampled: spend the spare freedom on smaller finite-change errors; returns
    (profile, sim, sens, frac) of the refined plan if it still verifies, else None."""
    q0 = np.asarray(request.q0, float)
    qf = np.asarray(request.qf, float)
    x = refine_sampled(hp, profile.currents[:, 0].copy(), names1, deadline, request.tol)
    if x is None:
        return None
    prof1 = CurrentProfile(profile.step_times, x.reshape(-1, 1), request.tf, request.coast)
    I2, frac = joint2_hold_currents(p, prof1, q0)
    new = CurrentProfile(profile.step_times, np.column_stack([x, I2]), request.tf, request.coast)
    sim = scara2._simulate_raw(p, new, q0, np.zeros(2))
    sens = scara2.sensitivities_scara2(p, new, q0, names, method="complex")
    smax = max(abs(v) for k, v in sens.items() if _is_pos(k))
    ok = (float(np.max(np.abs(sim.q_f - qf))) <= request.tol and smax <= request.tol
          and all(sim.stuck_tf) and frac > 0.0)
    if progress:
        progress({"stage": "refine-sampled", "robust": ok, "hold_fraction": frac,
                  "elapsed": time.perf_counter() - t_start})
    return (new, sim, sens, frac) if ok else None


def _plan_link2_moving(request: PlanRequest, p: Scara2Params, progress: Progress,
                       t_start: float) -> PlanResult:
    """Link 2 must move. First one joint at a time, each an exact robust 1-DOF problem with the
    other joint held by stiction (``robust2d_sequential``, up to half the budget); failing that,
    the least-worst-case plan over one-at-a-time ±10 % friction changes, labelled best_effort."""
    half = t_start + 0.5 * float(request.time_budget)
    res = plan_sequential(request, p, progress, t_start, half)
    if res is not None:
        return res
    return plan_least_worst(request, p, progress, t_start)


def warm_up() -> float:
    """Compile/load every kernel the 2-DOF planner uses (scara2, arm1dof, robust1d's solver)
    by planning a short task; returns the seconds it took. For install time or node start."""
    t = time.perf_counter()
    scara2.warm_up()
    req = PlanRequest(objective="robust-derivative", model="scara2", q0=(-0.5, 0.0), qf=(0.5, 0.0), tf=1.0,
                      uncertain=scara2.FRICTION_NAMES, starts=32, seed=0, time_budget=600)
    plan_robust_scara2(req)
    return time.perf_counter() - t
