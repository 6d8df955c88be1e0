"""Truly robust 2-DOF plans when BOTH links must move: one joint at a time.

Phase A (duration t_a): joint a moves as an exact 1-DOF robust problem (robust1d) and stops
inside its own zero-current coast, while the other motor holds joint b in stiction by cancelling
the reaction step by step. Phase B (the rest of tf): joint b moves the same way while joint a,
now at its goal, is held. Because each joint's final position depends only on its own phase and
its own friction (the held joint never slips), every ∂q_j(tf)/∂p_i is zero exactly when the two
1-DOF plans are robust; the plan is verified on the full 2-DOF model all the same.

Limits: each joint only has part of tf, and holding joint 1 while link 2 accelerates needs large
motor-1 torque (joint 1's stiction at 10 A is only ~3.4 Nm), so it works for moderate moves, or
when the links are near right angles (the coupling B·cos(q1 − q2) vanishes).

Position / speed limits (``request.limits``): each phase's 1-DOF robust plan is asked to keep the
moving joint within its limits (``limits2d.joint_limits``, the 1-DOF planner's own search under
limits); a phase whose held continuation leaves them is dropped, and the joined plan is simulated
on the full 2-DOF model at the corners of the whole box (``limits2d.corner_excess_2dof``) before
it is answered.
Units: rad, A, s.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Optional

import numpy as np

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest, PlanResult
from ff_planner.model.limits import MotionLimits
from ff_planner.optimize.hold_joint import Joint1Problem, hold_torques, joint1_params, joint2_params
from ff_planner.optimize.limits2d import corner_excess_2dof, joint_limits
from ff_planner.optimize.robust1d import plan_robust_1dof

SPLITS = {1: (0.7, 0.6, 0.5), 2: (0.3, 0.4, 0.5)}   # share of tf of the first phase, by its joint
HOLD_MIN = 0.1               # held joint must keep 10 % of its stiction unused


def _phase(p: Scara2Params, joint: int, qa0: float, qaf: float, q_other: float, t: float,
           request: PlanRequest, names: tuple, seed: int, budget: float, zero_coast: bool
           ) -> Optional[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """1-DOF robust plan for ``joint`` over t s with the other joint held at q_other.
    Returns (times (n+1,), I_moving (n,), T_held (n+1,), min hold fraction) or None."""
    if t <= request.coast:      # the phase must be longer than its zero-current coast
        return None
    stop = time.perf_counter() + budget
    pm = joint1_params(p) if joint == 1 else joint2_params(p)
    held = 2 if joint == 1 else 1
    k = len(names)
    lim = joint_limits(request, p, joint, q0=qa0, tf=t)
    fin = lambda v: [v] if lim is not None and math.isfinite(v) else None  # noqa: E731
    limits = (MotionLimits.of(fin(lim.lo), fin(lim.hi), fin(lim.vmax)) if lim is not None
              else None)
    box = ({u[:-1]: f for u, f in (request.box or {}).items()
            if u.endswith(str(joint)) and u[:-1] in names} if lim is not None else None)
    for n in (k + 2, k + 3, k + 5):
        for s in range(3):
            req = PlanRequest(objective="robust-derivative", model="arm1dof", q0=(qa0,), qf=(qaf,), tf=t,
                              uncertain=tuple(names) or ("pc",), steps=max(n, 3),
                              coast=request.coast, params=pm, starts=400, seed=seed + 7919 * s,
                              time_budget=budget, tol=request.tol, limits=limits, box=box)
            try:
                r = plan_robust_1dof(req)
            except PlanningError:
                return None
            prof0 = r.profile
            if not r.success or prof0 is None:
                break           # more starts at this n rarely help: try more steps
            if time.perf_counter() > stop:
                return None
            x = prof0.currents[:, 0].copy()
            T, frac = hold_torques(p, held, prof0, qa0, q_other, zero_coast=zero_coast)
            if frac.min() < HOLD_MIN:   # continuation along the robust set to a held joint
                hp = Joint1Problem(pm, qa0, qaf, t, request.coast, len(x), tuple(names), p2=p,
                                    q2=q_other, hold_min=HOLD_MIN, held=held,
                                    zero_coast=zero_coast)
                x2, fun, _ = hp.solve(x, max_nfev=60)
                if float(np.max(np.abs(fun))) > 0.1 * request.tol:
                    continue
                x = x2
                prof = CurrentProfile(prof0.step_times, x.reshape(-1, 1), t, request.coast)
                T, frac = hold_torques(p, held, prof, qa0, q_other, zero_coast=zero_coast)
            if lim is not None and not lim.ok(prof0.step_times, np.ascontiguousarray(x)):
                continue        # the continuation left the moving joint's limits
            if frac.min() >= 0.5 * HOLD_MIN:
                return prof0.step_times, x, T, float(frac.min())
    return None


def plan_sequential(request: PlanRequest, p: Scara2Params, progress: Optional[Callable],
                    t_start: float, deadline: float) -> Optional[PlanResult]:
    """A verified robust plan moving one joint after the other, or None."""
    q0 = np.asarray(request.q0, float)
    qf = np.asarray(request.qf, float)
    tf, tol = float(request.tf), float(request.tol)
    names = {1: tuple(n[:-1] for n in request.uncertain if n.endswith("1")),
             2: tuple(n[:-1] for n in request.uncertain if n.endswith("2"))}
    K = {1: p.n1 * p.kt1, 2: p.n2 * p.kt2}
    tries = 0
    for first, second in ((1, 2), (2, 1)):
        for split in SPLITS[first]:
            if time.perf_counter() >= deadline:
                return None
            tries += 1
            ta = split * tf
            tb = tf - ta
            budget = max(0.2, (deadline - time.perf_counter()) / 4)
            A = _phase(p, first, q0[first - 1], qf[first - 1], q0[second - 1], ta, request,
                       names[first], request.seed, budget, zero_coast=False)
            if progress:
                progress({"stage": "sequential", "order": f"{first}-then-{second}",
                          "split": split, "phase_a": A is not None,
                          "elapsed": time.perf_counter() - t_start})
            if A is None:
                continue
            B = _phase(p, second, q0[second - 1], qf[second - 1], qf[first - 1], tb, request,
                       names[second], request.seed + 1, budget, zero_coast=True)
            if B is None:
                continue
            times_a, Ia, Ta_held, fa = A
            times_b, Ib, Tb_held, fb = B
            # phase A steps, phase A's coast (moving motor off, held motor on), phase B steps
            t_all = np.concatenate([times_a, [ta], ta + times_b[1:]])
            rows = []
            for i in range(len(Ia)):
                r = [0.0, 0.0]
                r[first - 1] = Ia[i]
                r[second - 1] = Ta_held[i] / K[second]
                rows.append(r)
            r = [0.0, 0.0]
            r[second - 1] = Ta_held[-1] / K[second]
            rows.append(r)
            for i in range(len(Ib)):
                r = [0.0, 0.0]
                r[second - 1] = Ib[i]
                r[first - 1] = Tb_held[i] / K[first]
                rows.append(r)
            profile = CurrentProfile(t_all, np.array(rows), tf, request.coast)
            sim = scara2._simulate_raw(p, profile, q0, np.zeros(2))
            sens = scara2.sensitivities_scara2(p, profile, q0, request.uncertain)
            sens = {k: v for k, v in sens.items() if not k.startswith("qd")}
            smax = max(abs(v) for v in sens.values()) if sens else 0.0
            err = float(np.max(np.abs(sim.q_f - qf)))
            ok = err <= tol and smax <= tol and all(sim.stuck_tf)
            excess = corner_excess_2dof(request, p, profile) if ok else 0.0
            ok = ok and excess <= 0.0
            if progress:
                progress({"stage": "sequential-verify", "robust": ok, "max_sensitivity": smax,
                          "error": err, "elapsed": time.perf_counter() - t_start})
            if not ok:
                continue
            return PlanResult(
                success=True, robust=True, error_code="OK", profile=profile, model="scara2",
                params=p, q0=q0, qf=qf, uncertain=list(request.uncertain),
                objective=request.objective, q_final=sim.q_f, qd_final=sim.qd_f,
                sensitivities=sens, starts_tried=tries, solve_time=time.perf_counter() - t_start,
                message=(f"robust plan, one joint at a time: joint {first} in the first "
                         f"{ta:.3g} s, joint {second} after; the other joint held by stiction "
                         f"(hold fractions {fa:.2f}, {fb:.2f}); max |dq/dp| = {smax:.2g}"),
                extra={"method": "sequential", "order": [first, second], "split_s": ta,
                       "hold_fraction": min(fa, fb), "n_steps_total": len(rows)})
    return None
