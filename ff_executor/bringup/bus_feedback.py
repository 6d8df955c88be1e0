"""The drive's own samples, read off the CAN bus: each synchronous TPDO's position (and current)
at the SYNC it answered, for on-stack identification.

A synchronous TPDO holds the values the drive sampled *at* a SYNC. Which SYNC is certain only
while one is pending: a drive answers every SYNC in order, so an answer that comes after the
next SYNC is already on the bus (a drive process stalled for more than a period) may belong to
either of them to anyone who pairs it with "the latest SYNC seen". Placed there, a 10 ms-late
answer moves its sample one SYNC period (at 3 rad/s, 30 mrad: hundreds of encoder counts).
:class:`BusFeedback` (a frame sink of the bus monitor) therefore pairs with
:class:`ff_executor.bringup.bus_monitor.SyncPairing`
(first in, first out; an answer with more than one SYNC pending, or later than ``max_latency``,
is left out) and keeps the payload of each placed answer: every sample it returns is the drive's
encoder count at the SYNC's bus instant, whatever stamp the bridge gave its joint state.

TPDO1 (0x180 + node id): statusword + 0x6064 position actual (increments); TPDO2 (0x280 + node
id): 0x606C velocity actual + current actual (EPOS4 0x30D1:02, EPOS2 0x6078; mA), the layouts of
``ff_hwbridge.protocol.epos_od``. Times are the hub's wall clock (s), like the BusMonitor's.
"""
from __future__ import annotations

import struct
import threading
from collections import deque
from typing import Any

import numpy as np

from ff_executor.bringup.bus_monitor import SYNC_ID, TPDO1_BASE, BusMonitor, SyncPairing
from ff_hwbridge.protocol.epos_od import struct_format, tpdo1_layout, tpdo2_layout

TPDO2_BASE = 0x280


def _field(layout: list[tuple[int, int, str]], keys: tuple[tuple[int, int], ...]) -> int:
    """Position of the first of ``keys`` (index, subindex) in a PDO layout."""
    for n, (index, sub, _) in enumerate(layout):
        if (index, sub) in keys:
            return n
    raise ValueError(f"none of {keys} is mapped in {layout}")


class BusFeedback:
    """Drive ``node_id``'s synchronous TPDO1 (position) and TPDO2 (current) answers, each placed
    at the SYNC it answered: a frame sink of a :class:`BusMonitor` (which owns the connection and
    the receive thread and calls :meth:`on_frame` under its lock). ``family``: "epos4" or "epos2"
    (the TPDO layouts). ``max_latency`` (s): the longest an answer may follow its SYNC to be
    placed."""

    def __init__(self, node_id: int = 1, family: str = "epos4", max_latency: float = 0.009,
                 keep: int = 200_000) -> None:
        self.node_id = int(node_id)
        l1, l2 = tpdo1_layout(family), tpdo2_layout(family)
        self._fmt1, self._fmt2 = struct.Struct(struct_format(l1)), struct.Struct(struct_format(l2))
        self._pos = _field(l1, ((0x6064, 0),))
        self._cur = _field(l2, ((0x30D1, 2), (0x6078, 0)))
        self._tpdo1, self._tpdo2 = TPDO1_BASE + self.node_id, TPDO2_BASE + self.node_id
        self._pair1, self._pair2 = SyncPairing(max_latency), SyncPairing(max_latency)
        self._lock = threading.Lock()
        self._positions: deque[tuple[float, int]] = deque(maxlen=keep)    # (SYNC bus s, increments)
        self._currents: deque[tuple[float, float]] = deque(maxlen=keep)   # (SYNC bus s, A)
        self._syncs: deque[float] = deque(maxlen=keep)                    # SYNC bus s
        self.unplaced = 0               # TPDO1 answers not placed (their SYNC not certain)

    def on_frame(self, t: float, cid: int, data: bytes) -> None:
        """A data frame with COB-ID ``cid`` on the bus at ``t`` s."""
        with self._lock:
            if cid == SYNC_ID:
                self._syncs.append(t)
                self._pair1.sync(t)
                self._pair2.sync(t)
            elif cid == self._tpdo1 and len(data) >= self._fmt1.size:
                sync = self._pair1.answer(t)
                if sync is None:
                    self.unplaced += 1
                else:
                    self._positions.append((sync, int(self._fmt1.unpack_from(data)[self._pos])))
            elif cid == self._tpdo2 and len(data) >= self._fmt2.size:
                sync = self._pair2.answer(t)
                if sync is not None:
                    self._currents.append((sync, 1e-3 * self._fmt2.unpack_from(data)[self._cur]))

    def samples(self, t_from: float, t_to: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(SYNC instants s, positions in increments, currents A — NaN where TPDO2 was not
        placed) of the TPDO1 answers placed at SYNCs in [t_from, t_to] s, in time order."""
        with self._lock:
            pos = [p for p in self._positions if t_from <= p[0] <= t_to]
            cur = dict(c for c in self._currents if t_from <= c[0] <= t_to)
        t = np.array([p[0] for p in pos], float)
        counts = np.array([p[1] for p in pos], float)
        amps = np.array([cur.get(p[0], np.nan) for p in pos], float)
        return t, counts, amps

    def sync_count(self, t_from: float, t_to: float) -> int:
        """SYNCs on the bus in [t_from, t_to] s."""
        with self._lock:
            return sum(1 for s in self._syncs if t_from <= s <= t_to)


class StackBus(BusMonitor):
    """A :class:`BusMonitor` (current changes, SYNC instants) that also reads the drive's samples
    off the bus (``feedback``, a :class:`BusFeedback` fed by the monitor's receive thread): what
    on-stack identification times and measures its runs with. Arguments as the BusMonitor's."""

    def __init__(self, hub_url: str, node_id: int = 1, family: str = "epos4", nominal_current: float = 3.0,
                 latched: bool = True, max_latency: float = 0.009, **more: Any) -> None:
        self.feedback = BusFeedback(node_id=node_id, family=family, max_latency=max_latency)
        super().__init__(hub_url, node_id=node_id, family=family, nominal_current=nominal_current,
                         latched=latched, max_latency=max_latency, sinks=(self.feedback,), **more)
