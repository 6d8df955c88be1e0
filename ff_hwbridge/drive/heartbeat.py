"""The master's heartbeat (CiA 301 heartbeat producer) sent by a thread of this process.

Never by the bus's periodic sender: on SocketCAN python-can hands ``send_periodic`` to the
kernel's broadcast manager, which goes on sending for a process that is frozen (SIGSTOP, a
deadlock) but alive, and the drives' heartbeat consumers (0x1016) would never see the master
hang. A thread in user space falls silent with its process.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Callable, Optional

log = logging.getLogger(__name__)

__all__ = ["HeartbeatSender"]


class HeartbeatSender:
    """Calls ``send()`` every ``period`` s (absolute deadlines on the monotonic clock; a late
    wake-up does not shift the later ones) until ``stop()``. ``send`` failures are logged once
    and counted (``failures``) until one goes through."""

    def __init__(self, send: Callable[[], None], period: float, name: str = "ff-master-heartbeat") -> None:
        if not period > 0:
            raise ValueError(f"heartbeat period must be > 0 s, got {period!r}")
        self._send = send
        self.period = float(period)
        self._stop = threading.Event()
        self.sent = 0
        self.failures = 0
        self.thread: Optional[threading.Thread] = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        deadline = time.monotonic()
        while not self._stop.is_set():
            try:
                self._send()
                self.sent += 1
                if self.failures:
                    log.warning("master heartbeat goes through again after %d failed", self.failures)
                    self.failures = 0
            except Exception:  # noqa: BLE001 - a full bus must not end the heartbeat
                self.failures += 1
                if self.failures == 1:
                    log.exception("master heartbeat send failed (further failures counted)")
            deadline += self.period
            now = time.monotonic()
            if deadline < now:                  # held off for more than a period: from now on
                deadline = now
            self._stop.wait(deadline - now)

    def stop(self) -> None:
        """Stop sending (waits for the thread up to one period + 1 s)."""
        self._stop.set()
        t = self.thread
        if t is not None and t is not threading.current_thread():
            t.join(self.period + 1.0)
        self.thread = None
