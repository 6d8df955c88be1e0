"""Engine: switch-time statistics, reported and estimated."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ff_executor.engine import (NS, Stream, build_setpoints, estimate_applied_times, missed_cycles,
                                timing_stats)
from tests.ff_executor.engine.common import motion


def test_timing_stats():
    s = timing_stats([0, 1000, 2000], [100_000, 1000 + 200_000, 2000 - 50_000], "bridge")
    assert s.count == 3 and s.source == "bridge"
    assert s.max == pytest.approx(200e-6) and s.p50 == pytest.approx(100e-6)
    empty = timing_stats([], [], "bridge")
    assert empty.count == 0 and math.isnan(empty.p99) and empty.source == "none"


def test_estimate_applied_times_from_measured_current():
    m = motion(currents=[4.0, -2.0, 1.0])
    sps = build_setpoints(m, 0)
    t = np.arange(0, int(1.1 * NS), int(0.001 * NS))
    lag = int(0.0004 * NS)
    measured = [Stream(sps, 0.0).commanded(0) for _ in t]
    st = Stream(sps, 0.0)
    st.due(10 * NS)
    measured = np.array([st.commanded(int(x) - lag) for x in t])
    pairs = estimate_applied_times(sps, t, measured)
    assert len(pairs) == 4                      # 4.0, -2.0, 1.0, 0.0
    for stamp, est in pairs:
        assert 0 < est - stamp <= int(0.0014 * NS)


def test_missed_cycles_counts_whole_sync_periods_beyond_the_first():
    ms = 1_000_000
    stamps = [0, 10 * ms, 20 * ms, 30 * ms, 40 * ms]
    # applied at the first SYNC after the stamp (0.3 ms, 0.9 ms: in time), one cycle late (1.5 ms),
    # within the jitter tolerance of the next SYNC (1.05 ms: in time), two cycles late (2.6 ms)
    applied = [int(0.3 * ms), 10 * ms + int(0.9 * ms), 20 * ms + int(1.5 * ms),
               30 * ms + int(1.05 * ms), 40 * ms + int(2.6 * ms)]
    assert missed_cycles(stamps, applied, 1e-3) == 1 + 2
    assert missed_cycles(stamps, applied, 0.0) == 0          # applied on receipt: no cycles
    assert missed_cycles([], [], 1e-3) == 0
    assert missed_cycles([5 * ms], [5 * ms - 10_000], 1e-3) == 0   # a hair early (clock jitter)
