"""The planner node's logic without ROS: validation, motion library, worker processes, statistics.

``PlannerService.handle_fields(fields)`` turns the fields of a request into a :class:`PlanResult` and
never raises: bad requests come back with ``success=False``, an error code (PlanTrajectory names) and a
message saying what to change.

A request is checked once, here (``ff_planner.optimize.planner.check``: fields, model, objective,
reachability, then this node's limits); the worker plans the ``CheckedRequest`` without checking
it again. Order of work for a valid request:
1. motion library, exact task (same parameters): a stored plan is returned at once (warm);
   a stored "no plan here" is returned at once when it is a hard fact (UNREACHABLE) or came from a
   search at least as thorough (starts) as asked;
2. a stored task that is the same motion shifted in angle (canonical distance 0) is reused as is;
3. the nearest stored neighbour within ``warm_max_distance``: re-optimised from its currents
   without multistart (worker process); if that fails and time is left, a cold solve follows;
4. otherwise a cold multistart solve in a worker process.

Requests with a ``tolerance`` (a search over tf: ``ff_planner.optimize.fastest.plan_fastest``
in the worker) or with limits skip the motion library (neither looked up nor stored).

Request fields beyond the facade's: ``box_names``/``box_fractions`` (± fraction per uncertain
parameter, for robust-box and the certificate), ``coast_max`` (s, robust-box) and ``switch_grid``
(s: switch times on the drive's SYNC grid; 0 = the node's ``switch_grid``, negative = none). A
library row answers a request as it is only when it fits these (its switch times on the grid, its
certificate's box the request's). Every answer with a profile carries ``extra["predicted_rest"]``
(rad per joint, nominal parameters: 1-DOF where the arm stops with zero current after tf, 2-DOF
``q_final`` when the plan is at rest at tf).

``drive_config`` (the bridge's own config file) makes every answer drive-exact for that drive
(``ff_planner.optimize.drive_grid``): switch times on its SYNC period (which then replaces
``switch_grid``), currents on its setpoint unit, the certificate computed on that profile; a
library row planned otherwise is made drive-exact and certified again before it is answered.

Long plans: ``handle_fields(fields, progress=fn, cancel=event)`` reports the planner's progress
dicts (sent by the worker process over a Unix datagram socket, see :class:`ProgressChannel`) and
stops when ``event`` is set (the worker is killed and replaced, the answer says "canceled").

Concurrency: a pool of ``workers`` processes (pebble: a task running past its time budget has its
worker killed and replaced). At most ``workers − 1`` scara2 (long) plans run or wait in the pool at
once, so a worker is always left for 1-DOF requests. More than ``max_pending`` requests waiting or
running, or more than ``max_pending_long`` scara2 ones, are refused at once (TIME_BUDGET_EXHAUSTED,
"planner overloaded"): a caller's thread never waits behind an unbounded queue, and 2-DOF requests
can never take every place. Time budgets are counted from the moment a request arrives, queueing
included.
"""
from __future__ import annotations

import json
import math
import multiprocessing
import os
import shutil
import socket
import sqlite3
import tempfile
import threading
import time
import traceback
from collections import Counter, deque
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
from pebble import ProcessPool

from ff_planner.core.errors import ParameterError, PlanningError, WarmStartUnavailable, error_code_of
from ff_planner.export.motion_file import write_motion
from ff_planner.library.gridded import GridPlanRequest, applies, on_grid
from ff_planner.library.refusal import as_vector, failure
from ff_planner.library.store import LibraryError, MotionLibrary, MotionRecord, record_from_result, task_key
from ff_planner.library.warm import PlanFn, warm_plan
from ff_planner.model.limits import MotionLimits
from ff_planner.model.params import MODELS, Params, check_model, default_params, n_joints, preset
from ff_planner.model.profile import OBJECTIVES, PlanRequest, PlanResult, RobustnessCertificate
from ff_planner.model.simulate import rest_position
from ff_planner.optimize.fastest import DEFAULT_MOVE_TIME_MAX, plan_fastest
from ff_planner.optimize.drive_grid import DriveConfigError, DriveGrid, drive_grid_from_config
from ff_planner.optimize.planner import CheckedRequest, apply_drive_exact, check, plan
from ff_planner.optimize.sample_box import box_fractions

SHIFT_EPS = 1e-9          # rad / s: canonical distance below which a stored task is the same motion
LONG_MODELS = ("scara2",)  # models whose plans take long (seconds to minutes)
PROGRESS_PERIOD = 0.05    # s: a worker reports progress at most this often
CANCEL_POLL = 0.05        # s: how often a running plan looks at its cancel event
REST_SPEED = 1e-6         # rad/s: a 2-DOF plan with |qd(tf)| below this is at rest at tf
CANCELED = "canceled"     # extra["canceled"] of an answer stopped by its caller
LIMIT_NAMES = ("position_min", "position_max", "velocity_max")   # <model>.<name>: a cell's limits


class ServiceConfigError(ValueError):
    """A planner node configuration that cannot be used; the message says what to change."""


