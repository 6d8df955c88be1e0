"""On-stack identification reads the drive's samples off the CAN bus: each TPDO answer at the
SYNC it certainly answered (an answer that comes after the next SYNC is left out, never moved to
that SYNC), the position and current from its payload; a run whose answers could mostly not be
placed gives no data."""
from __future__ import annotations

import struct
import time
from types import SimpleNamespace

import can
import numpy as np
import pytest

from ff_executor.bringup.bus_feedback import BusFeedback, StackBus
from ff_executor.bringup.bus_monitor import BusMonitor
from ff_executor.bringup.identify import StackFault, bus_samples, record_of
from ff_hwbridge.sim.can_hub import start_hub
from ff_planner.model.profile import CurrentProfile

Q_RES = 2.0 * np.pi / (2048 * 54)
CYCLES = 30
LATE = 12                 # the drive answers this SYNC only after the next one is on the bus
AMPS = {3: 1.5, 9: -0.75, 20: 0.0}      # setpoint RPDOs sent in these cycles (after the answers)


def _counts(k: int) -> int:
    """The position (increments) the scripted drive samples at SYNC k."""
    return 1000 + 37 * k - k * k


def _script() -> list[tuple[int, bytes, int]]:
    """(COB-ID, data, SYNC index or -1) of a drive that answers every SYNC with TPDO1 (statusword,
    position) and TPDO2 (velocity, current mA = 10·k), SYNC ``LATE`` after the next SYNC."""
    out: list[tuple[int, bytes, int]] = []
    late: list[tuple[int, bytes, int]] = []
    for k in range(CYCLES):
        out.append((0x80, b"", k))
        answer = [(0x181, struct.pack("<Hi", 0x0637, _counts(k)), k), (0x281, struct.pack("<ii", 0, 10 * k), k)]
        out.extend(late)
        late = []
        if k == LATE:
            late = answer
        else:
            out.extend(answer)
        if k in AMPS:
            out.append((0x201, struct.pack("<Hh", 0x0F, int(round(AMPS[k] / 0.003))), -1))
    return out


def _play(hub, listener) -> list[tuple[int, float, int]]:
    """Send the script on the hub; (COB-ID, bus s, SYNC index) of each frame as a tap saw it."""
    tap = can.Bus(interface="remote", channel=hub.url)
    src = can.Bus(**hub.local_bus_config())
    script = _script()
    seen: list[tuple[int, float]] = []
    try:
        time.sleep(0.3)
        for cid, data, _ in script:
            src.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))
            time.sleep(0.002)
        end = time.monotonic() + 5.0
        while len(seen) < len(script) and time.monotonic() < end:
            m = tap.recv(0.2)
            if m is not None:
                seen.append((m.arbitration_id, float(m.timestamp)))
        assert listener.wait_seen(seen[-1][1] - 1e-6, timeout=5.0)
    finally:
        tap.shutdown()
        src.shutdown()
    assert [c for c, _ in seen] == [c for c, _, _ in script]
    return [(c, t, k) for (c, t), (_, _, k) in zip(seen, script)]


def test_each_answer_is_placed_at_the_sync_it_answered_and_a_late_one_is_left_out():
    hub = start_hub(0)
    try:
        fb = BusFeedback(node_id=1, family="epos4", max_latency=1.0)   # pairing, not latency
        mon = BusMonitor(hub.url, node_id=1, family="epos4", max_latency=1.0, sinks=(fb,))
        try:
            frames = _play(hub, mon)
            syncs = {k: t for c, t, k in frames if c == 0x80}
            t, counts, amps = fb.samples(syncs[0] - 1e-6, syncs[CYCLES - 1] + 1.0)
            assert fb.sync_count(syncs[0] - 1e-6, syncs[CYCLES - 1] + 1e-6) == CYCLES
            assert fb.unplaced == 1
        finally:
            mon.close()
    finally:
        hub.close()
    placed = [k for k in range(CYCLES) if k != LATE]
    np.testing.assert_allclose(t, [syncs[k] for k in placed], atol=1e-9)
    assert counts.tolist() == [_counts(k) for k in placed]       # the late answer is not at SYNC LATE + 1
    np.testing.assert_allclose(amps, [0.01 * k for k in placed], atol=1e-12)


def test_a_stack_bus_run_record_holds_the_drive_answers_and_the_latched_currents():
    hub = start_hub(0)
    try:
        bus = StackBus(hub.url, node_id=1, family="epos4", nominal_current=3.0, latched=True, max_latency=1.0)
        try:
            frames = _play(hub, bus)
            syncs = {k: t for c, t, k in frames if c == 0x80}
            rpdo = [t for c, t, _ in frames if c == 0x201]
            stamps = np.array([syncs[k] for k in range(CYCLES)])      # as the bridge stamps them
            joints = SimpleNamespace(arrays=lambda: (stamps, np.zeros((CYCLES, 1)), np.zeros((CYCLES, 1)),
                                                     np.zeros((CYCLES, 1))))
            outcome = SimpleNamespace(joints=joints, profile_start=rpdo[0])
            prof = CurrentProfile(np.array([0.0, 0.06]), np.array([[1.5], [-0.75]]), 0.3, 0.18)
            rec = record_of(outcome, prof, Q_RES, "joints", bus)
        finally:
            bus.close()
    finally:
        hub.close()
    placed = [k for k in range(CYCLES) if k != LATE]
    t0 = syncs[4]                                  # the first change, latched at the SYNC after its RPDO
    np.testing.assert_allclose(rec.t, [syncs[k] - t0 for k in placed], atol=1e-9)
    np.testing.assert_allclose(rec.q, [_counts(k) * Q_RES for k in placed], atol=1e-15)
    np.testing.assert_allclose(rec.current, [0.01 * k for k in placed], atol=1e-12)
    np.testing.assert_allclose(rec.profile.step_times, [0.0, syncs[10] - t0, syncs[21] - t0], atol=1e-9)
    assert rec.profile.currents[:, 0].tolist() == pytest.approx([1.5, -0.75])


class _Feedback:
    def __init__(self, n_placed: int, n_syncs: int) -> None:
        self.n, self.syncs, self.unplaced = n_placed, n_syncs, n_syncs - n_placed

    def samples(self, t_from, t_to):
        t = t_from + 0.01 * np.arange(self.n)
        return t, np.arange(self.n, dtype=float), np.full(self.n, np.nan)

    def sync_count(self, t_from, t_to):
        return self.syncs


def test_a_run_whose_answers_could_mostly_not_be_placed_gives_no_data():
    with pytest.raises(StackFault, match="only 40 of the 100 SYNCs"):
        bus_samples(_Feedback(40, 100), 5.0, 6.0, 5.0, Q_RES)
    t, q, amps = bus_samples(_Feedback(60, 100), 5.0, 6.0, 5.0, Q_RES)
    np.testing.assert_allclose(t, 0.01 * np.arange(60), atol=1e-12)
    np.testing.assert_allclose(q, Q_RES * np.arange(60))
    assert np.isnan(amps).all()
