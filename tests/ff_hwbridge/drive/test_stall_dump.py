"""StallDump: every thread's stack once the watched thread has not re-armed for the timeout;
nothing while it keeps re-arming, nothing after a disarm."""
from __future__ import annotations

import threading
import time

import pytest

from ff_hwbridge.drive.stall_dump import StallDump


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
