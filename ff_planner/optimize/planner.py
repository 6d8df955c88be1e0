"""The planner facade: ``check(request)`` validates once, ``plan(request)`` dispatches and labels.

``check`` does all validation (the request's fields, a planner for its model and objective, the
reachability bound) and returns a ``CheckedRequest``; ``plan`` takes either a plain
``PlanRequest`` (checked first) or a ``CheckedRequest`` (not checked again — e.g. one checked by
the planner service and handed to a worker process). Dispatch (``ROUTES``): robust-box ->
``box_robust.plan_box_robust_1dof`` (arm1dof) or ``robust2d_box.plan_box_robust_scara2``
(scara2, link 2 held); robust-derivative /
robust-sampled -> ``robust1d.plan_robust_1dof`` (arm1dof) or ``robust2d.plan_robust_scara2``
(scara2); time-optimal / energy-optimal -> ``baselines.plan_baseline`` (arm1dof). Errors are
``PlanningError`` with the PlanTrajectory error name in ``.code``. robust-box (the default
objective) with steps unset, steps = 0 or starts = 0 goes through ``plan_auto_1dof`` (N and
starts along ``auto_ladders``); ``request.current_quantum`` > 0 rounds the answer's currents to
the drive's setpoint grid before its rest position and certificate are computed.

Drive-exact plans: ``check(request, drive=DriveGrid)`` (``ff_planner.optimize.drive_grid``, read
from the bridge's configuration) carries the drive's current quantum (A) and SYNC period (s) in the
CheckedRequest. ``plan`` then has the robust 1-DOF planners place the switch times on the SYNC grid
(and solve the currents again there), puts any switch still off it on the nearest SYNC, rounds the
currents to the quantum, moves them by whole quanta where that lowers the worst rest error over
the box (1-DOF), and certifies exactly that profile: the certificate is a ``DriveCertificate``
whose ``drive`` says so, and ``extra["drive_exact"]`` gives the figures.

Beyond the request's own validation, ``check`` refuses positions beyond ±MAX_POSITION rad, a
torque-dependent friction ``pt`` ≥ 1 (it would take all of the motor torque) and a negative viscous
friction that Coulomb friction cannot stop (the arm would never come to rest). ``plan`` checks the
certificate's excursion against ``request.limits``: a plan that leaves them is labelled (not a
success, error NO_ROBUST_PLAN, ``extra["limit_violations"]``). A request with a ``tolerance`` is a
search over the move time: ``ff_planner.optimize.fastest.plan_fastest``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from dataclasses import replace as dc_replace
from typing import Callable, Optional, Union

import numpy as np

from ff_planner.core.errors import ParameterError, PlanningError, WarmStartUnavailable, error_code_of
from ff_planner.model.params import Arm1DofParams, Params, Scara2Params
from ff_planner.model.scara2 import sensitivities_scara2 as scara2_sensitivities
from ff_planner.model.profile import (
    DEFAULT_STARTS,
    MAX_TF,
    CurrentProfile,
    GridPlanRequest,
    PlanRequest,
    PlanResult,
)
from ff_planner.model.simulate import rest_position
from ff_planner.optimize.baselines import plan_baseline, reach_1dof
from ff_planner.optimize.box_robust import plan_box_robust_1dof
from ff_planner.optimize.certificate import certify_1dof
from ff_planner.optimize.certificate2d import certify_scara2
from ff_planner.optimize.drive_grid import (
    DriveCertificate,
    DriveGrid,
    land_on_times,
    landing_allowance,
    on_period,
    on_quantum,
    refine_on_quantum,
    snap_times,
)
from ff_planner.optimize.limits2d import joint1_limits
from ff_planner.optimize.quantize import quantize_result
from ff_planner.optimize.robust1d import plan_robust_1dof
from ff_planner.optimize.robust2d import plan_robust_scara2
from ff_planner.optimize.robust2d_box import plan_box_robust_scara2
from ff_planner.optimize.robust2d_drive import resolve_on_times

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


def _unreachable(request: PlanRequest, p: Params, bound: np.ndarray) -> None:
    """Raise PlanningError(code="UNREACHABLE") if the goal is beyond ``bound`` (rad per joint)."""
    dist = np.abs(np.asarray(request.qf, dtype=float) - np.asarray(request.q0, dtype=float))
    for j, (d, r) in enumerate(zip(dist, bound)):
        if d > r:
            joint = "" if len(dist) == 1 else f" joint {j + 1}"
            lim = p.i_max if isinstance(p, Arm1DofParams) else getattr(p, f"i_max{j + 1}")
            longer = ("raise tf, " if float(request.tf) < MAX_TF else
                      f"(tf is at its maximum of {MAX_TF:g} s) ")
            raise PlanningError(
                f"goal unreachable:{joint} distance {d:.4g} rad, but with I_max = {lim:g} A no "
                f"profile moves it more than {r:.4g} rad and back to rest in tf = {request.tf:g} s; "
                f"{longer}raise the current limit, or plan a shorter move", code="UNREACHABLE")


MAX_POSITION = 1.0e4         # rad, largest |q0|, |qf| accepted (far beyond any joint's travel)
MIN_ESCAPE_SPEED = 1.0e-2    # rad/s: with negative viscous friction pv, an arm faster than
#                              pc / |pv| never stops; below this speed no plan can come to rest
_FRICTION_PAIRS = {"arm1dof": (("pv", "pc", "pt", ""),),
                   "scara2": (("pv1", "pc1", "pt1", " joint 1"), ("pv2", "pc2", "pt2", " joint 2"))}


def _check_physics(request: PlanRequest, p: Params) -> None:
    """Refuse positions and friction values no plan can serve (INVALID_REQUEST, what to change)."""
    for name, v in (("q0", request.q0), ("qf", request.qf)):
        for x in v:
            if abs(float(x)) > MAX_POSITION:
                raise PlanningError(f"{name} = {float(x):g} rad is beyond ±{MAX_POSITION:g} rad; "
                                    f"give joint positions in rad", code="INVALID_REQUEST")
    box = request.box or {}
    for pv_key, pc_key, pt_key, joint in _FRICTION_PAIRS.get(request.model, ()):
        pv, pc, pt = (float(getattr(p, k)) for k in (pv_key, pc_key, pt_key))
        f_pt = float(box.get(pt_key, 0.2)) if pt_key in request.uncertain else 0.0
        if pt * (1.0 + f_pt) >= 1.0:
            raise PlanningError(
                f"{pt_key} = {pt:g}{'' if f_pt == 0.0 else f' (+{f_pt * 100:g} % in the box)'}: "
                f"torque-dependent friction {pt_key} * |n * kt * I| would take all of the motor "
                f"torque{joint}, so no current moves the arm; {pt_key} must be < 1"
                + ("" if f_pt == 0.0 else f" also at the box's edge (< {1.0 / (1.0 + f_pt):.4g})"),
                code="INVALID_REQUEST")
        if pv < 0.0:
            f_pv = float(box.get(pv_key, 0.2)) if pv_key in request.uncertain else 0.0
            f_pc = float(box.get(pc_key, 0.2)) if pc_key in request.uncertain else 0.0
            escape = pc * (1.0 - f_pc) / (-pv * (1.0 + f_pv))
            if escape < MIN_ESCAPE_SPEED:
                raise PlanningError(
                    f"{pc_key} = {pc:g} N*m is too small against the negative viscous friction "
                    f"{pv_key} = {pv:g} N*m*s/rad{joint}: an arm faster than {pc_key}/|{pv_key}| = "
                    f"{escape:.3g} rad/s (over the box) never comes to rest; raise {pc_key} above "
                    f"{MIN_ESCAPE_SPEED * -pv * (1.0 + f_pv) / (1.0 - f_pc):.3g} N*m or check "
                    f"{pv_key}'s sign", code="INVALID_REQUEST")


# --- dispatch --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Route:
    """The inner planner of one (model, objective) and whether it takes ``initial_currents``."""

    fn: Callable[..., PlanResult]    # fn(request, progress[, initial_currents=...]) -> PlanResult
    warm_start: bool                 # takes initial_currents (A, N × joints)


#: (model, objective) -> inner planner. The baselines exist for the 1-DOF arm only.
ROUTES: dict[tuple[str, str], Route] = {
    ("arm1dof", "robust-derivative"): Route(plan_robust_1dof, warm_start=True),
    ("arm1dof", "robust-sampled"): Route(plan_robust_1dof, warm_start=True),
    ("arm1dof", "robust-box"): Route(plan_box_robust_1dof, warm_start=True),
    ("arm1dof", "time-optimal"): Route(plan_baseline, warm_start=False),
    ("arm1dof", "energy-optimal"): Route(plan_baseline, warm_start=False),
    ("scara2", "robust-derivative"): Route(plan_robust_scara2, warm_start=False),
    ("scara2", "robust-sampled"): Route(plan_robust_scara2, warm_start=False),
    ("scara2", "robust-box"): Route(plan_box_robust_scara2, warm_start=False),
}


# --- chosen steps and starts (1-DOF robust planners) ----------------------------------------------
AUTO_OBJECTIVES = ("robust-derivative", "robust-sampled", "robust-box")
AUTO_MAX_STEPS = 12                 # largest N the planner escalates to
AUTO_STARTS = (50, 200, 1000)       # multistart counts tried per N before the next N
BOX_TARGET = 5e-3                   # rad: robust-box escalates N until its box worst is below


def _good(result: PlanResult, box_target: bool) -> bool:
    """A truly robust plan (zero exact derivatives, verified); with ``box_target`` (robust-box,
    steps = 0) also its box worst within BOX_TARGET."""
    if not (result.success and result.robust):
        return False
    if box_target and result.objective == "robust-box":
        return float(result.extra.get("box_worst", math.inf)) <= BOX_TARGET
    return True


def auto_ladders(req: PlanRequest) -> tuple[list[int], list[int], bool]:
    """(step counts N in the order tried, multistart counts tried per N, whether the box worst
    must reach BOX_TARGET) of a request the facade plans with ``plan_auto_1dof``.

    steps = 0: N from 2 + k up to AUTO_MAX_STEPS until a plan is truly robust (robust-box: and
    its box worst ≤ BOX_TARGET, else the least box worst of them). robust-box with steps unset:
    BOX_DEFAULT_STEPS, and only while it has no truly robust plan the others from 2 + k up
    (measured: the robust set is not monotone in N — 0 → 2 rad in 1 s, k = 3 has robust plans
    at N = 7 and 10, none at N = 8 in 1000 starts). starts = 0: the AUTO_STARTS ladder;
    otherwise the given starts, escalated along AUTO_STARTS beyond them before N changes
    (robust-box with steps unset) or not at all."""
    k = len(req.uncertain)
    box = req.objective == "robust-box"
    if req.auto_steps:
        ns = list(range(k + 2, AUTO_MAX_STEPS + 1))
    elif box and req.steps is None:
        first = req.n_steps()
        ns = [first] + [n for n in range(k + 2, AUTO_MAX_STEPS + 1) if n != first]
    else:
        ns = [req.n_steps()]
    if req.auto_starts:
        ladder = list(AUTO_STARTS)
    elif box and req.steps is None:
        ladder = [int(req.starts)] + [s for s in AUTO_STARTS if s > int(req.starts)]
    else:
        ladder = [int(req.starts)]
    return ns, ladder, bool(box and req.auto_steps)


def _tried_text(tried: list[dict]) -> str:
    parts = []
    for row in tried:
        what = "robust" if row["robust"] else "no robust plan"
        if row["robust"] and "box_worst" in row:
            what += f", box worst {row['box_worst'] * 1e3:.3g} mrad"
        parts.append(f"N={row['steps']} ({row['starts']} starts): {what}")
    return "; ".join(parts)


#: robust-box answers under limits after which the ladder stops (optimize/box_robust.py)
LIMITS_FINAL = ("least worst within the limits", "refused")


def plan_auto_1dof(req: PlanRequest, route: Route, progress: Progress = None,
                   initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """Choose N and the starts along ``auto_ladders(req)``, starts escalated before N: the first
    truly robust plan (``_good``), else the best robust one (least box worst for robust-box),
    else the last best effort. ``extra["auto"]`` lists every (steps, starts) tried with its
    outcome, and the message says it; the time budget covers all of them."""
    t0 = time.perf_counter()
    ns, ladder, box_target = auto_ladders(req)
    tried: list[dict] = []
    best: Optional[PlanResult] = None
    last: Optional[PlanResult] = None
    for n in ns:
        for s in ladder:
            left = req.time_budget - (time.perf_counter() - t0)
            if left <= 0.0:
                break
            sub = dc_replace(req, steps=n, starts=s, time_budget=left)
            warm = initial_currents if (initial_currents is not None and route.warm_start and
                                        np.size(initial_currents) % n == 0 and
                                        np.shape(initial_currents)[-1] in (n, 1)) else None
            try:
                r = route.fn(sub, progress) if warm is None else route.fn(
                    sub, progress, initial_currents=np.asarray(warm, dtype=float))
            except PlanningError:
                if warm is None:
                    raise
                r = route.fn(sub, progress)
            row = {"steps": n, "starts": s, "robust": bool(r.success and r.robust),
                   "starts_tried": int(r.starts_tried), "time_s": float(r.solve_time)}
            if "box_worst" in r.extra:
                row["box_worst"] = float(r.extra["box_worst"])
            tried.append(row)
            if last is None or last.profile is None or (
                    r.profile is not None and "box_worst" in r.extra and "box_worst" in last.extra
                    and float(r.extra["box_worst"]) < float(last.extra["box_worst"])):
                last = r         # with nothing robust: the best effort with the least box worst
            if r.success and r.robust and (best is None or float(
                    r.extra.get("box_worst", 0.0)) < float(best.extra.get("box_worst", 0.0))):
                best = r
            if r.success and r.robust:
                break            # robust at this N: more starts will not change N
            if r.extra.get("limits_answer") in LIMITS_FINAL:
                break            # the limits decided it: more starts only repeat the homotopy
        if best is not None and _good(best, box_target):
            break
        if last is not None and last.extra.get("limits_answer") in LIMITS_FINAL:
            break                # more steps do not free a plan the limits hold back
        if time.perf_counter() - t0 > req.time_budget:
            break
    result = best if best is not None else last
    if result is None:
        raise PlanningError(f"the time budget of {req.time_budget:.3g} s ran out before any plan "
                            f"was tried; raise the time budget", code="TIME_BUDGET_EXHAUSTED")
    result.extra = dict(result.extra or {})
    result.extra["auto"] = {"tried": tried, "steps_chosen": result.profile.n_steps
                            if result.profile is not None else None,
                            "steps_ladder": list(ns), "max_steps": AUTO_MAX_STEPS,
                            "starts_ladder": list(ladder),
                            "box_target": BOX_TARGET if box_target else None,
                            "box_target_met": bool(best is not None and box_target
                                                   and _good(best, True))}
    if len(tried) > 1 or req.auto_steps or req.auto_starts:
        result.message = f"{result.message} [tried {_tried_text(tried)}]"
    result.starts_tried = sum(row["starts_tried"] for row in tried)
    result.solve_time = time.perf_counter() - t0     # every N and starts tried, not the last one
    return result


# --- facade ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class CheckedRequest:
    """A request that passed ``check``: the request, its resolved parameters and the reach bound
    (rad, per joint) its goal lies within. Picklable; ``plan`` does not check it again."""

    request: PlanRequest
    params: Params
    reach: tuple[float, ...]
    drive: Optional[DriveGrid] = None     # the drive's current quantum and SYNC period, if any


#: (model, objective) whose planner places switch times on a grid (``request.grid``, s)
GRID_ROUTES = frozenset({("arm1dof", "robust-derivative"), ("arm1dof", "robust-sampled"),
                         ("arm1dof", "robust-box")})


#: what the facade hands a gridding planner (``GRID_ROUTES``) for a drive: the one request type
#: with a switch grid (``model.profile.GridPlanRequest``)
DrivePlanRequest = GridPlanRequest


def on_drive_grid(req: PlanRequest, drive: Optional[DriveGrid]) -> PlanRequest:
    """``req`` with ``grid`` = the drive's SYNC period for a planner that places switch times."""
    if drive is None or drive.period <= 0.0 or (req.model, req.objective) not in GRID_ROUTES:
        return req
    if hasattr(req, "grid"):
        return dc_replace(req, grid=drive.period)   # type: ignore[call-arg]
    kw = {f: getattr(req, f) for f in PlanRequest.__dataclass_fields__}
    return DrivePlanRequest(grid=drive.period, **kw)


