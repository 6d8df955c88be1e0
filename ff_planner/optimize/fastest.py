"""Tolerance first: the fastest move time whose certified worst rest error meets a tolerance.

A request with ``tolerance`` (rad: the certificate's worst |rest − qf| over the friction box) and
``move_time_max`` (s, default DEFAULT_MOVE_TIME_MAX) asks for the shortest tf ≤ move_time_max
whose plan is a success (within the limits, when the request has some) and certified within the
tolerance. The certified error of one seeded plan is not monotone in tf: it falls steeply up to a
knee, then hovers in a band whose spread is the multistart's (measured, 0 → 1 rad, N = 12, one
seed per tf: 54 mrad at 0.82 s, 9.6 at 0.90 s, then 1.96-4.5 mrad from 0.92 s to 1.5 s; five
seeds at 1.0 s: 1.67-2.52 mrad). A tolerance inside that band is met at a tf by some seeds and
not others, so the search treats the seed as part of the test:

1. tf = move_time_max first (a near miss there, a success certified within ``retry_within`` ×
   the tolerance, is planned again with the next ``retries`` seeds);
2. the knee, by bisection over [shortest reachable tf, move_time_max]: the shortest tf whose first
   seed is certified within ``hopeless_factor`` × the tolerance (below the knee the error grows
   fast, so one seed decides; inside the band it does not, so the knee is not looked for
   there), to ``knee_resolution`` × tf;
3. an upward scan from the knee in steps of ``scan_rel`` × tf until a tf passes, a near miss
   planned again with the next seeds;
4. bisection between the shortest pass and the tf tried just below it, until the bracket is
   within ``rel_resolution`` of it (tfs on a ``tf_step`` grid; a near miss gets the seeds too).

When no tf passes, the answer is the plan of least certified worst, labelled (not a success,
NO_ROBUST_PLAN). Every plan is reported (``extra["tolerance_search"]["trials"]``: tf, seed,
certified worst, whether it met the tolerance, time). A plan that fails the tolerance is never
answered as a success. Each plan gets at most ``trial_share`` of the time budget (and what is
left of it); the whole search keeps to the request's ``time_budget`` (s), and when the budget
ends it the message says so.

The search itself is :func:`search_move_time`, which takes any planner of one tf and seed
(``plan_fastest`` for the 1-DOF and SCARA planners, ``ff_planner.armplan.fastest`` for arms from a
URDF); ``plan_fastest`` adds the request's checks and the reach bound that gives the shortest tf.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from functools import partial
from typing import Callable, Optional, Union

import numpy as np

from ff_planner.core.errors import PlanningError
from ff_planner.model.profile import PlanRequest, PlanResult
from ff_planner.optimize.drive_grid import DriveGrid
from ff_planner.optimize.planner import CheckedRequest, Progress, check, on_drive_grid, plan, reach

DEFAULT_MOVE_TIME_MAX = 3.0   # s, longest tf a tolerance search considers when the request says none

PlanFn = Callable[..., PlanResult]   # plan_fn(request, progress) -> PlanResult


@dataclass(frozen=True)
class SearchSettings:
    """How the tf search brackets: knee, scan, seeds, resolution, grid and time per plan."""

    knee_resolution: float = 0.02   # the knee bisection stops within this share of tf
    rel_resolution: float = 0.01    # the final bisection stops when the bracket is within this
    scan_rel: float = 0.03          # upward scan from the knee: step, share of tf (0 = no scan)
    tf_step: float = 1e-3           # s, tfs tried are multiples of this (the drives' 1 ms SYNC)
    trial_share: float = 0.125      # at most this share of the time budget per plan (s / s)
    retries: int = 1                # a near miss is planned again with up to this many seeds ...
    retry_within: float = 2.0       # ... when certified within this many times the tolerance
    hopeless_factor: float = 5.0    # the knee: the first seed certified within this many times
    #                                 the tolerance (below it the error grows fast with less tf)
    min_trial_budget: float = 1.0   # s, ... but at least this much while the budget lasts


@dataclass
class Trial:
    """One move time tried: its plan's certified worst rest error (rad, None = no certificate)."""

    tf: float                        # s
    worst_rest_error: Optional[float]   # rad, certified over the box
    meets: bool                      # a success, certified within the tolerance
    error_code: str                  # the plan's PlanTrajectory error name
    time_s: float                    # s spent on this plan
    steps: Optional[int] = None      # the plan's current steps per joint
    seed: int = 0                    # the plan's multistart seed
    note: str = ""                   # why it failed, when it did

    def to_dict(self) -> dict:
        w = self.worst_rest_error
        return {"tf": self.tf, "worst_rest_error": w if w is not None and math.isfinite(w) else None,
                "meets": self.meets, "error_code": self.error_code, "time_s": self.time_s,
                "steps": self.steps, "seed": self.seed, "note": self.note}


