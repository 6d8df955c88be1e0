"""The master's SYNC producer (CiA 301, COB-ID 0x80) where no kernel periodic sender keeps it.

On SocketCAN the master's SYNC goes to the kernel's broadcast manager (``canopen``'s
``network.sync.start``, python-can's ``send_periodic``): an hrtimer keeps the period whatever this
process does, which is what a SYNC producer should do (the setpoint RPDO and the master's
heartbeat never go there: a frozen process must fall silent, ``drive.rpdo``,
``drive.heartbeat``). Every other interface (virtual, remote, pcan, kvaser ...) gets python-can's
``ThreadBasedCyclicSendTask`` instead, which advances its due time by one period per frame and
does not sleep while behind: after a stall of the process (a collection, a preempted thread) it
sends every missed SYNC back to back. A drive takes such a burst for a run of interpolation
periods with no target RPDO in them (EMCY 0x8250, interpolation aborted) and the master's own
SYNC watch for jitter. :class:`SyncSender` keeps slots instead: the k-th SYNC is due at
``t0 + k · period`` (monotonic clock); after a late send the next SYNC goes at the first slot at
least half a period later, the slots passed over are skipped (counted), never sent in a burst.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Callable, Optional

log = logging.getLogger(__name__)

__all__ = ["SyncSender"]


class SyncSender:
    """Calls ``send()`` once per slot of ``period`` s from a thread of this process until
    ``stop()``; a slot passed while the thread was held off is skipped (``skipped``), never sent
    late; two sends are at least half a period apart. ``send`` failures are logged once and
    counted (``failures``) until one goes through."""

    def __init__(self, send: Callable[[], None], period: float, name: str = "ff-sync-producer",
                 clock_ns: Callable[[], int] = time.monotonic_ns) -> None:
        if not period > 0:
            raise ValueError(f"SYNC period must be > 0 s, got {period!r}")
        self._send = send
        self.period_ns = int(round(period * 1e9))
        self._clock_ns = clock_ns
        self._stop = threading.Event()
        self.sent = 0
        self.skipped = 0
        self.failures = 0
        self.thread: Optional[threading.Thread] = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def next_slot(self, t0_ns: int, now_ns: int, k: int) -> tuple[int, int]:
        """(slot number, its instant ns) of the SYNC after slot ``k``, sent at ``now_ns``: the
        first slot at least half a period after ``now_ns`` (two SYNCs never closer than that:
        a drive would see an interpolation period with no RPDO in it); the ones passed over
        are skipped."""
        k_next = max(k + 1, -(-(now_ns + self.period_ns // 2 - t0_ns) // self.period_ns))
        return k_next, t0_ns + k_next * self.period_ns

    def _run(self) -> None:
        t0 = self._clock_ns()
        k = 0
        while not self._stop.is_set():
            try:
                self._send()
                self.sent += 1
                if self.failures:
                    log.warning("SYNC goes through again after %d failed", self.failures)
                    self.failures = 0
            except Exception:  # noqa: BLE001 - a full bus must not end the SYNC producer
                self.failures += 1
                if self.failures == 1:
                    log.exception("SYNC send failed (further failures counted)")
            now = self._clock_ns()
            k_next, due = self.next_slot(t0, now, k)
            self.skipped += k_next - k - 1
            k = k_next
            self._stop.wait(max(0, due - now) / 1e9)

    def stop(self) -> None:
        """Stop sending (waits for the thread up to one period + 1 s)."""
        self._stop.set()
        t = self.thread
        if t is not None and t is not threading.current_thread():
            t.join(self.period_ns / 1e9 + 1.0)
        self.thread = None
