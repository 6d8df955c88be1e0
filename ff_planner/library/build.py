"""Fill a motion library from a task grid on Dask distributed: continuation order,
exactly-once, resumable.

Who writes: the *client* writes every result into the store (``ff_planner.library.store.MotionLibrary``,
the same SQLite file and schema the planner node reads), as the results arrive. Workers only
compute: ``solve_task(payload) -> MotionRecord`` is a pure function of its payload. Why:

* workers of a remote cluster (``--scheduler``; TLS and its certificates:
  ``ff_planner.library.cluster``) need not see the client's disk, and SQLite must not live on a
  network file system; the client is the one place that always has the file;
* exactly-once is then a property of one writer plus the store's primary key: ``put`` is
  INSERT-OR-IGNORE on the task key (an upgrade only replaces a strictly worse row), so a result
  delivered twice is written once;
* a worker killed mid-task has written nothing; Dask's scheduler re-runs the task on another
  worker (up to ``distributed.scheduler.allowed-failures`` times, then the task is stored as
  failed with the reason), and the client still sees one result per task;
* a killed client loses only the tasks in flight; a re-run skips every task stored as solved or
  infeasible (failed rows are transient and are solved again).

Continuation: tasks are solved in the order of :func:`ff_planner.library.grid.continuation_tree`
(a task is submitted once its tree parent is stored); it starts from the currents of its nearest
*solved* ancestor (``warm_plan``, no multistart), then from a few seeded perturbations of them
(``local_starts``, each a single start), and falls back to a cold multistart solve when all
fail. Since the tree and the ancestors' outcomes are fixed before a task starts, the stored
results do not depend on the number of workers or on timing (for a deterministic, seeded planner
that finishes inside its time budget). The record says how: ``solved_how`` = "continuation"
(``warm_from`` = the ancestor's key), "cold" (multistart) or "shift" (a shifted copy of an
identical motion in the grid); a failed continuation is noted in ``reason``.

No ROS here.
"""
from __future__ import annotations

import copy
import logging
import math
import os
import socket
import sys
import time
import traceback
from collections import Counter, deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Optional, TextIO

import numpy as np

from ff_planner.core.errors import ParameterError, PlanningError, WarmStartUnavailable, error_code_of
from ff_planner.library.cluster import (DEFAULT_CONNECT_TIMEOUT, DEFAULT_WORKER_WAIT, ClusterError, SchedulerSettings,
                                        connect, wait_for_workers)
from ff_planner.library.grid import Grid, GridSpec, GridTask, continuation_tree, describe, expand, load_grid
from ff_planner.library.refusal import failure
from ff_planner.library.store import MotionLibrary, MotionRecord, record_from_result
from ff_planner.library.warm import PlanFn, warm_plan
from ff_planner.model.params import Params
from ff_planner.model.profile import PlanRequest, PlanResult
from ff_planner.optimize.planner import CheckedRequest, check, plan

DONE = ("solved", "infeasible")


class BuildError(ValueError):
    """A build that cannot run as asked; the message says what to change."""


# --- worker side ----------------------------------------------------------------------------------
@dataclass
class TaskPayload:
    """What a worker needs for one task (picklable: ``plan_fn`` is a module-level function)."""

    request: PlanRequest
    key: str
    neighbour: Optional[MotionRecord] = None    # solved ancestor to continue from; None = cold
    plan_fn: PlanFn = plan                      # plan(request, progress, initial_currents=...)
    fallback_cold: bool = True
    local_starts: int = 16          # continuation: the neighbour's currents + 15 perturbations of them
    local_sigma: float = 0.3        # A, perturbation scale (× √k for the k-th)


def _writer() -> str:
    return f"ff-library {socket.gethostname()} pid {os.getpid()}"


def current_limits(params: Params) -> np.ndarray:
    """The current limit of every joint (A), in joint order: the parameters ``i_max``, ``i_max1``, ..."""
    return np.array([float(getattr(params, k)) for k in params.keys() if k.startswith("i_max")])