def _baseline_on_drive_grid(req: PlanRequest, drive: Optional[DriveGrid]) -> PlanRequest:
    """An energy-optimal request with steps unset, for a drive: the most equal steps (at most
    100) whose boundaries fall on the SYNC grid when tf − coast is a whole number of periods,
    else min(periods, 100) equal steps (their switches then go to the nearest SYNC)."""
    if (drive is None or drive.period <= 0.0 or req.objective != "energy-optimal"
            or req.steps is not None):
        return req
    span = (float(req.tf) - float(req.coast)) / drive.period
    cells = math.floor(span + 1e-9)
    if cells < 1:
        return req
    steps = min(cells, 100)
    if abs(span - round(span)) < 1e-6:
        steps = max(n for n in range(1, min(cells, 100) + 1) if cells % n == 0)
    return dc_replace(req, steps=steps)


def _check_drive(request: PlanRequest, drive: DriveGrid) -> None:
    """Refuse a request the drive's grid cannot serve (INVALID_REQUEST, what to change)."""
    q = float(request.current_quantum)
    if q > 0.0 and abs(q - drive.quantum) > 1e-12:
        raise PlanningError(f"current_quantum {q:g} A differs from the drive's setpoint unit "
                            f"{drive.quantum:g} A ({drive.source or 'drive config'}); leave it 0",
                            code="INVALID_REQUEST")
    t = drive.period
    if t <= 0.0:
        return
    if t >= float(request.tf):
        raise PlanningError(f"the drive's SYNC period {t:g} s is not shorter than the move time "
                            f"{float(request.tf):g} s; ask for a longer move", code="INVALID_REQUEST")
    cells = math.floor((float(request.tf) - float(request.coast)) / t + 1e-9)
    if not request.auto_steps and request.n_steps() > cells:
        raise PlanningError(f"{request.n_steps()} steps do not fit on the drive's {t:g} s SYNC grid "
                            f"within tf - coast = {float(request.tf) - float(request.coast):g} s; "
                            f"ask for at most {cells} steps or a longer move", code="INVALID_REQUEST")


