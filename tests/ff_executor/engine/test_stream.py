"""Engine: streaming (due setpoints, commanded current, cancel) and the publishing loop, on a fake clock."""
from __future__ import annotations

import numpy as np
import pytest

from ff_executor.engine import (NS, Setpoint, Stream, StreamRunner, build_setpoints)
from tests.ff_executor.engine.common import CUR, FakeClock, motion


def test_stream_publishes_each_setpoint_lead_time_ahead():
    m = motion()
    clock = FakeClock()
    start = clock.t + int(0.25 * NS)
    stream = Stream(build_setpoints(m, start), lead_time=0.1)
    sent = []
    runner = StreamRunner(stream, lambda sp: sent.append((clock.t, sp)), clock, clock.sleep)
    assert runner.run() is False
    assert [sp.seq for _, sp in sent] == list(range(6))
    for t_pub, sp in sent:
        ahead = (sp.stamp_ns - t_pub) / NS
        assert 0.09 <= ahead <= 0.1 + 1e-9, ahead          # never late, never much earlier
    assert not stream.late()
    assert clock.t >= stream.end_ns


def test_stream_commanded_follows_the_plan():
    m = motion()
    stream = Stream(build_setpoints(m, 0), lead_time=0.1)
    stream.due(2 * NS)
    assert stream.commanded(-1) == (0.0,)
    assert stream.commanded(0) == (CUR[0],)
    assert stream.commanded(int(0.2 * NS)) == (CUR[1],)
    assert stream.commanded(int(0.96 * NS)) == (0.0,)


def test_cancel_sends_zero_now_and_after_every_pending_stamp():
    m = motion()
    clock = FakeClock()
    stream = Stream(build_setpoints(m, clock.t + int(0.25 * NS)), lead_time=0.3)
    sent: list[Setpoint] = []
    cancel_at = stream.start_ns + int(0.3 * NS)
    runner = StreamRunner(stream, sent.append, clock, clock.sleep,
                          should_cancel=lambda: clock.t >= cancel_at)
    assert runner.run() is True
    first = next(i for i, s in enumerate(sent) if s.last)
    zeros = sent[first:]
    assert all(s.currents == (0.0,) and s.last for s in zeros)   # nothing after but zeros
    assert abs(zeros[0].stamp_ns - clock.t) < NS // 1000          # stamped now
    # every non-zero setpoint already handed over with a later stamp is overridden 1 us after it
    pending = [s for s in sent[:first] if s.stamp_ns >= zeros[0].stamp_ns and any(s.currents)]
    assert pending, "the lead time should leave setpoints pending at the bridge"
    for s in pending:
        assert any(z.stamp_ns - s.stamp_ns == 1000 for z in zeros)
    # simulate a bridge that applies everything in stamp order: current is zero after cancel
    # except for 1 us after each overridden stamp
    timeline = sorted(sent, key=lambda s: (s.stamp_ns, s.seq))
    on = [(a.stamp_ns, b.stamp_ns) for a, b in zip(timeline, timeline[1:])
          if any(a.currents) and a.stamp_ns >= zeros[0].stamp_ns]
    assert sum(b - a for a, b in on) <= 1000 * len(pending)
    assert stream.commanded(clock.t) == (0.0,)
    assert stream.done and stream.cancel(clock.t) == []


def test_runner_ticks_at_the_feedback_rate():
    m = motion()
    clock = FakeClock()
    stream = Stream(build_setpoints(m, clock.t + int(0.25 * NS)), lead_time=0.1)
    ticks = []
    StreamRunner(stream, lambda sp: None, clock, clock.sleep, on_tick=ticks.append,
                 tick_period=0.05).run(until_ns=stream.end_ns + int(0.05 * NS))
    gaps = np.diff(ticks) / NS
    assert len(ticks) >= 20 and gaps.max() <= 0.1 + 1e-6   # >= 10 Hz


def test_stream_refuses_unordered_setpoints():
    with pytest.raises(ValueError):
        Stream([Setpoint(10, (1.0,), 0), Setpoint(5, (0.0,), 1)], 0.1)
    with pytest.raises(ValueError):
        Stream([], 0.1)
