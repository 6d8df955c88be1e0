"""The planner facade: ``plan(request)`` validates, checks reachability, dispatches, labels.

Dispatch: robust-derivative / robust-sampled -> ``robust1d.plan_robust_1dof`` (arm1dof) or
``robust2d.plan_robust_scara2`` (scara2); time-optimal / energy-optimal -> ``baselines``.
Errors are ``PlanningError`` with the PlanTrajectory error name in ``.code``.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Optional

import numpy as np

from ff_planner.model.params import Arm1DofParams, ParameterError, Params, Scara2Params
from ff_planner.model.profile import PlanningError, PlanRequest, PlanResult
from ff_planner.optimize.baselines import plan_baseline, reach_1dof

Progress = Optional[Callable[[dict], None]]


# --- reachability ----------------------------------------------------------------------------
def _energy_reach(tmax: np.ndarray, pc: np.ndarray, pt: np.ndarray, pv: np.ndarray,
                  lam: float, duration: float, cells: int = 4000) -> float:
    """Sound bound (rad) on the path length ∫‖q̇‖ dt of any rest-to-rest move of ``duration`` s.

    Energy E = ½ q̇ᵀM q̇ ≥ ½ λ‖q̇‖² (λ = smallest eigenvalue of M over all configurations). While
    speeding up, dE/dt ≤ Σ|q̇_i|(T_i − pc_i) − pv_i q̇_i² (no potential energy in the horizontal
    plane; Coriolis terms do no work); while slowing down to rest, −dE/dt ≤ Σ|q̇_i|(T_i(1+pt_i)+pc_i)
    + max(pv_i, 0) q̇_i². Hence ‖q̇(t)‖ ≤ min(s_a(t), s_b(duration − t)) with s' = a/λ + b/λ·s.
    """
    a = float(np.linalg.norm(np.maximum(tmax - pc, 0.0)))
    ba = float(np.max(np.maximum(-pv, 0.0)))
    c = float(np.linalg.norm(tmax * (1.0 + pt) + pc))
    bc = float(np.max(np.maximum(pv, 0.0)))

    def s_of(rate: float, grow: float, t: np.ndarray) -> np.ndarray:
        k = grow / lam
        if k < 1e-12:
            return rate / lam * t
        return rate / grow * np.expm1(k * t)

    t = np.linspace(0.0, duration, cells + 1)
    up = s_of(a, ba, t[1:])                   # increasing: value at each cell's right end
    down = s_of(c, bc, duration - t[:-1])     # s_b(duration − t), decreasing: left end
    return float(np.sum(np.minimum(up, down)) * (duration / cells))


def reach(params: Params, tf: float, coast: float = 0.0) -> np.ndarray:
    """Upper bound per joint (rad) on |q_i(tf) − q0_i| over all admissible current profiles.

    1-DOF: the bang-bang bound of ``baselines.reach_1dof`` (tight up to the coast). SCARA: the
    energy bound of ``_energy_reach`` (sound, loose). Never smaller than the true reach.
    """
    if isinstance(params, Arm1DofParams):
        return np.array([reach_1dof(params, tf)])
    if isinstance(params, Scara2Params):
        p = params
        A = p.Jc1 + p.m1 * p.lc1 ** 2 + p.m2 * p.l1 ** 2
        C = p.Jc2 + p.m2 * p.lc2 ** 2
        B = p.m2 * p.l1 * p.lc2
        lam = (A + C) / 2.0 - math.sqrt(((A - C) / 2.0) ** 2 + B ** 2)   # worst case |cos| = 1
        if lam <= 0.0:
            return np.array([math.inf, math.inf])
        tmax = np.array([p.n1 * p.kt1 * p.i_max1, p.n2 * p.kt2 * p.i_max2])
        r = _energy_reach(tmax, np.array([p.pc1, p.pc2]), np.array([p.pt1, p.pt2]),
                          np.array([p.pv1, p.pv2]), lam, tf)
        return np.array([r, r])
    raise PlanningError(f"no reachability bound for {type(params).__name__}", code="INVALID_REQUEST")


def check_reachable(request: PlanRequest) -> np.ndarray:
    """Raise PlanningError(code="UNREACHABLE") if the goal is beyond ``reach``; return the bound."""
    p = request.resolved_params()
    bound = reach(p, float(request.tf), float(request.coast))
    dist = np.abs(np.asarray(request.qf, dtype=float) - np.asarray(request.q0, dtype=float))
    for j, (d, r) in enumerate(zip(dist, bound)):
        if d > r:
            joint = "" if len(dist) == 1 else f" joint {j + 1}"
            lim = p.i_max if isinstance(p, Arm1DofParams) else getattr(p, f"i_max{j + 1}")
            raise PlanningError(
                f"goal unreachable:{joint} distance {d:.4g} rad, but with I_max = {lim:g} A no "
                f"profile moves it more than {r:.4g} rad and back to rest in tf = {request.tf:g} s; "
                f"raise tf, raise the current limit, or plan a shorter move", code="UNREACHABLE")
    return bound


# --- facade ----------------------------------------------------------------------------------
def _validate(request: PlanRequest) -> None:
    try:
        request.validate()
    except PlanningError:
        raise
    except ParameterError as e:
        msg = str(e)
        code = ("UNKNOWN_MODEL" if msg.startswith("unknown model") else
                "UNKNOWN_PARAMETER" if "unknown" in msg else "INVALID_REQUEST")
        raise PlanningError(msg, code=code) from None
    except (TypeError, ValueError) as e:
        raise PlanningError(f"invalid request: {e}", code="INVALID_REQUEST") from None


def _dispatch(request: PlanRequest):
    if request.objective in ("time-optimal", "energy-optimal"):
        return plan_baseline
    try:
        if request.model == "arm1dof":
            from ff_planner.optimize.robust1d import plan_robust_1dof as fn
        else:
            from ff_planner.optimize.robust2d import plan_robust_scara2 as fn
    except ImportError as e:
        raise PlanningError(f"the {request.model} robust planner is not available ({e})",
                            code="INTERNAL_ERROR") from None
    return fn


def plan(request: PlanRequest, progress: Progress = None,
         initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """Plan a rest-to-rest feedforward current profile.

    Raises PlanningError (with ``.code``) for bad input or an unreachable goal. Otherwise returns a
    PlanResult; when no plan met the tolerances it is the best plan found, labelled
    ``best_effort=True`` with error_code NO_ROBUST_PLAN (or TIME_BUDGET_EXHAUSTED when the time
    budget ran out first). The inner planners honour ``request.time_budget``; the facade labels a
    result that came back late. ``initial_currents`` (A, N x joints) warm-starts the search from a
    known plan instead of a multistart; WarmStartUnavailable if the model's planner cannot.
    """
    t0 = time.perf_counter()
    _validate(request)
    bound = check_reachable(request)
    fn = _dispatch(request)
    if initial_currents is None:
        result = fn(request, progress)
    else:   # warm start (motion library, continuation): one start from these currents (A)
        import inspect

        if "initial_currents" not in inspect.signature(fn).parameters:
            from ff_planner.library.store import WarmStartUnavailable

            raise WarmStartUnavailable(f"{fn.__module__}.{fn.__name__} takes no initial_currents")
        result = fn(request, progress, initial_currents=np.asarray(initial_currents, dtype=float))
    elapsed = time.perf_counter() - t0
    result.extra = dict(result.extra or {})
    result.extra.setdefault("reach_bound", bound.tolist())
    result.extra["facade_time_s"] = elapsed
    if elapsed > request.time_budget:
        result.extra["over_time_budget"] = True
    if result.profile is not None and "rest_position" not in result.extra:
        try:   # where the arm stops with zero current after tf: what a user will see
            from ff_planner.model.simulate import rest_position

            result.extra["rest_position"] = np.asarray(
                rest_position(result.params, result.profile, result.q0), dtype=float).tolist()
        except (ValueError, ArithmeticError):
            pass
    if not result.success:
        result.best_effort = result.profile is not None
        if result.error_code == "OK":
            result.error_code = ("TIME_BUDGET_EXHAUSTED" if elapsed > request.time_budget
                                 else "NO_ROBUST_PLAN")
        if result.profile is not None and "best plan" not in result.message:
            result.message = f"{result.message} (best plan found, not meeting the tolerances)"
    return result
