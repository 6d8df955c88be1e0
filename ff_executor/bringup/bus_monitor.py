"""A receive-only listener on the simulated stack's CAN hub: when each sample was taken and when
each current took effect, in bus time.

The bridge stamps a joint state with the bus time of the drive's TPDO1, i.e. when the drive
*answered* the SYNC, while a synchronous TPDO (CiA 301, transmission type 1) holds the values
sampled *at* the SYNC: the answer comes 0.2–1.1 ms later on the simulated stack (measured), which
at 3 rad/s is up to 3 mrad. And the bridge's ``~/applied`` stamp is when it handed the RPDO to
the bus, not the frame's bus time at which the drive applies it. An identification that wants
its positions to within an encoder count needs both instants exactly; a second client on the bus
(as ``candump`` on a real bus) sees them:

* SYNC (COB-ID 0x080): its bus time is the sampling instant of the TPDOs answering it;
* TPDO1 (0x180 + node id): paired with the SYNC it answers (first in, first out: a drive answers
  every SYNC in order; ``SyncPairing`` says when a pairing is not certain);
* RPDO1 (0x200 + node id): controlword (u16) + setpoint (i16; EPOS4 0x6071 per mille of the
  nominal current, EPOS2 0x2030 mA): the current (A) the drive applies from the bus time of the
  next SYNC (a synchronous RPDO, the bridge's ``setpoint_timing: sync``) or of the frame itself
  (on receipt; the simulated drive then applies it when its process reads the frame, a little
  later: only the synchronous path is exact).

Times are the hub's wall clock (s), the same clock as the bridge's joint-state stamps.
"""
from __future__ import annotations

import struct
import threading
import time
from collections import deque
from typing import Any, Optional, Protocol, Sequence

import numpy as np

from ff_hwbridge.drive.bus import open_bus

SYNC_ID = 0x080
TPDO1_BASE = 0x180
RPDO1_BASE = 0x200
_RPDO1 = struct.Struct("<Hh")        # controlword, setpoint (epos_od.rpdo_layout)


class SyncPairing:
    """Which SYNC (bus s) a synchronous TPDO (bus s) answers: the oldest pending one.

    A drive answers every SYNC, in order, so one SYNC is pending when its answer comes. More
    pending ones are either a backlog the drive is working off (a stalled process: it shrinks by
    one per answer) or SYNCs nobody answered (sent before the drive was operational: it stays).
    With a backlog the pairing is not certain and the answer is not placed (None); a backlog that
    does not shrink for 5 answers is dropped but for the newest SYNC before the answer (whose
    answer it then is); an answer more than ``max_latency`` s
    after its SYNC is not placed either; a SYNC pending ``max_age`` s is dropped."""

    def __init__(self, max_latency: float = 0.009, max_age: float = 1.0) -> None:
        self.max_latency = float(max_latency)
        self.max_age = float(max_age)
        self._pending: deque[float] = deque()
        self._stuck = 0
        self._last_backlog = 0

    def sync(self, t: float) -> None:
        """A SYNC on the bus at ``t`` s."""
        self._pending.append(float(t))

    def answer(self, t: float) -> Optional[float]:
        """A TPDO on the bus at ``t`` s: the SYNC instant (s) it was sampled at, or None."""
        pend = self._pending
        while pend and t - pend[0] > self.max_age:
            pend.popleft()
        backlog = len(pend)
        if backlog >= 2 and backlog >= self._last_backlog:
            self._stuck += 1
            if self._stuck >= 5:          # nobody answered those: keep the newest SYNC before t
                while len(pend) >= 2 and pend[1] <= t:
                    pend.popleft()
                backlog = sum(1 for x in pend if x <= t)
                self._stuck = 0
        else:
            self._stuck = 0
        self._last_backlog = backlog
        if not pend or pend[0] > t:
            return None
        sync = pend.popleft()
        return sync if backlog == 1 and t - sync <= self.max_latency else None


class FrameSink(Protocol):
    """More readers of the monitor's frames, called in its receive thread under its lock."""

    def on_frame(self, t: float, cid: int, data: bytes) -> None:
        """A data frame with COB-ID ``cid`` on the bus at ``t`` s."""