def check(request: PlanRequest, drive: Optional[DriveGrid] = None) -> CheckedRequest:
    """Validate ``request`` (fields, a planner for its model and objective, reachability) and,
    with ``drive``, that its steps fit the drive's SYNC grid.

    Raises PlanningError whose ``.code`` is the PlanTrajectory error name (INVALID_REQUEST,
    UNKNOWN_MODEL, UNKNOWN_PARAMETER, UNREACHABLE)."""
    try:
        request.validate()
        params = request.resolved_params()
    except PlanningError:
        raise
    except ParameterError as e:
        raise PlanningError(str(e), code=error_code_of(e)) from None
    except (TypeError, ValueError) as e:
        raise PlanningError(f"invalid request: {e}", code=error_code_of(e)) from None
    if (request.model, request.objective) not in ROUTES:
        served = ", ".join(o for m, o in ROUTES if m == request.model)
        raise PlanningError(f"the {request.objective} planner is implemented for "
                            f"{', '.join(sorted({m for m, o in ROUTES if o == request.objective}))} "
                            f"only; for model '{request.model}' use one of {served}",
                            code="INVALID_REQUEST")
    _check_physics(request, params)
    if drive is not None:
        _check_drive(request, drive)
    bound = reach(params, float(request.tf), float(request.coast))
    _unreachable(request, params, bound)
    return CheckedRequest(request, params, tuple(float(r) for r in bound), drive)


