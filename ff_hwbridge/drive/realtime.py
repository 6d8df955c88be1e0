"""Real-time set-up of a timing-critical process, in one place (as ros2_control keeps it in
``realtime_tools``/``realtime_helpers``): scheduling priority, memory lock, CPU affinity, the
interpreter's thread switch interval and the garbage collector's pauses.

Why each one matters to a Python CANopen master (10 ms SYNC is the supported rate; 1 ms is
experimental):

- **SCHED_FIFO** (:func:`use_fifo` for one thread, :func:`fifo_process` for every thread of the
  process and those it starts later): a thread at normal priority that holds the GIL can be
  preempted by any ordinary process while a SCHED_FIFO thread of the same process waits for the
  GIL (priority inversion); with every thread under SCHED_FIFO the GIL holder keeps its CPU.
  Needs CAP_SYS_NICE or an rtprio limit: refused, it warns and the process runs at normal priority.
- **Memory lock** (:func:`lock_memory`, ``mlockall``): no page fault on the timing path.
- **CPU affinity** (:func:`set_affinity`).
- **Switch interval** (:data:`SWITCH_INTERVAL`): the bus receiver and the setpoint thread get the
  GIL back from busy threads within this (Python's default 5 ms is half a SYNC cycle).
- **Garbage collector**: CPython's cyclic collector holds the GIL while it scans; a full collection
  of a process that imported rclpy, numpy and canopen took 12.6 ms (quiet 2-core machine), longer
  than a 10 ms SYNC cycle. :func:`freeze_heap` moves what a process built into the permanent
  generation (``gc.freeze``: a full collection then took 0.02 ms), :func:`hold_full_collections`
  stops the automatic full collections and :class:`IdleCollector` runs them while nothing is due;
  :class:`GcPauses` times every collection for the diagnostics.
- **Stall dump** (:class:`StallDump`): a diagnostic: every thread's stack once a timing thread
  stopped making progress (``faulthandler``'s watchdog thread needs no GIL).

:func:`setup_process` applies what a :class:`RealtimeConfig` asks for, once per process.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import faulthandler
import gc
import logging
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence, TextIO

log = logging.getLogger(__name__)

__all__ = ["FULL_HELD", "SWITCH_INTERVAL", "GcPauses", "IdleCollector", "ProcessTiming", "RealtimeConfig",
           "StallDump", "freeze_heap", "fifo_process", "hold_full_collections", "lock_memory", "pauses",
           "restore_process", "set_affinity", "setup_process", "use_fifo"]

#: s, thread switch interval of a process that plays setpoints
SWITCH_INTERVAL = 0.0002
#: generation-2 threshold that keeps the automatic full collection from ever running
FULL_HELD = 1_000_000
_MCL_CURRENT, _MCL_FUTURE = 1, 2


# --- scheduling --------------------------------------------------------------------------------
def use_fifo(priority: int, who: str, tid: int = 0, hint: str = "") -> bool:
    """SCHED_FIFO at ``priority`` for thread ``tid`` (0 = the calling thread); True when granted,
    else a logged warning naming ``who`` (and ``hint``) and False."""
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(priority)))
        return True
    except (AttributeError, OSError) as exc:
        log.warning("%s: cannot use SCHED_FIFO priority %d (%s); running at normal priority%s",
                    who, priority, exc, hint)
        return False


def fifo_process(priority: int, who: str) -> int:
    """SCHED_FIFO at ``priority`` for every thread of this process now (``/proc/self/task``), and
    so for every thread they start; returns how many threads got it (0 with a logged warning when
    not permitted)."""
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    done = 0
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(priority)))
            done += 1
        except ProcessLookupError:
            continue                    # the thread ended meanwhile
        except (AttributeError, OSError) as exc:
            log.warning("%s: cannot use SCHED_FIFO priority %d for its threads (%s); they run at "
                        "normal priority", who, priority, exc)
            return 0
    return done


def set_affinity(cpus: Sequence[int], who: str) -> bool:
    """Pin this process (its threads and those started later) to ``cpus``; False with a warning
    when refused."""
    try:
        os.sched_setaffinity(0, set(int(c) for c in cpus))
        return True
    except (AttributeError, OSError, ValueError) as exc:
        log.warning("%s: cannot pin to CPUs %s (%s)", who, list(cpus), exc)
        return False


def lock_memory(who: str) -> bool:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page faults later; False with a warning when
    refused (needs CAP_IPC_LOCK or a memlock limit)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:
            return True
        err = ctypes.get_errno()
        reason = os.strerror(err)
    except (OSError, AttributeError) as exc:
        reason = str(exc)
    log.warning("%s: cannot lock its memory (%s); page faults may delay it", who, reason)
    return False


# --- the garbage collector ---------------------------------------------------------------------
def freeze_heap() -> int:
    """Collect once and freeze what survives (``gc.freeze``); returns the frozen object count.
    Costs one full collection (~10 ms): call it before timing matters."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def hold_full_collections() -> tuple[int, int, int]:
    """No automatic full (generation 2) collection from now on; returns the thresholds before.
    The process must then collect in full itself when timing does not matter (:class:`IdleCollector`)."""
    before = gc.get_threshold()
    gc.set_threshold(before[0], before[1], FULL_HELD)
    return before


