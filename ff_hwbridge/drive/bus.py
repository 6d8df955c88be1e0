"""Open a python-can bus (and a canopen Network on it) from a config dict.

``open_bus(config)`` opens any python-can bus from a config dict (interface, channel, bitrate,
other keyword arguments). Settings whose traffic would leave this machine's loopback are refused:
``udp_multicast``, and a ``remote`` channel that is not a ws:// URL on a loopback host. For the
``remote`` interface it installs the periodic-sender workaround (python-can-remote's own cyclic
task breaks when its data changes; canopen changes heartbeat frames on every NMT state change;
python-can's generic thread-based sender works) and serialises sends from several threads onto
the one websocket. A frame sent on a ``remote`` bus carries its send instant as its bus timestamp
(``preserve_timestamps`` on the hub's side): on a real bus the controller puts a frame on the
wire microseconds after the send, while the hub's own scheduling (it may be descheduled for
milliseconds on a busy machine) is no part of the bus. Receivers order frames by these stamps.
"""
from __future__ import annotations

import ipaddress
import threading
import time
import types
from typing import Any, Mapping, Optional
from urllib.parse import urlparse

import can
import canopen

#: bit/s, the default bitrate of every bus
DEFAULT_BITRATE = 1_000_000
LOOPBACK = "127.0.0.1"

__all__ = ["DEFAULT_BITRATE", "LOOPBACK", "CanConfigError", "check_loopback",
           "normalise_bus_config", "open_bus", "open_network"]


class CanConfigError(ValueError):
    """A bus or hub setting that cannot be used; the message says what to change."""


def check_loopback(host: str) -> str:
    """Return ``host`` (``localhost`` as 127.0.0.1) if it is a loopback address, else raise
    CanConfigError."""
    name = LOOPBACK if host == "localhost" else host
    try:
        ok = ipaddress.ip_address(name).is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise CanConfigError(f"the CAN hub binds loopback only; got host {host!r}, use '127.0.0.1'")
    return name


def normalise_bus_config(config: Mapping[str, Any]) -> dict[str, Any]:
    """Check a python-can bus config dict: needs ``interface``; ``bitrate`` defaults to 1 Mbit/s.

    Refuses ``udp_multicast`` (its traffic leaves loopback) and a ``remote`` channel that is not
    a ws:// URL on a loopback host.
    """
    cfg = dict(config)
    iface = cfg.get("interface") or cfg.pop("bustype", None)
    if not iface:
        raise CanConfigError("bus config needs 'interface' (e.g. socketcan, pcan, kvaser, "
                             "virtual, remote) and usually 'channel'")
    cfg["interface"] = str(iface)
    cfg.setdefault("bitrate", DEFAULT_BITRATE)
    if cfg["interface"] == "udp_multicast":
        raise CanConfigError("interface 'udp_multicast' sends traffic off this machine; use "
                             "'remote' with a hub on 127.0.0.1 instead")
    if cfg["interface"] == "remote":
        url = str(cfg.get("channel", ""))
        parsed = urlparse(url)
        if parsed.scheme not in ("ws", "wss") or not parsed.hostname:
            raise CanConfigError(f"remote channel must look like 'ws://127.0.0.1:PORT/', got {url!r}")
        check_loopback(parsed.hostname)
    return cfg


def _fix_remote_bus(bus: can.BusABC) -> None:
    """python-can's generic periodic sender and one lock around ``send`` on a remote bus."""
    bus._send_periodic_internal = types.MethodType(  # type: ignore[method-assign]
        can.BusABC._send_periodic_internal, bus)
    # One websocket per bus, written by several threads (periodic tasks, canopen, user code):
    # serialise the writes so frames never interleave on the socket.
    send, lock = bus.send, threading.Lock()

    def locked_send(msg: can.Message, timeout: Optional[float] = None) -> None:
        with lock:
            msg.timestamp = time.time()     # the frame's bus instant: its send (see the module doc)
            send(msg, timeout)

    bus.send = locked_send  # type: ignore[method-assign]


def open_bus(config: Mapping[str, Any]) -> can.BusABC:
    """Open a python-can bus from a config dict; remote buses get the periodic-sender fix."""
    cfg = normalise_bus_config(config)
    kwargs = dict(cfg)
    if cfg["interface"] == "remote":
        kwargs.setdefault("preserve_timestamps", True)
    try:
        bus = can.Bus(**kwargs)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise CanConfigError(f"cannot open CAN bus {cfg}: {exc}") from exc
    if cfg["interface"] == "remote":
        _fix_remote_bus(bus)
    return bus


def open_network(config: Mapping[str, Any]) -> canopen.Network:
    """A connected ``canopen.Network`` on a bus opened by ``open_bus(config)``."""
    net = canopen.Network(open_bus(config))
    net.NOTIFIER_CYCLE = 0.1            # recv timeout: bounds how long disconnect() waits
    net.connect()
    return net