def _continue(checked: CheckedRequest, nb: MotionRecord, fn: PlanFn, local_starts: int, sigma: float
              ) -> tuple[Optional[PlanResult], int]:
    """Continuation from a solved neighbour: its currents as the single start, then up to
    ``local_starts`` − 1 seeded perturbations of them (σ·√k A, clipped to the limits), each a
    single start. ``plan_robust_1dof`` adds one seeded random start after the given one: for
    robust-derivative (stop at the first plan) a plan counts only if the given start found it
    (starts_tried = 1); robust-sampled always runs both starts and keeps the better, so there a
    success counts (noted in the record's reason). Returns (result or None, starts used).
    ``checked`` passed the facade's ``check``; the single-start copies share it (the start count
    does not change what ``check`` decides), so the task is validated once."""
    req = checked.request
    one = replace(checked, request=replace(req, starts=1))
    limit = 1 if req.objective == "robust-derivative" else 2

    def counts(r: PlanResult) -> bool:
        return bool(r.success) and r.starts_tried <= limit

    base = nb.currents()
    if base is None:
        raise WarmStartUnavailable(f"library entry {nb.task_key} holds no motion")
    r = warm_plan(one, base, fn, warm_from=nb.task_key)   # checks the shapes
    if counts(r):
        return r, 1
    i_max = current_limits(checked.params)
    rng = np.random.default_rng([int(req.seed), 0x1B])
    for k in range(1, max(1, int(local_starts))):
        init = np.clip(base + rng.normal(0.0, sigma * math.sqrt(k), base.shape), -i_max, i_max)
        r = fn(one, None, initial_currents=init)
        if counts(r):
            r.warm_start = True
            r.extra = dict(r.extra or {}, warm_from=nb.task_key, local_start=k)
            return r, k + 1
    return None, max(1, int(local_starts))


def solve_task(payload: TaskPayload) -> MotionRecord:
    """Solve one task (continuation first, then cold multistart); never raises for planner errors.

    Returns the library record (status solved / infeasible / failed, with the reason).
    """
    req = payload.request
    fn = payload.plan_fn
    t0 = time.perf_counter()
    note = ""
    how, warm_from = "cold", None
    result: Optional[PlanResult] = None
    checked: Optional[CheckedRequest] = None    # checked once when continuation tries many starts
    try:
        nb = payload.neighbour
        if nb is not None:
            try:
                checked = check(req)
                result, tries = _continue(checked, nb, fn, payload.local_starts, payload.local_sigma)
                if result is not None:
                    result.starts_tried = tries
                    how, warm_from = "continuation", nb.task_key
                    if tries > 1:
                        note = f"continuation from {nb.task_key}: perturbed start {tries - 1}; "
                    if req.objective != "robust-derivative":
                        note += "continuation = the neighbour's start + 1 seeded random start; "
                else:
                    note = f"continuation from {nb.task_key} failed ({tries} local start(s)); "
            except WarmStartUnavailable as exc:
                note = f"no continuation ({exc}); "
            except (PlanningError, ParameterError) as exc:
                result = failure(req, exc.code, str(exc))
        if result is None and (nb is None or payload.fallback_cold):
            result = fn(checked if checked is not None else req)
        elif result is None:
            result = failure(req, "NO_ROBUST_PLAN", note.rstrip("; "))
            note = ""
    except (PlanningError, ParameterError) as exc:
        result = failure(req, exc.code, str(exc))
    except Exception as exc:  # noqa: BLE001 - a planner bug becomes a failed row with the reason
        code = error_code_of(exc)
        tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
        result = failure(req, code if code != "INVALID_REQUEST" else "INTERNAL_ERROR", f"planner error: {tb}")
    result.solve_time = time.perf_counter() - t0    # everything this task took: warm tries + cold
    rec = record_from_result(req, result, solved_how=how, warm_from=warm_from, writer=_writer())
    if note:
        rec.reason = (note + rec.reason).strip()
    return rec


def failed_record(request: PlanRequest, reason: str, code: str = "INTERNAL_ERROR") -> MotionRecord:
    """A 'failed' row (transient: a later build solves it again)."""
    return record_from_result(request, failure(request, code, reason), solved_how="cold", writer=_writer())


def shift_record(rec: MotionRecord, twin: GridTask) -> MotionRecord:
    """``rec`` re-keyed for ``twin``, the same motion with every angle shifted by a constant."""
    d = float(twin.request.q0[0]) - float(rec.q0[0])
    out = copy.deepcopy(rec)
    out.task_key = twin.key
    out.q0 = [float(x) for x in twin.request.q0]
    out.qf = [float(x) for x in twin.request.qf]
    out.solved_how, out.warm_from = "shift", rec.task_key
    out.created, out.writer = time.time(), _writer()
    if rec.status != "solved":
        out.reason = f"same motion as {rec.task_key} (shifted by {d:+.6g} rad): {rec.reason}"
    m = out.motion
    if m:
        m["q0"], m["qf"] = list(out.q0), list(out.qf)
        pred = m.get("predicted") or {}
        for k in ("q_final", "rest_position"):
            if pred.get(k):
                pred[k] = [None if v is None else float(v) + d for v in pred[k]]
    return out


