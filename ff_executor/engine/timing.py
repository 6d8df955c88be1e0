"""Switch-time statistics: |applied − stamp| of the current switches of one motion.

From the bridge's reports of applied times (:func:`timing_stats`), or estimated from measured
currents when it does not report them (:func:`estimate_applied_times`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ff_executor.engine.config import NS
from ff_executor.engine.setpoints import Setpoint


@dataclass
class TimingStats:
    """Switch-time error |applied − stamp| over the current switches of one motion (s)."""

    count: int = 0
    p50: float = math.nan
    p99: float = math.nan
    max: float = math.nan
    source: str = "none"          # "bridge" (reported applied times), "estimated", or "none"

    def as_dict(self) -> dict[str, float | int | str]:
        """The figures as a plain dict (JSON-ready)."""
        return {"count": self.count, "p50": self.p50, "p99": self.p99, "max": self.max,
                "source": self.source}


def timing_stats(stamps_ns: Iterable[int], applied_ns: Iterable[int], source: str) -> TimingStats:
    """Statistics of |applied − stamp| (s) for matched pairs; NaN figures when there are none."""
    err = np.abs(np.asarray(list(applied_ns), dtype=float) - np.asarray(list(stamps_ns), dtype=float)) / NS
    if err.size == 0:
        return TimingStats(source="none")
    return TimingStats(int(err.size), float(np.percentile(err, 50)), float(np.percentile(err, 99)),
                       float(err.max()), source)


def estimate_applied_times(setpoints: Sequence[Setpoint], sample_ns: ArrayLike,
                           measured: ArrayLike, window: float = 0.02
                           ) -> list[tuple[int, int]]:
    """Estimate when each current switch took effect from measured currents (A) at ``sample_ns``.

    For each switching setpoint: the first sample no earlier than ``stamp − window`` whose
    current is nearer the new value than the old one (all joints). Returns (stamp, estimate)
    pairs; the estimate is an upper bound quantised by the sample period, so use it only when
    the bridge does not report applied times.
    """
    t = np.asarray(sample_ns, dtype=np.int64)
    if t.size == 0:
        return []
    m = np.asarray(measured, dtype=float).reshape(t.size, -1)
    order = np.argsort(t, kind="stable")
    t, m = t[order], m[order]
    pairs: list[tuple[int, int]] = []
    prev = np.zeros(m.shape[1])
    win = int(round(window * NS))
    switches = [s for s in setpoints if s.switch]
    for k, sp in enumerate(switches):
        new = np.asarray(sp.currents, dtype=float)
        if np.allclose(new, prev):
            continue
        limit = switches[k + 1].stamp_ns if k + 1 < len(switches) else sp.stamp_ns + 10 * win
        lo = int(np.searchsorted(t, sp.stamp_ns - win, side="left"))
        hi = int(np.searchsorted(t, limit, side="left"))
        for i in range(lo, hi):
            if np.all(np.abs(m[i] - new) < np.abs(m[i] - prev)):
                pairs.append((sp.stamp_ns, int(t[i])))
                break
        prev = new
    return pairs


def missed_cycles(stamps_ns: Iterable[int], applied_ns: Iterable[int], sync_period: float,
                  tolerance: float = 0.1) -> int:
    """SYNC cycles lost by setpoints that took effect late (SYNC-latched drives).

    A drive latching setpoints at SYNC applies a setpoint at the first SYNC at or after its stamp,
    i.e. less than one ``sync_period`` (s) after it; each whole period beyond that (applied − stamp
    ≥ (k + ``tolerance``)·period, the tolerance absorbing SYNC jitter) is one missed cycle.
    ``sync_period`` <= 0 (setpoints applied on receipt): 0.
    """
    if not sync_period > 0.0:
        return 0
    late = (np.asarray(list(applied_ns), dtype=float) - np.asarray(list(stamps_ns), dtype=float)) / NS
    if late.size == 0:
        return 0
    return int(np.sum(np.maximum(np.floor(late / sync_period + 1.0 - tolerance) - 1.0, 0.0)))
