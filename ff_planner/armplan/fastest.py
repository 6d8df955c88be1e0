"""Tolerance first for arms from a URDF: the fastest move time whose certified worst rest error
meets a tolerance.

The search is the 1-DOF and SCARA planners' (``ff_planner.optimize.fastest.search_move_time``:
tf_max first, the knee by bisection, an upward scan in 3 % steps, bisection down to 1 %, near
misses planned again with the next seed); each tf is planned by ``plan_box_robust_arm`` and
certified over the cell's friction box. The tolerance (rad) bounds the certificate's
``worst_rest_error``, the worst joint's |θ_rest − qf| over the box; a plan that violates the
cell's limits never meets it. When no tf ≤ tf_max meets it, the answer is the plan of least
certified worst, labelled (not a success, NO_ROBUST_PLAN) with what to change.

The shortest tf tried is each joint's 1-DOF reach bound (``baselines.reach_1dof``: bang-bang at
i_max, nominal friction) with the smaller of its inertias M_jj at q0 and qf, the others still:
exact for one joint without gravity, a heuristic for coupled joints or under gravity (the knee
bisection starts there; a tf it rules out is never planned). Units: rad, s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ff_planner.arm.model import UrdfArm
from ff_planner.armplan.robust_box import ArmPlan, plan_box_robust_arm, plan_result
from ff_planner.core.errors import PlanningError
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import PlanResult
from ff_planner.optimize.baselines import reach_1dof
from ff_planner.optimize.fastest import DEFAULT_MOVE_TIME_MAX, SearchSettings, search_move_time
from ff_planner.optimize.planner import Progress


@dataclass
class ArmFastest:
    """The search's answer: ``result`` (its ``extra["tolerance_search"]`` lists every tf tried)
    and the answered ``plan`` (the ArmPlan behind it)."""

    result: PlanResult
    plan: ArmPlan


def shortest_tf(arm: UrdfArm, q0: np.ndarray, qf: np.ndarray, tf_max: float, coast: float,
                step: float) -> float:
    """Smallest tf (s, on the ``step`` grid, above the coast, ≤ tf_max) whose per-joint reach
    bound (see the module) covers every joint's move; the bound grows with tf, so bisection."""
    dist = np.abs(qf - q0)
    params = []
    for j in range(arm.n):
        jc = arm.cells[j]
        assert jc.motor is not None
        J = min(float(arm.constants.mass_matrix(q0)[j, j]), float(arm.constants.mass_matrix(qf)[j, j]))
        params.append(Arm1DofParams(J=J, kt=jc.motor.kt, n=jc.motor.gear, i_max=jc.motor.i_max,
                                    pv=float(arm.friction[j, 0]), pc=float(arm.friction[j, 1]),
                                    pt=float(arm.friction[j, 2])))

    def ok(t: float) -> bool:
        return all(reach_1dof(p, t) >= d for p, d in zip(params, dist))

    lo, hi = coast + step, tf_max
    if ok(lo) or not ok(hi):
        return min(lo, tf_max) if ok(lo) else tf_max
    while hi - lo > step:
        mid = 0.5 * (lo + hi)
        if ok(mid):
            hi = mid
        else:
            lo = mid
    return min(math.ceil(hi / step - 1e-9) * step, tf_max)


def plan_fastest_arm(arm: UrdfArm, q0: Sequence[float], qf: Sequence[float], tolerance: float, *,
                     tf_max: float = DEFAULT_MOVE_TIME_MAX, coast: float = 0.05,
                     steps: Optional[int] = None, seed: int = 0, time_budget: float = 30.0,
                     settings: Optional[SearchSettings] = None, progress: Progress = None,
                     model: Optional[str] = None, tf_min: Optional[float] = None) -> ArmFastest:
    """The plan of the fastest tf ≤ ``tf_max`` (s) certified within ``tolerance`` (rad) for the
    move q0 → qf (motor angles of the moving joints, rad); see the module. The whole search keeps
    to ``time_budget`` (s); ``tf_min`` (s) raises the shortest tf tried above the reach bound's
    (a window known to hold the answer costs fewer plans). PlanningError, before any planning,
    for a bad request; also when no tf gave a plan at all (the first planner error)."""
    t0 = time.perf_counter()
    settings = settings or SearchSettings()
    n = arm.n
    q0a = np.asarray(q0, float).reshape(-1)
    qfa = np.asarray(qf, float).reshape(-1)
    if q0a.shape != (n,) or qfa.shape != (n,) or not (np.all(np.isfinite(q0a)) and np.all(np.isfinite(qfa))):
        raise PlanningError(f"q0 and qf need {n} finite values each (rad) for arm '{arm.name}'",
                            "INVALID_REQUEST")
    tol = float(tolerance)
    if not (math.isfinite(tol) and tol > 0.0):
        raise PlanningError(f"tolerance must be a number > 0 rad, got {tolerance!r}", "INVALID_REQUEST")
    if not (math.isfinite(coast) and coast > 0.0):
        raise PlanningError(f"coast must be > 0 s, got {coast!r}", "INVALID_REQUEST")
    step = settings.tf_step
    tf_hi = math.floor(float(tf_max) / step + 1e-9) * step
    if not (math.isfinite(tf_hi) and tf_hi > coast + step):
        raise PlanningError(f"the longest move time must exceed the coast {coast:g} s by at least "
                            f"{step:g} s, got {tf_max!r}", "INVALID_REQUEST")
    if not (math.isfinite(time_budget) and time_budget > 0.0):
        raise PlanningError(f"time_budget must be > 0 s, got {time_budget!r}", "INVALID_REQUEST")
    if not arm.limits.empty:
        arm.limits.validate(n, q0a.tolist(), qfa.tolist())
    name = model or f"urdf:{arm.name}"
    tf_lo = shortest_tf(arm, q0a, qfa, tf_hi, float(coast), step)
    if tf_min is not None:
        if not (math.isfinite(tf_min) and coast < tf_min <= tf_hi):
            raise PlanningError(f"the shortest move time must be in ({coast:g}, {tf_hi:g}] s, got "
                                f"{tf_min!r}", "INVALID_REQUEST")
        tf_lo = max(tf_lo, math.ceil(float(tf_min) / step - 1e-9) * step)
    plans: dict[int, ArmPlan] = {}      # id of a trial's PlanResult -> its ArmPlan

    def one(tf: float, s: int, budget: float) -> PlanResult:
        res = plan_box_robust_arm(arm, q0a.tolist(), qfa.tolist(), tf, coast=coast, steps=steps, seed=s,
                                  time_budget=budget)
        r = plan_result(arm, res, name)
        plans[id(r)] = res
        return r

    result = search_move_time(one, tf_lo, tf_hi, step, float(time_budget), tol, settings,
                              progress, seed=int(seed), t0=t0)
    return ArmFastest(result, plans[id(result)])
