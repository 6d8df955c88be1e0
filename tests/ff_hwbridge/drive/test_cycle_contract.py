"""The cyclic synchronous contract (CiA 402 CSx): while a drive is enabled, every SYNC cycle
carries its setpoint RPDO, the value in force repeated when nothing new came, and a new setpoint
takes effect at the SYNC that closes the cycle it was sent in. Both player placements: the
master's own per-cycle writer (in-process player) and the player process's link (run here in
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

from ff_hwbridge.drive.player import SetpointPlayer, SetpointRejected, _Queued
from ff_hwbridge.drive.player_process import ChildLink
from ff_hwbridge.protocol.cia402 import State
from tests.ff_hwbridge.drive.test_player_process_child import child_config, prepared
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


# --- the player process's link -----------------------------------------------------------------
CW = 0x0F


class _Epoch:
    value = 0


@pytest.fixture()
def child():
    channel = f"ff-child-{uuid.uuid4().hex[:8]}"
    gate = [CW, 1, 0]                 # joint 0: controlword, current allowed; not latched
    epoch = _Epoch()
    mon = can.Bus(interface="virtual", channel=channel)
    c = ChildLink(child_config(channel), gate, epoch, lambda *m: None)
    t = [time.time()]

    def sync() -> list[int]:
        """One SYNC seen by the link (as its receiver thread would); the setpoints sent in the
        cycle it closes, in bus order (the drive latches the last)."""
        time.sleep(SETTLE)
        closed = [struct.unpack("<Hh", f[:4])[1] for f in _frames(mon, 0x201)]
        t[0] += 0.01
        c.sync_watch.observe(t[0])
        return closed

    try:
        yield c, sync, gate, epoch
    finally:
        c.close()
        mon.shutdown()


def test_the_child_sends_exactly_one_rpdo_per_cycle_and_a_new_setpoint_in_its_own(child):
    c, sync, _, _ = child
    sync()
    c.send_prepared(prepared(500))                  # in the cycle the first SYNC opened
    assert sync() == [0, 500]                       # that cycle's repeat, then the new one
    assert [sync() for _ in range(CYCLES)] == [[500]] * CYCLES      # repeated, once a cycle
    c.send_prepared(prepared(-300))                                   # new, in the open cycle
    assert sync() == [500, -300]                    # latched at its own SYNC: the last before it
    assert [sync() for _ in range(5)] == [[-300]] * 5


def test_the_child_repeats_nothing_while_the_master_owns_the_rpdo_and_zero_after(child):
    c, sync, gate, _ = child
    sync()
    c.send_prepared(prepared(700))
    assert sync()[-1] == 700
    assert sync() == [700]
    gate[1] = 0                                     # the master's safe state took the drive
    assert [sync() for _ in range(3)] == [[700], [], []]
    gate[1] = 1                                     # enabled again after a fault reset
    sync()
    assert [sync() for _ in range(3)] == [[0], [0], [0]]


def test_the_child_forgets_the_value_in_force_at_a_reset_epoch_and_the_player_refuses_older_stamps(child):
    c, sync, _, epoch = child
    sync()
    c.send_prepared(prepared(400))
    assert sync()[-1] == 400
    epoch.value = time.time_ns()                    # a safe state / fault reset in the master
    assert sync() == [400]
    assert [sync() for _ in range(3)] == [[0], [0], [0]]
    player = SetpointPlayer(c)                      # the one player, on the process's link
    try:
        with pytest.raises(SetpointRejected, match="before the latest safe state"):
            player.submit(epoch.value - 1, [0.25])
        assert player._prepare(_Queued((0.25,), 0, "p", False, epoch.value - 1)).command.raw == (0,)
        assert player._prepare(_Queued((0.25,), 0, "p", False, epoch.value + 1)).command.raw[0] != 0
    finally:
        player.close()
