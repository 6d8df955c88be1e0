"""StampScheduler: applies payloads at their stamps, in stamp order, never early; drops stale
ones; prepares ahead of the stamp."""
from __future__ import annotations

import time

from ff_hwbridge.drive.scheduler import StampScheduler
from tests.support.canopen_helpers import waiter

_wait = waiter(3.0, 0.005)


def test_scheduler_applies_in_stamp_order_never_early_and_drops_stale():
    applied = []
    sched = StampScheduler(lambda stamp, p: applied.append((time.time_ns(), stamp, p))).start()
    try:
        t0 = time.time_ns() + 30_000_000
        for k in (3, 1, 2, 0):                                  # submitted out of order
            sched.submit(t0 + k * 5_000_000, k)
        assert _wait(lambda: len(applied) == 4)
        assert [p for _, _, p in applied] == [0, 1, 2, 3]
        assert all(now >= stamp for now, stamp, _ in applied)   # never before its stamp
        assert all(sent >= stamp for stamp, sent in sched.records)
        sched.submit(t0, "stale")                               # older than the last applied
        sched.submit(t0 + 14_000_000, "stale too")
        time.sleep(0.05)
        assert sched.stale == 2 and len(applied) == 4
        sched.submit(time.time_ns() - 1_000_000, "late")            # past, but newer: applied at once
        assert _wait(lambda: len(applied) == 5)
        assert sched.late >= 1
        sched.submit(time.time_ns() + 5_000_000, "x")
        sched.submit(time.time_ns() + 500_000_000, "dropped")
        assert _wait(lambda: len(applied) == 6)
        assert sched.clear() == 1 and sched.pending == 0
        st = sched.stats()
        assert st.count == 6 and st.min_us >= 0.0 and st.p50_us <= st.max_us
    finally:
        sched.stop()


def test_scheduler_prepares_before_the_stamp():
    seen = []
    sched = StampScheduler(lambda stamp, p: seen.append((time.time_ns(), stamp, p)),
                           prepare=lambda p: (time.time_ns(), p * 2)).start()
    try:
        stamp = time.time_ns() + 20_000_000
        sched.submit(stamp, 21)
        assert _wait(lambda: seen)
        applied_at, st, (prepared_at, value) = seen[0]
        assert value == 42 and st == stamp
        assert prepared_at <= applied_at and stamp <= applied_at   # prepared first, never early
    finally:
        sched.stop()