@dataclass
class _State:
    trials: list[Trial] = field(default_factory=list)
    best_pass: Optional[PlanResult] = None     # the shortest tf that met the tolerance
    best_fail: Optional[PlanResult] = None     # least certified worst among the others
    first_error: Optional[PlanningError] = None


def _worst(result: PlanResult) -> Optional[float]:
    c = result.certificate
    return float(c.worst_rest_error) if c is not None else None


def _tf(result: PlanResult) -> float:
    return float(result.profile.tf) if result.profile is not None else math.nan


def shortest_reachable_tf(req: PlanRequest, params, tf_max: float, step: float) -> float:
    """Smallest tf (s, on the ``step`` grid, above the coast) whose reach bound covers the move;
    the bound is monotone in tf, so bisection."""
    dist = np.abs(np.asarray(req.qf, dtype=float) - np.asarray(req.q0, dtype=float))
    lo = float(req.coast) + step
    hi = float(tf_max)

    def ok(t: float) -> bool:
        return bool(np.all(reach(params, t, float(req.coast)) >= dist))

    if ok(lo):
        return lo
    while hi - lo > step:
        mid = 0.5 * (lo + hi)
        if ok(mid):
            hi = mid
        else:
            lo = mid
    return math.ceil(hi / step - 1e-9) * step


def plan_fastest(request: Union[PlanRequest, CheckedRequest], progress: Progress = None,
                 initial_currents: Optional[np.ndarray] = None, plan_fn: PlanFn = plan,
                 settings: SearchSettings = SearchSettings(),
                 drive: Optional[DriveGrid] = None) -> PlanResult:
    """The plan of the fastest tf ≤ move_time_max certified within ``request.tolerance`` (rad).

    ``plan_fn(sub_request, progress)`` plans one tf (default: the facade). ``drive`` (or a
    CheckedRequest's drive): every plan drive-exact for it (the facade's ``drive``) and the tfs
    tried on its SYNC grid. ``initial_currents`` is not used (each tf is its own task). Raises
    PlanningError when the request is invalid or the move is unreachable even at move_time_max;
    otherwise returns a PlanResult whose ``extra["tolerance_search"]`` lists every tf tried."""
    t0 = time.perf_counter()
    req: PlanRequest = request.request if isinstance(request, CheckedRequest) else request
    if drive is None and isinstance(request, CheckedRequest):
        drive = request.drive
    if drive is not None:
        req = on_drive_grid(req, drive)
        if plan_fn is plan:
            plan_fn = partial(plan, drive=drive)
    if req.tolerance is None:
        raise PlanningError("plan_fastest needs a request with a tolerance (rad)")
    tolerance = float(req.tolerance)
    tf_max = float(req.move_time_max or DEFAULT_MOVE_TIME_MAX)
    step = float(getattr(req, "grid", None) or settings.tf_step)
    tf_max = math.floor(tf_max / step + 1e-9) * step
    base = dc_replace(req, tf=tf_max, tolerance=None, move_time_max=None)
    checked = check(base, drive)     # invalid or unreachable at tf_max: refused as the facade does
    tf_lo = min(shortest_reachable_tf(base, checked.params, tf_max, step), tf_max)
    return search_move_time(
        lambda tf, seed, share: plan_fn(dc_replace(base, tf=tf, seed=seed, time_budget=share),
                                        progress),
        tf_lo, tf_max, step, float(req.time_budget), tolerance, settings, progress,
        seed=int(base.seed), t0=t0)