@dataclass
class ServiceConfig:
    """The planner node's settings (the ROS parameters of config/planner*.yaml)."""

    default_model: str = "arm1dof"
    presets: dict[str, str] = field(default_factory=lambda: {"arm1dof": "table2", "scara2": "table3"})
    overrides: dict[str, dict[str, float]] = field(default_factory=dict)   # model -> {key: SI value}
    default_starts: int = 50
    default_time_budget: float = 10.0    # s
    max_time_budget: float = 600.0       # s
    max_steps: int = 40                  # per joint
    max_starts: int = 5000
    max_move_time: float = 60.0          # s
    coast: float = 0.05                  # s
    tol: float = 1e-6                    # rad per parameter unit / rad
    library_path: str = ""               # "" = no motion library
    use_library: bool = True
    warm_max_distance: float = 0.5       # canonical distance (rad; tf weighted by time_weight rad/s)
    time_weight: float = 1.0             # rad per s in the neighbour distance
    workers: int = 2
    max_pending: int = 16
    max_pending_long: int = 0            # scara2 requests waiting or running; 0 = max_pending // 2
    grace: float = 0.5                   # s beyond the time budget before a worker is killed
    motion_dir: str = ""                 # "" = no motion files
    warmup: bool = True                  # plan a small task in each worker at start (JIT caches)
    switch_grid: float = 0.001           # s, switch-time grid when a request says 0 (1 ms SYNC); 0 = none
    default_objective: str = PlanRequest().objective   # when a request leaves `objective` empty
    current_quantum: float = 0.0         # A, round every plan's currents to this grid (the drive's
    #                                      setpoint unit, e.g. an EPOS4's nominal current / 1000); 0 = none
    limits: dict[str, MotionLimits] = field(default_factory=dict)   # model -> the cell's limits,
    #                                      for requests that give none (<model>.position_min ...)
    drive_config: str = ""               # the bridge's config file (config/bridge_*.yaml): every
    #                                      plan drive-exact for its drive; "" = none

    def drive(self) -> Optional[DriveGrid]:
        """The DriveGrid of ``drive_config`` (None when unset); ServiceConfigError if unusable."""
        if not self.drive_config:
            return None
        try:
            grid = drive_grid_from_config(self.drive_config)
        except DriveConfigError as exc:
            raise ServiceConfigError(f"drive_config: {exc}") from None
        if self.current_quantum > 0.0 and abs(self.current_quantum - grid.quantum) > 1e-12:
            raise ServiceConfigError(f"current_quantum {self.current_quantum:g} A differs from the "
                                     f"drive's setpoint unit {grid.quantum:g} A ({self.drive_config}); "
                                     f"set it to 0 (the drive config gives it)")
        return grid

    def validate(self) -> None:
        """Raise ServiceConfigError naming the first setting that cannot be used."""
        if self.default_model not in MODELS:
            raise ServiceConfigError(f"default_model {self.default_model!r} is unknown; use one of "
                                     f"{', '.join(MODELS)}")
        for model, name in self.presets.items():
            if model not in MODELS:
                raise ServiceConfigError(f"preset given for unknown model {model!r}")
            if preset(name).model != model:
                raise ServiceConfigError(f"preset {name!r} is for model '{preset(name).model}', not '{model}'")
        for model in self.overrides:
            if model not in MODELS:
                raise ServiceConfigError(f"overrides given for unknown model {model!r}")
        for model, lim in self.limits.items():
            if model not in MODELS:
                raise ServiceConfigError(f"limits given for unknown model {model!r}")
            nj = n_joints(model)
            try:
                lim.validate(nj, [], [])
            except PlanningError as exc:
                raise ServiceConfigError(f"{model} limits: {exc}") from None
        for name in ("default_starts", "max_steps", "max_starts", "workers", "max_pending"):
            if int(getattr(self, name)) < 1:
                raise ServiceConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("default_time_budget", "max_time_budget", "max_move_time", "tol"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ServiceConfigError(f"{name} must be a finite number > 0, got {v}")
        if not (self.coast >= 0 and math.isfinite(self.coast)):
            raise ServiceConfigError(f"coast must be >= 0 s, got {self.coast}")
        if not (math.isfinite(self.switch_grid) and 0.0 <= self.switch_grid < 1.0):
            raise ServiceConfigError(f"switch_grid must be in [0, 1) s (0 = no grid), got {self.switch_grid}")
        if self.default_objective not in OBJECTIVES:
            raise ServiceConfigError(f"default_objective {self.default_objective!r} is unknown; use "
                                     f"one of {', '.join(OBJECTIVES)}")
        if not (math.isfinite(self.current_quantum) and 0.0 <= self.current_quantum < 1.0):
            raise ServiceConfigError(f"current_quantum must be in [0, 1) A (0 = none), got "
                                     f"{self.current_quantum}")
        self.drive()

    def model_params(self, model: str) -> Params:
        """The node's parameters for ``model``: its preset with the configured overrides."""
        name = self.presets.get(model)
        base = preset(name) if name else default_params(model)
        over = self.overrides.get(model) or {}
        try:
            return base.replace(**over) if over else base
        except ParameterError as exc:
            raise ServiceConfigError(f"configured overrides for {model}: {exc}") from None


# --- worker side (runs in the pool's processes) ------------------------------------------------
def _worker_init(plan_fn: PlanFn, warmup: bool) -> None:
    """Pool initializer: plan one small task, cold and warm, k = 1 and 3 (loads the JIT caches of
    both paths), and a small robust-box task, so that no request pays for them."""
    if not warmup:
        return
    for unc in (["pc"], ["pv", "pc", "pt"]):
        try:
            req = PlanRequest(objective="robust-derivative", model="arm1dof", q0=[0.0], qf=[1.0],
                              tf=1.0, uncertain=unc, starts=20,
                              time_budget=120.0)
            res = plan_fn(req)
            if res.profile is not None:
                plan_fn(replace(req, qf=[1.01]), initial_currents=res.profile.currents)
        except Exception:  # noqa: BLE001 - warming is best effort; a request reports real errors
            pass
    try:    # the robust-box kernels (the default objective), one small plan
        plan_fn(PlanRequest(objective="robust-box", model="arm1dof", q0=[0.0], qf=[1.0], tf=1.0,
                            steps=5, starts=5, time_budget=120.0))
    except Exception:  # noqa: BLE001 - warming is best effort
        pass


def _ping() -> int:
    return os.getpid()


class _Reporter:
    """The progress callback of a plan in a worker: sends the planner's dicts (numbers and strings
    only) as JSON datagrams to ``path``, at most every PROGRESS_PERIOD s (a new stage at once).
    Never blocks and never raises: a full or closed socket drops the report."""

    def __init__(self, path: str, tag: int) -> None:
        self.path, self.tag = path, tag
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.last = -math.inf
        self.stage: Any = None

    def __call__(self, report: Mapping[str, Any]) -> None:
        now = time.monotonic()
        stage = report.get("stage")
        if now - self.last < PROGRESS_PERIOD and stage == self.stage:
            return
        self.last, self.stage = now, stage
        out: dict[str, Any] = {"tag": self.tag}
        for k, v in report.items():
            if isinstance(v, (bool, str)):
                out[str(k)] = v
            elif isinstance(v, (int, float, np.integer, np.floating)):
                out[str(k)] = float(v) if isinstance(v, (float, np.floating)) else int(v)
        try:
            self.sock.sendto(json.dumps(out).encode(), self.path)
        except OSError:
            pass


def _solve(checked: CheckedRequest, deadline: float, initial_currents: Optional[np.ndarray],
           plan_fn: PlanFn, report_to: Optional[tuple[str, int]] = None) -> PlanResult:
    """One plan in a worker: cold (multistart) or warm (from ``initial_currents``, A), within
    ``deadline`` (time.monotonic(), shared by all processes on Linux). Raises WarmStartUnavailable
    when the planner cannot start from the currents; every other error becomes a refusal.
    ``report_to``: (socket path, tag) of a :class:`ProgressChannel` for the planner's progress."""
    request = checked.request
    t0 = time.monotonic()
    left = deadline - t0
    if left <= 0.0:
        return failure(request, "TIME_BUDGET_EXHAUSTED",
                       f"the time budget of {request.time_budget:.3g} s ran out while waiting for a "
                       f"free worker; raise time_budget or retry later")
    req = replace(checked, request=replace(request, time_budget=min(float(request.time_budget), left)))
    progress = _Reporter(*report_to) if report_to is not None else None
    try:
        if initial_currents is not None:
            result = warm_plan(req, initial_currents, plan_fn, progress)
        else:
            result = plan_fn(req, progress)
    except WarmStartUnavailable:
        raise
    except (PlanningError, ParameterError) as exc:
        result = failure(request, exc.code, str(exc))
    except Exception as exc:  # noqa: BLE001 - a planner bug must not take the node down; report it
        tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
        result = failure(request, "INTERNAL_ERROR", f"planner error: {tb}")
    result.solve_time = result.solve_time or (time.monotonic() - t0)
    return result


# --- progress from the workers ---------------------------------------------------------------------
class ProgressChannel:
    """Progress reports from worker processes: a Unix datagram socket in a private temporary
    folder and a thread that hands each report to the callback registered under its tag.

    Datagrams share no lock with the workers, so a worker killed mid-report (time budget, cancel)
    cannot leave the channel blocked or garbled for the others.
    """

    def __init__(self) -> None:
        self.folder = tempfile.mkdtemp(prefix="ff_plan_")
        self.path = os.path.join(self.folder, "progress")
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.sock.settimeout(0.2)
        self._subs: dict[int, Callable[[dict], None]] = {}
        self._next = 0
        self._lock = threading.Lock()
        self._closed = False
        self._thread = threading.Thread(target=self._loop, name="ff_plan_progress", daemon=True)
        self._thread.start()

    def register(self, fn: Callable[[dict], None]) -> tuple[str, int]:
        """Route reports to ``fn``; returns the (path, tag) a worker sends them to."""
        with self._lock:
            self._next += 1
            self._subs[self._next] = fn
            return self.path, self._next

    def unregister(self, tag: int) -> None:
        with self._lock:
            self._subs.pop(tag, None)

    def _loop(self) -> None:
        while not self._closed:
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                continue
            except OSError:
                return
            try:
                report = json.loads(data)
                fn = self._subs.get(int(report.pop("tag")))
            except (ValueError, KeyError, TypeError):
                continue
            if fn is not None:
                try:
                    fn(report)
                except Exception:  # noqa: BLE001 - a caller's callback must not stop the channel
                    pass

    def close(self) -> None:
        self._closed = True
        self._thread.join(timeout=1.0)
        self.sock.close()
        shutil.rmtree(self.folder, ignore_errors=True)


# --- the service ------------------------------------------------------------------------------
@dataclass
class RequestFields:
    """A plan request as it arrives (the PlanTrajectory request fields, plain python)."""

    model: str = ""
    q0: Sequence[float] = ()
    qf: Sequence[float] = ()
    move_time: float = 0.0
    uncertain: Sequence[str] = ()
    objective: str = ""
    steps: int = 0
    starts: int = 0
    seed: int = 0
    time_budget: float = 0.0
    override_names: Sequence[str] = ()
    override_values: Sequence[float] = ()
    box_names: Sequence[str] = ()        # uncertain parameters given their own box half-width
    box_fractions: Sequence[float] = ()  # ± fraction of the nominal value, one per box_names entry
    coast_max: float = 0.0               # s, robust-box; 0 = the planner's default
    switch_grid: float = 0.0             # s; 0 = the node's switch_grid, negative = no grid
    position_min: Sequence[float] = ()   # rad per joint; empty = the node's <model>.position_min
    position_max: Sequence[float] = ()   # rad per joint; empty = the node's <model>.position_max
    velocity_max: Sequence[float] = ()   # rad/s per joint; empty = the node's <model>.velocity_max
    tolerance: float = 0.0               # rad, > 0: the fastest tf certified within it; 0 = none
    move_time_max: float = 0.0           # s, longest tf of a tolerance search; 0 = 3 s


class PlannerService:
    """Serve plan requests (thread-safe; call :meth:`start` first and :meth:`close` at the end).

    ``plan_fn`` is the planner, ``plan(checked, progress, initial_currents=...)`` taking a
    ``CheckedRequest`` (default: the facade ``ff_planner.optimize.planner.plan``); a module-level
    function, as it is sent to the worker processes by reference.
    """

    def __init__(self, config: ServiceConfig, plan_fn: PlanFn = plan,
                 log: Optional[Callable[[str], None]] = None) -> None:
        config.validate()
        self.config = config
        self.plan_fn = plan_fn
        self.log = log or (lambda msg: None)
        self.params = {m: config.model_params(m) for m in MODELS}
        self.drive = config.drive()
        self.library: Optional[MotionLibrary] = None
        try:
            if config.use_library and config.library_path:
                self.library = MotionLibrary(config.library_path)
            if config.motion_dir:
                Path(config.motion_dir).expanduser().mkdir(parents=True, exist_ok=True)
        except (LibraryError, sqlite3.Error, OSError) as exc:
            raise ServiceConfigError(f"cannot open library_path {config.library_path!r} / motion_dir "
                                     f"{config.motion_dir!r}: {exc}; fix the path or set it to \"\"") from None
        self._pool: Optional[ProcessPool] = None
        self._lock = threading.Lock()
        self._pending = 0
        self._pending_long = 0
        self.long_limit = max(1, min(config.max_pending - 1, config.max_pending_long or config.max_pending // 2))
        self._long_slots = threading.BoundedSemaphore(max(1, config.workers - 1))
        self._stats: Counter[str] = Counter()
        self._times: dict[str, deque[float]] = {}
        self._closed = False
        self._no_warm: set[tuple[str, str]] = set()   # (model, objective) whose planner cannot warm start
        self._channel: Optional[ProgressChannel] = None

    @property
    def planner_name(self) -> str:
        """``module.function`` of the plan function (for logs)."""
        fn = self.plan_fn
        return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(fn))}"

    # lifecycle
    def start(self, wait: float = 300.0) -> None:
        """Start the worker processes (spawned: no fork of a ROS process) and wait until they answer."""
        ctx = multiprocessing.get_context("spawn")
        pool = ProcessPool(max_workers=self.config.workers, initializer=_worker_init,
                           initargs=(self.plan_fn, self.config.warmup), context=ctx)
        self._pool = pool
        self._channel = ProgressChannel()
        futs = [pool.schedule(_ping) for _ in range(self.config.workers)]
        for f in futs:
            f.result(timeout=wait)

    def close(self) -> None:
        """Stop the workers (a running plan is abandoned) and close the library."""
        self._closed = True
        if self._pool is not None:
            self._pool.stop()
            self._pool.join(timeout=10)
            self._pool = None
        if self._channel is not None:
            self._channel.close()
            self._channel = None
        if self.library is not None:
            self.library.close()

    # requests
    def make_request(self, f: RequestFields) -> CheckedRequest:
        """Fields -> checked request (node defaults filled in, node limits applied); raises
        PlanningError/ParameterError whose ``.code`` is the PlanTrajectory error name."""
        model = check_model(f.model or self.config.default_model)
        names, values = list(f.override_names), list(f.override_values)
        if len(names) != len(values):
            raise PlanningError(f"{len(names)} override names but {len(values)} override values; "
                                f"give one value per name")
        params = self.params[model]
        if names:
            params = params.replace(**dict(zip(names, values)))   # unknown names: UNKNOWN_PARAMETER
        c = self.config
        objective = f.objective or c.default_objective
        tolerance, tf_max = self._tolerance(f)
        tf = float(f.move_time) if tolerance is None else tf_max
        if not math.isfinite(tf) or tf <= 0:
            raise PlanningError(f"move_time must be a finite number > 0 s, got {tf}")
        if tf > c.max_move_time:
            what = "move_time" if tolerance is None else "move_time_max"
            raise PlanningError(f"{what} {tf} s exceeds this planner's limit of {c.max_move_time} s; "
                                f"split the move or raise max_move_time")
        budget = float(f.time_budget) if f.time_budget else c.default_time_budget
        if not math.isfinite(budget) or budget <= 0:
            raise PlanningError(f"time_budget must be a finite number > 0 s (0 = node default), got {budget}")
        if budget > c.max_time_budget:
            raise PlanningError(f"time_budget {budget} s exceeds this planner's limit of "
                                f"{c.max_time_budget} s; ask for less")
        starts = int(f.starts) or c.default_starts
        if starts > c.max_starts:
            raise PlanningError(f"starts = {starts} exceeds this planner's limit of {c.max_starts}; ask for fewer")
        uncertain = list(f.uncertain) if len(f.uncertain) else list(params.friction_keys)  # empty = all
        steps = int(f.steps) or None
        if steps is not None and steps > c.max_steps:
            raise PlanningError(f"steps = {steps} per joint exceeds this planner's limit of {c.max_steps}; "
                                f"ask for fewer (default is 2 + number of uncertain parameters)")
        box = self._box(f, uncertain)
        coast_max = float(f.coast_max)
        if not (math.isfinite(coast_max) and coast_max >= 0.0):
            raise PlanningError(f"coast_max must be a finite number >= 0 s (0 = default), got {coast_max}")
        grid = self._grid(f, objective, model, tf)
        chosen = None       # the baseline's own step count (it is not limited by max_steps)
        if steps is None and objective == "energy-optimal" and model == "arm1dof" and tolerance is None:
            chosen = steps = _energy_steps_on_grid(tf - c.coast,
                                                   float(f.switch_grid) or float(self.config.switch_grid))
        kw: dict[str, Any] = dict(model=model, q0=[float(x) for x in f.q0], qf=[float(x) for x in f.qf],
                                  tf=tf, uncertain=uncertain, objective=objective, steps=steps,
                                  starts=starts, seed=int(f.seed), time_budget=budget, coast=c.coast,
                                  params=params, tol=c.tol, box=box,
                                  current_quantum=float(c.current_quantum),
                                  limits=self._limits(f, model), tolerance=tolerance,
                                  move_time_max=tf_max if tolerance is not None else None)
        if coast_max > 0.0:
            kw["coast_max"] = coast_max
        req = GridPlanRequest(grid=grid, **kw) if grid is not None else PlanRequest(**kw)
        checked = check(req, drive=self.drive)   # UNREACHABLE answered at once, before the library lookup
        if req.n_steps() > c.max_steps and chosen is None:
            raise PlanningError(f"{req.n_steps()} steps per joint exceeds this planner's limit of "
                                f"{c.max_steps}; ask for fewer steps or uncertain parameters")
        if grid is not None and req.steps != 0:
            cells = math.floor((tf - c.coast) / grid + 1e-9)
            if cells < req.n_steps():
                raise PlanningError(f"{req.n_steps()} steps do not fit on a {grid:g} s switch_grid within "
                                    f"tf - coast = {tf - c.coast:g} s; ask for fewer steps, a longer "
                                    f"move, or a finer switch_grid")
        return checked

    def _limits(self, f: RequestFields, model: str) -> Optional[MotionLimits]:
        """The request's limits; each list left empty takes the node's for ``model`` (if set).
        Not validated here (PlanRequest.validate, through ``check``)."""
        own = MotionLimits.of(*(list(getattr(f, k) or []) or None
                                for k in ("position_min", "position_max", "velocity_max")))
        cell = self.config.limits.get(model) or MotionLimits()
        merged = MotionLimits(own.position_min or cell.position_min,
                              own.position_max or cell.position_max,
                              own.velocity_max or cell.velocity_max)
        return None if merged.empty else merged

    def _tolerance(self, f: RequestFields) -> tuple[Optional[float], float]:
        """(tolerance rad or None, longest move time s) of a request."""
        tol = float(f.tolerance)
        tf_max = float(f.move_time_max)
        if not (math.isfinite(tol) and tol >= 0.0):
            raise PlanningError(f"tolerance must be a finite number >= 0 rad (0 = none), got {tol}")
        if not (math.isfinite(tf_max) and tf_max >= 0.0):
            raise PlanningError(f"move_time_max must be a finite number >= 0 s (0 = "
                                f"{DEFAULT_MOVE_TIME_MAX:g} s), got {tf_max}")
        if tol == 0.0:
            return None, tf_max
        return tol, tf_max or DEFAULT_MOVE_TIME_MAX

    @staticmethod
    def _box(f: RequestFields, uncertain: Sequence[str]) -> Optional[dict[str, float]]:
        """The request's box (± fraction per uncertain parameter) or None (the default box)."""
        names, fracs = [str(n) for n in f.box_names], [float(x) for x in f.box_fractions]
        if len(names) != len(fracs):
            raise PlanningError(f"{len(names)} box names but {len(fracs)} box fractions; give one "
                                f"fraction per name")
        if not names:
            return None
        if len(set(names)) != len(names):
            raise PlanningError(f"box names repeat: {names}")
        extra = [n for n in names if n not in uncertain]
        if extra:
            raise PlanningError(f"box names {extra} are not uncertain parameters of this request; "
                                f"uncertain are {list(uncertain)} (name them in `uncertain` too)")
        for n, x in zip(names, fracs):
            if not (math.isfinite(x) and 0.0 < x < 1.0):
                raise PlanningError(f"box fraction of {n} must be a finite number in (0, 1) "
                                    f"(0.2 = ±20 %), got {x}")
        return dict(zip(names, fracs))

    def _grid(self, f: RequestFields, objective: str, model: str, tf: float) -> Optional[float]:
        """The switch-time grid (s) of a request, or None: 0 = the node's switch_grid, negative =
        none; only the 1-DOF planners of ``gridded.GRID_OBJECTIVES`` place switches on a grid.
        ``tf``: the move time (s; a tolerance search's longest)."""
        g = float(f.switch_grid)
        if not math.isfinite(g):
            raise PlanningError(f"switch_grid must be a finite number of seconds (0 = node default, "
                                f"negative = no grid), got {g}")
        if g == 0.0:
            g = float(self.config.switch_grid)
        if self.drive is not None and self.drive.period > 0.0:
            g = self.drive.period              # the drive applies setpoints at its SYNC only
        if g <= 0.0 or not applies(model, objective):
            return None
        if g >= tf:
            raise PlanningError(f"switch_grid {g:g} s must be shorter than the move time {tf:g} s")
        return g

    def handle_fields(self, f: RequestFields, progress: Optional[Callable[[dict], None]] = None,
                      cancel: Optional[threading.Event] = None) -> PlanResult:
        """Validate and serve one request; never raises. ``progress`` gets dicts (``stage`` and the
        planner's own keys: ``starts_done``, ``best`` ...); ``cancel`` set = stop and answer
        "canceled" (``extra["canceled"]``)."""
        t0 = time.monotonic()
        try:
            req = self.make_request(f)
        except Exception as exc:  # noqa: BLE001 - every bad request becomes an answer
            code = error_code_of(exc)
            elapsed = time.monotonic() - t0
            self._count("invalid", code, elapsed)
            res = failure(None if code == "INTERNAL_ERROR" else _partial(f), code, str(exc))
            res.extra = {"source": "invalid", "latency": elapsed}
            return res
        try:
            wanted = float(f.switch_grid) or float(self.config.switch_grid)
        except (TypeError, ValueError):
            wanted = 0.0
        if self.drive is not None and self.drive.period > 0.0:
            wanted = self.drive.period
        return self.handle(req, received=t0, progress=progress, cancel=cancel, grid=max(0.0, wanted))

    def handle(self, checked: CheckedRequest, received: Optional[float] = None,
               progress: Optional[Callable[[dict], None]] = None,
               cancel: Optional[threading.Event] = None, grid: float = 0.0) -> PlanResult:
        """Serve a checked request (see module docstring; ``received``: time.monotonic() of its
        arrival, default now; ``grid``: the switch grid asked for, s, 0 = none: an answer whose
        switch times are off it says so); never raises."""
        t0 = received if received is not None else time.monotonic()
        request = checked.request
        deadline = t0 + float(request.time_budget)
        try:
            result, source = self._serve(checked, deadline, progress, cancel)
        except Exception as exc:  # noqa: BLE001 - the node must keep serving
            tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
            self.log(f"internal error: {traceback.format_exc()}")
            result, source = failure(request, "INTERNAL_ERROR", f"planner node error: {tb}"), "error"
        elapsed = time.monotonic() - t0
        result.extra = dict(result.extra or {}, source=source, latency=elapsed)
        if result.profile is not None:
            if checked.drive is not None or request.current_quantum > 0.0:
                try:     # e.g. a library row planned without the drive's grid
                    apply_drive_exact(result, checked)
                except Exception as exc:  # noqa: BLE001 - the node must keep serving
                    self.log(f"drive grid / current quantum not applied: {exc!r}")
            result.extra["predicted_rest"] = predicted_rest(result, checked.params)
            if grid > 0.0 and not on_grid(result.profile, grid):
                result.message = ((result.message + "; ") if result.message else "") + (
                    f"switch times are not on the {grid:g} s switch_grid (the {request.model} "
                    f"{request.objective} planner places them freely; the drive applies each at its "
                    f"next SYNC)")
        self._count(source, result.error_code, elapsed)
        if result.success and self.config.motion_dir and result.profile is not None:
            self._write_motion(request, result)
        return result

    def _serve(self, checked: CheckedRequest, deadline: float,
               progress: Optional[Callable[[dict], None]] = None,
               cancel: Optional[threading.Event] = None) -> tuple[PlanResult, str]:
        request = checked.request
        plain = _library_task(request)
        lib = self.library if plain else None
        tell = progress or (lambda d: None)
        warm_from: Optional[tuple[float, MotionRecord]] = None
        if lib is not None:
            tell({"stage": "library"})
            rec = lib.lookup(request)
            if rec is not None and self._usable(rec, request):
                return _from_record(rec, request, self._hit_message(rec, False), False), "hit"
            near = lib.nearest(request, k=1, max_distance=self.config.warm_max_distance,
                               time_weight=self.config.time_weight)
            if near:
                dist, rec = near[0]
                if dist < SHIFT_EPS and self._usable(rec, request):
                    return _from_record(rec, request, self._hit_message(rec, True), True), "shift"
                cur = rec.currents()
                if (request.objective.startswith("robust") and cur is not None
                        and cur.shape == (request.n_steps(), len(request.q0))):
                    warm_from = (dist, rec)   # baselines are closed-form: nothing to warm start
        note = ""
        if warm_from is not None and (request.model, request.objective) not in self._no_warm:
            dist, rec = warm_from
            tell({"stage": "warm-start"})
            try:
                result = self._run(checked, deadline, rec.currents(), progress, cancel)
            except WarmStartUnavailable as exc:   # this model's planner cannot start from currents
                self._no_warm.add((request.model, request.objective))
                self.log(f"warm starts off for {request.model} {request.objective}: {exc}")
                note = f"warm start from {rec.task_key} failed (unavailable: {exc}); "
            else:
                if result.success:
                    result.warm_start = True
                    result.message = (f"warm start from library entry {rec.task_key} (distance {dist:.3g}); "
                                      + (result.message or ""))
                    self._store(request, result, "warm", rec.task_key)
                    return result, "warm"
                if (result.error_code == "TIME_BUDGET_EXHAUSTED" or time.monotonic() >= deadline
                        or result.extra.get(CANCELED)):
                    return result, ("canceled" if result.extra.get(CANCELED) else "warm")
                note = f"warm start from {rec.task_key} failed ({result.message}); "
        tell({"stage": "multistart"})
        result = self._run(checked, deadline, None, progress, cancel)
        if note:
            result.message = note + (result.message or "")
        result.warm_start = False
        if result.extra.get(CANCELED):
            return result, "canceled"
        if plain:
            self._store(request, result, "cold", None)
        return result, ("refused" if result.extra.get("refused") else "cold")

    def _usable(self, rec: MotionRecord, request: PlanRequest) -> bool:
        """May a stored row answer this request without solving? (A solved row must also fit the
        request's switch grid and, for robust-box, its box and coast_max.)"""
        if rec.status == "solved" and not _fits(rec, request):
            return False
        if rec.status == "solved":
            return rec.robust or not request.objective.startswith("robust") or rec.starts_tried >= request.starts
        if rec.status == "infeasible":
            return rec.error_code == "UNREACHABLE" or rec.starts_tried >= request.starts
        return False  # failed rows are transient

    @staticmethod
    def _hit_message(rec: MotionRecord, shifted: bool) -> str:
        what = "shifted copy of library entry" if shifted else "library entry"
        if rec.status == "solved":
            return f"from the motion library ({what} {rec.task_key}, solved {rec.solved_how})"
        return f"known from the motion library: no plan here ({rec.error_code}): {rec.reason}"

    def _run(self, checked: CheckedRequest, deadline: float, initial: Optional[np.ndarray],
             progress: Optional[Callable[[dict], None]] = None,
             cancel: Optional[threading.Event] = None) -> PlanResult:
        """Run one plan in the pool, with admission control, the deadline and ``cancel`` enforced.

        Raises WarmStartUnavailable (from the worker) when ``initial`` currents cannot be used.
        """
        request = checked.request
        if cancel is not None and cancel.is_set():
            return _canceled(request)
        pool = self._pool
        if pool is None or self._closed:
            return failure(request, "INTERNAL_ERROR", "planner workers are not running")
        long = request.model in LONG_MODELS
        with self._lock:
            full = self._pending >= self.config.max_pending
            full_long = long and self._pending_long >= self.long_limit
            if full or full_long:
                what = (f"{self._pending_long} long (scara2) plans" if full_long and not full
                        else f"{self._pending} requests")
                lim = self.long_limit if full_long and not full else self.config.max_pending
                r = failure(request, "TIME_BUDGET_EXHAUSTED",
                            f"planner overloaded: {what} already waiting or running (limit {lim}); "
                            f"retry later")
                r.extra = {"refused": True}
                return r
            self._pending += 1
            self._pending_long += int(long)
        try:
            if long:
                left = deadline - time.monotonic()
                if not self._long_slots.acquire(timeout=max(0.0, left)):
                    return failure(request, "TIME_BUDGET_EXHAUSTED",
                                   f"all long-plan workers stayed busy for the whole time budget of "
                                   f"{request.time_budget:.3g} s; retry later or raise time_budget")
            channel = self._channel
            tag: Optional[int] = None
            try:
                report_to = None
                if progress is not None and channel is not None:
                    report_to = channel.register(progress)
                    tag = report_to[1]
                one = self.plan_fn if checked.drive is None else partial(self.plan_fn,
                                                                          drive=checked.drive)
                plan_fn = (partial(plan_fastest, plan_fn=one)
                           if request.tolerance is not None else self.plan_fn)
                fut = pool.schedule(_solve, args=(checked, deadline, initial, plan_fn, report_to),
                                    timeout=max(0.0, deadline - time.monotonic()) + 2 * self.config.grace)
                try:
                    end = deadline + self.config.grace
                    while True:
                        if cancel is not None and cancel.is_set():
                            fut.cancel()  # pebble: a running task's worker is killed and replaced
                            with self._lock:
                                self._stats["canceled"] += 1
                            return _canceled(request)
                        wait = min(CANCEL_POLL, end - time.monotonic()) if cancel is not None \
                            else end - time.monotonic()
                        try:
                            return fut.result(timeout=max(0.0, wait))
                        except FutureTimeout:
                            if fut.done() or time.monotonic() >= end:
                                raise
                except WarmStartUnavailable:
                    raise
                except FutureTimeout:
                    fut.cancel()  # pebble: a running task's worker is killed and replaced
                    with self._lock:
                        self._stats["workers_killed"] += 1
                    return failure(request, "TIME_BUDGET_EXHAUSTED",
                                   f"no plan within the time budget of {request.time_budget:.3g} s; "
                                   f"raise time_budget, ask for fewer starts, or plan offline (ff-plan)")
                except Exception as exc:  # noqa: BLE001 - a dead worker, pickling error ...
                    return failure(request, "INTERNAL_ERROR", f"planner worker failed: {exc!r}")
            finally:
                if tag is not None and channel is not None:
                    channel.unregister(tag)
                if long:
                    self._long_slots.release()
        finally:
            with self._lock:
                self._pending -= 1
                self._pending_long -= int(long)

    def _store(self, request: PlanRequest, result: PlanResult, how: str, warm_from: Optional[str]) -> None:
        """Put solved and infeasible results in the library (failed ones are transient: not stored)."""
        if self.library is None:
            return
        if not (result.success or result.error_code in ("UNREACHABLE", "NO_ROBUST_PLAN")):
            return
        try:
            rec = record_from_result(request, result, solved_how=how, warm_from=warm_from,
                                     writer=f"ff_planner node pid {os.getpid()}")
            self.library.put(rec, request.resolved_params())
        except (LibraryError, ValueError, OSError) as exc:
            self.log(f"could not store plan in the motion library: {exc}")

    def _write_motion(self, request: PlanRequest, result: PlanResult) -> None:
        try:

            path = Path(self.config.motion_dir).expanduser() / f"{task_key(request)}.json"
            write_motion(path, result)
            result.extra["motion_file"] = str(path)
        except Exception as exc:  # noqa: BLE001 - a file problem must not fail the plan
            self.log(f"could not write motion file: {exc}")

    # statistics
    def _count(self, source: str, code: str, seconds: float) -> None:
        with self._lock:
            self._stats["requests"] += 1
            self._stats[f"source_{source}"] += 1
            self._stats[f"code_{code}"] += 1
            self._times.setdefault(source, deque(maxlen=1000)).append(seconds)

    def stats(self) -> dict[str, Any]:
        """Counters and latency quantiles (s) per source, for diagnostics."""
        with self._lock:
            out: dict[str, Any] = dict(self._stats)
            out["pending"] = self._pending
            out["pending_long"] = self._pending_long
            for src, d in self._times.items():
                if d:
                    a = np.fromiter(d, float)
                    out[f"latency_{src}_p50"] = float(np.percentile(a, 50))
                    out[f"latency_{src}_p95"] = float(np.percentile(a, 95))
        out["workers"] = self.config.workers
        if self.library is not None:
            try:
                out.update({f"library_{k}": v for k, v in self.library.stats().items()})
            except Exception:  # noqa: BLE001
                pass
        return out


def _library_task(request: PlanRequest) -> bool:
    """May the motion library answer (and store) this request? Not a tolerance search (its tf is
    chosen) nor a request with limits (the library's task key does not hold them)."""
    return request.tolerance is None and (request.limits is None or request.limits.empty)


def _canceled(request: PlanRequest) -> PlanResult:
    r = failure(request, "TIME_BUDGET_EXHAUSTED", "canceled by the caller before a plan was found")
    r.extra = {CANCELED: True}
    return r


def _energy_steps_on_grid(span: float, grid: float, most: int = 100) -> Optional[int]:
    """The most equal energy-optimal steps (at most ``most``) whose boundaries fall on the switch
    grid over ``span`` = tf - coast (s), or None (the planner's default) when the span is not a
    whole number of grid cells or no grid is asked for."""
    if not grid > 0.0:
        return None
    cells = round(span / grid)
    if cells < 1 or abs(cells * grid - span) > 1e-9 * max(1.0, span):
        return None
    return max(n for n in range(1, min(most, cells) + 1) if cells % n == 0)


def _fits(rec: MotionRecord, request: PlanRequest) -> bool:
    """Does a stored plan fit what ``request`` asks beyond its task key: switch times on its grid;
    a certificate (when the row has one) over the request's box, and no box of its own asked
    when the row has none; for robust-box a coast within coast_max?"""
    prof = rec.profile()
    grid = getattr(request, "grid", None)
    if prof is not None and grid is not None and not on_grid(prof, float(grid)):
        return False
    cert = (rec.motion or {}).get("certificate")
    if not cert and request.box:
        return False
    if cert and request.uncertain:
        want = box_fractions(list(request.uncertain), request.box)
        have = {str(k): float(v) for k, v in (cert.get("box") or {}).items()}
        if set(have) != set(want) or any(abs(have[k] - want[k]) > 1e-12 for k in want):
            return False
    if request.objective == "robust-box" and prof is not None \
            and prof.coast > request.box_coast_max() + 1e-12:
        return False
    return True


def _certificate_from_dict(d: Mapping[str, Any]) -> Optional[RobustnessCertificate]:
    """A RobustnessCertificate from its motion-file form (``RobustnessCertificate.to_dict``)."""
    try:
        return RobustnessCertificate(
            box={str(k): float(v) for k, v in d["box"].items()},
            worst_rest_error=float(d["worst_rest_error"]),
            worst_at={str(k): float(v) for k, v in d["worst_at"].items()},
            per_parameter={str(k): float(v) for k, v in d["per_parameter"].items()},
            moving_at_tf=float(d["moving_at_tf"]),
            switch_timing=[float(x) for x in d["switch_timing_per_100us"]],
            samples=int(d["samples"]),
            worst_per_joint=[float(x) for x in d.get("worst_per_joint", [])],
            switch_timing_per_joint=[[float(x) for x in row]
                                     for row in d.get("switch_timing_per_joint_per_100us", [])])
    except (KeyError, TypeError, ValueError, AttributeError):
        return None


def _from_record(rec: MotionRecord, request: PlanRequest, message: str, shift: bool) -> PlanResult:
    """A library row as the answer to ``request``, with the certificate and the rest position
    the row's motion carries (the rest position moved with a shifted copy)."""
    result = rec.to_result(request, message=message, shift=shift)
    motion = rec.motion or {}
    cert = motion.get("certificate")
    if isinstance(cert, Mapping):
        result.certificate = _certificate_from_dict(cert)
    rest = (motion.get("predicted") or {}).get("rest_position")
    if rest is not None:
        try:
            r = np.asarray(rest, dtype=float).ravel()
            if shift:
                r = r + (float(request.q0[0]) - float(rec.q0[0]))
            result.extra["rest_position"] = [float(x) for x in r]
        except (TypeError, ValueError):
            pass
    return result


def predicted_rest(result: PlanResult, params: Optional[Params] = None) -> list[float]:
    """Where the plan leaves the arm at rest (rad per joint, nominal parameters); [] = unknown.

    1-DOF: the position where it stops with zero current after tf (``extra["rest_position"]`` of
    the facade, else simulated); 2-DOF: ``q_final`` when the plan is at rest at tf (|qd(tf)| below
    REST_SPEED), else the facade's rest position if it has one."""
    prof = result.profile
    if prof is None:
        return []
    known = (result.extra or {}).get("rest_position")
    if result.model == "arm1dof":
        if known is not None and len(known) == 1 and all(math.isfinite(float(x)) for x in known):
            return [float(x) for x in known]
        p = params if params is not None else result.params
        try:
            rest = rest_position(p if p is not None else default_params("arm1dof"), prof,
                                 [float(x) for x in result.q0])
        except (ValueError, ArithmeticError, TypeError):
            return []
        return [float(x) for x in rest] if np.all(np.isfinite(rest)) else []
    qd = np.asarray(result.qd_final, dtype=float).ravel()
    q = np.asarray(result.q_final, dtype=float).ravel()
    if q.size == len(result.q0) and qd.size == q.size and np.all(np.isfinite(q)) \
            and np.all(np.abs(qd) <= REST_SPEED):
        return [float(x) for x in q]
    if known is not None and all(math.isfinite(float(x)) for x in known):
        return [float(x) for x in known]
    return []


def _partial(f: RequestFields) -> PlanRequest:
    """A PlanRequest-like object echoing what can be read of an invalid request."""
    return PlanRequest(model=f.model, q0=list(as_vector(f.q0)), qf=list(as_vector(f.qf)), tf=0.0,
                       uncertain=list(f.uncertain), objective=f.objective)


def config_from_mapping(values: Mapping[str, Any]) -> ServiceConfig:
    """ServiceConfig from flat node parameters (see config/planner.yaml); unknown names refused.

    Model parameter overrides use ``<model>.params.<key>``, presets ``<model>.preset``.
    """
    cfg = ServiceConfig()
    plain = {f for f in cfg.__dataclass_fields__ if f not in ("presets", "overrides", "limits")}
    presets = dict(cfg.presets)
    overrides: dict[str, dict[str, float]] = {}
    limits: dict[str, dict[str, list[float]]] = {}
    unknown = []
    for name, v in values.items():
        if name in plain:
            cur = getattr(cfg, name)
            try:
                setattr(cfg, name, type(cur)(v))
            except (TypeError, ValueError):
                raise ServiceConfigError(f"parameter {name!r} must be a {type(cur).__name__}, got {v!r}") from None
            continue
        parts = name.split(".")
        if len(parts) == 2 and parts[0] in MODELS and parts[1] == "preset":
            presets[parts[0]] = str(v)
        elif len(parts) == 2 and parts[0] in MODELS and parts[1] in LIMIT_NAMES:
            items = list(v) if hasattr(v, "__iter__") and not isinstance(v, str) else [v]
            try:
                limits.setdefault(parts[0], {})[parts[1]] = [float(x) for x in items]
            except (TypeError, ValueError):
                raise ServiceConfigError(f"parameter {name!r} must be numbers, one per joint, got "
                                         f"{v!r}") from None
        elif len(parts) == 3 and parts[0] in MODELS and parts[1] == "params":
            keys = default_params(parts[0]).keys()
            if parts[2] not in keys:
                raise ServiceConfigError(f"unknown model parameter {parts[2]!r} in {name!r}; valid keys "
                                         f"for {parts[0]}: {', '.join(keys)}")
            overrides.setdefault(parts[0], {})[parts[2]] = float(v)
        else:
            unknown.append(name)
    if unknown:
        raise ServiceConfigError(f"unknown planner parameter(s) {unknown}; valid: {sorted(plain)}, "
                                 f"<model>.preset, <model>.params.<key>, <model>.position_min, "
                                 f"<model>.position_max, <model>.velocity_max (and for the node: "
                                 f"diagnostics_period, executor_threads)")
    cfg.presets, cfg.overrides = presets, overrides
    cfg.limits = {m: MotionLimits.of(d.get("position_min"), d.get("position_max"),
                                     d.get("velocity_max")) for m, d in limits.items()}
    cfg.validate()
    for m in MODELS:
        cfg.model_params(m)
    return cfg
