"""Stamped setpoints onto the SYNC grid: each one sent during the cycle before the SYNC it takes
effect at, and its applied instant taken from that SYNC's bus timestamp.

With synchronous RPDOs (transmission type 1, CiA 301) a drive latches the latest received
setpoint at each SYNC. :class:`CycleScheduler` therefore

1. assigns each stamped setpoint to the first SYNC at or after its stamp (``stamp − tolerance``,
   the tolerance absorbing float rounding; the grid is predicted from the latest SYNC seen,
   corrected for its lateness: ``SyncWatch.grid``, nominal + k · period);
2. sends it (``send(stamp, payload) -> (marks, token)``, marks: per joint the RPDO count
   including this one, None without an echo) as soon as the SYNC before that one has been seen,
   or, when that SYNC's frame is late here (or several frames before it are: a bus receiver
   that stalled), ``SEND_MARGIN`` of a period after its predicted instant on the grid (a SYNC
   timer keeps time, the frames' path to this process may not); i.e. up to one whole period
   early, so that the sender may be late by most of a cycle without any error
   (``clock_opens=False``: only the SYNC seen opens it, for SYNC frames whose lateness here is
   lateness on the bus, or that are seen by a proxy that follows them). A setpoint that a SYNC
   before its own latched (that SYNC came later than the margin) calls ``on_fault(reason)``;
3. resolves it at the first SYNC stamped at or after the RPDO's own bus instant (from the
   bus's echo of our own frames, ``echo_time(marks)``; without an echo the local send time):
   applied = that SYNC's bus instant, missed cycles = how many SYNCs after its own cycle that
   was (counted in SYNCs seen, so SYNC jitter does not count). A setpoint that misses by more
   than ``missed_tolerance`` cycles calls ``on_fault(reason)``; a stop (zero current, e.g. a
   cancel's zero stamped when the cancel came) is counted (``late_stops``) and logged instead:
   it has no planned cycle, and the safe state would only send the same zero.

A setpoint older than one already sent is dropped (``stale``: it would undo a newer command),
unless it is a stop (``submit(..., stop=True)``, zero current): a stop is never dropped, it is
sent at once (counted ``stale_stops``). A setpoint that is due (``clock_ns()`` past its stamp)
while no SYNC has been seen cannot be placed on the grid: ``on_fault(reason)``. A payload that
fails to prepare or to send, or a pass of the thread that raises, calls ``on_fault(reason)``
too, besides the log: the player latches the safe state with the reason.

Records are (stamp ns, applied SYNC instant ns); the switch error is applied − stamp.
"""
from __future__ import annotations

import heapq
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np

from ff_hwbridge.drive.ring import FloatRing
from ff_hwbridge.drive.scheduler import StampedItem, StampedQueue, SwitchStats
from ff_hwbridge.drive.realtime import StallDump
from ff_hwbridge.drive.sync_watch import SyncEvent, SyncWatch

log = logging.getLogger(__name__)

#: fraction of a period: a setpoint is sent at the latest this long after the predicted instant
#: of the SYNC before its own, seen or not
SEND_MARGIN = 0.2

__all__ = ["CycleScheduler", "CycleStats", "Resolved"]


@dataclass
class _InFlight:
    stamp_ns: int
    target_ns: int            # predicted nominal instant of the SYNC it was meant for
    target_count: int         # number of that SYNC (SyncEvent.count)
    seen_count: int           # latest SYNC seen before the send
    marks: Optional[tuple[int, ...]]
    sent_wall_ns: int
    lead_ns: int              # sent − bus instant of the SYNC seen before it
    token: Any
    stop: bool = False        # a zero-current stop (no cycle of its own to keep)
    picked_wall_ns: int = 0   # when the thread took it from the queue
    send_ns: int = 0          # how long preparing and sending took
    queued_wall_ns: int = 0   # when it was submitted


@dataclass(frozen=True)
class Resolved:
    """A setpoint latched by the drives: stamp, SYNC instant it took effect at (bus, wall ns),
    RPDO's bus instant (wall ns: its echo's stamp, the one the drive latched it by; without an
    echo when its send returned), SYNC cycles after its own (0 = on time), the sender's token, and
    whether it was a stop."""

    stamp_ns: int
    applied_ns: int
    sent_ns: int
    missed_cycles: int
    token: Any
    stop: bool = False
    early_cycles: int = 0     # SYNC cycles before its own (sent by the clock, its SYNC late)
    picked_ns: int = 0        # wall ns: when the thread took it from the queue to send it
    send_took_ns: int = 0     # ns: preparing and sending it
    queued_ns: int = 0        # wall ns: when it was submitted (0: unknown)


