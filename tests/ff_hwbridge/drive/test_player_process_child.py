"""The player process's link without a process: its per-cycle repeat never goes out between a
new setpoint and the record of it, so the drive's last RPDO before a SYNC is always the newest
setpoint (a repeat of the previous one after it would be what the drive latches)."""
from __future__ import annotations

import struct
import threading
import time
import uuid

import can
import pytest

from ff_hwbridge.drive.config import BridgeConfig, config_from_mapping
from ff_hwbridge.drive.node import PreparedCommand
from ff_hwbridge.drive.player_process import ChildLink
from ff_hwbridge.drive.safety import SafeCommand

CW = 0x0F


class Epoch:
    value = 0


def child_config(channel: str) -> BridgeConfig:
    """One EPOS4 joint (node 1, 10 A) on a python-can virtual channel, 10 ms SYNC."""
    return config_from_mapping({"bus": {"interface": "virtual", "channel": channel}, "sync_period": 0.01,
                                "joints": [{"name": "joint1", "node_id": 1, "family": "epos4",
                                            "current_limit": 10.0}]})


def prepared(raw: int) -> PreparedCommand:
    """A command of ``raw`` (the guard's part unused by the link's send)."""
    import numpy as np

    return PreparedCommand(SafeCommand(np.zeros(1), (False,), None, False), (raw,))


@pytest.fixture()
def child():
    channel = f"ff-child-{uuid.uuid4().hex[:8]}"
    gate = [CW, 1, 0]                 # joint 0: controlword, current allowed; not latched
    listener = can.Bus(interface="virtual", channel=channel)
    told: list = []
    c = ChildLink(child_config(channel), gate, Epoch(), lambda *m: told.append(m))
    try:
        yield c, listener
    finally:
        c.close()
        listener.shutdown()


def setpoints(listener: can.BusABC) -> list[int]:
    out = []
    while (m := listener.recv(0.05)) is not None:
        if m.arbitration_id == 0x201:
            out.append(struct.unpack("<Hh", bytes(m.data[:4]))[1])
    return out


def test_repeats_racing_new_setpoints_never_send_an_older_one_after_a_newer(child):
    """A SYNC's repeat (receiver thread) racing new setpoints (scheduler thread)."""
    c, listener = child
    stop = threading.Event()

    def receiver() -> None:
        t = time.time()
        while not stop.is_set():
            t += 0.01
            c.sync_watch.observe(t)

    thread = threading.Thread(target=receiver, daemon=True)
    thread.start()
    try:
        for raw in range(1, 400):
            c.send_prepared(prepared(raw))
    finally:
        stop.set()
        thread.join(2.0)
    seen = setpoints(listener)
    assert seen and seen[-1] == 399
    back = [(a, b) for a, b in zip(seen, seen[1:]) if b < a]
    assert not back, f"a repeat sent an older setpoint after a newer one: {back[:5]}"