def _certify(result: PlanResult, req: PlanRequest, checked: CheckedRequest) -> None:
    """Attach the box certificate (1-DOF or SCARA) to ``result`` if it has none."""
    arm = result.params if isinstance(result.params, Arm1DofParams) else checked.params
    if (result.profile is not None and isinstance(arm, Arm1DofParams)
            and req.uncertain and result.certificate is None):
        try:
            result.certificate = certify_1dof(arm, result.profile,
                                              float(result.q0[0]), float(result.qf[0]),
                                              list(req.uncertain), req.box)
        except (ValueError, ArithmeticError):
            pass
    scara = result.params if isinstance(result.params, Scara2Params) else checked.params
    if (result.profile is not None and isinstance(scara, Scara2Params)
            and req.uncertain and result.certificate is None):
        try:
            result.certificate = certify_scara2(scara, result.profile, list(result.q0),
                                                list(result.qf), list(req.uncertain), req.box)
        except (PlanningError, ValueError, ArithmeticError):
            pass


def _quantize(result: PlanResult, req: PlanRequest, checked: CheckedRequest) -> None:
    """Round the profile's currents to ``req.current_quantum`` (A): the profile as the drive
    applies it; the rest position (and, through ``_certify``, the certificate) follow it."""
    if result.profile is None:
        return
    try:
        result.extra["current_quantum"] = quantize_result(
            result, result.params if result.params is not None else checked.params,
            float(req.current_quantum), list(req.uncertain))
    except (ValueError, ArithmeticError) as exc:
        result.extra["current_quantum"] = {"quantum": float(req.current_quantum),
                                           "error": str(exc)}