class IdleCollector:
    """A full collection when ``idle()`` has held for ``idle_s`` s, at most every ``every_s`` s:
    ``tick()`` from a periodic timer of the owner. Returns the pause (ms) when it collected."""

    def __init__(self, idle: Callable[[], bool], idle_s: float = 1.0, every_s: float = 10.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._idle, self.idle_s, self.every_s, self._clock = idle, float(idle_s), float(every_s), clock
        self._idle_since: Optional[float] = None
        self._last = -math.inf
        self.collections = 0

    def tick(self) -> Optional[float]:
        now = self._clock()
        if not self._idle():
            self._idle_since = None
            return None
        if self._idle_since is None:
            self._idle_since = now
        if now - self._idle_since < self.idle_s or now - self._last < self.every_s:
            return None
        t0 = time.perf_counter()
        gc.collect()
        self._last = now
        self.collections += 1
        return (time.perf_counter() - t0) * 1e3


@dataclass
class GcPauses:
    """Durations of the collector's passes in this process (ms), per generation."""

    count: list[int] = field(default_factory=lambda: [0, 0, 0])
    max_ms: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    total_ms: float = 0.0
    _t0: Optional[float] = None
    _installed: bool = False
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def install(self) -> "GcPauses":
        """Start timing collections (idempotent)."""
        with self._lock:
            if not self._installed:
                gc.callbacks.append(self._callback)
                self._installed = True
        return self

    def uninstall(self) -> None:
        with self._lock:
            if self._installed:
                gc.callbacks.remove(self._callback)
                self._installed = False

    def _callback(self, phase: str, info: dict[str, Any]) -> None:
        # runs in the collecting thread with the GIL held: no lock, no allocation beyond floats
        if phase == "start":
            self._t0 = time.perf_counter()
        elif self._t0 is not None:
            ms = (time.perf_counter() - self._t0) * 1e3
            self._t0 = None
            g = int(info.get("generation", 2))
            self.count[g] += 1
            self.total_ms += ms
            if ms > self.max_ms[g]:
                self.max_ms[g] = ms

    def as_dict(self, prefix: str = "gc.") -> dict[str, object]:
        """``gc.collections`` / ``gc.max_pause_ms`` (per generation), ``gc.frozen``, ``gc.full_held``."""
        return {f"{prefix}collections": "/".join(str(c) for c in self.count),
                f"{prefix}max_pause_ms": "/".join(f"{m:.2f}" for m in self.max_ms),
                f"{prefix}frozen": gc.get_freeze_count(),
                f"{prefix}full_held": gc.get_threshold()[2] >= FULL_HELD}


#: this process's pause record (installed by whoever needs it: ``pauses.install()``)
pauses = GcPauses()


# --- a diagnostic ------------------------------------------------------------------------------
class StallDump:
    """``arm()`` from the watched thread on every pass: when ``seconds`` pass without another
    ``arm()`` (or a ``disarm()``), every thread's stack goes to ``file`` (stderr) once. Re-arming
    costs ~30 µs: a pass re-arms at most every ``rearm_every`` s. 0 s: off. One per process
    (``faulthandler.dump_traceback_later``)."""

    def __init__(self, seconds: float, rearm_every: float = 0.02, file: TextIO | None = None) -> None:
        if not 0.0 <= seconds <= 3600.0:
            raise ValueError(f"stall dump must be 0 .. 3600 s, got {seconds!r}")
        self.seconds = float(seconds)
        self._every_ns = int(rearm_every * 1e9)
        self._file = file
        self._armed_ns = 0

    @property
    def on(self) -> bool:
        return self.seconds > 0.0

    def arm(self, mono_ns: int | None = None) -> None:
        """The watched thread made progress (``mono_ns``: ``time.monotonic_ns()``, read if None)."""
        if not self.on:
            return
        now = time.monotonic_ns() if mono_ns is None else mono_ns
        if now - self._armed_ns >= self._every_ns:
            self._armed_ns = now
            faulthandler.dump_traceback_later(self.seconds + self._every_ns / 1e9, repeat=False,
                                              file=self._file or sys.stderr)

    def disarm(self) -> None:
        """Nothing to keep time for (idle): no dump until the next ``arm()``."""
        if self._armed_ns:
            faulthandler.cancel_dump_traceback_later()
            self._armed_ns = 0


# --- the one set-up ----------------------------------------------------------------------------
@dataclass(frozen=True)
class RealtimeConfig:
    """What :func:`setup_process` does: ``priority`` 1..99 SCHED_FIFO for every thread (0: none),
    ``switch_interval`` s at most (lowered to it, never raised; 0: unchanged), ``lock_memory``,
    ``cpus`` (empty: unchanged),
    ``freeze_gc`` (freeze the heap and hold the automatic full collections),
    ``time_gc`` (time every collection from now on: :data:`pauses`, for the diagnostics)."""

    priority: int = 0
    switch_interval: float = SWITCH_INTERVAL
    lock_memory: bool = False
    cpus: tuple[int, ...] = ()
    freeze_gc: bool = False
    time_gc: bool = False


@dataclass(frozen=True)
class ProcessTiming:
    """Scheduling policy and priority of every thread of this process and its switch interval,
    as they were (``now()``), for :func:`restore_process` (a CLI called in a longer-lived process)."""

    policies: dict[int, tuple[int, int]]
    switch_interval: float

    @classmethod
    def now(cls) -> "ProcessTiming":
        out: dict[int, tuple[int, int]] = {}
        try:
            tids = [int(t) for t in os.listdir("/proc/self/task")]
        except OSError:
            tids = []
        for tid in tids:
            try:
                out[tid] = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
            except OSError:
                continue
        return cls(out, sys.getswitchinterval())


def restore_process(saved: ProcessTiming) -> None:
    """Put the threads that still run and the switch interval back as ``saved``."""
    sys.setswitchinterval(saved.switch_interval)
    for tid, (policy, prio) in saved.policies.items():
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(prio))
        except OSError:
            continue


def setup_process(config: RealtimeConfig, who: str) -> dict[str, object]:
    """Apply ``config`` to this process; returns what was granted (for the log / diagnostics).
    Whatever is refused is logged as a warning and the process goes on without it."""
    out: dict[str, object] = {}
    if 0 < config.switch_interval < sys.getswitchinterval():
        sys.setswitchinterval(config.switch_interval)
    if config.switch_interval > 0:
        out["switch_interval"] = sys.getswitchinterval()
    if config.cpus:
        out["affinity"] = set_affinity(config.cpus, who)
    if config.lock_memory:
        out["memory_locked"] = lock_memory(who)
    if config.time_gc:
        pauses.install()
        out["gc_timed"] = True
    if config.freeze_gc:
        out["frozen"] = freeze_heap()
        hold_full_collections()
    if config.priority > 0:
        out["fifo_threads"] = fifo_process(config.priority, who)
    return out
