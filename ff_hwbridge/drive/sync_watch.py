"""What the master sees of the SYNC (CiA 301, COB-ID 0x80, 0x1005/0x1006): when each one was on
the bus, its period and jitter, and whether it stopped.

:class:`SyncWatch` is fed by the bus receiver (``observe(bus_ts_s, echoes)``) with each SYNC
frame's BUS timestamp (the kernel's on SocketCAN, the hub's on the simulation hub; both wall
clock s) and, per joint, how many of the master's own setpoint RPDOs the bus had echoed back
before it (a diagnostic; which SYNC latched an RPDO is decided on the bus timestamps, the RPDO's
echo against the SYNC's, as a drive orders them: ``EposMaster.echo_time``).

Statistics: interval jitter = (t_k − t_{k−1}) − period (µs); a gap of more than 1.5 periods counts
the SYNCs that are missing in it.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from ff_hwbridge.drive.ring import FloatRing

__all__ = ["SyncEvent", "SyncStats", "SyncWatch"]


@dataclass(frozen=True)
class SyncEvent:
    """One SYNC: running count (1 = first seen), bus instant (wall ns), local arrival
    (``time.monotonic_ns``), echoed setpoint RPDOs per joint before it (None: no echo)."""

    count: int
    bus_ns: int
    local_ns: int
    echoes: Optional[tuple[int, ...]]


@dataclass(frozen=True)
class SyncStats:
    """SYNC seen so far: count, mean period (µs, gaps left out), interval jitter |Δt − period| p50/p99/max (µs),
    SYNCs missing in gaps, age of the latest (ms, -1 before the first)."""

    count: int
    period_us: float
    jitter_p50_us: float
    jitter_p99_us: float
    jitter_max_us: float
    missing: int
    age_ms: float

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("count", "period_us", "jitter_p50_us", "jitter_p99_us",
                                              "jitter_max_us", "missing", "age_ms")}


class SyncWatch:
    """SYNC arrivals of one bus (see the module docstring); thread-safe."""

    def __init__(self, period_s: float, history: int = 256, max_intervals: int = 100_000,
                 mono_ns: Callable[[], int] = time.monotonic_ns) -> None:
        self.period_ns = int(round(period_s * 1e9))
        self._mono_ns = mono_ns
        self._lock = threading.Lock()
        self._events: deque[SyncEvent] = deque(maxlen=history)
        self._intervals = FloatRing(max_intervals)     # ns between SYNCs
        self._listeners: list[Callable[[SyncEvent], None]] = []
        self.count = 0
        self.missing = 0
        self._grid: Optional[tuple[int, int, SyncEvent, int]] = None   # (count, window, ev, nominal)

    def add_listener(self, fn: Callable[[SyncEvent], None]) -> None:
        """Call ``fn(event)`` on the receiver's thread after every SYNC."""
        self._listeners.append(fn)

    def remove_listener(self, fn: Callable[[SyncEvent], None]) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    def observe(self, bus_ts_s: float, echoes: Optional[tuple[int, ...]] = None) -> SyncEvent:
        """A SYNC frame with bus timestamp ``bus_ts_s`` (wall s; 0 = none: the arrival time)."""
        local = self._mono_ns()
        bus_ns = int(round(bus_ts_s * 1e9)) if bus_ts_s else time.time_ns()
        with self._lock:
            last = self._events[-1] if self._events else None
            self.count += 1
            ev = SyncEvent(self.count, bus_ns, local, echoes)
            if last is not None:
                dt = bus_ns - last.bus_ns
                self._intervals.append(dt)
                if dt > 1.5 * self.period_ns:
                    self.missing += int(round(dt / self.period_ns)) - 1
            self._events.append(ev)
        for fn in list(self._listeners):
            fn(ev)
        return ev

    def latest(self) -> Optional[SyncEvent]:
        """The latest SYNC (None before the first)."""
        with self._lock:
            return self._events[-1] if self._events else None

    def grid(self, window: int = 64) -> Optional[tuple[SyncEvent, int]]:
        """(latest SYNC, its NOMINAL instant ns): the latest bus instant corrected by the least
        lateness over the last ``window`` SYNCs (a timer's jitter only ever delays a SYNC), so
        that one late SYNC does not shift the predicted grid. None before the first SYNC."""
        with self._lock:
            if not self._events:
                return None
            last = self._events[-1]
            cached = self._grid
            if cached is not None and cached[0] == last.count and cached[1] == window:
                return cached[2], cached[3]       # computed once per SYNC
            p = self.period_ns
            n = min(window, len(self._events))
            best = 0
            for i in range(len(self._events) - n, len(self._events)):
                d = self._events[i].bus_ns - last.bus_ns
                off = d - round(d / p) * p
                best = min(best, off)
            self._grid = (last.count, window, last, last.bus_ns + best)
            return last, last.bus_ns + best

    def since(self, count: int) -> list[SyncEvent]:
        """The SYNCs after the one numbered ``count``, oldest first (as far as kept)."""
        with self._lock:
            ev = self._events
            if not ev:
                return []
            # the counts are consecutive: slice instead of scanning
            k = max(0, count + 1 - ev[0].count)
            return [ev[i] for i in range(k, len(ev))]

    def age_s(self) -> Optional[float]:
        """s since the latest SYNC arrived here (None before the first)."""
        ev = self.latest()
        return None if ev is None else (self._mono_ns() - ev.local_ns) / 1e9

    def reset_stats(self) -> None:
        with self._lock:
            self._intervals.clear()
            self.missing = 0

    def stats(self) -> SyncStats:
        with self._lock:
            iv = self._intervals.values()
            count, missing = self.count, self.missing
        age = self.age_s()
        age_ms = -1.0 if age is None else age * 1000.0
        if iv.size == 0:
            nan = float("nan")
            return SyncStats(count, nan, nan, nan, nan, missing, age_ms)
        # jitter of the SYNCs that came (gaps are counted as missing instead)
        ok = iv[iv <= 1.5 * self.period_ns]
        jit = np.abs(ok - self.period_ns) / 1000.0 if ok.size else np.array([float("nan")])
        period = float(ok.mean()) / 1000.0 if ok.size else float("nan")
        return SyncStats(count, period, float(np.percentile(jit, 50)),
                         float(np.percentile(jit, 99)), float(jit.max()), missing, age_ms)