def _drive_exact(result: PlanResult, req: PlanRequest, checked: CheckedRequest) -> None:
    """Make ``result.profile`` the profile the drive applies (``checked.drive``): switch times on
    the nearest SYNC, currents rounded to the quantum, then (1-DOF, uncertain parameters) moved
    by whole quanta while the worst rest error over the box falls. q(tf), the rest position and
    the derivatives follow; the certificate is dropped for ``_certify`` to compute on this
    profile. ``extra["drive_exact"]`` gets the figures."""
    drive = checked.drive
    prof = result.profile
    if drive is None or prof is None:
        return
    params = result.params if result.params is not None else checked.params
    q0 = [float(x) for x in result.q0]
    info: dict = drive.to_dict()
    try:
        rest_before = rest_position(params, prof, q0)
        snapped = snap_times(prof, drive.period)
    except (PlanningError, ValueError, ArithmeticError) as exc:
        info["error"] = str(exc)
        result.extra["drive_exact"] = info
        result.success = False
        result.best_effort = True
        if result.error_code == "OK":
            result.error_code = "NO_ROBUST_PLAN"
        result.message = f"{result.message}; not drive-exact: {exc}"
        return
    info["max_switch_shift_s"] = float(np.max(np.abs(snapped.step_times - prof.step_times)))
    planned_currents = np.asarray(prof.currents, dtype=float).copy()
    rest_error_before = np.asarray(rest_before, dtype=float) - np.asarray(result.qf, dtype=float)
    result.profile = snapped
    unc = list(req.uncertain)
    if (isinstance(params, Scara2Params) and result.success and unc
            and info["max_switch_shift_s"] > 0.0):
        _resolve_scara2(result, params, prof, snapped, req, info)
        planned_currents = np.asarray(result.profile.currents, dtype=float).copy()
    elif isinstance(params, Arm1DofParams) and info["max_switch_shift_s"] > 0.0:
        _land_1dof(result, params, snapped, q0[0], rest_error_before, info)
        planned_currents = np.asarray(result.profile.currents, dtype=float).copy()
    try:
        info["rounding"] = quantize_result(result, params, drive.quantum, unc)
        if (isinstance(params, Arm1DofParams) and unc and result.profile is not None):
            refined, how = refine_on_quantum(params, result.profile, q0[0], float(result.qf[0]),
                                             unc, req.box, drive.quantum, float(params.i_max))
            info["refine"] = how
            if how["worst_after_rad"] < how["worst_before_rad"]:
                result.profile = refined
                again = quantize_result(result, params, drive.quantum, unc)
                info["rounding"].update({k: again[k] for k in ("max_abs_derivative",
                                                               "q_tf_error_rad") if k in again})
        if isinstance(params, Scara2Params) and unc and result.profile is not None:
            sens = scara2_sensitivities(params, result.profile, np.asarray(q0, dtype=float),
                                        tuple(unc), method="complex")
            info["rounding"]["max_abs_derivative"] = max(
                abs(float(v)) for k, v in sens.items() if k.startswith("q") and not k.startswith("qd"))
            info["rounding"]["q_tf_error_rad"] = [
                float(a) - float(b) for a, b in zip(result.q_final, result.qf)]
        rest_after = [float(x) for x in (result.extra.get("rest_position") or [])]
        info["rest_shift_rad"] = [a - float(b) for a, b in zip(rest_after, rest_before)]
    except (ValueError, ArithmeticError) as exc:
        info["error"] = str(exc)
    out = result.profile
    info["on_grid"] = bool(out is not None and on_period(out, drive.period))
    info["on_quantum"] = bool(out is not None and on_quantum(out, drive.quantum))
    result.certificate = None
    result.extra["drive_exact"] = info
    if out is not None and "error" not in info:
        _judge_landing(result, params, out, q0, out.currents - planned_currents, drive.quantum,
                       float(req.tol), rest_error_before, info)


