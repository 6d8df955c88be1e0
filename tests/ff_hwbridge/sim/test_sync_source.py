"""The simulation's SYNC timer (``SyncSource``): its two timing models, on a private virtual
channel (no hub, no ROS)."""
from __future__ import annotations

import time

import can
import numpy as np
import pytest

from ff_hwbridge.sim.sync import SyncSource
from tests.support.canopen_helpers import unique_channel

PERIOD = 0.002


class LateBus:
    """A virtual bus whose every 10th send stalls 3.5 periods: a timer thread that lost the CPU
    (the next slots are due before it returns)."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        self.preserve_timestamps = True
        self.sends = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sends += 1
        if self.sends % 10 == 5:
            time.sleep(3.5 * PERIOD)
        self.bus.send(msg, timeout)


def _drain(rx: can.BusABC) -> list[can.Message]:
    frames = []
    while (m := rx.recv(0)) is not None:
        frames.append(m)
    return frames


def test_send_model_stamps_the_send_and_skips_late_slots():
    channel = unique_channel("ff-syncsrc")
    bus = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    try:
        src = SyncSource(bus, PERIOD, stamp="send")
        t0 = time.monotonic()
        src.start()
        time.sleep(0.3)
        src.stop()
        elapsed = time.monotonic() - t0
        st = src.stats()
        assert st.period_us == 2000.0 and st.count >= 10 and st.stamp == "send"
        # every grid slot is either sent or counted as skipped (no drift, no bursts)
        assert abs((st.count + st.skipped) - elapsed / PERIOD) <= 0.2 * elapsed / PERIOD
        assert 0.0 <= st.jitter_p50_us <= st.jitter_p99_us <= st.jitter_max_us
        assert st.send_late_p99_us == pytest.approx(st.jitter_p99_us)   # the same thing here
        frames = _drain(rx)
        assert len(frames) == st.count and all(m.arbitration_id == 0x80 for m in frames)
        ts = [m.timestamp for m in frames]
        assert all(b > a for a, b in zip(ts, ts[1:]))
        src.reset_stats()
        assert src.stats().skipped == 0 and np.isnan(src.stats().jitter_p99_us)
    finally:
        bus.shutdown()
        rx.shutdown()


def test_deadline_model_puts_every_sync_on_its_grid_instant_however_late_the_thread_is():
    channel = unique_channel("ff-syncsrc")
    bus = LateBus(channel)
    rx = can.Bus(interface="virtual", channel=channel)
    try:
        src = SyncSource(bus, PERIOD)            # type: ignore[arg-type]
        src.start()
        time.sleep(0.3)
        src.stop()
        st = src.stats()
        frames = _drain(rx)
        assert st.stamp == "deadline" and len(frames) == st.count >= 20
        # the thread was really late (the SYNC after each stall by 2.5 periods) ...
        assert st.send_late_max_us >= 2.0 * PERIOD * 1e6 and st.late_slots >= 2
        # ... yet no slot is lost and every bus instant sits on the grid (µs: clock conversion)
        steps = np.diff([m.timestamp for m in frames]) / PERIOD
        assert np.all(np.abs(steps - 1.0) < 0.01), steps
        assert st.skipped == 0 and st.jitter_max_us == 0.0
    finally:
        bus.bus.shutdown()
        rx.shutdown()


def test_deadline_model_jitter_stays_within_the_stated_model():
    channel = unique_channel("ff-syncsrc")
    bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    rx = can.Bus(interface="virtual", channel=channel)
    try:
        src = SyncSource(bus, PERIOD, jitter_model=20e-6, seed=3)
        src.start()
        time.sleep(0.2)
        src.stop()
        st = src.stats()
        assert st.jitter_model_us == 20.0 and 0.0 <= st.jitter_p50_us <= st.jitter_max_us <= 20.0
        assert st.jitter_max_us > 0.0                   # the model is drawn, not constant
        frames = _drain(rx)
        offsets = np.array([m.timestamp for m in frames])
        dev = (offsets - offsets[0]) / PERIOD
        assert np.all(np.abs(dev - np.round(dev)) * PERIOD <= 25e-6)
    finally:
        bus.shutdown()
        rx.shutdown()


def test_bad_settings_are_refused():
    channel = unique_channel("ff-syncsrc")
    plain = can.Bus(interface="virtual", channel=channel)
    try:
        with pytest.raises(ValueError, match="preserve_timestamps"):
            SyncSource(plain, PERIOD)
        with pytest.raises(ValueError, match="stamp"):
            SyncSource(plain, PERIOD, stamp="wall")
        with pytest.raises(ValueError, match="jitter"):
            SyncSource(plain, PERIOD, stamp="send", jitter_model=0.5)
        with pytest.raises(ValueError, match="period"):
            SyncSource(plain, 5.0, stamp="send")
    finally:
        plain.shutdown()
