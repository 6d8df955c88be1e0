"""CycleScheduler and StampScheduler without a bus: SYNCs observed by hand on a SyncWatch,
sends recorded. A stop is never dropped as stale; a setpoint that cannot be placed on the grid,
a failing send and a failing pass of the thread call the fault reaction with the reason."""
from __future__ import annotations

import time
from typing import Any

import pytest

from ff_hwbridge.drive.cycle import SEND_MARGIN, CycleScheduler
from ff_hwbridge.drive.scheduler import StampScheduler
from ff_hwbridge.drive.sync_watch import SyncWatch
from tests.support.canopen_helpers import waiter

wait_for = waiter(3.0, 0.002)
PERIOD = 0.01
P_NS = int(PERIOD * 1e9)


class Rig:
    """A CycleScheduler on a hand-fed SyncWatch; ``sent`` payloads, ``sent_ns`` their send
    instants (wall ns), ``faults`` reasons."""

    def __init__(self, fail_send: Any = None) -> None:
        self.watch = SyncWatch(PERIOD)
        self.sent: list[Any] = []
        self.sent_ns: list[int] = []
        self.faults: list[str] = []
        self.fail_send = fail_send

        def send(stamp: int, payload: Any) -> tuple[None, Any]:
            if self.fail_send is not None and payload == self.fail_send:
                raise RuntimeError("bus gone")
            self.sent_ns.append(time.time_ns())
            self.sent.append(payload)
            return None, payload

        self.sched = CycleScheduler(self.watch, send, lambda r: None,
                                    on_fault=self.faults.append).start()

    def sync(self) -> int:
        """One SYNC now; its bus instant (ns)."""
        return self.watch.observe(time.time()).bus_ns

    def close(self) -> None:
        self.sched.close()


