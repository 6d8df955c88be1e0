"""The cyclic synchronous contract (CiA 402 CSx): while a drive is enabled, every SYNC cycle
carries its setpoint RPDO, the value in force repeated when nothing new came, and a new setpoint
takes effect at the SYNC that closes the cycle it was sent in. Both player placements: the
master's own per-cycle writer (in-process player) and the player process's child (run here in
the test's process, its bus a python-can virtual channel).

SYNCs are injected in lock step (the next one only once the previous cycle's frames have been
seen), so that the per-cycle counts are exact on a loaded machine too.
"""
from __future__ import annotations

import struct
import time
import uuid

import can
import pytest

from ff_hwbridge.drive.player import SetpointRejected
from ff_hwbridge.drive.player_process import _Child, _Joint, _Spec
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.epos_od import rpdo_layout, struct_format
from ff_hwbridge.protocol.units import DriveUnits
from tests.ff_hwbridge.drive.test_sync_player import SyncBench
from tests.support.canopen_helpers import waiter

wait_for = waiter(5.0)
CYCLES = 100
SETTLE = 0.003          # s after a cycle's first RPDO: a second one would be seen by then


def _frames(mon: can.BusABC, cob: int) -> list[bytes]:
    """Every frame of ``cob`` queued on ``mon`` now."""
    out = []
    while (m := mon.recv(0)) is not None:
        if m.arbitration_id == cob:
            out.append(bytes(m.data))
    return out


# --- in-process: the master's per-cycle writer ------------------------------------------------
@pytest.fixture
def lockstep():
    """An enabled drive (SYNC from the bench's source), then the source stopped: SYNCs come
    from ``step()`` only."""
    b = SyncBench(heartbeat_timeout=5.0, feedback_timeout=5.0, sync_timeout=5.0, setpoint_timeout=5.0,
                  missed_cycle_tolerance=1000)
    b.enable()
    b.source.stop()
    tx = can.Bus(interface="virtual", channel=b.channel, preserve_timestamps=True)
    mon = can.Bus(interface="virtual", channel=b.channel)

    def step() -> list[bytes]:
        """One SYNC; the RPDO1 frames of the cycle it opens (waited for: the first, then
        ``SETTLE`` s more)."""
        before = b.master.rpdo_marks()[0]
        _frames(mon, 0x201)
        tx.send(can.Message(arbitration_id=0x80, data=b"", timestamp=time.time(), is_extended_id=False))
        assert wait_for(lambda: b.master.rpdo_marks()[0] > before), "no RPDO in a SYNC cycle"
        time.sleep(SETTLE)
        return _frames(mon, 0x201)

    try:
        yield b, step
    finally:
        tx.shutdown()
        mon.shutdown()
        b.close()


def test_an_enabled_drive_gets_exactly_one_rpdo_per_sync_cycle_with_the_value_in_force(lockstep):
    b, step = lockstep
    b.master.command_currents([0.5])
    raw = b.drive.current_to_setpoint(0.5)
    step()                                          # the cycle the setpoint was sent in
    counts, values = [], set()
    for _ in range(CYCLES):
        frames = step()
        counts.append(len(frames))
        values.update(struct.unpack("<Hh", f[:4]) for f in frames)
    assert counts == [1] * CYCLES, counts
    assert values == {(0x000F, raw)}                # the value in force, repeated
    assert b.drive.state is State.OPERATION_ENABLED   # its interpolation supervision is content
    assert not b.master.latched


def test_a_new_setpoint_takes_effect_at_the_sync_that_closes_its_cycle(lockstep):
    b, step = lockstep
    for _ in range(5):
        step()
    raw = b.drive.current_to_setpoint(1.25)
    b.drive.clear_setpoint_log()
    b.master.command_currents([1.25])              # sent in the cycle the latest SYNC opened
    frames = step()                                 # its closing SYNC, and the next cycle's repeat
    assert [struct.unpack("<Hh", f[:4])[1] for f in frames] == [raw]
    assert wait_for(lambda: any(r.raw == raw for r in b.drive.setpoint_log()))
    first = next(r for r in b.drive.setpoint_log() if r.raw == raw)
    assert b.master.sync_watch.latest().bus_ns == first.wall_ns    # latched at that SYNC
    assert [len(step()) for _ in range(10)] == [1] * 10


