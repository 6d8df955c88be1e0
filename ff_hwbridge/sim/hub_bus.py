"""A client of the simulation's CAN hub with the hub's transmit schedule: python-can interface
``ff_hub`` (``can.interface`` entry point).

The hub's channel (:mod:`~ff_hwbridge.sim.time_keeper`) holds a frame whose timestamp lies in
the future and puts it on the bus at that instant, as a controller's scheduled transmit would.
:class:`HubBus` is the client side: a ``remote`` bus (python-can-remote, ``preserve_timestamps``)
opened like ``open_bus`` opens one, whose ``send`` stamps a frame with its send instant and whose
``send_at(msg, at_ns)`` stamps it with a future wall instant (ns) for the hub to hold.

This is simulation only: the real master (``ff_hwbridge.drive``) never schedules frames ahead; it
sends each setpoint RPDO itself in the cycle before its SYNC.

    bus = can.Bus(interface="ff_hub", channel="ws://127.0.0.1:54701/")
"""
from __future__ import annotations

import threading
import time
from typing import Any, Optional

import can

from ff_hwbridge.drive.bus import open_bus

__all__ = ["INTERFACE", "HubBus"]

#: the python-can interface name of a hub client with the transmit schedule
INTERFACE = "ff_hub"


class HubBus(can.BusABC):
    """A hub client (``channel``: the hub's ws:// URL on loopback) with ``send_at``."""

    def __init__(self, channel: Any = None, **kwargs: Any) -> None:
        cfg = {k: v for k, v in kwargs.items() if k not in ("interface", "bustype")}
        self._bus = open_bus({**cfg, "interface": "remote", "channel": channel})
        self.channel_info = f"{self._bus.channel_info} (scheduled transmit)"
        self._lock = threading.Lock()       # one writer at a time on the one websocket
        super().__init__(channel=channel, **kwargs)

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        """Send now (stamped with the send instant)."""
        with self._lock:
            self._bus.send(msg, timeout)

    def send_at(self, msg: can.Message, at_ns: int, timeout: Optional[float] = None) -> bool:
        """Hand ``msg`` to the hub's transmit schedule for wall instant ``at_ns`` (ns): True when
        scheduled, False when that instant had passed (then sent now)."""
        with self._lock:
            if at_ns <= time.time_ns():
                self._bus.send(msg, timeout)
                return False
            msg.timestamp = at_ns / 1e9
            type(self._bus).send(self._bus, msg, timeout)   # python-can-remote's own: keeps the stamp
            return True

    def _recv_internal(self, timeout: Optional[float]) -> tuple[Optional[can.Message], bool]:
        return self._bus.recv(timeout), False

    def shutdown(self) -> None:
        self._bus.shutdown()
        super().shutdown()
