"""One CAN bus shared by processes on this machine, on loopback only, plus a bus opener.

There is no kernel CAN device here (no vcan). The hub is a python-can-remote server on
127.0.0.1 serving a python-can ``virtual`` channel; every process that opens
``{"interface": "remote", "channel": "ws://127.0.0.1:PORT/"}`` sees the same frames.
It is for tests and demos: a product on socketcan / pcan / kvaser needs none of it.

    python -m ff_hwbridge.sim.can_hub --port 54701      # prints the URL, stops on SIGINT/SIGTERM

``open_bus(config)`` opens any python-can bus from a config dict (interface, channel, bitrate,
other keyword arguments) and, for the ``remote`` interface, installs the periodic-sender
workaround (python-can-remote's own cyclic task breaks when its data changes; canopen changes
heartbeat frames on every NMT state change; python-can's generic thread-based sender works) and
serialises sends from several threads onto the one websocket.
"""
from __future__ import annotations

import argparse
import ipaddress
import signal
import socket
import sys
import threading
import types
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

import can

DEFAULT_BITRATE = 1_000_000
LOOPBACK = "127.0.0.1"


class CanConfigError(ValueError):
    """A bus or hub setting that cannot be used; the message says what to change."""


def _check_loopback(host: str) -> str:
    """Return ``host`` if it is a loopback address, else raise CanConfigError."""
    name = "127.0.0.1" if host == "localhost" else host
    try:
        ok = ipaddress.ip_address(name).is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise CanConfigError(f"the CAN hub binds loopback only; got host {host!r}, use '127.0.0.1'")
    return name


@dataclass
class CanHub:
    """A running hub: a python-can-remote server on loopback serving a virtual channel."""

    host: str
    port: int
    channel: str
    _server: Any = field(repr=False, default=None)
    _thread: Optional[threading.Thread] = field(repr=False, default=None)

    @property
    def url(self) -> str:
        """The channel clients pass with ``interface="remote"``."""
        return f"ws://{self.host}:{self.port}/"

    def bus_config(self) -> dict[str, Any]:
        """A python-can bus config that joins this hub."""
        return {"interface": "remote", "channel": self.url, "bitrate": DEFAULT_BITRATE}

    def local_bus_config(self) -> dict[str, Any]:
        """A bus config for code in THIS process: the hub's virtual channel directly (no
        websocket hop; frames still reach every remote client)."""
        return {"interface": "virtual", "channel": self.channel, "bitrate": DEFAULT_BITRATE}

    def bound_address(self) -> tuple[str, int]:
        """The (host, port) the server socket is bound to (tests check it is loopback)."""
        return self._server.socket.getsockname()[:2]

    def close(self) -> None:
        """Stop serving and close the listening socket (idempotent)."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            if self._thread is not None:
                self._thread.join(timeout=5.0)
            self._server = None

    def __enter__(self) -> "CanHub":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def start_hub(port: int = 0, host: str = LOOPBACK, channel: Optional[str] = None,
              bitrate: int = DEFAULT_BITRATE) -> CanHub:
    """Start a hub in a background thread of this process; ``port`` 0 picks a free one.

    ``channel`` is the name of the virtual channel behind the hub (default ``ff-hub-PORT``);
    processes joining through the hub never see it.
    """
    from can_remote.server import RemoteServer

    host = _check_loopback(host)
    if not 0 <= int(port) <= 65535:
        raise CanConfigError(f"hub port must be 0..65535, got {port}")
    if port == 0:  # the virtual channel name must be fixed before the server exists
        with socket.socket() as s:
            s.bind((host, 0))
            port = s.getsockname()[1]
    chan = channel or f"ff-hub-{port}"
    try:
        server = RemoteServer(host, int(port), interface="virtual", channel=chan, bitrate=bitrate)
    except OSError as exc:
        raise CanConfigError(f"cannot serve the CAN hub on {host}:{port}: {exc}; "
                             "choose another --port") from exc
    hub = CanHub(host=host, port=server.server_port, channel=chan, _server=server)
    hub._thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1},
                                   name=f"can-hub-{hub.port}", daemon=True)
    hub._thread.start()
    return hub


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
        from urllib.parse import urlparse

        parsed = urlparse(url)
        if parsed.scheme not in ("ws", "wss") or not parsed.hostname:
            raise CanConfigError(f"remote channel must look like 'ws://127.0.0.1:PORT/', got {url!r}")
        _check_loopback(parsed.hostname)
    return cfg


def open_bus(config: Mapping[str, Any]) -> can.BusABC:
    """Open a python-can bus from a config dict; remote buses get the periodic-sender fix."""
    cfg = normalise_bus_config(config)
    try:
        bus = can.Bus(**cfg)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise CanConfigError(f"cannot open CAN bus {cfg}: {exc}") from exc
    if cfg["interface"] == "remote":
        bus._send_periodic_internal = types.MethodType(can.BusABC._send_periodic_internal, bus)
        # One websocket per bus, written by several threads (periodic tasks, canopen, user
        # code): serialise the writes so frames never interleave on the socket.
        send, lock = bus.send, threading.Lock()

        def locked_send(msg: can.Message, timeout: Optional[float] = None) -> None:
            with lock:
                send(msg, timeout)

        bus.send = locked_send
    return bus


def open_network(config: Mapping[str, Any]):
    """A connected ``canopen.Network`` on a bus opened by ``open_bus(config)``."""
    import canopen

    net = canopen.Network(open_bus(config))
    net.NOTIFIER_CYCLE = 0.1            # recv timeout: bounds how long disconnect() waits
    net.connect()
    return net


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m ff_hwbridge.sim.can_hub --port P``: serve until SIGINT/SIGTERM."""
    ap = argparse.ArgumentParser(prog="ff_can_hub", description=__doc__.splitlines()[0])
    ap.add_argument("--port", type=int, default=54701, help="TCP port on 127.0.0.1 (0 = any free)")
    ap.add_argument("--host", default=LOOPBACK, help="loopback address to bind (default 127.0.0.1)")
    args = ap.parse_args(argv)
    try:
        hub = start_hub(args.port, args.host)
    except CanConfigError as exc:
        print(f"ff_can_hub: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"CAN hub on {hub.url}", flush=True)
    while not stop.wait(0.2):
        pass
    hub.close()
    print("CAN hub stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
