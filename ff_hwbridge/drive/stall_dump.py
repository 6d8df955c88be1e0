"""A stack dump of every thread when a timing-critical thread stops making progress.

``faulthandler.dump_traceback_later`` runs a watchdog thread in C that needs no GIL: re-armed by
the thread that must keep time, it fires only when that thread has not come back for the
timeout, and then prints what every thread of the process is doing — the one holding the GIL
among them. A process has one such watchdog: one :class:`StallDump` per process (the bridge's
setpoint cycle, the simulated drive's SYNC handling).
"""
from __future__ import annotations

import faulthandler
import sys
import time
from typing import TextIO

__all__ = ["StallDump"]


class StallDump:
    """``arm()`` from the watched thread on every pass: when ``seconds`` pass without another
    ``arm()`` (or a ``disarm()``), every thread's stack goes to ``file`` (stderr) once.
    Re-arming costs ~30 µs: a pass re-arms at most every ``rearm_every`` s, so the dump comes
    ``seconds`` to ``seconds + rearm_every`` after the thread's last pass. 0 s: off."""

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
