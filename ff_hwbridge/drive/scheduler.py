"""Apply stamped setpoints at their stamp time, from a dedicated thread, and record the timing.

The thread sleeps until ``spin_margin`` s before the earliest due stamp, runs the optional
``prepare(payload)`` (work that need not wait: safety clamp, unit conversion), then spins on the
clock (yielding the GIL while more than 50 µs remain) until the stamp and calls
``apply(stamp_ns, payload)`` (which sends the RPDO). After it returns, ``(stamp_ns, sent_ns)`` is
recorded for switch-time statistics. Stamps are integer ns on ``clock_ns`` (default
``time.time_ns``, the ROS system clock). :class:`~ff_hwbridge.drive.player.SetpointPlayer` runs
the drives' setpoints on it.

``rt_priority`` > 0 asks Linux for SCHED_FIFO at that priority for the scheduler thread (a
real-time kernel and CAP_SYS_NICE make the timing hold under load; without permission it warns
and runs normally).

A setpoint whose stamp already passed is applied at once (counted ``late``); one whose stamp is
older than the last applied stamp is dropped (``stale``: it would undo a newer command) unless it
is a stop (``submit(..., stop=True)``, zero current): a stop is never dropped, it is applied at
once (counted ``stale_stops``). A payload that fails to prepare or to apply calls
``on_error(reason)`` (the player latches the safe state with it) besides the log.
"""
from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Self

import numpy as np

from ff_hwbridge.drive.realtime import fifo_process, use_fifo

log = logging.getLogger(__name__)

__all__ = ["StampScheduler", "StampedItem", "StampedQueue", "SwitchStats", "fifo_process", "use_fifo"]


@dataclass(order=True)
class StampedItem:
    """A queued payload: ordered by stamp (ns), then by submission order."""

    stamp_ns: int
    order: int
    payload: Any = field(compare=False)
    stop: bool = field(default=False, compare=False)
    queued_ns: int = field(default=0, compare=False)   # wall ns: when it was submitted


