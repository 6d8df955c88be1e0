"""The drive's own samples, read off the CAN bus: each synchronous TPDO's position (and current)
at the SYNC it answered, for on-stack identification.

A synchronous TPDO holds the values the drive sampled *at* a SYNC. Which SYNC is certain only
while one is pending: a drive answers every SYNC in order, so an answer that comes after the
next SYNC is already on the bus (a drive process stalled for more than a period) may belong to
either of them to anyone who pairs it with "the latest SYNC seen". Placed there, a 10 ms-late
answer moves its sample one SYNC period (at 3 rad/s, 30 mrad: hundreds of encoder counts).
:class:`BusFeedback` therefore pairs with :class:`ff_executor.bringup.bus_monitor.SyncPairing`
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
import time
from collections import deque
from typing import Any

import numpy as np

from ff_executor.bringup.bus_monitor import SYNC_ID, TPDO1_BASE, BusMonitor, SyncPairing
from ff_hwbridge.drive.bus import open_bus
from ff_hwbridge.protocol.epos_od import struct_format, tpdo1_layout, tpdo2_layout

TPDO2_BASE = 0x280


def _field(layout: list[tuple[int, int, str]], keys: tuple[tuple[int, int], ...]) -> int:
    """Position of the first of ``keys`` (index, subindex) in a PDO layout."""
    for n, (index, sub, _) in enumerate(layout):
        if (index, sub) in keys:
            return n
    raise ValueError(f"none of {keys} is mapped in {layout}")


class BusFeedback:
    """Receive-only client of the CAN hub at ``hub_url``: drive ``node_id``'s synchronous TPDO1
    (position) and TPDO2 (current) answers, each placed at the SYNC it answered; a context
    manager. ``family``: "epos4" or "epos2" (the TPDO layouts). ``max_latency`` (s): the longest
    an answer may follow its SYNC to be placed."""

    def __init__(self, hub_url: str, node_id: int = 1, family: str = "epos4", max_latency: float = 0.009,
                 keep: int = 200_000) -> None:
        self.node_id = int(node_id)
        l1, l2 = tpdo1_layout(family), tpdo2_layout(family)
        self._fmt1, self._fmt2 = struct.Struct(struct_format(l1)), struct.Struct(struct_format(l2))
        self._pos = _field(l1, ((0x6064, 0),))
        self._cur = _field(l2, ((0x30D1, 2), (0x6078, 0)))
        self._pair1, self._pair2 = SyncPairing(max_latency), SyncPairing(max_latency)
        self._lock = threading.Lock()
        self._positions: deque[tuple[float, int]] = deque(maxlen=keep)    # (SYNC bus s, increments)
        self._currents: deque[tuple[float, float]] = deque(maxlen=keep)   # (SYNC bus s, A)
        self._syncs: deque[float] = deque(maxlen=keep)                    # SYNC bus s
        self.unplaced = 0               # TPDO1 answers not placed (their SYNC not certain)
        self.latest = 0.0               # bus s of the newest frame received
        self._stop = threading.Event()
        self._bus: Any = open_bus({"interface": "remote", "channel": hub_url, "bitrate": 1_000_000})
        self._thread = threading.Thread(target=self._run, name="bus-feedback", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        tpdo1, tpdo2 = TPDO1_BASE + self.node_id, TPDO2_BASE + self.node_id
        while not self._stop.is_set():
            try:
                m = self._bus.recv(0.1)
            except Exception:              # the hub went away: nothing more to see
                if self._stop.is_set():
                    return
                continue
            if m is None or m.is_remote_frame:
                continue
            t, cid, data = float(m.timestamp), m.arbitration_id, bytes(m.data)
            with self._lock:
                self.latest = max(self.latest, t)
                if cid == SYNC_ID:
                    self._syncs.append(t)
                    self._pair1.sync(t)
                    self._pair2.sync(t)
                elif cid == tpdo1 and len(data) >= self._fmt1.size:
                    sync = self._pair1.answer(t)
                    if sync is None:
                        self.unplaced += 1
                    else:
                        self._positions.append((sync, int(self._fmt1.unpack_from(data)[self._pos])))
                elif cid == tpdo2 and len(data) >= self._fmt2.size:
                    sync = self._pair2.answer(t)
                    if sync is not None:
                        self._currents.append((sync, 1e-3 * self._fmt2.unpack_from(data)[self._cur]))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        try:
            self._bus.shutdown()
        except Exception:
            pass

    def __enter__(self) -> "BusFeedback":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def wait_seen(self, t: float, timeout: float = 1.0) -> bool:
        """Wait until a frame with a bus time after ``t`` s has been received; False after
        ``timeout`` s."""
        end = time.monotonic() + timeout
        while True:
            with self._lock:
                if self.latest > t:
                    return True
            if time.monotonic() >= end:
                return False
            time.sleep(0.005)

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
    off the bus (``feedback``, a :class:`BusFeedback` on the same hub): what on-stack
    identification times and measures its runs with. Arguments as the BusMonitor's."""

    def __init__(self, hub_url: str, node_id: int = 1, family: str = "epos4", nominal_current: float = 3.0,
                 latched: bool = True, max_latency: float = 0.009, **more: Any) -> None:
        super().__init__(hub_url, node_id=node_id, family=family, nominal_current=nominal_current,
                         latched=latched, max_latency=max_latency, **more)
        try:
            self.feedback = BusFeedback(hub_url, node_id=node_id, family=family, max_latency=max_latency)
        except Exception:
            super().close()
            raise

    def close(self) -> None:
        self.feedback.close()
        super().close()

    def wait_seen(self, t: float, timeout: float = 1.0) -> bool:
        """Wait until both listeners have received a frame with a bus time after ``t`` s; False
        after ``timeout`` s."""
        end = time.monotonic() + timeout
        seen = super().wait_seen(t, timeout)
        return self.feedback.wait_seen(t, max(0.0, end - time.monotonic())) and seen
