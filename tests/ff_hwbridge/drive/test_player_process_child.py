"""The player process's send path without a process: its per-cycle repeat never goes out between
a new setpoint and the record of it, so the drive's last RPDO before a SYNC is always the newest
setpoint (a repeat of the previous one after it would be what the drive latches)."""
from __future__ import annotations

import struct
import threading
import time
import uuid

import can
import pytest

from ff_hwbridge.drive.player_process import _Child, _Joint, _Spec
from ff_hwbridge.protocol.epos_od import rpdo_layout, struct_format
from ff_hwbridge.protocol.units import DriveUnits

CW = 0x0F


@pytest.fixture()
def child():
    channel = f"ff-child-{uuid.uuid4().hex[:8]}"
    units = DriveUnits()
    spec = _Spec({"interface": "virtual", "channel": channel}, False,
                 (_Joint(1, units, 10.0, struct_format(rpdo_layout(units.family))),), 0.01, 0.1, 1, 0, 0.5)
    gate = [CW, 1, 0]                 # joint 0: controlword, current allowed; not latched
    listener = can.Bus(interface="virtual", channel=channel)
    c = _Child(spec, None, gate)
    try:
        yield c, listener
    finally:
        c.bus.shutdown()
        listener.shutdown()


def setpoints(listener: can.BusABC) -> list[int]:
    out = []
    while (m := listener.recv(0.05)) is not None:
        if m.arbitration_id == 0x201:
            out.append(struct.unpack("<Hh", bytes(m.data[:4]))[1])
    return out


def prepared(raw: int) -> tuple:
    return ((0, (0.0,), 0, "p", False), (raw,), "", False)


def test_repeats_racing_new_setpoints_never_send_an_older_one_after_a_newer(child):
    """A SYNC's repeat (receiver thread) racing new setpoints (scheduler thread)."""
    c, listener = child
    stop = threading.Event()

    def receiver() -> None:
        t = time.time()
        while not stop.is_set():
            t += 0.01
            c.watch.observe(t)

    thread = threading.Thread(target=receiver, daemon=True)
    thread.start()
    try:
        for raw in range(1, 400):
            c._send(0, prepared(raw))
    finally:
        stop.set()
        thread.join(2.0)
    seen = setpoints(listener)
    assert seen and seen[-1] == 399
    back = [(a, b) for a, b in zip(seen, seen[1:]) if b < a]
    assert not back, f"a repeat sent an older setpoint after a newer one: {back[:5]}"