# --- progress ---------------------------------------------------------------------------------------
class ProgressBar:
    """done / failed / remaining and an ETA on one stderr line (a line every few s when not a tty)."""

    def __init__(self, total: int, already: int, stream: Optional[TextIO] = None, enabled: bool = True,
                 every: float = 5.0) -> None:
        self.total, self.already = total, already
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every = 0.2 if self.tty else every
        self.counts: Counter = Counter()
        self.t0 = time.monotonic()
        self._last = 0.0

    def update(self, status: str, n: int = 1) -> None:
        self.counts[status] += n
        self.show()

    def line(self) -> str:
        c = self.counts
        done = c["solved"] + c["infeasible"]
        new = done + c["failed"]
        remaining = max(0, self.total - self.already - new)
        el = time.monotonic() - self.t0
        eta = remaining * el / new if new else math.nan
        width = 24
        frac = (self.already + new) / self.total if self.total else 1.0
        bar = "#" * int(round(frac * width))
        eta_s = "?" if not math.isfinite(eta) else (f"{eta / 60:.0f}m{eta % 60:02.0f}s" if eta >= 60
                                                     else f"{eta:.0f}s")
        return (f"[{bar:<{width}}] {self.already + done}/{self.total} done ({c['solved']} solved, "
                f"{c['infeasible']} infeasible, {self.already} stored before), {c['failed']} failed, "
                f"{remaining} remaining, {60 * new / el if el > 0 else 0:.1f} tasks/min, ETA {eta_s}")

    def show(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < self.every:
            return
        self._last = now
        if self.tty:
            self.stream.write("\r" + self.line() + "\x1b[K")
        else:
            self.stream.write(self.line() + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.show(force=True)
            if self.tty:
                self.stream.write("\n")
            self.stream.flush()


# --- executors ----------------------------------------------------------------------------------------
class _SerialRunner:
    """Runs payloads in this process, in submission order (the reference for 'identical')."""

    def __init__(self) -> None:
        self.queue: deque = deque()

    def submit(self, idx: int, payload: TaskPayload) -> None:
        self.queue.append((idx, payload))

    def __bool__(self) -> bool:
        return bool(self.queue)

    def next_done(self) -> tuple[int, Optional[MotionRecord], Optional[BaseException]]:
        idx, payload = self.queue.popleft()
        return idx, solve_task(payload), None

    def close(self) -> None:
        pass


class _DaskRunner:
    """Submits payloads to a Dask cluster; yields results as they complete."""

    def __init__(self, client: Any) -> None:
        from distributed import as_completed

        self.client = client
        self.ac = as_completed([], with_results=False)
        self.idx: dict[Any, int] = {}
        self.pending = 0

    def submit(self, idx: int, payload: TaskPayload) -> None:
        fut = self.client.submit(solve_task, payload, key=f"ff-library-{payload.key}", pure=False)
        self.idx[fut.key] = idx
        self.ac.add(fut)
        self.pending += 1

    def __bool__(self) -> bool:
        return self.pending > 0

    def next_done(self) -> tuple[int, Optional[MotionRecord], Optional[BaseException]]:
        fut = next(self.ac)
        self.pending -= 1
        idx = self.idx.pop(fut.key)
        try:
            rec = fut.result()
            exc = None
        except Exception as e:  # noqa: BLE001 - KilledWorker (task killed its workers), ...
            rec, exc = None, e
        fut.release()
        return idx, rec, exc

    def close(self) -> None:
        pass


def start_local_cluster(workers: Optional[int] = None, *, dashboard: bool = False,
                        silence_logs: int = logging.ERROR) -> tuple[Any, Any]:
    """A LocalCluster on 127.0.0.1 (scheduler, workers; dashboard off or on 127.0.0.1, random port):
    one single-threaded worker process per core by default. Returns (cluster, client)."""
    from distributed import Client, LocalCluster

    n = int(workers) if workers else (os.cpu_count() or 1)
    if n < 1:
        raise BuildError(f"--workers must be >= 1, got {workers}")
    # With the dashboard off the scheduler still serves its small HTTP API (health, metrics): on
    # 127.0.0.1 and a free port, so that parallel builds do not fight over 8787.
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                           scheduler_port=0, dashboard_address="127.0.0.1:0" if dashboard else None,
                           worker_dashboard_address=None, silence_logs=silence_logs,
                           scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    return cluster, Client(cluster)


# --- the build --------------------------------------------------------------------------------------------
@dataclass
class BuildReport:
    """What a build did. Times in s."""

    grid: dict[str, Any]
    library: str
    workers: int                      # 0 = serial (in this process)
    scheduler: str
    stored_before: int                # grid tasks already stored as solved/infeasible
    solved: int = 0                   # this run (grid tasks, shift copies included)
    infeasible: int = 0
    failed: int = 0
    how: dict[str, int] = field(default_factory=dict)    # solved_how counts of this run's distinct solves
    distinct_solved: int = 0          # distinct motions planned this run
    wall_time: float = 0.0
    solve_time: float = 0.0           # sum of the planner's solve times of this run's distinct tasks
    worker_errors: list[str] = field(default_factory=list)

    @property
    def tasks_per_minute(self) -> float:
        """Distinct motions planned per minute of wall time."""
        return 60.0 * self.distinct_solved / self.wall_time if self.wall_time > 0 else 0.0

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["tasks_per_minute"] = self.tasks_per_minute
        return d


def _close(own_client: Any, own_cluster: Any, client: Any) -> None:
    """Close the client and LocalCluster that build_library made (not a client it was given)."""
    if own_client is not None:
        own_client.close()
    if own_cluster is not None:
        client.close()
        own_cluster.close()


def _nearest_solved_ancestor(grid: Grid, i: int, recs: dict[int, MotionRecord]) -> Optional[MotionRecord]:
    p = grid.tasks[i].parent
    while p >= 0:
        r = recs.get(p)
        if r is not None and r.status == "solved" and r.motion:
            return r
        p = grid.tasks[p].parent
    return None


def build_library(grid: Grid | GridSpec | str | os.PathLike, library: str | os.PathLike | MotionLibrary, *,
                  workers: Optional[int] = None, scheduler: str | SchedulerSettings | None = None,
                  client: Any = None, serial: bool = False, continuation: bool = True, roots: int = 1,
                  plan_fn: PlanFn = plan, local_starts: int = 16, progress: bool = True,
                  stream: Optional[TextIO] = None,
                  on_result: Optional[Callable[[int, MotionRecord], None]] = None,
                  connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
                  worker_wait: float = DEFAULT_WORKER_WAIT) -> BuildReport:
    """Solve every task of ``grid`` not yet stored in ``library``; see the module docstring.

    Executor: ``client`` (a distributed.Client) if given; else ``scheduler``, an existing cluster
    (a :class:`~ff_planner.library.cluster.SchedulerSettings` with its TLS files, or an address:
    "tls://HOST:PORT" then needs the settings, "tcp://HOST:PORT" is plain); else ``serial`` (this
    process); else a LocalCluster on 127.0.0.1 with ``workers`` processes (default one per core).
    The grid's own ``scheduler`` keys are not read here (``ff-library build`` reads them). The
    executor is set up before the library file is opened: a scheduler that cannot be reached or
    refuses this client raises ClusterError (a ValueError) and nothing is written; so does one
    that has no worker within ``worker_wait`` s.
    ``continuation=False`` solves every task cold
    (multistart) in grid order (for comparison); ``local_starts`` = single-start solves from the
    neighbour's currents and perturbations of them before falling back to multistart. ``plan_fn``
    is the planner, ``plan(request, progress, initial_currents=...)``: a module-level function, so
    that it pickles by reference to the workers. ``on_result(task_index, record)`` is called
    after each distinct task is stored.
    """
    if not isinstance(grid, Grid):
        spec = grid if isinstance(grid, GridSpec) else load_grid(Path(grid))
        grid = expand(spec)
    if roots != 1:
        continuation_tree(grid, n_roots=int(roots))
    t0 = time.monotonic()

    # the executor first: a refused scheduler leaves no file behind
    own_cluster = own_client = None
    address = "serial"
    if serial and client is None and scheduler is None:
        runner: Any = _SerialRunner()
    else:
        if client is None:
            if scheduler is not None:
                settings = scheduler if isinstance(scheduler, SchedulerSettings) else SchedulerSettings(str(scheduler))
                client = own_client = connect(settings, timeout=connect_timeout)
                address = settings.parsed.url
                try:
                    wait_for_workers(client, address, worker_wait)
                except ClusterError:
                    client.close()
                    raise
            else:
                own_cluster, client = start_local_cluster(workers)
        runner = _DaskRunner(client)
    try:
        lib = library if isinstance(library, MotionLibrary) else MotionLibrary(library)
        try:
            report = _fill(grid, lib, runner, address, client, continuation=continuation, plan_fn=plan_fn,
                           local_starts=local_starts, progress=progress, stream=stream, on_result=on_result)
        finally:
            if not isinstance(library, MotionLibrary):
                lib.close()
    finally:
        runner.close()
        _close(own_client, own_cluster, client)
    report.wall_time = time.monotonic() - t0
    return report


def _fill(grid: Grid, lib: MotionLibrary, runner: Any, address: str, client: Any, *, continuation: bool,
          plan_fn: PlanFn, local_starts: int, progress: bool, stream: Optional[TextIO],
          on_result: Optional[Callable[[int, MotionRecord], None]]) -> BuildReport:
    """The build proper on a ready executor and an open library (see build_library)."""
    params = grid.spec.params

    # what is stored already
    recs: dict[int, MotionRecord] = {}
    stored_before = 0
    for i, t in enumerate(grid.tasks):
        r = lib.get(t.key)
        if r is not None and r.status in DONE:
            stored_before += 1
            if t.rep == i:
                recs[i] = r
    report = BuildReport(grid=describe(grid), library=str(lib.path), workers=0, scheduler=address,
                         stored_before=stored_before)
    if not isinstance(runner, _SerialRunner):
        report.workers = len(client.scheduler_info().get("workers", {}))
        if report.scheduler == "serial":
            report.scheduler = str(client.scheduler.address)
    bar = ProgressBar(len(grid.tasks), stored_before, stream=stream, enabled=progress)

    def put_twins(i: int, rec: MotionRecord) -> None:
        for j in grid.twins.get(i, []):
            tw = grid.tasks[j]
            old = lib.get(tw.key)
            if old is not None and old.status in DONE:
                continue
            lib.put(shift_record(rec, tw), params)
            setattr(report, rec.status, getattr(report, rec.status) + 1)
            bar.update(rec.status)

    order = grid.order() if continuation else list(grid.reps)
    todo = set(i for i in grid.reps if i not in recs)

    def payload(i: int) -> TaskPayload:
        nb = _nearest_solved_ancestor(grid, i, recs) if continuation else None
        return TaskPayload(grid.tasks[i].request, grid.tasks[i].key, nb, plan_fn,
                           local_starts=local_starts)

    def ready(i: int) -> bool:
        if not continuation:
            return True
        p = grid.tasks[i].parent
        return p < 0 or p in recs

    submitted: set[int] = set()
    try:
        for i, r in list(recs.items()):   # resumed: the shift copies of stored tasks are stored too
            put_twins(i, r)
        for i in order:
            if i in todo and ready(i):
                runner.submit(i, payload(i))
                submitted.add(i)
        while runner:
            i, rec, err = runner.next_done()
            t = grid.tasks[i]
            if rec is None:
                msg = f"{type(err).__name__}: {err}"
                report.worker_errors.append(f"{t.key}: {msg}")
                rec = failed_record(t.request, f"worker error (the task was retried): {msg}")
            lib.put(rec, params)
            stored = lib.get(t.key) or rec     # what the store holds (another writer may have won)
            recs[i] = stored
            report.distinct_solved += 1
            report.solve_time += float(rec.solve_time)
            report.how[rec.solved_how] = report.how.get(rec.solved_how, 0) + 1
            setattr(report, stored.status, getattr(report, stored.status) + 1)
            bar.update(stored.status)
            put_twins(i, stored)
            if on_result is not None:
                on_result(i, stored)
            for c in grid.children.get(i, []) if continuation else ():
                if c in todo and c not in submitted:
                    runner.submit(c, payload(c))
                    submitted.add(c)
    finally:
        bar.close()
    return report
