"""The bus monitor of on-stack identification: each TPDO1 placed at the SYNC it answers, current
changes at the instant the drive applies them (latched at the next SYNC, or on receipt)."""
from __future__ import annotations

import struct
import time

import can
import numpy as np
import pytest

from ff_executor.bringup.bus_monitor import BusMonitor, SyncPairing
from ff_hwbridge.sim.can_hub import start_hub


def test_pairing_places_each_answer_at_its_sync_and_never_guesses():
    p = SyncPairing(max_latency=0.009)
    p.sync(1.000)
    assert p.answer(1.0006) == 1.000                      # the usual case
    p.sync(1.010)
    p.sync(1.020)                                         # a stalled drive: two pending
    assert p.answer(1.0215) is None                       # backlog: not certainly 1.010's
    assert p.answer(1.0216) == 1.020                      # the backlog shrank: one pending, its answer
    p.sync(1.030)
    assert p.answer(1.0395) is None                       # 9.5 ms late: not placed
    # SYNCs before the drive answered (pre-operational): a backlog that does not shrink goes
    q = SyncPairing()
    for k in range(3):
        q.sync(2.0 + 0.01 * k)
    placed = []
    for k in range(3, 12):
        q.sync(2.0 + 0.01 * k)
        placed.append(q.answer(2.0 + 0.01 * k + 0.0005))
    assert placed[:4] == [None] * 4                        # unsure while the backlog stays
    good = [x for x in placed if x is not None]
    assert good and all(abs(a - (2.0 + 0.01 * k)) < 1e-12 for a, k in zip(good, range(12 - len(good), 12)))


def _put(bus, cid, data=b""):
    bus.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))


def test_monitor_on_a_hub_sees_syncs_answers_and_current_changes():
    hub = start_hub(0)
    try:
        mon = BusMonitor(hub.url, node_id=1, family="epos4", nominal_current=3.0, latched=True)
        seen = []
        tap = can.Bus(interface="remote", channel=hub.url)
        src = can.Bus(**hub.local_bus_config())
        try:
            time.sleep(0.3)
            sp = lambda amps: struct.pack("<Hh", 0x0F, int(round(amps / 0.003)))   # noqa: E731
            script = [(0x80, b""), (0x181, b"\x37\x06\0\0\0\0"), (0x201, sp(0.0)), (0x80, b""),
                      (0x181, b"\x37\x06\0\0\0\0"), (0x201, sp(1.5)), (0x80, b""), (0x181, b"\x37\x06\0\0\0\0"),
                      (0x201, sp(1.5)), (0x201, sp(-0.75)), (0x80, b""), (0x181, b"\x37\x06\0\0\0\0"),
                      (0x201, sp(0.0)), (0x80, b""), (0x181, b"\x37\x06\0\0\0\0")]
            for cid, data in script:
                _put(src, cid, data)
                time.sleep(0.004)
            end = time.monotonic() + 5.0
            while len(seen) < len(script) and time.monotonic() < end:
                m = tap.recv(0.2)
                if m is not None:
                    seen.append((m.arbitration_id, m.timestamp))
            time.sleep(0.3)
        finally:
            tap.shutdown()
            src.shutdown()
            mon.close()
        assert len(seen) == len(script)
        syncs = [t for c, t in seen if c == 0x80]
        answers = [t for c, t in seen if c == 0x181]
        rpdo = [t for c, t in seen if c == 0x201]
        assert mon.syncs == 5 and mon.unpaired == 0
        np.testing.assert_allclose(mon.sample_instants(answers), syncs, atol=1e-9)
        assert np.isnan(mon.sample_instants([answers[0] + 1.0])[0])          # no such TPDO
        # a bridge that stamps its samples with their SYNC already: taken as they are
        np.testing.assert_allclose(mon.sample_instants(syncs), syncs, atol=1e-9)
        # on receipt: at the frames; latched: at the next SYNC; repeats are no change
        on_receipt = mon.current_changes(rpdo[0] - 0.5, rpdo[-1] + 0.5, latched=False)
        assert [a for _, a in on_receipt] == pytest.approx([0.0, 1.5, -0.75, 0.0])
        assert [t for t, _ in on_receipt] == pytest.approx([rpdo[0], rpdo[1], rpdo[3], rpdo[4]], abs=1e-9)
        latched = mon.current_changes(rpdo[0] - 0.5, rpdo[-1] + 0.5)
        assert [t for t, _ in latched] == pytest.approx([syncs[1], syncs[2], syncs[3], syncs[4]], abs=1e-9)
    finally:
        hub.close()
