"""Engine: stamped setpoints built from a checked motion."""
from __future__ import annotations

import numpy as np

from ff_executor.engine import (NS, build_setpoints)
from tests.ff_executor.engine.common import CUR, motion


# --- setpoints --------------------------------------------------------------------------------
def test_build_setpoints_one_per_switch_and_final_zero():
    m = motion()
    start = 5 * NS
    sps = build_setpoints(m, start)
    assert len(sps) == 6
    assert [s.seq for s in sps] == list(range(6))
    assert [s.currents[0] for s in sps[:5]] == CUR
    dt = 0.95 / 5
    for i, s in enumerate(sps[:5]):
        assert s.stamp_ns == start + round(i * dt * NS)
        assert not s.last and s.switch and s.profile_id == "p1"
    final = sps[-1]
    assert final.last and final.currents == (0.0,)
    assert final.stamp_ns == start + round(0.95 * NS)    # tf - coast


def test_build_setpoints_merges_equal_steps_and_adds_keepalives():
    m = motion(currents=[2.0, 2.0, -1.0])
    sps = build_setpoints(m, 0)
    assert [s.currents[0] for s in sps] == [2.0, -1.0, 0.0]
    ka = build_setpoints(m, 0, keepalive=0.05)
    stamps = [s.stamp_ns for s in ka]
    assert stamps == sorted(stamps) and ka[-1].last
    assert max(np.diff(stamps)) <= 0.05 * NS * 1.25 + 1
    assert [s.currents[0] for s in ka if s.switch] == [2.0, -1.0, 0.0]
    assert len(ka) > 15 and [s.seq for s in ka] == list(range(len(ka)))