def _land_1dof(result: PlanResult, params: Arm1DofParams, snapped: CurrentProfile, q0: float,
               rest_error_before: np.ndarray, info: dict) -> None:
    """A 1-DOF plan whose switches moved to the SYNC grid and which then lands farther from
    the goal than planned: its currents moved as little as possible to land again
    (``drive_grid.land_on_times``; ``info["land"]`` says so). A plan that still lands where
    planned is left as it is (the robust planners place their switches on the grid)."""
    qf = float(result.qf[0])
    try:
        err = abs(float(rest_position(params, snapped, [q0])[0]) - qf)
    except (ValueError, ArithmeticError):
        return
    if err <= 2.0 * float(np.max(np.abs(rest_error_before))) + 1e-6:
        return
    t0 = time.perf_counter()
    out = land_on_times(params, snapped, q0, qf)
    info["land"] = {"ok": out is not None, "rest_error_snapped_rad": err,
                    "time_s": time.perf_counter() - t0}
    if out is None:
        return
    info["land"]["max_change_A"] = float(np.max(np.abs(out.currents - snapped.currents)))
    result.profile = out
    result.message = (f"{result.message}; currents solved again to land on the goal with the "
                      f"switches on the drive's SYNC grid (moved by up to "
                      f"{info['max_switch_shift_s'] * 1e3:.3g} ms; landing {err * 1e3:.3g} mrad off "
                      f"before)")


def _resolve_scara2(result: PlanResult, params: Scara2Params, planned: CurrentProfile,
                    snapped: CurrentProfile, req: PlanRequest, info: dict) -> None:
    """A held-link-2 SCARA plan whose switches moved to the SYNC grid: joint 1 solved again on
    the snapped times (``robust2d_drive.resolve_on_times``) so that the profile sent lands where
    it was planned to; ``result`` keeps the snapped profile (judged by ``_judge_landing``) when
    the re-solve does not verify. ``info["resolve"]`` says which."""
    t0 = time.perf_counter()
    out = resolve_on_times(params, planned, snapped.step_times, result.q0, result.qf,
                           list(req.uncertain), float(req.tol),
                           limits=joint1_limits(req, params))
    how: dict = {"ok": out is not None, "time_s": 0.0}
    if out is not None:
        new, fig = out
        result.profile = new
        result.q_final, result.qd_final = fig["q_final"], fig["qd_final"]
        result.sensitivities = dict(fig["sensitivities"])
        result.extra["hold_fraction"] = fig["hold_fraction"]
        how.update({k: fig[k] for k in ("evaluations", "hold_fraction", "max_abs_derivative",
                                        "q_tf_error_rad")})
        result.message = (f"{result.message}; joint 1 solved again on the drive's SYNC grid "
                          f"(switches moved by up to {info['max_switch_shift_s'] * 1e3:.3g} ms): "
                          f"max |dq/dp| = {fig['max_abs_derivative']:.2g}, link 2 holds down to "
                          f"{100 * (1 - fig['hold_fraction']):.0f} % of nominal joint-2 friction")
    how["time_s"] = time.perf_counter() - t0
    info["resolve"] = how