@dataclass(frozen=True)
class CycleStats:
    """Missed setpoints (took effect at least one SYNC late), the worst miss (cycles), setpoints
    superseded within one cycle, and the send lead after the SYNC before (µs: p50/p99/max)."""

    missed: int
    missed_max_cycles: int
    superseded: int
    send_after_sync_p50_us: float
    send_after_sync_p99_us: float
    send_after_sync_max_us: float


class CycleScheduler(StampedQueue):
    """A thread that puts stamped payloads on the SYNC grid (see the module docstring)."""

    _rt_who = "cycle scheduler"

    def __init__(self, watch: SyncWatch,
                 send: Callable[..., tuple[Optional[tuple[int, ...]], Any]],
                 report: Callable[[Resolved], None], *,
                 echo_time: Callable[[tuple[int, ...]], Optional[int]] = lambda marks: None,
                 prepare: Optional[Callable[[Any], Any]] = None,
                 on_fault: Callable[[str], object] = lambda reason: None,
                 tolerance: float = 0.1, missed_tolerance: int = 1, rt_priority: int = 0,
                 max_records: int = 200_000, name: str = "ff-cycle-scheduler",
                 clock_ns: Callable[[], int] = time.time_ns, clock_opens: bool = True,
                 stall_dump: float = 0.0) -> None:
        super().__init__(name, rt_priority, threading.Condition(threading.RLock()))
        # s: this thread away that long while setpoints are pending dumps every thread's stack
        # (what held it: the GIL's holder, a lock); 0 = off. One per process (faulthandler).
        self._stall = StallDump(stall_dump)
        self.watch = watch
        self._send, self._report, self._prepare = send, report, prepare
        self._echo_time = echo_time
        self._on_fault = on_fault
        self._clock_ns = clock_ns
        self.period_ns = watch.period_ns
        self._tol_ns = int(tolerance * self.period_ns)
        self._margin_ns = int(SEND_MARGIN * self.period_ns)
        self.clock_opens = bool(clock_opens)
        self.missed_tolerance = int(missed_tolerance)
        self._inflight: deque[_InFlight] = deque()
        self._last_stamp: Optional[int] = None
        self.records: deque[tuple[int, int]] = deque(maxlen=max_records)
        # the statistics' samples in rings (µs): read without a copy of the records in Python
        self._err = FloatRing(max_records)
        self._leads = FloatRing(max_records)
        self.late = self.stale = self.stale_stops = self.errors = 0
        self.missed = self.missed_max = self.superseded = self.late_stops = 0
        self._last_applied_ns: Optional[int] = None
        watch.add_listener(self._on_sync)

    # --- control ------------------------------------------------------------------------------
    # start / stop / submit (for the SYNC at or after the stamp) / clear: StampedQueue's; clear
    # and stop also forget the setpoints on the bus waiting for their SYNC (a safe state's zero
    # current follows them)
    def close(self) -> None:
        self.stop()
        self.watch.remove_listener(self._on_sync)

    @property
    def pending(self) -> int:
        """Setpoints queued or sent and waiting for their SYNC."""
        return len(self._heap) + len(self._inflight)

    def _drop_queued(self) -> None:
        self._heap.clear()
        self._inflight.clear()

    def reset_stats(self) -> None:
        self.records.clear()
        self._err.clear()
        self._leads.clear()
        self.late = self.stale = self.stale_stops = self.missed = self.missed_max = self.superseded = 0
        self.late_stops = 0

    def grid(self) -> Optional[tuple[int, int]]:
        """(nominal instant of the latest SYNC, period) in ns; None before the first SYNC."""
        g = self.watch.grid()
        return None if g is None else (g[1], self.period_ns)

    def stats(self) -> SwitchStats:
        """Switch error = SYNC instant − stamp (µs); ``late`` = missed setpoints."""
        err = self._err.values()
        if not err.size:
            nan = float("nan")
            return SwitchStats(0, self.missed, self.stale, nan, nan, nan, nan)
        return SwitchStats(int(err.size), self.missed, self.stale, float(np.percentile(err, 50)),
                           float(np.percentile(err, 99)), float(err.max()), float(err.min()))

    def cycle_stats(self) -> CycleStats:
        leads = self._leads.values()
        if leads.size == 0:
            leads = np.array([float("nan")])
        return CycleStats(self.missed, self.missed_max, self.superseded,
                          float(np.percentile(leads, 50)), float(np.percentile(leads, 99)),
                          float(np.max(leads)))

    # --- the thread ---------------------------------------------------------------------------
    def _on_sync(self, ev: SyncEvent) -> None:
        with self._cond:
            self._cond.notify_all()

    def _cycles_ahead(self, stamp_ns: int, nominal_ns: int) -> int:
        """k: the stamp's SYNC is the k-th after the one at ``nominal_ns`` (<= 0: passed)."""
        return math.ceil((stamp_ns - self._tol_ns - nominal_ns) / self.period_ns)

    def _run(self) -> None:
        self._set_rt_priority()
        while not self._stop:
            try:
                if self._cycle():
                    return
            except Exception as exc:  # noqa: BLE001 - the thread must survive whatever one cycle does
                self._failed("a pass of the setpoint cycle", None, exc)
                time.sleep(0.001)

    def _failed(self, what: str, item: Optional[StampedItem], exc: BaseException) -> None:
        """Logged, counted and ``on_fault(reason)``: what failed cannot be trusted on the bus."""
        self.errors += 1
        log.exception("%s failed", what)
        stamp = f" (setpoint stamped {item.stamp_ns} ns)" if item is not None else ""
        self._fault(f"setpoint cycle: {what} failed{stamp}: {type(exc).__name__}: {exc}")

    def _fault(self, reason: str) -> None:
        try:
            self._on_fault(reason)
        except Exception:  # noqa: BLE001 - the thread must survive a failing reaction
            log.exception("reacting to a setpoint cycle fault failed")

    def _cycle(self) -> bool:
        """One pass: resolve what its SYNC has latched, send what is due; True when stopped."""
        done: list[Resolved] = []
        g: Optional[tuple[SyncEvent, int]] = None
        picked = 0
        with self._cond:
            item: Optional[StampedItem] = None
            while not self._stop:
                if self._heap or self._inflight:
                    self._stall.arm()
                else:
                    self._stall.disarm()
                done += self._resolve()
                if done:
                    break
                g = self.watch.grid()
                wait = 0.05 if g is not None else 0.005
                if self._heap and g is not None:
                    k = self._cycles_ahead(self._heap[0].stamp_ns, g[1])
                    # its window opens with the SYNC before its own: seen (k <= 1), or by the
                    # grid's clock SEND_MARGIN after that SYNC's predicted instant when its
                    # frame (and any number before it) is late here: a SYNC timer keeps time,
                    # the frames' way to this process may not
                    opens = g[1] + (k - 1) * self.period_ns + self._margin_ns
                    now = self._clock_ns()
                    if k <= 1 or (self.clock_opens and now >= opens):
                        item = heapq.heappop(self._heap)
                        picked = time.time_ns()
                        break
                    if self.clock_opens:
                        wait = min(wait, max((opens - now) / 1e9, 0.0002))
                elif self._heap and self._heap[0].stamp_ns <= self._clock_ns():
                    item = heapq.heappop(self._heap)         # due, and no SYNC to place it on
                    break
                self._cond.wait(wait)
            if self._stop:
                self._stall.disarm()
                return True
        for r in done:
            self._deliver(r)
        if item is not None:
            if g is not None:
                self._send_item(item, *g, picked)
            else:
                self._unplaceable(item)
        return False

    def _unplaceable(self, item: StampedItem) -> None:
        """A setpoint due while no SYNC has been seen: no drive latches it; a stop is sent
        all the same, and the safe state is called for with the reason."""
        if item.stop:
            try:
                payload = self._prepare(item.payload) if self._prepare is not None else item.payload
                self._send(item.stamp_ns, payload)
            except Exception:  # noqa: BLE001
                self.errors += 1
                log.exception("sending a stop without SYNC failed")
        self._fault(f"setpoint stamped {item.stamp_ns} ns ({'stop' if item.stop else 'current'}) "
                    f"is due but no SYNC has been seen: it cannot be placed on the SYNC grid "
                    f"({self.period_ns / 1e6:g} ms)")

    def _send_item(self, item: StampedItem, ev: SyncEvent, nominal_ns: int, picked_ns: int = 0) -> None:
        stale = self._last_stamp is not None and item.stamp_ns < self._last_stamp
        if stale:
            if not item.stop:
                self.stale += 1
                return
            self.stale_stops += 1          # a stop is sent at once, never dropped
        k = self._cycles_ahead(item.stamp_ns, nominal_ns)
        target = nominal_ns + k * self.period_ns
        payload = item.payload
        t0 = time.time_ns()
        try:
            if self._prepare is not None:
                payload = self._prepare(payload)
            seen = self.watch.latest()
            marks, token = self._send(item.stamp_ns, payload)
        except Exception as exc:  # noqa: BLE001 - the thread must survive a failing send
            self._failed("preparing / sending a setpoint", item, exc)
            return
        sent = time.time_ns()
        self._last_stamp = max(item.stamp_ns, self._last_stamp or item.stamp_ns)
        seen_count = seen.count if seen is not None else ev.count
        lead = sent - (seen.bus_ns if seen is not None else ev.bus_ns)
        with self._cond:
            self._inflight.append(_InFlight(item.stamp_ns, target, ev.count + k, seen_count, marks,
                                            sent, lead, token, bool(item.stop),
                                            picked_ns or t0, sent - t0, item.queued_ns))
            self._cond.notify_all()

    def _resolve(self) -> list[Resolved]:
        """In-flight setpoints whose SYNC has come (caller holds the lock)."""
        out: list[Resolved] = []
        while self._inflight:
            f = self._inflight[0]
            later = self.watch.since(f.seen_count)
            # the RPDO's own bus instant from its echo (a drive latches it at the first SYNC
            # stamped at or after it); without an echo (or one lost for 3 cycles) the send time
            t_bus = self._echo_time(f.marks) if f.marks is not None else None
            if t_bus is None and f.marks is not None and len(later) < 3:
                break                              # its echo is still on the way
            if t_bus is None:
                t_bus = f.sent_wall_ns
            hit = next((e for e in later if e.bus_ns >= t_bus), None)
            if hit is None:
                break
            self._inflight.popleft()
            missed = max(0, hit.count - f.target_count)
            early = max(0, f.target_count - hit.count)
            self._leads.append(f.lead_ns / 1000.0)
            if self._last_applied_ns == hit.bus_ns:
                self.superseded += 1
            self._last_applied_ns = hit.bus_ns
            out.append(Resolved(f.stamp_ns, hit.bus_ns, t_bus, missed, f.token, f.stop, early,
                                f.picked_wall_ns, f.send_ns, f.queued_wall_ns))
        return out

    def _deliver(self, r: Resolved) -> None:
        self.records.append((r.stamp_ns, r.applied_ns))
        self._err.append((r.applied_ns - r.stamp_ns) / 1000.0)
        if r.missed_cycles:
            self.missed += 1
            self.missed_max = max(self.missed_max, r.missed_cycles)
        try:
            self._report(r)
        except Exception:  # noqa: BLE001
            log.exception("reporting a setpoint failed")
        if r.early_cycles and not r.stop:
            self._fault(f"setpoint took effect {r.early_cycles} SYNC cycle(s) early: the SYNC "
                        f"before its own came more than {SEND_MARGIN:.0%} of a period after its "
                        f"predicted instant; stamp {r.stamp_ns} ns")
        elif r.missed_cycles > self.missed_tolerance and r.stop:
            # a zero-current stop (a cancel's zero stamped "now"): it has no cycle to keep, and
            # what it asks for is what the safe state would do; counted and logged, not a fault
            self.late_stops += 1
            log.warning("a stop took effect %d SYNC cycle(s) after its stamp's", r.missed_cycles)
        elif r.missed_cycles > self.missed_tolerance:
            # queued late: its sender or this process's intake was held up; taken late with
            # time to spare: this thread was
            queued = f"queued {(r.queued_ns - r.stamp_ns) / 1e3:+.0f} µs, " if r.queued_ns else ""
            self._fault(f"setpoint missed its SYNC cycle: took effect {r.missed_cycles} "
                            f"cycle(s) of {self.period_ns / 1e6:g} ms late (missed_cycle_tolerance "
                            f"{self.missed_tolerance}); stamp {r.stamp_ns} ns, sent "
                            f"{(r.sent_ns - r.stamp_ns) / 1e3:+.0f} µs from it ({queued}taken from "
                            f"the queue {(r.picked_ns - r.stamp_ns) / 1e3:+.0f} µs, preparing and "
                            f"sending took {r.send_took_ns / 1e3:.0f} µs)")
