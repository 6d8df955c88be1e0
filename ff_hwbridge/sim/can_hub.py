"""One CAN bus shared by processes on this machine, on loopback only.

There is no kernel CAN device here (no vcan). The hub is a python-can-remote server on
127.0.0.1 serving a python-can ``virtual`` channel; every process that opens
``{"interface": "remote", "channel": "ws://127.0.0.1:PORT/"}`` (``ff_hwbridge.drive.bus.open_bus``)
sees the same frames. With ``sync_period`` > 0 the hub also produces SYNC itself
(:class:`~ff_hwbridge.sim.sync.SyncSource`, a timer thread putting the frame straight on the
virtual channel), the simulation's stand-in for the kernel's SYNC timer. Every frame carries
its bus instant as timestamp: a client's frame its send instant (``open_bus`` stamps it), the
SYNC its modelled instant (the timer's deadline, see ``SyncSource``); clients receive it with
the frame. The channel keeps a transmit schedule (:mod:`~ff_hwbridge.sim.time_keeper`): a frame
stamped with a future instant is put on the bus at that instant, as a controller's scheduled
transmit or the kernel's broadcast manager would. It is for tests and demos: a product on
socketcan / pcan / kvaser needs
none of it. Command line: ``ff-can-hub`` (``ff_hwbridge.cli.can_hub``).
"""
from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import can
from can import BusABC
from can.interfaces.virtual import VirtualBus, channels, channels_lock

from ff_hwbridge.drive.bus import DEFAULT_BITRATE, LOOPBACK, CanConfigError, check_loopback
from ff_hwbridge.sim.sync import SyncSource
from ff_hwbridge.sim.time_keeper import INTERFACE as TIMED_INTERFACE
from ff_hwbridge.sim.time_keeper import fan_out

__all__ = ["CanHub", "start_hub"]


class _TransmitOnlyBus(VirtualBus):
    """A virtual bus that only sends (the SYNC source's): python-can's would get a copy of every
    frame on the channel, kept unread (at 1 kHz SYNC some 3000 frames a second). It looks the
    channel up at each send: python-can drops a channel whose last receiver left, and a client
    joining later gets a new one."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        with channels_lock:
            self.channel.remove(self.queue)
            if not self.channel:
                del channels[self.channel_id]

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        self._check_if_open()
        with channels_lock:
            self.channel = channels.setdefault(self.channel_id, [])
        fan_out(self, msg, msg.timestamp if self.preserve_timestamps else time.time())

    def shutdown(self) -> None:
        BusABC.shutdown(self)
        self._open = False


@dataclass
class CanHub:
    """A running hub: a python-can-remote server on loopback serving a virtual channel."""

    host: str
    port: int
    channel: str
    _server: Any = field(repr=False, default=None)
    _thread: Optional[threading.Thread] = field(repr=False, default=None)
    sync: Optional[SyncSource] = field(repr=False, default=None)
    _sync_bus: Any = field(repr=False, default=None)

    def start_sync(self, period: float, rt_priority: int = 0, stamp: str = "deadline",
                   jitter_model: float = 0.0) -> SyncSource:
        """Produce SYNC every ``period`` s on the hub's channel (idempotent); ``stamp`` and
        ``jitter_model`` (s): the SYNC timing model (:class:`~ff_hwbridge.sim.sync.SyncSource`)."""
        if self.sync is None:
            self._sync_bus = _TransmitOnlyBus(channel=self.channel, bitrate=DEFAULT_BITRATE,
                                              preserve_timestamps=stamp == "deadline")
            try:
                self.sync = SyncSource(self._sync_bus, period, rt_priority=rt_priority, stamp=stamp,
                                       jitter_model=jitter_model).start()
            except ValueError:
                self._sync_bus.shutdown()
                self._sync_bus = None
                raise
        return self.sync

    def stop_sync(self) -> None:
        if self.sync is not None:
            self.sync.stop()
            self.sync = None
        if self._sync_bus is not None:
            self._sync_bus.shutdown()
            self._sync_bus = None

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
        host, port = self._server.socket.getsockname()[:2]
        return str(host), int(port)

    def close(self) -> None:
        """Stop SYNC, stop serving and close the listening socket (idempotent)."""
        self.stop_sync()
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
              bitrate: int = DEFAULT_BITRATE, sync_period: float = 0.0,
              sync_rt_priority: int = 0, sync_stamp: str = "deadline",
              sync_jitter_model: float = 0.0) -> CanHub:
    """Start a hub in a background thread of this process; ``port`` 0 picks a free one.

    ``channel`` is the name of the virtual channel behind the hub (default ``ff-hub-PORT``);
    processes joining through the hub never see it. ``bitrate`` in bit/s. ``sync_period`` > 0 s:
    the hub produces SYNC (``sync_rt_priority`` > 0: SCHED_FIFO for its timer thread;
    ``sync_stamp``, ``sync_jitter_model`` s: its timing model, ``SyncSource``).
    """
    # python-can-remote's server pulls in its web stack: imported only when a hub is started
    from can_remote.server import RemoteServer

    host = check_loopback(host)
    if not 0 <= int(port) <= 65535:
        raise CanConfigError(f"hub port must be 0..65535, got {port}")
    if port == 0:  # the virtual channel name must be fixed before the server exists
        with socket.socket() as s:
            s.bind((host, 0))
            port = s.getsockname()[1]
    chan = channel or f"ff-hub-{port}"
    try:
        server = RemoteServer(host, int(port), interface=TIMED_INTERFACE, channel=chan,
                              bitrate=bitrate)
    except OSError as exc:
        raise CanConfigError(f"cannot serve the CAN hub on {host}:{port}: {exc}; "
                             "choose another --port") from exc
    hub = CanHub(host=host, port=server.server_port, channel=chan, _server=server)
    hub._thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1},
                                   name=f"can-hub-{hub.port}", daemon=True)
    hub._thread.start()
    if sync_period > 0:
        try:
            hub.start_sync(sync_period, sync_rt_priority, sync_stamp, sync_jitter_model)
        except ValueError as exc:
            hub.close()
            raise CanConfigError(str(exc)) from exc
    return hub
