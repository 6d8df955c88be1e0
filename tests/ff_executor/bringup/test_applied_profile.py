"""The profile the bridge applied: one reported delay per current change (equal neighbouring
currents make no change); pure computation."""
from __future__ import annotations

import numpy as np
import pytest

from ff_executor.bringup.identify import applied_profile, switch_changes
from ff_planner.model.profile import CurrentProfile


def _profile(currents: list[float]) -> CurrentProfile:
    n = len(currents)
    return CurrentProfile(np.linspace(0.0, 0.8, n + 1), np.array(currents).reshape(n, 1), 1.0, 0.2)


def test_equal_neighbours_and_a_zero_end_make_no_switch():
    assert switch_changes(_profile([1.0, -2.0, -2.0, 0.5]).currents) == [0, 1, 3, 4]
    assert switch_changes(_profile([1.0, 0.0]).currents) == [0, 1]            # ends on 0 A: no coast switch
    assert switch_changes(_profile([0.0, 2.0, 1.0]).currents) == [1, 2, 3]    # 0 A first: no start switch


def test_delays_move_the_switches_that_change_and_their_equal_followers():
    prof = _profile([1.0, -2.0, -2.0, 0.5])
    delays = [0.001, 0.0012, 0.0015, 0.0011]                       # s, per change, first is common
    got = applied_profile(prof, delays)
    shift = got.step_times - prof.step_times
    assert shift == pytest.approx([0.0, 0.0002, 0.0002, 0.0005, 0.0001])
    assert got.coast == pytest.approx(1.0 - got.step_times[-1])
    assert applied_profile(prof, delays[:3]) is prof                # delays that do not fit
