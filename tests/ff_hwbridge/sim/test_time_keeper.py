"""The CAN hub's transmit schedule (``ff_hwbridge.sim.time_keeper``): a frame stamped ahead goes
on the bus at its instant, an immediate frame replaces what was scheduled after it, a closed
client leaves nothing behind; its client side is the simulation's python-can interface
``ff_hub`` (``ff_hwbridge.sim.hub_bus``), the real master never schedules frames ahead
(``setpoint_lead`` is accepted with a warning and not used)."""
from __future__ import annotations

import time
import uuid

import can
import pytest

from ff_hwbridge.drive.bus import open_bus
from ff_hwbridge.drive.config import ConfigError
from ff_hwbridge.sim.can_hub import start_hub
from ff_hwbridge.sim.rig_process import rig_master_config
from ff_hwbridge.sim.time_keeper import TimedVirtualBus, keeper_stats
from tests.support.canopen_helpers import waiter

wait_for = waiter(5.0)


def _frame(can_id: int, at_s: float, data: bytes = b"\x01") -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False, timestamp=at_s)


@pytest.fixture
def channel():
    name = f"ff-keeper-{uuid.uuid4().hex[:8]}"
    buses = [TimedVirtualBus(channel=name) for _ in range(3)]
    yield name, buses
    for b in buses:
        b.shutdown()


def test_a_frame_stamped_ahead_goes_on_the_bus_at_its_instant(channel):
    name, (a, b, _) = channel
    at = time.time() + 0.05
    a.send(_frame(0x201, at))
    assert b.recv(0.02) is None                       # held: not on the bus yet
    msg = b.recv(1.0)
    got = time.time()
    assert msg is not None and msg.arbitration_id == 0x201
    assert msg.timestamp == pytest.approx(at, abs=1e-6)    # its bus instant is the scheduled one
    assert got >= at - 1e-4
    st = keeper_stats(name)
    assert st is not None and st["sent"] == 1 and st["held"] == 0


def test_an_immediate_frame_replaces_what_was_scheduled_after_it_from_any_client(channel):
    name, (a, b, c) = channel
    now = time.time()
    a.send(_frame(0x201, now + 0.06, b"\x02"))
    a.send(_frame(0x201, now + 0.08, b"\x03"))
    a.send(_frame(0x181, now + 0.07, b"\x04"))        # another id: kept
    c.send(_frame(0x201, time.time(), b"\x00"))       # e.g. the master's safe-state zero
    seen = []
    end = time.time() + 0.3
    while time.time() < end:
        m = b.recv(0.05)
        if m is not None:
            seen.append((m.arbitration_id, bytes(m.data)))
    assert seen == [(0x201, b"\x00"), (0x181, b"\x04")], seen
    assert keeper_stats(name)["cancelled"] == 2


def test_a_closed_clients_scheduled_frames_are_dropped(channel):
    name, (a, b, _) = channel
    a.send(_frame(0x201, time.time() + 0.05))
    a.shutdown()
    assert b.recv(0.2) is None
    st = keeper_stats(name)
    assert st["dropped"] == 1 and st["held"] == 0


def test_send_at_through_the_hub_with_its_python_can_interface():
    with start_hub() as hub:
        tx = can.Bus(interface="ff_hub", channel=hub.url)
        rx = open_bus(hub.bus_config())
        try:
            at_ns = time.time_ns() + 50_000_000
            assert tx.send_at(_frame(0x201, 0.0), at_ns) is True
            assert tx.send_at(_frame(0x202, 0.0), time.time_ns() - 1_000_000) is False  # passed: now
            first = rx.recv(1.0)
            assert first is not None and first.arbitration_id == 0x202
            second = rx.recv(1.0)
            assert second is not None and second.arbitration_id == 0x201
            assert abs(second.timestamp * 1e9 - at_ns) < 1000     # ns: float seconds on the wire
            assert time.time_ns() >= at_ns - 100_000
            tx.send(_frame(0x203, 0.0))                           # an ordinary send: now
            third = rx.recv(1.0)
            assert third is not None and third.arbitration_id == 0x203
            assert abs(third.timestamp - time.time()) < 0.5
        finally:
            tx.shutdown()
            rx.shutdown()


def test_the_real_master_has_no_transmit_schedule_and_setpoint_lead_is_not_used(caplog):
    from ff_hwbridge.drive import bus

    assert not hasattr(bus, "send_at")
    url = "ws://127.0.0.1:1/"
    with pytest.raises(ConfigError, match="0 .. 0.25 s"):
        rig_master_config(url, sync_period=0.01, setpoint_lead=0.5, player_process=True)
    with caplog.at_level("WARNING", logger="ff_hwbridge.drive.config"):
        cfg = rig_master_config(url, sync_period=0.01, setpoint_lead=0.05)
    assert cfg.setpoint_lead == 0.05 and "no longer used" in caplog.text
