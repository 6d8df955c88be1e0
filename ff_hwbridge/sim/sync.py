"""A SYNC producer (CiA 301, COB-ID 0x80) for the simulation that behaves like the kernel's timer.

On SocketCAN the SYNC comes from the kernel (python-can's broadcast manager, a BCM timer); here
there is no kernel CAN device, so :class:`SyncSource` plays that part in the CAN hub's process
(``ff-can-hub --sync-period``), outside every ROS process: a thread on an absolute-deadline grid
(nominal instants t0 + n · period on ``time.monotonic_ns``; never drifting), which sleeps until
``spin`` s before each instant, then spins to it and puts the SYNC frame on the hub's virtual
channel itself (the frame's bus timestamp is taken right there). It asks for SCHED_FIFO
(``rt_priority``) and a 1 µs timer slack, and runs at normal priority with a warning when not
permitted.

Jitter = actual send instant − nominal instant (µs, ≥ 0), kept per SYNC; ``stats()`` gives
p50 / p99 / max, the count and the slots skipped (a send later than one whole period skips to
the next slot, so that SYNC never comes in bursts).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Optional

import can
import numpy as np

from ff_hwbridge.drive.scheduler import use_fifo

log = logging.getLogger(__name__)

__all__ = ["SyncSource", "SyncSourceStats"]

SYNC_COB_ID = 0x80
_PR_SET_TIMERSLACK = 29


@dataclass(frozen=True)
class SyncSourceStats:
    """SYNCs sent, slots skipped, jitter (send − nominal) p50 / p99 / max (µs), SCHED_FIFO on."""

    count: int
    skipped: int
    jitter_p50_us: float
    jitter_p99_us: float
    jitter_max_us: float
    period_us: float
    realtime: bool

    def as_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in ("count", "skipped", "jitter_p50_us", "jitter_p99_us",
                                              "jitter_max_us", "period_us", "realtime")}


def _timer_slack_1us() -> None:
    """Linux: 1 µs timer slack for the calling thread (default 50 µs); ignored elsewhere."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_TIMERSLACK, 1000, 0, 0, 0)
    except (OSError, AttributeError):
        pass


class SyncSource:
    """SYNC every ``period`` s on ``bus`` (a python-can bus; in the hub its virtual channel)."""

    def __init__(self, bus: can.BusABC, period: float = 0.001, *, spin: float = 0.00005,
                 rt_priority: int = 0, max_records: int = 600_000,
                 name: str = "ff-sync-source") -> None:
        if not 0.0001 <= period <= 1.0:
            raise ValueError(f"SYNC period must be 0.1 ms .. 1 s, got {period!r} s")
        self.bus = bus
        self.period_ns = int(round(period * 1e9))
        self.spin_ns = int(spin * 1e9)
        self.rt_priority = int(rt_priority)
        self.rt_active = False
        self._jitter: deque[int] = deque(maxlen=max_records)
        self.count = 0
        self.skipped = 0
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._name = name
        self._msg = can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)
        self._lock = threading.Lock()

    def start(self) -> "SyncSource":
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None

    def __enter__(self) -> "SyncSource":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def reset_stats(self) -> None:
        with self._lock:
            self._jitter.clear()
            self.skipped = 0

    def stats(self) -> SyncSourceStats:
        with self._lock:
            j = np.array(self._jitter, dtype=float) / 1000.0
            count, skipped = self.count, self.skipped
        if j.size == 0:
            nan = float("nan")
            return SyncSourceStats(count, skipped, nan, nan, nan, self.period_ns / 1000.0,
                                   self.rt_active)
        return SyncSourceStats(count, skipped, float(np.percentile(j, 50)),
                               float(np.percentile(j, 99)), float(j.max()),
                               self.period_ns / 1000.0, self.rt_active)

    def _set_priority(self) -> None:
        _timer_slack_1us()
        if self.rt_priority > 0:
            self.rt_active = use_fifo(self.rt_priority, "SYNC source", hint=", expect more jitter under load")

    def _run(self) -> None:
        self._set_priority()
        mono, period, spin = time.monotonic_ns, self.period_ns, self.spin_ns
        nxt = mono() + period
        while not self._stop.is_set():
            left = nxt - mono() - spin
            if left > 0:
                time.sleep(left / 1e9)
            while mono() < nxt:
                pass
            sent = mono()
            try:
                self.bus.send(self._msg)
            except can.CanError:
                log.exception("SYNC send failed")
            with self._lock:
                self.count += 1
                self._jitter.append(sent - nxt)
            nxt += period
            late = mono() - nxt
            if late > 0:                 # a whole period late: skip the slots (no burst)
                skip = late // period + 1
                self.skipped += int(skip)
                nxt += skip * period