class StampedQueue:
    """What both schedulers share: a heap of stamped payloads guarded by one condition, and the
    thread (``_run``, the subclass's) that serves it, optionally under SCHED_FIFO."""

    #: names the thread in the warning when SCHED_FIFO is refused
    _rt_who = "scheduler"

    def __init__(self, name: str, rt_priority: int, cond: Optional[threading.Condition] = None) -> None:
        self._heap: list[StampedItem] = []
        self._counter = itertools.count()
        self._cond = cond if cond is not None else threading.Condition()
        self._stop = False
        self._thread: Optional[threading.Thread] = None
        self._name = name
        self.rt_priority = int(rt_priority)
        self.rt_active = False

    def start(self) -> Self:
        """Start the thread (idempotent)."""
        if self._thread is None or not self._thread.is_alive():
            self._stop = False
            self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread (waiting up to ``timeout`` s); pending setpoints are dropped."""
        with self._cond:
            self._stop = True
            self._drop_queued()
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def submit(self, stamp_ns: int, payload: Any, stop: bool = False) -> None:
        """Queue ``payload`` for ``stamp_ns``; ``stop``: a stop (zero current), never dropped as
        stale."""
        with self._cond:
            heapq.heappush(self._heap, StampedItem(int(stamp_ns), next(self._counter), payload, bool(stop),
                                                  time.time_ns()))
            self._cond.notify_all()

    def clear(self) -> int:
        """Drop every pending setpoint (safe state); returns how many were not yet sent."""
        with self._cond:
            n = len(self._heap)
            self._drop_queued()
            self._cond.notify_all()
            return n

    @property
    def pending(self) -> int:
        """Setpoints queued and not yet sent."""
        return len(self._heap)

    def _drop_queued(self) -> None:
        """Forget the queued setpoints (called with the condition held)."""
        self._heap.clear()

    def _set_rt_priority(self) -> None:
        """Linux: SCHED_FIFO for the calling thread (needs CAP_SYS_NICE / an rtprio limit); else
        a warning."""
        if self.rt_priority > 0:
            self.rt_active = use_fifo(self.rt_priority, self._rt_who)

    def _run(self) -> None:
        raise NotImplementedError


@dataclass(frozen=True)
class SwitchStats:
    """Switch-time error = sent − stamp (µs) over the recorded setpoints."""

    count: int
    late: int
    stale: int
    p50_us: float
    p99_us: float
    max_us: float
    min_us: float

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("count", "late", "stale", "p50_us", "p99_us",
                                              "max_us", "min_us")}


class StampScheduler(StampedQueue):
    """A thread that applies payloads at their stamps (ns)."""

    def __init__(self, apply: Callable[[int, Any], None], clock_ns: Callable[[], int] = time.time_ns,
                 spin_margin: float = 0.0003, max_records: int = 200_000,
                 late_threshold: float = 0.0005, name: str = "ff-stamp-scheduler",
                 rt_priority: int = 0, prepare: Optional[Callable[[Any], Any]] = None,
                 on_error: Callable[[str], object] = lambda reason: None) -> None:
        if not 0.0 <= spin_margin < 0.05:
            raise ValueError(f"spin_margin must be in [0, 0.05) s, got {spin_margin!r}")
        super().__init__(name, rt_priority)
        self._apply = apply
        self._prepare = prepare
        self._on_error = on_error
        self._clock_ns = clock_ns
        self._margin_ns = int(spin_margin * 1e9)
        self._late_ns = int(late_threshold * 1e9)
        self._last_applied: Optional[int] = None
        self.records: deque[tuple[int, int]] = deque(maxlen=max_records)
        self.late = 0
        self.stale = 0
        self.stale_stops = 0
        self.errors = 0

    # --- control ------------------------------------------------------------------------------
    def next_stamp(self) -> Optional[int]:
        with self._cond:
            return self._heap[0].stamp_ns if self._heap else None

    def reset_stats(self) -> None:
        self.records.clear()
        self.late = self.stale = self.stale_stops = 0

    def stats(self) -> SwitchStats:
        """p50 / p99 / max of sent − stamp (µs) over the recorded setpoints."""
        recs = self.records.copy()        # one C-level copy: the thread appends meanwhile
        if not recs:
            return SwitchStats(0, self.late, self.stale, float("nan"), float("nan"),
                               float("nan"), float("nan"))
        err = np.array([s - t for t, s in recs], dtype=float) / 1000.0
        return SwitchStats(int(err.size), self.late, self.stale, float(np.percentile(err, 50)),
                           float(np.percentile(err, 99)), float(err.max()), float(err.min()))

    # --- the thread ---------------------------------------------------------------------------
    def _run(self) -> None:
        self._set_rt_priority()
        while True:
            with self._cond:
                while not self._stop:
                    if not self._heap:
                        self._cond.wait(0.1)
                        continue
                    wait_ns = self._heap[0].stamp_ns - self._clock_ns() - self._margin_ns
                    if wait_ns <= 0:
                        break
                    self._cond.wait(min(wait_ns / 1e9, 0.1))
                if self._stop:
                    return
                item = heapq.heappop(self._heap)
            if self._last_applied is not None and item.stamp_ns < self._last_applied:
                if not item.stop:
                    self.stale += 1
                    continue
                self.stale_stops += 1            # a stop is applied at once, never dropped
            payload = item.payload
            if self._prepare is not None:        # the work that need not wait for the stamp
                try:
                    payload = self._prepare(payload)
                except Exception as exc:  # noqa: BLE001
                    self._failed("preparing", item, exc)
                    continue
            # spin; while more than ~50 µs remain, yield the GIL so that the bus receiver and
            # the SYNC thread of this process are not starved by the spin
            while True:
                left = item.stamp_ns - self._clock_ns()
                if left <= 0:
                    break
                if left > 50_000:
                    time.sleep(0)
            start = self._clock_ns()
            if start - item.stamp_ns > self._late_ns:
                self.late += 1
            try:
                self._apply(item.stamp_ns, payload)
            except Exception as exc:  # noqa: BLE001 - the thread must survive a failing send
                self._failed("applying", item, exc)
                continue
            sent = self._clock_ns()
            self._last_applied = max(item.stamp_ns, self._last_applied or item.stamp_ns)
            self.records.append((item.stamp_ns, sent))

    def _failed(self, what: str, item: StampedItem, exc: BaseException) -> None:
        """A payload could not be prepared / applied: logged, counted, ``on_error(reason)``."""
        self.errors += 1
        log.exception("%s a setpoint failed", what)
        reason = (f"setpoint player: {what} the setpoint stamped {item.stamp_ns} ns failed "
                  f"({type(exc).__name__}: {exc})")
        try:
            self._on_error(reason)
        except Exception:  # noqa: BLE001 - the thread must survive a failing reaction
            log.exception("reacting to a failed setpoint failed")
