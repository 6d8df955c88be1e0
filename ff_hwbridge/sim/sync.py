"""A SYNC producer (CiA 301, COB-ID 0x80) for the simulation that behaves like the kernel's timer.

On SocketCAN the SYNC comes from the kernel (python-can's broadcast manager, a BCM timer) and
a CAN controller puts it on the wire; here there is no kernel CAN device, so
:class:`SyncSource` plays that part in the CAN hub's process (``ff-can-hub --sync-period``),
outside every ROS process: a thread on an absolute-deadline grid (nominal instants
t0 + n · period on ``time.monotonic_ns``; never drifting), which sleeps until ``spin`` s before
each instant, then spins to it and puts the SYNC frame on the hub's virtual channel itself.
It asks for SCHED_FIFO (``rt_priority``) and a 1 µs timer slack, and runs at normal priority
with a warning when not permitted.

Two timing models (``stamp``):

- ``"deadline"`` (default): the SYNC's BUS instant (its frame timestamp, which every drive and
  the master use to order frames and to time latching) is the nominal instant plus a modelled
  jitter drawn uniformly from [0, ``jitter_model``] s — a hardware or kernel timer, which a
  Python thread is not: how late this thread really got the frame out is measured and reported
  apart (``send_late_*``) but moves no bus instant. Frames are ordered by bus instant: an RPDO
  that reached the hub after a SYNC's instant waits for the next SYNC, wherever the late SYNC
  frame landed in the channel's delivery order (the simulated drive compares stamps). Every slot
  gets its SYNC, a late one too (``late_slots`` counts sends more than one period late).
- ``"send"``: the bus instant is when this thread put the frame on the channel (what the thread
  achieves; a send later than one whole period skips to the next slot, ``skipped``).

Jitter = bus instant − nominal instant (µs, ≥ 0), kept per SYNC; ``stats()`` gives p50 / p99 /
max, the count, the send lateness p50 / p99 / max and the slots skipped or sent late.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Optional

import can
import numpy as np

from ff_hwbridge.drive.scheduler import use_fifo

log = logging.getLogger(__name__)

__all__ = ["STAMPS", "SyncSource", "SyncSourceStats", "wall_minus_mono"]

SYNC_COB_ID = 0x80
_PR_SET_TIMERSLACK = 29


STAMPS = ("deadline", "send")


def _percentiles(ns: "deque[int]") -> tuple[float, float, float]:
    """(p50, p99, max) in µs of a record in ns; nan when empty."""
    if not ns:
        return (math.nan, math.nan, math.nan)
    us = np.array(ns, dtype=float) / 1000.0
    return (float(np.percentile(us, 50)), float(np.percentile(us, 99)), float(us.max()))


@dataclass(frozen=True)
class SyncSourceStats:
    """SYNCs sent; bus instant − nominal p50 / p99 / max (µs); the timing model (``stamp``,
    ``jitter_model_us``); how late the thread really sent, p50 / p99 / max (µs); slots skipped
    (``send``) or sent more than a period late (``deadline``); SCHED_FIFO on."""

    count: int
    skipped: int
    jitter_p50_us: float
    jitter_p99_us: float
    jitter_max_us: float
    period_us: float
    realtime: bool
    stamp: str = "send"
    jitter_model_us: float = 0.0
    send_late_p50_us: float = math.nan
    send_late_p99_us: float = math.nan
    send_late_max_us: float = math.nan
    late_slots: int = 0

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def timer_slack_1us() -> None:
    """Linux: 1 µs timer slack for the calling thread (default 50 µs); ignored elsewhere."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_TIMERSLACK, 1000, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def wall_minus_mono(tries: int = 5, tight_ns: int = 5_000) -> int:
    """ns: ``time.time_ns()`` − ``time.monotonic_ns()`` now, from the tightest of a few bracketed
    reads (a thread preempted between two clock reads would otherwise be off by the preemption)."""
    best: Optional[tuple[int, int]] = None
    for _ in range(tries):
        a = time.monotonic_ns()
        w = time.time_ns()
        b = time.monotonic_ns()
        if best is None or b - a < best[0]:
            best = (b - a, w - (a + b) // 2)
        if b - a <= tight_ns:
            break
    assert best is not None
    return best[1]


class SyncSource:
    """SYNC every ``period`` s on ``bus`` (a python-can bus; in the hub its virtual channel,
    opened with ``preserve_timestamps=True`` for ``stamp="deadline"``); ``jitter_model`` (s):
    the modelled bus-instant jitter of the deadline model (see the module docstring)."""

    def __init__(self, bus: can.BusABC, period: float = 0.001, *, spin: float = 0.00005,
                 rt_priority: int = 0, max_records: int = 600_000, stamp: str = "deadline",
                 jitter_model: float = 0.0, seed: Optional[int] = None,
                 name: str = "ff-sync-source") -> None:
        if not 0.0001 <= period <= 1.0:
            raise ValueError(f"SYNC period must be 0.1 ms .. 1 s, got {period!r} s")
        if stamp not in STAMPS:
            raise ValueError(f"SYNC stamp must be one of {', '.join(STAMPS)}, got {stamp!r}")
        if not (math.isfinite(jitter_model) and 0.0 <= jitter_model <= 0.1 * period):
            raise ValueError(f"modelled SYNC jitter must be 0 .. 10 % of the period, got {jitter_model!r} s")
        if stamp == "deadline" and not getattr(bus, "preserve_timestamps", False):
            raise ValueError("the deadline model needs a bus that keeps the frame's timestamp "
                             "(python-can virtual with preserve_timestamps=True)")
        self.bus = bus
        self.period_ns = int(round(period * 1e9))
        self.spin_ns = int(spin * 1e9)
        self.rt_priority = int(rt_priority)
        self.rt_active = False
        self.stamp = stamp
        self.jitter_model_ns = int(round(jitter_model * 1e9))
        self._rng = np.random.default_rng(seed)
        self._jitter: deque[int] = deque(maxlen=max_records)
        self._late: deque[int] = deque(maxlen=max_records)
        self.count = 0
        self.skipped = 0
        self.late_slots = 0
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._name = name
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
            self._late.clear()
            self.skipped = 0
            self.late_slots = 0

    def stats(self) -> SyncSourceStats:
        with self._lock:
            jitter, late = _percentiles(self._jitter), _percentiles(self._late)
            count, skipped, late_slots = self.count, self.skipped, self.late_slots
        return SyncSourceStats(count, skipped, *jitter, self.period_ns / 1000.0, self.rt_active,
                               self.stamp, self.jitter_model_ns / 1000.0, *late, late_slots)

    def _set_priority(self) -> None:
        timer_slack_1us()
        if self.rt_priority > 0:
            self.rt_active = use_fifo(self.rt_priority, "SYNC source", hint=", expect more jitter under load")

    def _model_jitter(self) -> int:
        return int(self._rng.integers(0, self.jitter_model_ns + 1)) if self.jitter_model_ns else 0

    def _run(self) -> None:
        self._set_priority()
        mono, period, spin = time.monotonic_ns, self.period_ns, self.spin_ns
        deadline = self.stamp == "deadline"
        nxt = mono() + period
        while not self._stop.is_set():
            left = nxt - mono() - spin
            if left > 0:
                time.sleep(left / 1e9)
            while mono() < nxt:
                pass
            bus_mono = nxt + self._model_jitter() if deadline else 0
            if deadline:                 # a modelled instant after nxt: spin to it as well
                while mono() < bus_mono:
                    pass
            msg = can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)
            sent = mono()
            if deadline:                 # the wall clock of the modelled instant
                msg.timestamp = (bus_mono + wall_minus_mono()) / 1e9
            try:
                self.bus.send(msg)
            except can.CanError:
                log.exception("SYNC send failed")
            with self._lock:
                self.count += 1
                self._jitter.append(bus_mono - nxt if deadline else sent - nxt)
                self._late.append(sent - nxt)
                if deadline and sent - nxt > period:
                    self.late_slots += 1
            nxt += period
            late = mono() - nxt
            if late > 0 and not deadline:    # a whole period late: skip the slots (no burst)
                skip = late // period + 1
                self.skipped += int(skip)
                nxt += skip * period