TrialFn = Callable[[float, int, float], PlanResult]   # one(tf s, seed, time budget s) -> plan


def search_move_time(one: TrialFn, tf_lo: float, tf_max: float, step: float, budget: float,
                     tolerance: float, settings: SearchSettings = SearchSettings(),
                     progress: Progress = None, *, seed: int = 0,
                     t0: Optional[float] = None) -> PlanResult:
    """The tolerance-first search over tf in [tf_lo, tf_max] (s, on the ``step`` grid) of any
    planner (the module's steps 1-4 and its answer): ``one(tf, seed, time_budget)`` plans one
    move time with one multistart seed in at most ``time_budget`` s and returns its PlanResult
    (its ``certificate.worst_rest_error``, rad, is what meets ``tolerance``, rad) or raises
    PlanningError. The whole search keeps to ``budget`` s counted from ``t0`` (default: now);
    seeds tried at a tf are ``seed``, ``seed`` + 1, ... Returns the shortest passing plan, else
    the least-worst one labelled (not a success); raises the first PlanningError when no tf
    gave a plan."""
    t0 = time.perf_counter() if t0 is None else t0
    deadline = t0 + budget
    st = _State()

    def left() -> float:
        return deadline - time.perf_counter()

    def trial(tf: float, seed: int) -> tuple[bool, Optional[float]]:
        """Plan tf with ``seed``: (meets, certified worst or None); recorded as a trial."""
        t1 = time.perf_counter()
        share = min(left(), max(settings.min_trial_budget, settings.trial_share * budget))
        if progress is not None:
            progress({"stage": f"tolerance search: tf {tf:.3f} s"})
        try:
            r = one(tf, seed, max(share, 1e-3))
        except PlanningError as exc:
            if st.first_error is None:
                st.first_error = exc
            st.trials.append(Trial(tf, None, False, exc.code, time.perf_counter() - t1,
                                   seed=seed, note=" ".join(str(exc).split())[:200]))
            return False, None
        w = _worst(r)
        meets = bool(r.success and w is not None and math.isfinite(w) and w <= tolerance)
        note = "" if meets else (
            "no certificate" if w is None else
            f"{r.error_code}: " + " ".join(str(r.message).split())[:160] if not r.success else
            f"certified worst {w * 1e3:.3g} mrad > {tolerance * 1e3:.3g} mrad")
        st.trials.append(Trial(tf, w, meets, r.error_code, time.perf_counter() - t1,
                               r.profile.n_steps if r.profile is not None else None, seed, note))
        if meets:
            if st.best_pass is None or tf < _tf(st.best_pass):
                st.best_pass = r
        elif r.profile is not None and w is not None and math.isfinite(w):
            if st.best_fail is None or w < float(_worst(st.best_fail) or math.inf):
                st.best_fail = r
        return meets, (w if r.success else None)

    def within(w: Optional[float], factor: float) -> bool:
        return w is not None and w <= factor * tolerance

    def near(w: Optional[float]) -> bool:
        return within(w, settings.retry_within)

    first: dict[int, Optional[float]] = {}     # tf (grid index) -> seed-0 result (None: no plan)
    seeds_done: dict[int, int] = {}             # tf (grid index) -> seeds planned there
    passed: set[int] = set()

    def key(tf: float) -> int:
        return int(round(tf / step))

    def attempt(tf: float, seeds: int = 1) -> tuple[bool, Optional[float]]:
        """Plan tf with the next seed(s) not yet tried there, at most ``seeds`` of them, while
        they are near misses: (met, the first seed's certified worst or None)."""
        k = key(tf)
        tf = k * step
        if k in passed:
            return True, first.get(k)
        meets = False
        while seeds_done.get(k, 0) < seeds and left() > 0.0:
            j = seeds_done.get(k, 0)
            if j > 0 and not near(first.get(k)):
                break       # far from the tolerance: another seed will not do
            meets, w = trial(tf, seed + j)
            seeds_done[k] = j + 1
            if j == 0:
                first[k] = w
            if meets:
                passed.add(k)
                break
        return meets, first.get(k)

    def shortest_pass() -> Optional[int]:
        return min(passed) if passed else None

    complete = True
    kmax, klo = key(tf_max), key(tf_lo)
    # 1. the longest tf (with the seeds when it is a near miss)
    attempt(tf_max, 1 + settings.retries)
    # 2. the knee: the shortest tf whose first seed is within hopeless_factor × the tolerance
    lo, hi = klo - 1, kmax
    if not within(first.get(kmax), settings.hopeless_factor):
        hi = kmax + 1        # not even tf_max is close: the scan below has nothing to start from
    while hi <= kmax and hi - lo > max(1, int(settings.knee_resolution * hi)):
        if left() <= 0.0:
            complete = False
            break
        mid = (lo + hi) // 2
        attempt(mid * step)
        if within(first.get(mid), settings.hopeless_factor):
            hi = mid
        else:
            lo = mid
    # 3. upward scan from the knee until a pass (a near miss gets the next seeds)
    if hi <= kmax and settings.scan_rel > 0.0 and complete:
        k = hi
        while k < min(kmax, shortest_pass() or kmax):
            if left() <= 0.0:
                complete = False
                break
            if attempt(k * step, 1 + settings.retries)[0]:
                break
            k = max(k + 1, key(k * step * (1.0 + settings.scan_rel)))
    # 4. bisection between the shortest pass and the tf tried just below it
    pass_tf: Optional[float] = None
    fail_tf: Optional[float] = None
    while complete and passed:
        top = shortest_pass()
        assert top is not None
        below = [k for k in first if k < top]
        fk = max(below) if below else klo - 1
        pass_tf, fail_tf = top * step, fk * step
        if top - fk <= max(1, int(settings.rel_resolution * top + 1e-9)):
            break
        if left() <= 0.0:
            complete = False
            break
        attempt(((top + fk) // 2) * step, 1 + settings.retries)
    elapsed = time.perf_counter() - t0
    return _answer(budget, st, tolerance, tf_max, tf_lo, pass_tf, fail_tf, complete, elapsed)


def _answer(budget: float, st: _State, tolerance: float, tf_max: float, tf_lo: float,
            pass_tf: Optional[float], fail_tf: Optional[float], complete: bool,
            elapsed: float) -> PlanResult:
    """The search's PlanResult: the shortest passing plan, else the least-worst one labelled."""
    info = {"tolerance": tolerance, "move_time_max": tf_max, "shortest_reachable_tf": tf_lo,
            "trials": [t.to_dict() for t in st.trials], "time_s": elapsed,
            "complete": complete, "met": st.best_pass is not None,
            "bracket": [fail_tf, pass_tf], "units": {"tolerance": "rad", "tf": "s",
                                                     "worst_rest_error": "rad", "time_s": "s"}}
    tried = ", ".join(f"{t.tf:.3f} s: " + ("-" if t.worst_rest_error is None or not
                                            math.isfinite(t.worst_rest_error)
                                            else f"{t.worst_rest_error * 1e3:.3g}")
                      + ("" if t.meets else " (fails)") for t in st.trials)
    if st.best_pass is not None:
        r = st.best_pass
        w = float(_worst(r) or 0.0)
        tf = _tf(r)
        stop = "" if complete else (f"; the time budget ended the search: a faster tf may exist "
                                    f"above {fail_tf if fail_tf is not None else tf_lo:.3f} s")
        head = (f"fastest tf certified within {tolerance * 1e3:.3g} mrad: {tf:.3f} s (worst rest "
                f"error {w * 1e3:.3g} mrad over the box){stop}; tried (tf: certified mrad) "
                f"{tried}")
    else:
        if st.best_fail is None:
            if st.first_error is not None:
                raise st.first_error
            raise PlanningError(f"no plan within the time budget of {budget:.3g} s at "
                                f"any tf tried; raise the time budget",
                                code="TIME_BUDGET_EXHAUSTED")
        r = st.best_fail
        w = float(_worst(r) or math.inf)
        head = (f"no move time up to {tf_max:g} s is certified within {tolerance * 1e3:.3g} mrad: "
                f"the least certified worst is {w * 1e3:.3g} mrad at tf = {_tf(r):.3f}"
                f" s; relax the tolerance, raise the longest move time, or widen the limits or "
                f"the box; tried (tf: certified mrad) {tried}")
        r.success = False
        r.best_effort = True
        if r.error_code == "OK":
            r.error_code = "NO_ROBUST_PLAN"
    r.extra = dict(r.extra or {})
    r.extra["tolerance_search"] = info
    r.message = f"{head}. Plan: {r.message}"
    r.solve_time = elapsed
    return r


# --- the trade-off: certified rest error against move time, per set of limits ---------------------
@dataclass
class TradeoffPoint:
    """One plan of the trade-off: tf (s), under ``label``'s limits, its certified worst rest
    error (rad, None = none) and worst excursion over the box (rad, rad/s per joint)."""

    label: str
    tf: float
    worst_rest_error: Optional[float]
    success: bool
    error_code: str
    time_s: float
    worst_min: list[float] = field(default_factory=list)
    worst_max: list[float] = field(default_factory=list)
    worst_speed: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        w = self.worst_rest_error
        return {"label": self.label, "tf": self.tf, "success": self.success,
                "worst_rest_error": w if w is not None and math.isfinite(w) else None,
                "error_code": self.error_code, "time_s": self.time_s,
                "worst_min": self.worst_min, "worst_max": self.worst_max,
                "worst_speed": self.worst_speed}


def tradeoff(request: PlanRequest, points: int = 8, tf_max: Optional[float] = None,
             plan_fn: PlanFn = plan, settings: SearchSettings = SearchSettings(),
             progress: Progress = None) -> list[TradeoffPoint]:
    """Plan the request's move at ``points`` move times from the shortest the reach bound allows
    to ``tf_max`` (s, default move_time_max or DEFAULT_MOVE_TIME_MAX), without limits and, when
    the request has some, under them: what each tf costs in certified rest error and excursion.
    Each plan gets the time a tolerance search's trial gets."""
    t_hi = float(tf_max or request.move_time_max or DEFAULT_MOVE_TIME_MAX)
    base = dc_replace(request, tf=t_hi, tolerance=None, move_time_max=None)
    checked = check(base)
    step = settings.tf_step
    t_lo = max(shortest_reachable_tf(base, checked.params, t_hi, step), 0.1 * t_hi)
    tfs = sorted({round(t / step) * step for t in np.linspace(t_lo, t_hi, max(2, int(points)))})
    sets: list[tuple[str, PlanRequest]] = [("no limits", dc_replace(base, limits=None))]
    if request.limits is not None and not request.limits.empty:
        sets.append(("limits", base))
    budget = max(settings.min_trial_budget, settings.trial_share * float(request.time_budget))
    out: list[TradeoffPoint] = []
    for label, req in sets:
        for tf in tfs:
            if progress is not None:
                progress({"stage": f"trade-off {label}: tf {tf:.3f} s"})
            t1 = time.perf_counter()
            try:
                r = plan_fn(dc_replace(req, tf=tf, time_budget=budget), progress)
            except PlanningError as exc:
                out.append(TradeoffPoint(label, tf, None, False, exc.code, time.perf_counter() - t1))
                continue
            ex = r.certificate.excursion if r.certificate is not None else None
            out.append(TradeoffPoint(
                label, tf, _worst(r), bool(r.success), r.error_code, time.perf_counter() - t1,
                list(ex.worst_min) if ex is not None else [],
                list(ex.worst_max) if ex is not None else [],
                list(ex.worst_speed) if ex is not None else []))
    return out
