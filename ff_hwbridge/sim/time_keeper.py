"""The CAN hub's transmit schedule: frames handed in ahead of time go on the bus at their instant.

A CAN controller's scheduled transmit, or the kernel's broadcast manager sending a sequence of
frames on its hrtimer, puts a frame on the wire at a set instant whatever the sending process
is doing then. The simulation's hub plays that part for its clients: the hub's channel is a
:class:`TimedVirtualBus` (python-can interface ``ff_hub_virtual``, registered as a
``can.interface`` entry point), and

- a frame whose timestamp (wall s, the bus instant a client's ``send_at`` gives it, ``sim.hub_bus``) lies in
  the future when it reaches the hub is held by the channel's :class:`TimeKeeper` and put on the
  channel at that instant, keeping that timestamp (the frame's bus instant is its scheduled one,
  as the SYNC's is its timer deadline; how late the keeper's thread really was is measured and
  reported apart: ``late_p99_us``, ``late_max_us``);
- a frame whose timestamp has passed (every ordinary send) goes on the channel at once, and
  removes the held frames of the same CAN id with a later instant, from every client: a new
  immediate write (a stop, a safe-state reaction, the master's controlword) replaces what was
  scheduled after it, so that no scheduled setpoint overrides it;
- a client's held frames are dropped when its connection closes (a player process that died
  leaves nothing behind on the bus), as the kernel drops a socket's broadcast jobs.

The keeper's thread sleeps until shortly before the earliest instant and spins to it; it takes
the hub's SCHED_FIFO priority when the hub has one (``ff-can-hub`` sets it for every thread it
starts). Units: s (python-can timestamps, wall clock), ns inside.
"""
from __future__ import annotations

import copy
import heapq
import itertools
import logging
import threading
import time
from collections import deque
from typing import Any, Optional

import can
import numpy as np
from can.interfaces.virtual import VirtualBus

log = logging.getLogger(__name__)

__all__ = ["INTERFACE", "TimeKeeper", "TimedVirtualBus", "keeper_stats"]

#: the python-can interface name of the hub's channel (entry point ``can.interface``)
INTERFACE = "ff_hub_virtual"
SPIN_NS = 50_000          # the keeper spins this long before an instant (ns)
MAX_HELD = 65_536         # frames held per channel at most (a runaway sender is refused)

_keepers: dict[Any, "TimeKeeper"] = {}
_keepers_lock = threading.Lock()


class TimeKeeper:
    """The held frames of one virtual channel, and the thread that sends them at their instant."""

    def __init__(self, channel: Any) -> None:
        self.channel = channel
        self._heap: list[tuple[int, int, "TimedVirtualBus", can.Message]] = []
        self._order = itertools.count()
        self._cond = threading.Condition()
        self._late: deque[int] = deque(maxlen=100_000)
        self.sent = self.cancelled = self.dropped = 0
        self._thread = threading.Thread(target=self._run, name=f"ff-hub-time-keeper-{channel}",
                                        daemon=True)
        self._thread.start()

    def hold(self, bus: "TimedVirtualBus", msg: can.Message, at_ns: int) -> None:
        """Send ``msg`` on ``bus`` at wall instant ``at_ns``."""
        with self._cond:
            if len(self._heap) >= MAX_HELD:
                raise can.CanOperationError(f"the hub's transmit schedule is full ({MAX_HELD} frames)")
            heapq.heappush(self._heap, (at_ns, next(self._order), bus, msg))
            self._cond.notify()

    def supersede(self, can_id: int, after_ns: int) -> int:
        """Drop the held frames of ``can_id`` scheduled after wall instant ``after_ns``."""
        with self._cond:
            keep = [h for h in self._heap if not (h[3].arbitration_id == can_id and h[0] > after_ns)]
            n = len(self._heap) - len(keep)
            if n:
                heapq.heapify(keep)
                self._heap = keep
                self.cancelled += n
        return n

    def forget(self, bus: "TimedVirtualBus") -> int:
        """Drop every frame ``bus`` still has held (its connection closed)."""
        with self._cond:
            keep = [h for h in self._heap if h[2] is not bus]
            n = len(self._heap) - len(keep)
            if n:
                heapq.heapify(keep)
                self._heap = keep
                self.dropped += n
        return n

    def stats(self) -> dict[str, float]:
        """Frames sent from the schedule, cancelled by a later immediate frame, dropped with their
        client; held now; how late the thread put them on the channel (µs, p50 / p99 / max)."""
        with self._cond:
            late = np.array(self._late, dtype=float) / 1000.0
            held = len(self._heap)
        nan = float("nan")
        return {"sent": self.sent, "cancelled": self.cancelled, "dropped": self.dropped,
                "held": held,
                "late_p50_us": float(np.percentile(late, 50)) if late.size else nan,
                "late_p99_us": float(np.percentile(late, 99)) if late.size else nan,
                "late_max_us": float(late.max()) if late.size else nan}

    def _run(self) -> None:
        from ff_hwbridge.sim.sync import timer_slack_1us, wall_minus_mono

        timer_slack_1us()
        while True:
            with self._cond:
                while not self._heap:
                    self._cond.wait()
                at_ns = self._heap[0][0]
                left = at_ns - time.time_ns() - SPIN_NS
                if left > 0:
                    self._cond.wait(left / 1e9)      # a new earlier frame wakes it too
                    continue
            # spin on the monotonic clock to the instant (the wall clock may be stepped)
            end = at_ns - wall_minus_mono()
            while time.monotonic_ns() < end:
                pass
            with self._cond:
                due = []
                now = time.time_ns()
                while self._heap and self._heap[0][0] <= now:
                    due.append(heapq.heappop(self._heap))
            for at, _, bus, msg in due:
                self._late.append(time.time_ns() - at)
                try:
                    bus.send_scheduled(msg)
                    self.sent += 1
                except can.CanError:
                    self.dropped += 1          # its client closed meanwhile


