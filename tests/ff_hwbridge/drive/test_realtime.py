"""The real-time helpers: collector pauses (a frozen heap is not scanned again, every pause is
recorded), the stall dump, SCHED_FIFO for a whole process, and the one set-up."""
from __future__ import annotations

import gc
import sys
import threading
import time

import pytest

from ff_hwbridge.drive.realtime import (FULL_HELD, GcPauses, IdleCollector, RealtimeConfig, StallDump, freeze_heap,
                                        hold_full_collections, setup_process)


def test_freeze_heap_takes_the_heap_out_of_later_collections():
    junk = [[i] for i in range(50_000)]      # long-lived objects a full collection would scan
    try:
        frozen = freeze_heap()
        assert frozen >= len(junk)
        # at least: another thread of this process may freeze its own heap meanwhile
        assert gc.get_freeze_count() >= frozen
        # what survived is frozen: a full collection finds no more of it to scan
        assert sum(len(gc.get_objects(g)) for g in range(3)) < frozen
    finally:
        gc.unfreeze()


def test_pauses_are_counted_and_timed_per_generation():
    p = GcPauses().install()
    try:
        gc.collect(0)
        gc.collect(2)
    finally:
        p.uninstall()
    assert p.count[0] >= 1 and p.count[2] >= 1
    assert p.max_ms[2] > 0.0 and p.total_ms >= p.max_ms[2]
    d = p.as_dict()
    assert d["gc.collections"].count("/") == 2 and "gc.max_pause_ms" in d
    before = list(p.count)
    gc.collect(2)                            # uninstalled: no longer counted
    assert p.count == before


@pytest.fixture(autouse=True)
def _collector_thresholds():
    """Each test starts from the interpreter's default thresholds and leaves them as it found
    them: an in-process master or player tested earlier in the same process may hold them."""
    saved = gc.get_threshold()
    gc.set_threshold(700, 10, 10)
    try:
        yield
    finally:
        gc.set_threshold(*saved)


def test_held_full_collections_wait_for_the_idle_collector():
    before = hold_full_collections()
    try:
        assert gc.get_threshold()[2] == FULL_HELD and before[2] != FULL_HELD
        p = GcPauses().install()
        junk = []
        for _ in range(100_000):           # many young collections, no automatic full one
            junk.append([])
        p.uninstall()
        assert p.count[0] > 0 and p.count[2] == 0, p.count
    finally:
        gc.set_threshold(*before)
    now = [0.0]
    busy = [True]
    idle = IdleCollector(lambda: not busy[0], idle_s=1.0, every_s=10.0, clock=lambda: now[0])
    assert idle.tick() is None                       # busy
    busy[0] = False
    assert idle.tick() is None                       # idle, not yet for 1 s
    now[0] = 1.5
    assert idle.tick() is not None and idle.collections == 1
    now[0] = 5.0
    assert idle.tick() is None                       # at most every 10 s
    busy[0] = True
    now[0] = 20.0
    assert idle.tick() is None                       # busy again: the idle time starts over
    busy[0] = False
    assert idle.tick() is None
    now[0] = 21.5
    assert idle.tick() is not None and idle.collections == 2


def _held(event: threading.Event) -> None:
    event.wait(5.0)


def test_a_thread_that_stops_re_arming_gets_every_stack_dumped(tmp_path):
    out = (tmp_path / "dump.txt").open("w+")
    release = threading.Event()
    other = threading.Thread(target=_held, args=(release,), name="held-thread", daemon=True)
    other.start()
    dump = StallDump(0.05, rearm_every=0.0, file=out)
    try:
        dump.arm()
        time.sleep(0.3)
        out.flush()
        text = (tmp_path / "dump.txt").read_text()
        assert "Timeout" in text and "_held" in text, text       # the other thread's frame too
    finally:
        dump.disarm()
        release.set()
        out.close()


def test_re_arming_and_disarming_keep_it_quiet(tmp_path):
    out = (tmp_path / "dump.txt").open("w+")
    dump = StallDump(0.1, rearm_every=0.0, file=out)
    try:
        end = time.monotonic() + 0.4
        while time.monotonic() < end:            # the watched thread keeps coming back
            dump.arm()
            time.sleep(0.01)
        dump.disarm()                            # idle: no dump however long it stays so
        time.sleep(0.25)
        out.flush()
        assert (tmp_path / "dump.txt").read_text() == ""
    finally:
        dump.disarm()
        out.close()


def test_off_and_bad_values():
    StallDump(0.0).arm()                         # off: arms nothing
    with pytest.raises(ValueError, match="stall dump"):
        StallDump(-1.0)


def test_fifo_process_puts_every_thread_and_later_ones_under_sched_fifo():
    import os
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import os, threading, time
        from ff_hwbridge.drive.realtime import fifo_process
        ev = threading.Event()
        t = threading.Thread(target=ev.wait, daemon=True); t.start()
        n = fifo_process(3, "test")
        later = []
        t2 = threading.Thread(target=lambda: later.append(os.sched_getscheduler(0)), daemon=True)
        t2.start(); t2.join()
        policies = []
        for x in os.listdir("/proc/self/task"):
            try:
                policies.append(os.sched_getscheduler(int(x)))
            except ProcessLookupError:      # a thread that ended after the listing (t2, joined)
                pass
        print(n, len(policies), all(p == os.SCHED_FIFO for p in policies), later[0] == os.SCHED_FIFO)
        ev.set()
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert out.returncode == 0, out.stderr
    n, tids, all_fifo, later_fifo = out.stdout.split()
    if int(n) == 0:        # not permitted here: a warning, nothing changed
        assert "cannot use SCHED_FIFO" in out.stderr, out.stderr
        return
    assert int(n) >= 2 and all_fifo == "True" and later_fifo == "True", out.stdout


def test_setup_process_sets_the_switch_interval_and_freezes_the_heap():
    before, thresholds = sys.getswitchinterval(), gc.get_threshold()
    try:
        sys.setswitchinterval(0.005)                 # Python's default
        got = setup_process(RealtimeConfig(priority=0, switch_interval=0.0003, freeze_gc=True), "test")
        assert sys.getswitchinterval() == pytest.approx(0.0003)
        assert int(got["frozen"]) > 0 and gc.get_freeze_count() > 0  # type: ignore[call-overload]
        assert gc.get_threshold()[2] == FULL_HELD and "fifo_threads" not in got
        sys.setswitchinterval(0.0001)
        setup_process(RealtimeConfig(switch_interval=0.0003), "test")
        assert sys.getswitchinterval() == pytest.approx(0.0001)     # lowered to it, never raised
    finally:
        sys.setswitchinterval(before)
        gc.set_threshold(*thresholds)
        gc.unfreeze()


def test_setup_process_times_the_collections_when_asked():
    from ff_hwbridge.drive.realtime import pauses

    was = pauses._installed
    try:
        pauses.uninstall()
        before = sum(pauses.count)
        got = setup_process(RealtimeConfig(switch_interval=0.0, time_gc=True), "test")
        assert got["gc_timed"] is True and "switch_interval" not in got
        gc.collect()
        assert sum(pauses.count) > before and pauses.as_dict()["gc.collections"] != "0/0/0"
    finally:
        if not was:
            pauses.uninstall()
