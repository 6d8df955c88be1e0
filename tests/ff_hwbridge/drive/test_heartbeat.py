"""The master's heartbeat comes from a thread of this process, never from the bus's periodic
sender (the kernel's broadcast manager on SocketCAN keeps sending for a frozen process)."""
from __future__ import annotations

import time

import can
import pytest

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.drive.heartbeat import HeartbeatSender
from tests.support.canopen_helpers import mini_config, unique_channel, waiter

wait_for = waiter(3.0)


def test_the_sender_keeps_its_period_and_stops():
    sent: list[float] = []
    hb = HeartbeatSender(lambda: sent.append(time.monotonic()), 0.02)
    time.sleep(0.5)
    hb.stop()
    n = len(sent)
    time.sleep(0.1)
    assert len(sent) == n                               # stopped
    # absolute deadlines: ~25 in 0.5 s, a loaded machine's late wake-ups do not add up
    assert 15 <= n <= 27, n
    with pytest.raises(ValueError, match="period must be > 0"):
        HeartbeatSender(lambda: None, 0.0)


def test_the_master_heartbeat_is_sent_from_user_space(monkeypatch):
    channel = unique_channel("ff-hb")
    cfg = mini_config(channel, master_heartbeat_ms=20)
    mon = can.Bus(interface="virtual", channel=channel)
    master = EposMaster(cfg)
    try:
        master.connect()

        def refused(*a, **k):
            raise AssertionError("the master heartbeat must not go to a periodic sender")

        monkeypatch.setattr(master.network.bus, "send_periodic", refused)
        master._start_master_heartbeat()
        t0 = time.monotonic()
        seen = []
        while time.monotonic() - t0 < 0.3:
            m = mon.recv(0.05)
            if m is not None and m.arbitration_id == 0x700 + cfg.master_node_id:
                seen.append(bytes(m.data))
        assert len(seen) >= 5 and set(seen) == {b"\x05"}     # OPERATIONAL, every 20 ms
        master.stop_master_heartbeat()
    finally:
        master.disconnect()
        mon.shutdown()
