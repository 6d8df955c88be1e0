"""SyncSender: one SYNC per slot, a stall skips the slots it covered instead of sending them in a
burst (python-can's thread-based periodic sender catches up with one frame per missed period)."""
from __future__ import annotations

import threading
import time

import pytest

from ff_hwbridge.drive.sync_sender import SyncSender


def test_next_slot_after_a_stall_is_the_next_one_not_begun():
    s = SyncSender.__new__(SyncSender)
    s.period_ns = 10_000_000
    assert s.next_slot(0, 1_000_000, 0) == (1, 10_000_000)           # slot 0 sent on time
    assert s.next_slot(0, 4_000_000, 0) == (1, 10_000_000)           # a little late: slot 1 kept
    assert s.next_slot(0, 6_000_000, 0) == (2, 20_000_000)           # slot 1 would follow too soon
    assert s.next_slot(0, 57_000_000, 0) == (7, 70_000_000)          # stalled: 1..6 skipped


def test_a_stalled_sender_sends_no_burst():
    sends: list[int] = []
    hold = threading.Event()
    hold.set()

    def send() -> None:
        sends.append(time.monotonic_ns())
        if len(sends) == 5:
            hold.clear()
            time.sleep(0.1)          # the thread held off for 10 periods
            hold.set()

    s = SyncSender(send, 0.01)
    try:
        time.sleep(0.35)
    finally:
        s.stop()
    gaps = [(b - a) / 1e6 for a, b in zip(sends, sends[1:])]
    after = gaps[4:]                  # from the stalled send on
    assert min(gaps) >= 4.9, gaps                 # ms: never closer than half a period
    assert after[0] > 100.0, gaps                 # the missed slots were not sent after the stall
    assert s.skipped >= 8, s.skipped
    assert len(sends) < 35 - 8 + 3


def test_bad_period():
    with pytest.raises(ValueError, match="SYNC period"):
        SyncSender(lambda: None, 0.0)