def fan_out(bus: VirtualBus, msg: can.Message, timestamp: float) -> None:
    """``msg`` to every other queue of ``bus``'s channel (and its own with
    ``receive_own_messages``), stamped ``timestamp``. python-can's virtual bus deep-copies the
    frame for every receiver (~20 µs each); the hub's receivers only read it, so a shallow copy
    per receiver does (measured at 1 kHz SYNC: some 8000 deliveries a second)."""
    for q in list(bus.channel):
        if q is bus.queue and not bus.receive_own_messages:
            continue
        m = copy.copy(msg)
        m.timestamp = timestamp
        m.channel = bus.channel_id
        m.is_rx = q is not bus.queue
        q.put_nowait(m)


def _keeper(channel: Any) -> TimeKeeper:
    with _keepers_lock:
        k = _keepers.get(channel)
        if k is None:
            k = _keepers[channel] = TimeKeeper(channel)
        return k


def keeper_stats(channel: Any) -> Optional[dict[str, float]]:
    """The statistics of ``channel``'s keeper (None: no frame was ever scheduled on it)."""
    with _keepers_lock:
        k = _keepers.get(channel)
    return None if k is None else k.stats()


class TimedVirtualBus(VirtualBus):
    """python-can's virtual bus with the hub's transmit schedule (see the module docstring).

    Timestamps are kept as sent (``preserve_timestamps`` is forced on): every client of the hub
    stamps its frames with their bus instant. Receive queues are unbounded (python-can's
    default): a send never blocks the hub."""

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        kwargs["preserve_timestamps"] = True
        super().__init__(channel=channel, **kwargs)
        self.channel_info = f"Virtual bus channel {channel} (scheduled transmit)"

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        self._check_if_open()
        at_ns = int(round(msg.timestamp * 1e9)) if msg.timestamp else 0
        keeper = _keeper(self.channel_id)
        if at_ns > time.time_ns():
            keeper.hold(self, msg, at_ns)
            return
        keeper.supersede(msg.arbitration_id, at_ns)
        fan_out(self, msg, msg.timestamp)

    def send_scheduled(self, msg: can.Message) -> None:
        """Put a held frame on the channel now, with its scheduled instant as timestamp."""
        self._check_if_open()
        fan_out(self, msg, msg.timestamp)

    def shutdown(self) -> None:
        with _keepers_lock:
            k = _keepers.get(self.channel_id)
        if k is not None:
            k.forget(self)
        super().shutdown()