def test_a_fault_reset_brings_zero_back_not_the_setpoint_before_the_safe_state(lockstep):
    b, step = lockstep
    b.master.command_currents([0.8])
    step()
    b.master.trip("test: watchdog")
    t_trip = time.time_ns()
    for _ in range(3):
        step()
    b.master.fault_reset()
    with pytest.raises(SetpointRejected, match="before the latest safe state"):
        b.player.submit(t_trip, [0.8])             # stamped before the reset: refused
    for _ in range(40):                             # the drive re-enables over a few cycles
        step()
        if b.drive.state is State.OPERATION_ENABLED and b.master.states()[0] is State.OPERATION_ENABLED:
            break
    assert b.drive.state is State.OPERATION_ENABLED, b.master.fault_reason
    values = {struct.unpack("<Hh", f[:4])[1] for _ in range(10) for f in step()}
    assert values == {0}
    assert b.drive.applied_current == 0.0


# --- the player process's child --------------------------------------------------------------
CW = 0x0F


class _Epoch:
    value = 0


@pytest.fixture()
def child():
    channel = f"ff-child-{uuid.uuid4().hex[:8]}"
    units = DriveUnits()
    spec = _Spec({"interface": "virtual", "channel": channel}, False,
                 (_Joint(1, units, 10.0, struct_format(rpdo_layout(units.family))),), 0.01, 0.1, 1, 0, 0.5)
    gate = [CW, 1, 0]                 # joint 0: controlword, current allowed; not latched
    epoch = _Epoch()
    mon = can.Bus(interface="virtual", channel=channel)
    c = _Child(spec, None, gate, epoch)
    t = [time.time()]

    def sync() -> list[int]:
        """One SYNC seen by the child (as its receiver thread would); the setpoints sent in the
        cycle it closes, in bus order (the drive latches the last)."""
        time.sleep(SETTLE)
        closed = [struct.unpack("<Hh", f[:4])[1] for f in _frames(mon, 0x201)]
        t[0] += 0.01
        c.watch.observe(t[0])
        return closed

    try:
        yield c, sync, gate, epoch
    finally:
        c.bus.shutdown()
        mon.shutdown()


def _prepared(raw: int, stamp: int = 0) -> tuple:
    return ((stamp, (0.0,), 0, "p", False), (raw,), "", False)


def test_the_child_sends_exactly_one_rpdo_per_cycle_and_a_new_setpoint_in_its_own(child):
    c, sync, _, _ = child
    sync()
    c._send(0, _prepared(500))                      # in the cycle the first SYNC opened
    assert sync() == [0, 500]                       # that cycle's repeat, then the new one
    assert [sync() for _ in range(CYCLES)] == [[500]] * CYCLES      # repeated, once a cycle
    c._send(0, _prepared(-300))                                       # new, in the open cycle
    assert sync() == [500, -300]                    # latched at its own SYNC: the last before it
    assert [sync() for _ in range(5)] == [[-300]] * 5


def test_the_child_repeats_nothing_while_the_master_owns_the_rpdo_and_zero_after(child):
    c, sync, gate, _ = child
    sync()
    c._send(0, _prepared(700))
    assert sync()[-1] == 700
    assert sync() == [700]
    gate[1] = 0                                     # the master's safe state took the drive
    assert [sync() for _ in range(3)] == [[700], [], []]
    gate[1] = 1                                     # enabled again after a fault reset
    sync()
    assert [sync() for _ in range(3)] == [[0], [0], [0]]


def test_the_child_forgets_the_value_in_force_at_a_reset_epoch_and_drops_older_stamps(child):
    c, sync, _, epoch = child
    sync()
    c._send(0, _prepared(400))
    assert sync()[-1] == 400
    epoch.value = time.time_ns()                    # a safe state / fault reset in the master
    assert sync() == [400]
    assert [sync() for _ in range(3)] == [[0], [0], [0]]
    q, raws, reason, _ = c._prepare(((epoch.value - 1, (0.25,), 0, "p", False)))
    assert raws == (0,) and "before the latest" in reason
    q, raws, _, _ = c._prepare(((epoch.value + 1, (0.25,), 0, "p", False)))
    assert raws[0] != 0                             # stamped after it: applied


