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
in the same process). Objects made later are collected as usual. :class:`GcPauses` times every
collection through ``gc.callbacks``, for the diagnostics: count and longest pause per generation.
"""
from __future__ import annotations

import gc
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Optional

__all__ = ["GcPauses", "freeze_heap", "pauses"]


def freeze_heap() -> int:
    """Collect once and freeze what survives (``gc.freeze``); returns the frozen object count.

    Costs one full collection (~10 ms): call it before timing matters, not during a motion."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


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
                f"{prefix}frozen": gc.get_freeze_count()}


#: this process's pause record (installed by whoever needs it: ``pauses.install()``)
pauses = GcPauses()
