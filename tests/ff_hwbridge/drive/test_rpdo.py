"""The setpoint RPDO exists once (``drive.rpdo.SetpointRpdos``): the master in the bridge's
process and the player process's link build the same frames from the same setpoints, and the
writer's explicit parameters (who owns a drive's RPDO in a cycle, how echoes are told apart, what
a failed send does) behave as documented."""
from __future__ import annotations

import struct
import time
import uuid

import can
import numpy as np
import pytest

from ff_hwbridge.drive.config import with_bus
from ff_hwbridge.drive.node import PreparedCommand
from ff_hwbridge.drive.player_process import ChildLink
from ff_hwbridge.drive.rpdo import EchoMatch, RpdoChannel, SetpointRpdos, rpdo_frame
from ff_hwbridge.drive.safety import SafeCommand
from ff_hwbridge.drive.sync_watch import SyncEvent
from tests.ff_hwbridge.drive.test_sync_player import SyncBench
from tests.support.canopen_helpers import waiter

wait_for = waiter(5.0)
AMPS = [0.5, -1.25, 2.0, 9.9, 12.0, -50.0, float("nan"), 0.0, 3.3, -0.001]
RAWS = [99_999, -99_999, 1234]        # past the raw limit: the RPDO clamps them once more


def _raw(raw: int) -> PreparedCommand:
    return PreparedCommand(SafeCommand(np.zeros(1), (False,), None, False), (raw,))


def _monitor(channel: str) -> can.BusABC:
    """A listener for RPDO1 of node 1 only (the bus carries heartbeats and TPDOs too)."""
    return can.Bus(interface="virtual", channel=channel, can_filters=[{"can_id": 0x201, "can_mask": 0x7FF}])


def _play(link, mon: can.BusABC, sync) -> list[bytes]:
    """The setpoint sequence through ``link``'s guard + units + RPDO, then a SYNC's repeat; the
    RPDO1 frames on the bus in order."""
    frames: list[bytes] = []
    for a in AMPS:
        link.send_prepared(link.prepare_currents([a]))
        frames += _expect(mon, 1)
    for r in RAWS:
        link.send_prepared(_raw(r))
        frames += _expect(mon, 1)
    sync()
    frames += _expect(mon, 1)       # the value in force, repeated in the cycle it opens
    return frames


def _expect(mon: can.BusABC, n: int) -> list[bytes]:
    """The next ``n`` RPDO1 frames of node 1 (waited for up to 5 s)."""
    out: list[bytes] = []
    deadline = time.monotonic() + 5.0
    while len(out) < n and time.monotonic() < deadline:
        m = mon.recv(0.05)
        if m is not None and m.arbitration_id == 0x201:
            out.append(bytes(m.data))
    return out


def test_both_placements_put_byte_identical_frames_on_the_bus_for_the_same_setpoints():
    b = SyncBench(heartbeat_timeout=5.0, feedback_timeout=5.0, sync_timeout=5.0, setpoint_timeout=5.0,
                  missed_cycle_tolerance=1000)
    child_channel = f"ff-rpdo-{uuid.uuid4().hex[:8]}"
    mon_child = _monitor(child_channel)
    link = None
    try:
        b.enable()
        b.source.stop()                       # no SYNC: nothing but our sends until we sync
        time.sleep(0.05)
        tx = can.Bus(interface="virtual", channel=b.channel, preserve_timestamps=True)
        mon = _monitor(b.channel)
        try:
            cw = b.master.gate()[0][0]
            assert b.master.gate()[0][1], "the drive is not enabled"

            def master_sync() -> None:
                tx.send(can.Message(arbitration_id=0x80, data=b"", timestamp=time.time(),
                                    is_extended_id=False))

            master_frames = _play(b.master, mon, master_sync)
            assert not b.master.latched, b.master.fault_reason
        finally:
            tx.shutdown()
            mon.shutdown()
        link = ChildLink(with_bus(b.master.config, {"interface": "virtual", "channel": child_channel}),
                         [cw, 1, 0], None, lambda *m: None)
        child_frames = _play(link, mon_child, lambda: link.sync_watch.observe(time.time()))
    finally:
        if link is not None:
            link.close()
        mon_child.shutdown()
        b.close()
    n = len(AMPS) + len(RAWS) + 1
    assert len(master_frames) == n and len(child_frames) == n, (master_frames, child_frames)
    assert master_frames == child_frames
    values = [struct.unpack("<Hh", f[:4]) for f in master_frames]
    limit = b.drive.current_to_setpoint(10.0)
    assert {v[0] for v in values} == {0x000F}
    assert max(abs(v[1]) for v in values) == limit            # both clamps hold at the limit
    assert values[len(AMPS)][1] == limit and values[len(AMPS) + 1][1] == -limit
    assert values[-1] == values[-2]                          # the SYNC repeated the value in force


