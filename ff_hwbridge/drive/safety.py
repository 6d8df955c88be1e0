"""The single path every current command takes: limit clamp, setpoint watchdog, safe-state latch.

Rules (units: A, s):
- Every output current is finite and within +-limit of its joint. NaN/inf -> 0 A and a reason;
  a wrong number of currents -> all 0 A and a reason; non-finite or non-positive limits are
  refused when the guard is built.
- Watchdog: while a motion runs, no fresh setpoint for ``setpoint_timeout`` s (and none still
  waiting to be applied) -> the guard latches "setpoint watchdog" (zero current + quick stop is
  the caller's reaction to a latch).
- Latch: once latched (watchdog, EMCY, drive fault, heartbeat loss, ...), every command is 0 A
  until an explicit ``reset()`` (the fault reset request). The first reason is kept.

Thread-safe: one lock around the state; the clock is passed in (``now`` in s, monotonic).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np


class SafetyConfigError(ValueError):
    """Bad limits or timeout for the guard; the message says what to change."""


@dataclass(frozen=True)
class SafeCommand:
    """What may be sent: ``currents`` (A, within limits), whether each was changed, and why."""

    currents: np.ndarray
    clamped: tuple[bool, ...]
    reason: Optional[str]        # None when the request went through unchanged
    latched: bool


class SafetyGuard:
    """Clamp + watchdog + latch for one drive group (one limit per joint)."""

    def __init__(self, limits: Sequence[float], setpoint_timeout: float) -> None:
        lim = [float(x) for x in limits]
        if not lim or any(not math.isfinite(x) or x <= 0.0 for x in lim):
            raise SafetyConfigError(f"current limits must be finite and > 0 A, got {list(limits)!r}")
        t = float(setpoint_timeout)
        if not math.isfinite(t) or t <= 0.0:
            raise SafetyConfigError(f"setpoint_timeout must be finite and > 0 s, got {setpoint_timeout!r}")
        self._limits = np.asarray(lim, dtype=float)
        self._limits.setflags(write=False)
        self._limit_list = [float(x) for x in lim]
        self.setpoint_timeout = t
        self._lock = threading.Lock()
        self._reason: Optional[str] = None
        self._motion = False
        self._last_feed: Optional[float] = None

    # --- state ----------------------------------------------------------------------------------
    @property
    def limits(self) -> np.ndarray:
        """A, per joint (read-only)."""
        return self._limits

    @property
    def latched(self) -> bool:
        return self._reason is not None

    @property
    def reason(self) -> Optional[str]:
        """Why the safe state is latched (None when not latched)."""
        return self._reason

    @property
    def motion_running(self) -> bool:
        return self._motion

    def latch(self, reason: str) -> bool:
        """Enter the safe state; returns True if this call latched it (the first reason stays)."""
        with self._lock:
            if self._reason is not None:
                return False
            self._reason = str(reason) or "safe state"
            self._motion = False
            return True

    def reset(self) -> Optional[str]:
        """Explicit fault reset: clear the latch and the watchdog; returns the cleared reason."""
        with self._lock:
            old, self._reason = self._reason, None
            self._motion = False
            self._last_feed = None
            return old

    # --- watchdog -------------------------------------------------------------------------------
    def feed(self, now: float, motion_running: bool) -> None:
        """A fresh setpoint arrived at ``now`` (s); ``motion_running`` says whether a motion is
        under way after it (False on a profile's last setpoint or a manual zero)."""
        with self._lock:
            self._last_feed = float(now)
            self._motion = bool(motion_running) and self._reason is None

    def end_motion(self) -> None:
        """The motion ended (e.g. its last setpoint was applied): stop watching."""
        with self._lock:
            self._motion = False

    def check(self, now: float, pending: bool = False) -> Optional[str]:
        """Watchdog check at ``now`` (s). Returns the reason if this call latched, else None.

        ``pending`` = setpoints received but not yet applied (the stream is still fed).
        """
        with self._lock:
            if self._reason is not None or not self._motion or pending or self._last_feed is None:
                return None
            age = float(now) - self._last_feed
            if age > self.setpoint_timeout or math.isnan(age):
                self._reason = (f"setpoint watchdog: no fresh setpoint for {age * 1000.0:.0f} ms "
                                f"during a motion (timeout {self.setpoint_timeout * 1000.0:.0f} ms)")
                self._motion = False
                return self._reason
            return None

    # --- the command path -----------------------------------------------------------------------
    def filter(self, currents: Sequence[float]) -> SafeCommand:
        """The currents that may be sent for a request: clamped, finite, zero when latched.

        Plain python on purpose: a few joints, on the timing path (a few µs, numpy ~15 µs).
        """
        limits = self._limit_list
        n = len(limits)
        try:
            req = [float(x) for x in currents]
        except (TypeError, ValueError):
            req = None
        if req is None or len(req) != n:
            got = "unreadable" if req is None else f"{len(req)}"
            return SafeCommand(np.zeros(n), (True,) * n,
                               f"expected {n} current(s), got {got}: sending 0 A", self.latched)
        if self._reason is not None:
            return SafeCommand(np.zeros(n), tuple(x != 0.0 for x in req),
                               f"safe state: {self._reason}", True)
        out = [0.0] * n
        changed = [False] * n
        bad, over = [], []
        for i, (x, lim) in enumerate(zip(req, limits)):
            if not math.isfinite(x):
                bad.append(i)
                changed[i] = True
            elif x > lim:
                out[i], changed[i] = lim, True
                over.append(i)
            elif x < -lim:
                out[i], changed[i] = -lim, True
                over.append(i)
            else:
                out[i] = x
        reasons = []
        if bad:
            reasons.append(f"non-finite current for joint(s) {bad}: 0 A")
        if over:
            reasons.append(f"current clamped to the limit for joint(s) {over}")
        # belt and braces: a limit can never be exceeded, whatever happened above
        if not all(math.isfinite(v) and abs(v) <= lim for v, lim in zip(out, limits)):
            out = [0.0] * n
            reasons.append("internal clamp check failed: 0 A")
        return SafeCommand(np.array(out), tuple(changed), "; ".join(reasons) or None, False)