def test_with_a_lead_the_child_schedules_each_cycles_repeat_mid_cycle_with_the_value_in_force(monkeypatch):
    """``setpoint_lead``: setpoints go to the bus's transmit schedule cycles ahead; every cycle
    without one gets the value in force for THAT cycle, scheduled mid-cycle (a frame sent at
    once would replace the ones scheduled after it)."""
    from ff_hwbridge.drive import player_process

    channel = f"ff-child-{uuid.uuid4().hex[:8]}"
    units = DriveUnits()
    spec = _Spec({"interface": "virtual", "channel": channel}, False,
                 (_Joint(1, units, 10.0, struct_format(rpdo_layout(units.family))),), 0.01, 0.1, 1, 0, 0.5,
                 lead=0.05)
    scheduled: list[tuple[int, int]] = []          # (at_ns, raw)

    def send_at(bus, msg, at_ns):
        scheduled.append((at_ns, struct.unpack("<Hh", bytes(msg.data[:4]))[1]))
        return True

    monkeypatch.setattr(player_process, "send_at", send_at)
    c = _Child(spec, None, [CW, 1, 0], _Epoch())
    try:
        p = 10_000_000
        t0 = time.time_ns() + 5 * p                 # SYNCs a little in the future: on time
        c.watch.observe(t0 / 1e9)                   # cycle 1 opens
        n0 = c.watch.latest().bus_ns                # its bus instant (float s: ±0.5 µs)
        assert scheduled == [(n0 + p // 2, 0)]
        c._send(0, _prepared(600), at_ns=n0 + 3 * p + p // 2)   # a setpoint for cycle 4
        for k in range(1, 6):
            c.watch.observe((t0 + k * p) / 1e9)
        by_cycle = {round((at - n0 - p // 2) / p) + 1: raw for at, raw in scheduled}
        assert by_cycle == {1: 0, 2: 0, 3: 0, 4: 600, 5: 600, 6: 600}
        # mid-cycle, every one (within the float rounding of the SYNCs' bus instants)
        assert all(abs((at - n0 - p // 2) - round((at - n0 - p // 2) / p) * p) < 2_000 for at, _ in scheduled)
        assert len(scheduled) == 6                  # one frame per cycle, none twice
    finally:
        c.bus.shutdown()


def test_with_a_lead_echoes_are_matched_by_their_instant_not_the_hand_over_order(monkeypatch):
    """A setpoint scheduled cycles ahead is handed over before the repeats of the cycles before
    it; the bus echoes them in the order of their instants. Each echo is the frame scheduled for
    its instant (a repeat's echo is never taken for the setpoint's: that made a setpoint look
    latched cycles early)."""
    from ff_hwbridge.drive import player_process

    channel = f"ff-child-{uuid.uuid4().hex[:8]}"
    units = DriveUnits()
    spec = _Spec({"interface": "virtual", "channel": channel}, True,
                 (_Joint(1, units, 10.0, struct_format(rpdo_layout(units.family))),), 0.01, 0.1, 1, 0, 0.5,
                 lead=0.05)
    monkeypatch.setattr(player_process, "send_at", lambda bus, msg, at_ns: True)
    c = _Child(spec, None, [CW, 1, 0], _Epoch())
    try:
        p = 10_000_000
        t = time.time_ns() + 10 * p
        same = struct.pack("<Hh", CW, 0)
        c._tx(0, same, 0, at_ns=t + 3 * p)              # tx 1: a zero setpoint, cycle 4
        for k in range(3):
            c._tx(0, same, 0, at_ns=t + k * p)          # tx 2..4: the repeats of cycles 1..3
        got = [c._own(c.sent_data[0], same, t + k * p) for k in range(4)]   # bus order
        assert got == [2, 3, 4, 1]
        assert not c.sent_data[0]
        assert c._own(c.sent_data[0], same, t + 5 * p) == 0       # not ours
    finally:
        c.bus.shutdown()