def _judge_landing(result: PlanResult, params: Params, profile: CurrentProfile, q0: list[float],
                   changes: np.ndarray, quantum: float, tol: float,
                   rest_error_before: np.ndarray, info: dict) -> None:
    """The drive-exact profile's nominal rest error against what the drive's quantum forces
    (``drive_grid.landing_allowance``): a profile that lands farther from the goal (e.g. its
    switches moved to the SYNC grid and could not be solved again) is not a success and not
    robust (NO_ROBUST_PLAN, best effort, the figures in the message)."""
    try:
        rest = rest_position(params, profile, q0)
        allowed = landing_allowance(params, profile, q0, changes, quantum, tol, rest_error_before)
    except (PlanningError, ValueError, ArithmeticError) as exc:
        info["landing_error"] = str(exc)
        return
    err = np.abs(np.asarray(rest, dtype=float) - np.asarray(result.qf, dtype=float))
    info["rest_error_rad"] = [float(x) for x in err]
    info["rest_error_allowed_rad"] = [float(x) for x in allowed]
    bad = [j for j in range(len(err)) if not err[j] <= allowed[j]]
    info["landing_ok"] = not bad
    if not bad:
        deriv = (info.get("rounding") or {}).get("max_abs_derivative")
        result.message = (f"{result.message}; as sent to the drive: nominal rest error "
                          f"{float(err.max()) * 1e3:.3g} mrad" + (
                              f", max |dq(tf)/dp| = {float(deriv):.2g}" if deriv is not None
                              else ""))
        return
    result.success = False
    result.robust = False
    result.best_effort = True
    if result.error_code == "OK":
        result.error_code = "NO_ROBUST_PLAN"
    where = ", ".join(f"joint {j + 1} rests at {float(rest[j]):.6g} rad, {err[j] * 1e3:.3g} mrad "
                      f"from the goal (the drive's {quantum * 1e3:g} mA unit accounts for "
                      f"{allowed[j] * 1e3:.3g} mrad)" for j in bad)
    result.message = (f"NOT robust as sent to the drive: the drive-exact profile (switch times "
                      f"moved by up to {info.get('max_switch_shift_s', 0.0) * 1e3:.3g} ms to the "
                      f"SYNC grid, currents rounded) lands off the goal: {where}; the planned "
                      f"profile was: {result.message}")


def _mark_drive_certificate(result: PlanResult, checked: CheckedRequest) -> None:
    """Turn the certificate of a drive-exact plan into a DriveCertificate that says what it was
    computed on; a plan whose profile is off the drive's grid or quantum gets no such claim."""
    drive = checked.drive
    cert = result.certificate
    info = (result.extra or {}).get("drive_exact")
    if drive is None or cert is None or info is None or isinstance(cert, DriveCertificate):
        return
    if not (info.get("on_grid") and info.get("on_quantum")):
        return
    fields = {f: getattr(cert, f) for f in cert.__dataclass_fields__}
    result.certificate = DriveCertificate(drive=dict(
        drive.to_dict(), certified_profile=("the profile sent to the drive: currents on its "
                                            "quantum, switch times on its SYNC grid")), **fields)
    result.message = (f"{result.message}; drive-exact ({drive.describe()}): certified on the "
                      f"profile the drive applies, worst rest error "
                      f"{float(result.certificate.worst_rest_error) * 1e3:.3g} mrad")


def apply_drive_exact(result: PlanResult, checked: CheckedRequest) -> PlanResult:
    """A plan from elsewhere (e.g. a motion-library row) as ``plan`` would answer it for
    ``checked``: with a drive, made drive-exact and certified again (unchanged when it already
    is); without one, ``apply_current_quantum``."""
    if checked.drive is None:
        return apply_current_quantum(result, checked)
    prof = result.profile
    if prof is None:
        return result
    if (isinstance(result.certificate, DriveCertificate) and on_quantum(prof, checked.drive.quantum)
            and on_period(prof, checked.drive.period)):
        return result
    req = checked.request
    result.extra = dict(result.extra or {})
    if on_quantum(prof, checked.drive.quantum) and on_period(prof, checked.drive.period):
        result.extra["drive_exact"] = dict(checked.drive.to_dict(), on_grid=True, on_quantum=True)
        result.certificate = None     # certified again below, on this very profile
    else:
        _drive_exact(result, req, checked)
    _certify(result, req, checked)
    _mark_drive_certificate(result, checked)
    _check_limits(result, req)
    return result


def _never_at_rest(result: PlanResult) -> None:
    """Label a plan after which the nominal arm never comes to rest (rest position not finite)."""
    rest = (result.extra or {}).get("rest_position")
    if result.profile is None or rest is None:
        return
    if all(math.isfinite(float(x)) for x in rest):
        return
    result.extra["rest_position"] = None
    result.success = False
    result.message = (f"{result.message}; with this plan the arm never comes to rest after tf "
                      f"(negative viscous friction outruns Coulomb friction at its speed)")


def _check_limits(result: PlanResult, req: PlanRequest) -> None:
    """Compare the certificate's excursion with ``req.limits``: a plan that leaves them is not a
    success (NO_ROBUST_PLAN, ``extra["limit_violations"]``); ``extra["limits_checked"]`` says
    whether an excursion was there to check."""
    limits = req.limits
    if limits is None or limits.empty or result.profile is None:
        return
    exc = result.certificate.excursion if result.certificate is not None else None
    result.extra["limits_checked"] = exc is not None
    if exc is None:
        result.message = (f"{result.message}; the limits were not checked: this plan has no "
                          f"excursion in its certificate")
        return
    broken = exc.violations(limits)
    if not broken:
        return
    result.extra["limit_violations"] = broken
    result.success = False
    result.message = (f"{result.message}; the plan leaves the limits over the box: "
                      f"{'; '.join(broken)} (widen the limits or allow a longer move time)")


