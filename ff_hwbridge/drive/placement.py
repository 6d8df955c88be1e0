"""Stamps onto the SYNC grid: one shift per profile run, and the order of stamps kept.

:class:`GridPlacement` turns a setpoint's stamp (ns) into the stamp the cycle scheduler assigns
to a SYNC:

- a profile's run is shifted onto the grid as a whole: its first setpoint (seq 0, or the first
  seen of that profile id) goes to the first SYNC at or after its stamp (shift 0 … one period;
  a stamp less than ``GRID_TOLERANCE`` of a period after a SYNC goes to that SYNC, so that a
  run planned on the grid is not put one whole period late by a grid estimate that moved by
  nanoseconds)
  and every later one of the same profile id gets the same shift, those after its ``last`` too
  (a cancel's zeros), until the profile's next seq 0;
- whatever shift each setpoint got, a shifted stamp is never before the shifted stamp of a
  setpoint submitted before it with a stamp at or before its own, so a zero stamped after a step
  takes effect at or after it (the scheduler sends equal stamps in the order submitted, and a
  drive latches the last RPDO it received before the SYNC).
"""
from __future__ import annotations

from collections import deque
from typing import Callable, Optional

__all__ = ["GRID_TOLERANCE", "GridPlacement", "MAX_ORDER", "MAX_PHASES"]

MAX_PHASES = 1_000        # profiles whose shift onto the SYNC grid is remembered
MAX_ORDER = 256           # recent (stamp, shifted stamp) pairs that keep the order of stamps
GRID_TOLERANCE = 100      # a stamp up to period / this after a SYNC goes to that SYNC (SYNC timer
                          # and bus timestamps may run on two clocks that drift apart by ppm)


class GridPlacement:
    """Shifted stamps (ns) for a SYNC grid given by ``grid()`` -> (nominal SYNC ns, period ns)
    or None before the first SYNC (see the module docstring). Not thread-safe: one feeder."""

    def __init__(self, grid: Callable[[], Optional[tuple[int, int]]]) -> None:
        self._grid = grid
        self._phases: dict[str, int] = {}      # profile id -> its shift onto the SYNC grid (ns)
        self._order: deque[tuple[int, int]] = deque(maxlen=MAX_ORDER)   # (stamp, shifted) ns
        self._max_stamp: Optional[int] = None
        self._max_shifted: Optional[int] = None

    def place(self, stamp_ns: int, profile_id: str = "", seq: int = 0) -> int:
        """The stamp to schedule for a setpoint stamped ``stamp_ns`` (ns)."""
        shifted = stamp_ns + (self.phase(profile_id, stamp_ns, seq) if profile_id else 0)
        return self._in_order(stamp_ns, shifted)

    def phase(self, profile_id: str, stamp_ns: int, seq: int) -> int:
        """ns: the shift of ``profile_id``'s run; a seq 0 (or an unknown id) starts a run. A
        profile whose switch times sit on the grid (the planner's switch_grid) then lands every
        switch exactly on a SYNC, with the same common delay, instead of each stamp being
        rounded on its own (a stamp near a cycle boundary could go to either SYNC: one period
        of relative error)."""
        shift = self._phases.pop(profile_id, None)
        if shift is None or seq == 0:
            grid = self._grid()
            if grid is None:
                return 0
            nominal, period = grid
            # ceil: the first SYNC at or after the stamp, less 1 / GRID_TOLERANCE of a period
            k = -(-(stamp_ns - nominal - period // GRID_TOLERANCE) // period)
            shift = nominal + k * period - stamp_ns
            if len(self._phases) >= MAX_PHASES:
                self._phases.pop(next(iter(self._phases)))   # the least recently used
        self._phases[profile_id] = shift                     # most recently used last
        return shift

    def _in_order(self, stamp_ns: int, shifted_ns: int) -> int:
        """``shifted_ns``, raised to the shifted stamp of any setpoint submitted before with a
        stamp at or before ``stamp_ns`` where that one is later."""
        if self._max_stamp is None or stamp_ns >= self._max_stamp:     # in order: every one before
            out = max(shifted_ns, shifted_ns if self._max_shifted is None else self._max_shifted)
            self._max_stamp = stamp_ns
        else:                                                            # earlier than the latest
            out = max(shifted_ns, max((s for t, s in self._order if t <= stamp_ns),
                                      default=shifted_ns))
        self._max_shifted = out if self._max_shifted is None else max(self._max_shifted, out)
        self._order.append((stamp_ns, out))
        return out
