"""The CAN hub's transmit schedule (``ff_hwbridge.sim.time_keeper``): a frame stamped ahead goes
on the bus at its instant, an immediate frame replaces what was scheduled after it, a closed
client leaves nothing behind; and across processes, setpoints the player process hands to the
schedule ahead (``setpoint_lead``) latch at their own SYNC, and a clear + stop leaves none of the
scheduled ones to reach the drive."""
from __future__ import annotations

import json
import os
import tempfile
import time
import uuid

import can
import pytest

from ff_hwbridge.drive.bus import CanConfigError, open_bus, send_at
from ff_hwbridge.drive.config import ConfigError
from ff_hwbridge.drive.player_process import ProcessPlayer
from ff_hwbridge.sim.can_hub import start_hub
from ff_hwbridge.sim.rig_process import rig_master_config
from ff_hwbridge.sim.time_keeper import TimedVirtualBus, keeper_stats
from tests.ff_hwbridge.sim.test_sync_hub import HubBench
from tests.support.canopen_helpers import configure_and_enable, waiter

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


def test_send_at_through_the_hub_and_a_bus_without_a_schedule():
    with start_hub() as hub:
        tx, rx = open_bus(hub.bus_config()), open_bus(hub.bus_config())
        try:
            at_ns = time.time_ns() + 50_000_000
            assert send_at(tx, _frame(0x201, 0.0), at_ns) is True
            assert send_at(tx, _frame(0x202, 0.0), time.time_ns() - 1_000_000) is False  # passed: now
            first = rx.recv(1.0)
            assert first is not None and first.arbitration_id == 0x202
            second = rx.recv(1.0)
            assert second is not None and second.arbitration_id == 0x201
            assert abs(second.timestamp * 1e9 - at_ns) < 1000     # ns: float seconds on the wire
            assert time.time_ns() >= at_ns - 100_000
        finally:
            tx.shutdown()
            rx.shutdown()
    plain = can.Bus(interface="virtual", channel=f"ff-plain-{uuid.uuid4().hex[:6]}")
    try:
        with pytest.raises(CanConfigError, match="no transmit schedule"):
            send_at(plain, _frame(0x201, 0.0), time.time_ns() + 10_000_000)
    finally:
        plain.shutdown()


def test_setpoint_lead_is_refused_where_nothing_keeps_the_schedule():
    url = "ws://127.0.0.1:1/"
    with pytest.raises(ConfigError, match="player_process: true"):
        rig_master_config(url, sync_period=0.005, setpoint_lead=0.05)
    with pytest.raises(ConfigError, match="0 .. 0.25 s"):
        rig_master_config(url, sync_period=0.005, setpoint_lead=0.5, player_process=True)
    cfg = rig_master_config(url, sync_period=0.005, setpoint_lead=0.05, player_process=True)
    assert cfg.setpoint_lead == 0.05


@pytest.mark.integration
def test_setpoints_handed_ahead_latch_at_their_own_sync_and_a_stop_replaces_the_rest(ros_env):
    record = os.path.join(tempfile.mkdtemp(prefix="ff-keeper-"), "sim.json")
    lead = 0.05
    with HubBench(ros_env, ["--record", record], setpoint_timeout=2.0, player_process=True,
                  setpoint_lead=lead) as bench:
        master = bench.master
        configure_and_enable(master, 5.0)
        player = bench.player = ProcessPlayer(master).start()
        assert wait_for(lambda: player.sync_grid() is not None)
        nominal, period = player.sync_grid()
        # a first stream, all of it latched; then a long one, cut by clear + stop while many of
        # its setpoints sit in the hub's schedule
        first = [0.1 * (k % 5) + 0.1 for k in range(10)]
        t0 = nominal + 40 * period
        for k, a in enumerate(first):
            player.submit(t0 + k * period, [a], seq=k, profile_id="lead-1", last=k == len(first) - 1)
        got: list = []
        assert wait_for(lambda: got.extend(player.take_applied()) or len(got) == len(first))
        for g in got:
            # on the bus mid-cycle before its SYNC, latched at the SYNC of its stamp
            assert abs((g.sent_ns - g.rpdo_sent_ns) - period / 2) < 2_000, g
            assert abs(g.sent_ns - g.stamp_ns) < 0.1 * period, g
        assert player.diagnostics()["missed_setpoints"] == 0
        nominal, period = player.sync_grid()
        t1 = nominal + 40 * period
        second = [0.7] * 200
        for k, a in enumerate(second):
            player.submit(t1 + k * period, [a], seq=k, profile_id="lead-2")
        # wait until the first of them is latched, with the next lead's worth scheduled
        assert wait_for(lambda: abs(master.feedback()[0].current - 0.7) < 0.05), master.feedback()
        player.clear()
        player.submit(time.time_ns(), [0.0], seq=len(second), profile_id="lead-2", last=True)
        stopped_ns = time.time_ns()
        assert wait_for(lambda: abs(master.feedback()[0].current) < 0.01), master.feedback()
        time.sleep(2 * lead)                              # every scheduled instant has passed
        assert abs(master.feedback()[0].current) < 0.01, master.feedback()
        assert bench.drive_caught_up(time.time_ns() - int(0.05e9))
    assert bench.code == 0
    with open(record) as fh:
        log = json.load(fh)["setpoints"]["1"]            # [mono_ns, wall_ns, raw, A]
    units = master.units[0]
    for g, a in zip(got, first):            # latched at the SYNC instant the player reported
        raw = units.amps_to_setpoint(a, limit=5.0)
        assert g.sent_ns in [r[1] for r in log if r[2] == raw]
    seven = units.amps_to_setpoint(0.7, limit=5.0)
    after = [r for r in log if r[1] > stopped_ns + 2 * period]
    assert after and all(r[2] != seven for r in after), after[:5]
    line = next(x for x in bench.hub.output().splitlines() if x.startswith('{"sync"'))
    keeper = json.loads(line)["time_keeper"]
    assert keeper["sent"] >= len(first) and keeper["cancelled"] >= 1, keeper