def apply_current_quantum(result: PlanResult, checked: CheckedRequest) -> PlanResult:
    """A plan from elsewhere (e.g. a motion-library row) as ``plan`` would answer it under
    ``checked.request.current_quantum``: currents rounded, rest position and certificate
    recomputed for the rounded profile (unchanged when the quantum is 0 or the currents are on
    the grid already)."""
    req = checked.request
    q = float(req.current_quantum)
    prof = result.profile
    if q <= 0.0 or prof is None:
        return result
    if np.allclose(prof.currents, np.round(prof.currents / q) * q, rtol=0.0, atol=1e-12):
        return result
    result.extra = dict(result.extra or {})
    _quantize(result, req, checked)
    _certify(result, req, checked)
    return result


def plan(request: Union[PlanRequest, CheckedRequest], progress: Progress = None,
         initial_currents: Optional[np.ndarray] = None,
         drive: Optional[DriveGrid] = None) -> PlanResult:
    """Plan a rest-to-rest feedforward current profile.

    A plain PlanRequest is checked first (``check``: PlanningError with ``.code`` for bad input
    or an unreachable goal); a CheckedRequest is planned as it is. Returns a PlanResult; when no
    plan met the tolerances it is the best plan found, labelled ``best_effort=True`` with
    error_code NO_ROBUST_PLAN (or TIME_BUDGET_EXHAUSTED when the time budget ran out first). The
    inner planners honour ``request.time_budget``; the facade labels a result that came back
    late. ``initial_currents`` (A, N × joints) warm-starts the search from a known plan (e.g. a
    motion-library neighbour); WarmStartUnavailable if the route's planner takes none
    (``ROUTES``). ``drive`` (or ``CheckedRequest.drive``): answer the drive-exact plan (module
    docstring); a CheckedRequest given with ``drive`` is checked again for it.
    """
    t0 = time.perf_counter()
    checked = (request if isinstance(request, CheckedRequest) and drive is None else
               check(request.request if isinstance(request, CheckedRequest) else request, drive))
    req = on_drive_grid(_baseline_on_drive_grid(checked.request, checked.drive), checked.drive)
    if req.tolerance is not None:
        raise PlanningError("a request with a tolerance is a search over the move time: plan it "
                            "with ff_planner.optimize.fastest.plan_fastest", code="INVALID_REQUEST")
    route = ROUTES[(req.model, req.objective)]
    auto = req.auto_steps or req.auto_starts or (req.objective == "robust-box"
                                                 and req.steps is None)
    if auto and not (req.model == "arm1dof" and req.objective in AUTO_OBJECTIVES):
        req = dc_replace(req, steps=None if req.auto_steps else req.steps,
                         starts=DEFAULT_STARTS if req.auto_starts else req.starts)
        auto = False
    if auto:
        result = plan_auto_1dof(req, route, progress, initial_currents)
    elif initial_currents is None:
        result = route.fn(req, progress)
    elif route.warm_start:
        result = route.fn(req, progress, initial_currents=np.asarray(initial_currents, dtype=float))
    else:
        raise WarmStartUnavailable(f"the {req.model} {req.objective} planner "
                                   f"({route.fn.__module__}.{route.fn.__name__}) takes no "
                                   f"initial_currents")
    result.extra = dict(result.extra or {})
    if checked.drive is not None:
        _drive_exact(result, req, checked)
    elif req.current_quantum > 0.0:
        _quantize(result, req, checked)
    elapsed = time.perf_counter() - t0
    result.extra.setdefault("reach_bound", list(checked.reach))
    result.extra["facade_time_s"] = elapsed
    if elapsed > req.time_budget:
        result.extra["over_time_budget"] = True
    if result.profile is not None and "rest_position" not in result.extra:
        try:   # where the arm stops with zero current after tf: what a user will see
            rest = rest_position(checked.params, result.profile, [float(x) for x in result.q0])
            result.extra["rest_position"] = [float(x) for x in rest]
        except (ValueError, ArithmeticError):
            pass
    _certify(result, req, checked)
    _mark_drive_certificate(result, checked)
    _never_at_rest(result)
    _check_limits(result, req)
    if float(req.tf) >= MAX_TF and "a longer move time" in result.message:
        result.message = result.message.replace(
            "or a longer move time", f"(the move time is at its maximum of {MAX_TF:g} s)")
    if not result.success:
        result.best_effort = result.profile is not None
        if result.error_code == "OK":
            result.error_code = ("TIME_BUDGET_EXHAUSTED" if elapsed > req.time_budget
                                 else "NO_ROBUST_PLAN")
        if result.profile is not None and "best plan" not in result.message:
            result.message = f"{result.message} (best plan found, not meeting the tolerances)"
        if result.certificate is not None and result.model == "scara2":
            c = result.certificate
            result.message = (f"{result.message}; worst rest error over the box "
                              f"{c.worst_rest_error * 1e3:.3g} mrad (per joint "
                              f"{', '.join(f'{w * 1e3:.3g}' for w in c.worst_per_joint)} mrad)")
    return result