def test_a_stale_stop_is_sent_not_dropped():
    rig = Rig()
    try:
        t = rig.sync()
        rig.sched.submit(t + P_NS, "step")               # for the next SYNC: sent at once
        assert wait_for(lambda: rig.sent == ["step"])
        rig.sched.submit(t + P_NS // 2, "older step")          # older than the one sent: stale
        rig.sched.submit(t + P_NS // 2, "stop", stop=True)     # older too, but a stop
        assert wait_for(lambda: rig.sent == ["step", "stop"])
        assert rig.sched.stale == 1 and rig.sched.stale_stops == 1 and not rig.faults
    finally:
        rig.close()


@pytest.mark.parametrize("stop", [False, True], ids=["current", "stop"])
def test_a_setpoint_that_missed_its_cycle_is_a_fault_a_stop_that_did_is_counted(stop):
    rig = Rig()
    try:
        t = rig.sync()
        rig.sched.submit(t - 3 * P_NS, "x", stop=stop)       # its SYNC passed 3 cycles ago
        assert wait_for(lambda: rig.sent == ["x"])
        rig.sync()                                           # latches it, cycles late
        if stop:
            assert wait_for(lambda: rig.sched.late_stops == 1) and not rig.faults
        else:
            assert wait_for(lambda: len(rig.faults) == 1)
            assert "missed its SYNC cycle" in rig.faults[0] and rig.sched.late_stops == 0
        assert rig.sched.missed == 1
    finally:
        rig.close()


def test_a_late_sync_frame_does_not_shorten_the_window_and_a_late_sync_itself_is_a_fault():
    rig = Rig()
    try:
        t = rig.sync()
        rig.sched.submit(t + 2 * P_NS, "x")              # its window opens with the SYNC at t + P
        # that SYNC's frame never comes here: the grid's clock opens the window, not before
        # SEND_MARGIN after that SYNC's instant
        assert wait_for(lambda: rig.sent == ["x"])
        assert rig.sent_ns[0] >= t + P_NS + int(SEND_MARGIN * P_NS)
        assert not rig.faults
        rig.sync()      # ... but a SYNC now, after the send, means that SYNC was late: it latches x
        assert wait_for(lambda: len(rig.faults) == 1)
        assert "1 SYNC cycle(s) early" in rig.faults[0], rig.faults
    finally:
        rig.close()


def test_the_grid_clock_opens_the_window_when_several_sync_frames_are_late():
    rig = Rig()
    try:
        t = rig.sync()
        rig.sched.submit(t + 4 * P_NS, "x")              # its window opens with the SYNC at t + 3P
        # no SYNC frame after the first comes here: the grid's clock opens the window, not
        # before SEND_MARGIN after that SYNC's instant
        assert wait_for(lambda: rig.sent == ["x"])
        assert rig.sent_ns[0] >= t + 3 * P_NS + int(SEND_MARGIN * P_NS)
        assert not rig.faults
    finally:
        rig.close()


def test_a_due_setpoint_without_sync_trips_with_the_reason_and_a_stop_is_still_sent():
    rig = Rig()
    try:
        rig.sched.submit(time.time_ns() + 20_000_000, "step")   # due in 20 ms; no SYNC ever
        rig.sched.submit(time.time_ns() + 30_000_000, "stop", stop=True)
        assert wait_for(lambda: len(rig.faults) == 2)
        assert all("no SYNC has been seen" in f and "SYNC grid" in f for f in rig.faults)
        assert "(current)" in rig.faults[0] and "(stop)" in rig.faults[1]
        assert rig.sent == ["stop"]
    finally:
        rig.close()


def test_a_failing_send_is_a_fault_with_the_reason():
    rig = Rig(fail_send="step")
    try:
        t = rig.sync()
        rig.sched.submit(t + P_NS, "step")
        assert wait_for(lambda: rig.faults)
        assert "bus gone" in rig.faults[0] and "RuntimeError" in rig.faults[0]
        assert rig.sched.errors == 1
    finally:
        rig.close()


def test_a_failing_pass_of_the_thread_is_a_fault_and_the_thread_goes_on():
    rig = Rig()
    calls = {"n": 0}
    real = rig.watch.grid

    def broken_once(window: int = 64):
        calls["n"] += 1
        if calls["n"] == 1:
            raise ValueError("grid exploded")
        return real(window)

    try:
        rig.watch.grid = broken_once        # type: ignore[method-assign]
        t = rig.sync()
        rig.sched.submit(t + P_NS, "step")
        assert wait_for(lambda: rig.faults and rig.sent == ["step"])
        assert "grid exploded" in rig.faults[0]
    finally:
        rig.close()


def test_stamp_scheduler_applies_a_stale_stop_and_reports_a_failing_apply():
    applied: list[Any] = []
    errors: list[str] = []

    def apply(stamp: int, p: Any) -> None:
        if p == "bad":
            raise OSError("no buffer space")
        applied.append(p)

    sched = StampScheduler(apply, on_error=errors.append).start()
    try:
        t0 = time.time_ns() + 20_000_000
        sched.submit(t0, "step")
        assert wait_for(lambda: applied == ["step"])
        sched.submit(t0 - 5_000_000, "older")
        sched.submit(t0 - 5_000_000, "stop", stop=True)
        assert wait_for(lambda: applied == ["step", "stop"])
        assert sched.stale == 1 and sched.stale_stops == 1
        sched.submit(time.time_ns() + 5_000_000, "bad")
        assert wait_for(lambda: errors)
        assert "no buffer space" in errors[0] and sched.errors == 1
    finally:
        sched.stop()


def test_statistics_can_be_read_while_the_thread_records():
    import sys
    import threading

    rig = Rig()
    stop = threading.Event()

    def record() -> None:                 # what the scheduler thread does on each applied setpoint
        k = 0
        while not stop.is_set():
            rig.sched.records.append((k, k + 1000))
            rig.sched._leads.append(k)
            k += 1

    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)           # switch threads as often as the interpreter allows
    t = threading.Thread(target=record, daemon=True)
    t.start()
    try:
        for _ in range(12):
            assert rig.sched.stats().count >= 0
            rig.sched.cycle_stats()
    finally:
        stop.set()
        t.join()
        sys.setswitchinterval(old)
        rig.close()