# --- the writer's parameters, on a fake bus --------------------------------------------------------
class Bus:
    def __init__(self) -> None:
        self.frames: list[tuple[int, bytes]] = []
        self.fail = False

    def send(self, cob: int, data: bytes) -> None:
        if self.fail:
            raise can.CanOperationError("bus off")
        self.frames.append((cob, data))


def _writer(bus: Bus, *, owned: list[bool], echo: EchoMatch, forget: bool = False, errors=None,
            zero: list[bool] | None = None):
    count = [0]
    chans = [RpdoChannel(0x201, "<Hh", 1000), RpdoChannel(0x202, "<Hh", 1000)]
    w = SetpointRpdos(chans, bus.send, lambda: count[0], owner=lambda i: 0x0F if owned[i] else None,
                      zero_current=lambda: bool(zero and zero[0]), echo=echo, forget_when_not_owned=forget,
                      on_send_error=errors)

    def sync() -> None:
        count[0] += 1
        w.on_cycle(SyncEvent(count[0], time.time_ns(), time.monotonic_ns(), None))
    return w, sync


def test_frame_clamps_to_the_raw_limit_and_masks_the_controlword():
    assert rpdo_frame("<Hh", 500, 0x1000F, 900) == (struct.pack("<Hh", 0x000F, 500), 500)
    assert rpdo_frame("<Hh", 500, 0x0F, -900)[1] == -500


def test_only_owned_drives_are_repeated_once_a_cycle_and_a_forgetting_writer_zeroes_the_rest():
    bus = Bus()
    owned = [True, False]
    w, sync = _writer(bus, owned=owned, echo=EchoMatch.EVERY_FRAME, forget=True)
    w.send(0, 0x0F, 300)
    w.send(1, 0x0F, 200)
    bus.frames.clear()
    sync()
    sync()
    assert bus.frames == [(0x201, struct.pack("<Hh", 0x0F, 300))] * 2
    assert w.channels[1].setpoint == 0 and w.repeats == 2
    owned[1] = True
    bus.frames.clear()
    sync()
    assert (0x202, struct.pack("<Hh", 0x0F, 0)) in bus.frames


def test_zero_current_sends_zero_whatever_the_setpoint():
    bus, zero = Bus(), [True]
    w, _ = _writer(bus, owned=[True, True], echo=EchoMatch.EVERY_FRAME, zero=zero)
    w.send(0, 0x0F, 700)
    assert bus.frames[-1] == (0x201, struct.pack("<Hh", 0x0F, 0)) and w.channels[0].setpoint == 0


def test_sent_frames_echo_ignores_another_senders_frame_and_every_frame_counts_it():
    for echo, foreign_is_ours in ((EchoMatch.SENT_FRAMES, False), (EchoMatch.EVERY_FRAME, True)):
        bus = Bus()
        w, _ = _writer(bus, owned=[True, True], echo=echo)
        m = w.send(0, 0x0F, 100)
        assert w.on_echo(0, struct.pack("<Hh", 0x06, 0), 5) is foreign_is_ours   # the master's step
        if echo is EchoMatch.SENT_FRAMES:
            assert w.echo_time([m, 0]) is None
            assert w.on_echo(0, bus.frames[-1][1], 7)
            assert w.echo_time([m, 0]) == 7
        else:
            assert w.echo_time([m, 0]) == 5


def test_a_failed_send_raises_or_is_counted_as_the_placement_asks():
    bus = Bus()
    w, _ = _writer(bus, owned=[True, True], echo=EchoMatch.SENT_FRAMES)
    bus.fail = True
    with pytest.raises(can.CanOperationError):
        w.send(0, 0x0F, 100)
    assert not w.channels[0].unechoed and w.channels[0].tx_seq == 0
    failures: list[int] = []
    w, _ = _writer(bus, owned=[True, True], echo=EchoMatch.EVERY_FRAME, errors=lambda i, e: failures.append(i))
    assert w.send(1, 0x0F, 100) == 0 and failures == [1] and w.channels[1].tx_failing == 1
    bus.fail = False
    assert w.send(1, 0x0F, 100) == 1 and w.channels[1].tx_failing == 0
