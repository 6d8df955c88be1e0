"""What the drives report (TPDO1 statusword + position, TPDO2 velocity + current) as immutable
snapshots, and the instant each sample was taken.

:class:`JointFeedback` is frozen: the bus receiver builds a new one per TPDO and swaps it in
under a lock (``EposMaster``), so a reader always gets one consistent sample, never the fields of
two TPDOs.

:class:`SamplePairing` places a synchronous TPDO at the SYNC it answers (a drive samples at the
SYNC; ``feedback_every`` = N: it answers every N-th): SYNCs are queued as they are seen, and a
TPDO takes the latest queued SYNC only when exactly N are pending. With more pending the pairing
is not certain (a late answer, or one after a lost TPDO): the TPDO keeps its own bus instant and
the oldest N are taken as answered (first in, first out); the same twice in a row means a TPDO was
lost, and the pairing starts again from the next SYNC. One that came before its SYNC (a
bus that fans a frame out to its receivers one after another may queue the drive's answer before
the SYNC's own copy) is placed when that SYNC arrives within one period before it.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Optional

from ff_hwbridge.protocol.cia402 import State

__all__ = ["JointFeedback", "SamplePairing"]


@dataclass(frozen=True)
class JointFeedback:
    """Latest measured values of one joint (rad, rad/s, A) and its drive state."""

    position: float = 0.0
    velocity: float = 0.0
    current: float = 0.0
    statusword: int = 0
    state: Optional[State] = None
    position_raw: int = 0
    velocity_raw: int = 0
    current_raw: int = 0
    stamp: float = 0.0            # monotonic s of the latest TPDO1
    sample_ns: int = 0            # wall-clock ns the latest TPDO1's values were sampled: the
                                  #   SYNC it answers, else its bus timestamp (or arrival time)
    stamp_motion: float = 0.0     # monotonic s of the latest TPDO2


class SamplePairing:
    """SYNC ↔ TPDO pairing of one drive (module docstring); bus instants in wall ns. Called from
    the bus receiver's thread only."""

    def __init__(self, period_ns: int, every: int = 1) -> None:
        self.period_ns = int(period_ns)
        self.every = max(1, int(every))
        self._pending: deque[int] = deque(maxlen=4 * self.every + 4)
        self._early = 0            # bus ns of a TPDO that came before its SYNC (0: none)
        self._ambiguous = False    # the latest TPDO found more SYNCs pending than it answers

    def on_sync(self, bus_ns: int) -> Optional[int]:
        """A SYNC at ``bus_ns``: its instant when it is the one a TPDO already received answers
        (the caller re-places that sample), else None (queued)."""
        t = self._early
        if t and 0 <= t - bus_ns < self.period_ns and len(self._pending) == self.every - 1:
            self._early = 0
            self._pending.clear()
            return bus_ns
        self._early = 0
        self._pending.append(bus_ns)
        return None

    def on_tpdo(self, tpdo_ns: int) -> int:
        """The sample instant (ns) of a TPDO with bus instant ``tpdo_ns``."""
        p = self._pending
        if len(p) == self.every and p[-1] <= tpdo_ns:
            at = p[-1]
            p.clear()
            self._ambiguous = False
            return at
        self._early = 0
        if len(p) > self.every:
            # a late answer (to the oldest pending: first in, first out) or one after a lost
            # TPDO (to the latest): not certain, its own instant; twice in a row means a TPDO
            # was lost: start again from the next SYNC
            if self._ambiguous:
                p.clear()
                self._ambiguous = False
            else:
                for _ in range(self.every):
                    p.popleft()
                self._ambiguous = True
        elif len(p) == self.every - 1:
            self._early = tpdo_ns  # its SYNC may still come
        else:
            p.clear()
        return tpdo_ns

    def reset(self) -> None:
        self._pending.clear()
        self._early = 0
        self._ambiguous = False
