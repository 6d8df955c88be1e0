"""The player process's send path without a process: its RPDO refresh never goes out between a
new setpoint and the record of it, so the drive's last RPDO before a SYNC is always the newest
setpoint (a refresh of the previous one after it would be what the drive latches)."""
from __future__ import annotations

import struct
import threading
import uuid

import can
import pytest

from ff_hwbridge.drive import player_process
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


def test_a_refresh_repeats_the_newest_setpoint_and_only_when_one_is_due(child):
    c, listener = child
    c._send(0, prepared(500))
    c._refresh(0)                                   # just sent: nothing is due
    assert setpoints(listener) == [500]
    c.last_tx[0] -= player_process.REFRESH_PERIOD   # as if a period had passed
    c._refresh(0)
    assert setpoints(listener) == [500]


def test_refreshes_racing_new_setpoints_never_send_an_older_one_after_a_newer(child, monkeypatch):
    c, listener = child
    monkeypatch.setattr(player_process, "REFRESH_PERIOD", 0.0)    # every refresh is due
    stop = threading.Event()

    def refresher() -> None:
        while not stop.is_set():
            c._refresh(0)

    t = threading.Thread(target=refresher, daemon=True)
    t.start()
    try:
        for raw in range(1, 400):
            c._send(0, prepared(raw))
    finally:
        stop.set()
        t.join(2.0)
    seen = setpoints(listener)
    assert seen and seen[-1] == 399
    back = [(a, b) for a, b in zip(seen, seen[1:]) if b < a]
    assert not back, f"a refresh sent an older setpoint after a newer one: {back[:5]}"