class BusMonitor:
    """Receive-only client of the CAN hub at ``hub_url`` for drive ``node_id``; a context manager.

    ``family``/``nominal_current`` (A) decode the RPDO setpoint: "epos4" per mille of the nominal
    current, "epos2" mA. ``latched``: the drive latches setpoints at SYNC (the default of
    ``current_changes``). ``max_latency`` (s): the longest a TPDO may follow its SYNC. ``sinks``
    see every data frame too (one connection and one receive thread for all of them).
    """

    def __init__(self, hub_url: str, node_id: int = 1, family: str = "epos4", nominal_current: float = 3.0,
                 latched: bool = True, max_latency: float = 0.009, max_age: float = 1.0,
                 keep: int = 200_000, sinks: Sequence[FrameSink] = ()) -> None:
        if family not in ("epos4", "epos2"):
            raise ValueError(f"family must be 'epos4' or 'epos2', got {family!r}")
        self.node_id = int(node_id)
        self.latched = bool(latched)
        self._scale = float(nominal_current) / 1000.0 if family == "epos4" else 1e-3   # A per unit
        self._lock = threading.Lock()
        self.pairing = SyncPairing(max_latency, max_age)
        self._pairs: deque[tuple[float, float]] = deque(maxlen=keep)      # (TPDO1 bus s, SYNC bus s)
        self._rpdo: deque[tuple[float, float]] = deque(maxlen=keep)       # (bus s, current A)
        self._sync_times: deque[float] = deque(maxlen=keep)               # SYNC bus s
        self.syncs = 0
        self.unpaired = 0               # TPDO1s not placed (no SYNC, or not certainly theirs)
        self.latest = 0.0               # bus s of the newest frame received
        self._sinks = tuple(sinks)
        self._stop = threading.Event()
        self._bus: Any = open_bus({"interface": "remote", "channel": hub_url, "bitrate": 1_000_000})
        self._thread = threading.Thread(target=self._run, name="bus-monitor", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        tpdo, rpdo = TPDO1_BASE + self.node_id, RPDO1_BASE + self.node_id
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
                    self.syncs += 1
                    self.pairing.sync(t)
                    self._sync_times.append(t)
                elif cid == tpdo:
                    self._on_tpdo(t)
                elif cid == rpdo and len(data) >= _RPDO1.size:
                    _, raw = _RPDO1.unpack_from(data)
                    self._rpdo.append((t, raw * self._scale))
                for sink in self._sinks:
                    sink.on_frame(t, cid, data)

    def _on_tpdo(self, t: float) -> None:
        sync = self.pairing.answer(t)
        if sync is None:
            self.unpaired += 1
        else:
            self._pairs.append((t, sync))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        try:
            self._bus.shutdown()
        except Exception:
            pass

    def __enter__(self) -> "BusMonitor":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def wait_seen(self, t: float, timeout: float = 1.0) -> bool:
        """Wait until a frame with a bus time after ``t`` s has been received (the monitor is a
        thread of a process that may be slow: it can lag the bus); False after ``timeout`` s."""
        end = time.monotonic() + timeout
        while True:
            with self._lock:
                if self.latest > t:
                    return True
            if time.monotonic() >= end:
                return False
            time.sleep(0.005)

    def sample_instants(self, stamps: Sequence[float] | np.ndarray, tol: float = 2e-6) -> np.ndarray:
        """The SYNC instant (s) each joint-state ``stamp`` was sampled at: the stamp is a TPDO1's
        bus time (paired here with the SYNC it answered) or already that SYNC's instant (a bridge
        that stamps samples at their SYNC); NaN where it is neither, within ``tol`` s."""
        with self._lock:
            pairs = np.array(self._pairs, float).reshape(-1, 2)
        st = np.asarray(stamps, float)
        out = np.full(st.shape, np.nan)
        if pairs.shape[0] == 0 or st.size == 0:
            return out
        order = np.argsort(pairs[:, 0], kind="stable")
        tp, sy = pairs[order, 0], pairs[order, 1]
        k = np.clip(np.searchsorted(tp, st), 1, tp.size - 1) if tp.size > 1 else np.zeros(st.size, int)
        for cand in (k - 1, k) if tp.size > 1 else (k,):
            hit = np.abs(tp[cand] - st) <= tol
            out = np.where(hit & np.isnan(out), sy[cand], out)
        syncs = np.unique(sy)
        if syncs.size:
            j = np.clip(np.searchsorted(syncs, st), 0, syncs.size - 1)
            for cand in (np.clip(j - 1, 0, syncs.size - 1), j):
                hit = np.abs(syncs[cand] - st) <= tol
                out = np.where(hit & np.isnan(out), syncs[cand], out)
        return out

    def current_changes(self, t_from: float, t_to: float,
                        latched: Optional[bool] = None) -> list[tuple[float, float]]:
        """(s, A) of each RPDO1 on the bus between ``t_from`` and ``t_to`` (s) whose current
        differs from the one before it: when the drive's current changed — the frame's bus time
        (applied on receipt), or with ``latched`` the bus time of the first SYNC after it (a
        synchronous RPDO, CiA 301 transmission type 0-240; of two latched at the same SYNC the
        later one holds); a change whose SYNC has not been seen yet is left out. ``latched``
        None: the monitor's ``latched``."""
        latched = self.latched if latched is None else latched
        with self._lock:
            frames = list(self._rpdo)
            syncs = np.array(self._sync_times, float)
        out: list[tuple[float, float]] = []
        prev: Optional[float] = None
        for t, a in frames:
            if t < t_from:
                prev = a
                continue
            if t > t_to:
                break
            if prev is None or a != prev:
                if latched:
                    k = int(np.searchsorted(syncs, t, side="right"))
                    if k >= syncs.size:
                        break
                    t = float(syncs[k])
                if out and out[-1][0] == t:       # latched at the same SYNC: the later one holds
                    out.pop()
                    if out and out[-1][1] == a:
                        prev = a
                        continue
                out.append((t, a))
            prev = a
        return out
