"""Garbage-collector pauses of a timing-critical process: a frozen heap, and every pause measured.

CPython's cyclic collector runs in whichever thread allocates when a generation's threshold is
reached, and holds the GIL while it scans: every other thread of the process (the setpoint
player, the bus receiver, the SYNC timer) waits. A full collection (generation 2) of a process
that has imported rclpy, numpy and canopen scans ~50 000 objects: 12.6 ms measured on a quiet
2-core machine, more than the 10 ms SYNC cycle a setpoint has to be sent in, and it comes
whenever the long-lived objects have grown by a quarter.

:func:`freeze_heap` is called once a process has built what it keeps (after configure / activate,
before motion): one collection, then ``gc.freeze()`` moves every surviving object into the
permanent generation, which later collections do not scan (a full collection then took 0.02 ms
in the same process). What a long stream of setpoints leaves behind (reports, records) grows the
unfrozen part again, so :func:`hold_full_collections` also stops the automatic full collections
(the youngest generations, well under a millisecond, still run), and the owner collects in full
when nothing is due (:class:`IdleCollector`: the player idle for a while, e.g. between motions).
:class:`GcPauses` times every collection through ``gc.callbacks``, for the diagnostics: count and
longest pause per generation.
"""
from __future__ import annotations

import gc
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

__all__ = ["GcPauses", "IdleCollector", "freeze_heap", "hold_full_collections", "pauses"]

#: generation-2 threshold that keeps the automatic full collection from ever running
FULL_HELD = 1_000_000


def freeze_heap() -> int:
    """Collect once and freeze what survives (``gc.freeze``); returns the frozen object count.

    Costs one full collection (~10 ms): call it before timing matters, not during a motion."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def hold_full_collections() -> tuple[int, int, int]:
    """No automatic full (generation 2) collection from now on; returns the thresholds before.
    The process must then collect in full itself when timing does not matter
    (:class:`IdleCollector`), or cyclic garbage that reached the oldest generation stays."""
    before = gc.get_threshold()
    gc.set_threshold(before[0], before[1], FULL_HELD)
    return before


class IdleCollector:
    """A full collection when ``idle()`` has held for ``idle_s`` s, at most every ``every_s`` s:
    ``tick()`` from a periodic timer of the owner (e.g. its diagnostics). Returns the pause (ms)
    when it collected, else None."""

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
        """``gc.collections`` (per generation), ``gc.max_pause_ms`` (per generation),
        ``gc.frozen`` (objects in the permanent generation)."""
        return {f"{prefix}collections": "/".join(str(c) for c in self.count),
                f"{prefix}max_pause_ms": "/".join(f"{m:.2f}" for m in self.max_ms),
                f"{prefix}frozen": gc.get_freeze_count(),
                f"{prefix}full_held": gc.get_threshold()[2] >= FULL_HELD}


#: this process's pause record (installed by whoever needs it: ``pauses.install()``)
pauses = GcPauses()
