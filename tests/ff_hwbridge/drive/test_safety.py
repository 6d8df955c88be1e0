"""Property tests: no sequence of inputs makes the command path exceed the current limit."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ff_hwbridge.drive.safety import SafetyConfigError, SafetyGuard
from ff_hwbridge.protocol.units import DriveUnits

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
limits_st = st.lists(st.floats(min_value=1e-3, max_value=50.0), min_size=1, max_size=3)
units_st = st.builds(DriveUnits, family=st.sampled_from(["epos4", "epos2"]),
                     nominal_current=st.floats(min_value=0.05, max_value=20.0),
                     direction=st.sampled_from([1, -1]))

op_st = st.one_of(
    st.tuples(st.just("cmd"), st.lists(any_float, min_size=0, max_size=4)),
    st.tuples(st.just("feed"), any_float, st.booleans()),
    st.tuples(st.just("check"), any_float, st.booleans()),
    st.tuples(st.just("latch"), st.text(max_size=5)),
    st.tuples(st.just("reset")),
)


@settings(max_examples=300, deadline=None)
@given(limits=limits_st, timeout=st.floats(min_value=1e-3, max_value=10.0),
       ops=st.lists(op_st, max_size=40), units=units_st)
def test_no_input_sequence_exceeds_the_limit(limits, timeout, ops, units):
    guard = SafetyGuard(limits, timeout)
    lim = np.asarray(limits)
    for op in ops:
        kind = op[0]
        if kind == "cmd":
            out = guard.filter(op[1])
            assert out.currents.shape == lim.shape
            assert np.all(np.isfinite(out.currents))
            assert np.all(np.abs(out.currents) <= lim)
            if guard.latched:
                assert np.all(out.currents == 0.0)
            # and in raw drive units, as the master sends them
            for a, l in zip(out.currents, lim):
                raw = units.amps_to_setpoint(float(a), limit=float(l))
                assert abs(units.setpoint_to_amps(raw)) <= l
            # a finite in-range request goes through unchanged
            req = np.asarray(op[1], dtype=float)
            if (not guard.latched and req.shape == lim.shape and np.all(np.isfinite(req))
                    and np.all(np.abs(req) <= lim)):
                assert np.array_equal(out.currents, req) and out.reason is None
        elif kind == "feed":
            guard.feed(op[1], op[2])
        elif kind == "check":
            guard.check(op[1], pending=op[2])
        elif kind == "latch":
            guard.latch(op[1])
            assert guard.latched
        else:
            guard.reset()
            assert not guard.latched


@settings(max_examples=200, deadline=None)
@given(raw_request=any_float, units=units_st, limit=st.floats(min_value=1e-3, max_value=1e6))
def test_raw_setpoint_never_exceeds_limit(raw_request, units, limit):
    raw = units.amps_to_setpoint(raw_request, limit=limit)
    assert -32768 <= raw <= 32767
    assert abs(units.setpoint_to_amps(raw)) <= limit


@settings(max_examples=200, deadline=None)
@given(t0=st.floats(min_value=0, max_value=1e6), timeout=st.floats(min_value=1e-3, max_value=5.0),
       gap=st.floats(min_value=0, max_value=20.0))
def test_watchdog_trips_exactly_after_the_timeout(t0, timeout, gap):
    guard = SafetyGuard([10.0], timeout)
    guard.feed(t0, motion_running=True)
    assert guard.check(t0 + gap, pending=True) is None          # still fed by queued setpoints
    reason = guard.check(t0 + gap)
    if gap > timeout * (1 + 1e-9) + 1e-9:
        assert reason and "watchdog" in reason and guard.latched
        assert np.all(guard.filter([5.0]).currents == 0.0)
        guard.reset()
        assert guard.filter([5.0]).currents[0] == 5.0
    elif gap < timeout * (1 - 1e-9):
        assert reason is None and not guard.latched


def test_latch_keeps_first_reason_and_needs_explicit_reset():
    guard = SafetyGuard([1.0, 2.0], 0.1)
    assert guard.latch("EMCY 0x2310")
    assert not guard.latch("heartbeat lost")
    assert guard.reason == "EMCY 0x2310"
    assert np.all(guard.filter([0.5, 0.5]).currents == 0)
    guard.feed(0.0, True)                                        # a setpoint does not clear it
    assert guard.latched
    assert guard.reset() == "EMCY 0x2310"
    out = guard.filter([math.nan, -7.0])
    assert list(out.currents) == [0.0, -2.0] and "non-finite" in out.reason and "clamped" in out.reason
    assert "expected 2" in guard.filter([1.0]).reason


@pytest.mark.parametrize("limits,timeout", [([], 1.0), ([0.0], 1.0), ([math.inf], 1.0),
                                            ([1.0], 0.0), ([1.0], math.nan)])
def test_bad_guard_settings_are_refused(limits, timeout):
    with pytest.raises(SafetyConfigError):
        SafetyGuard(limits, timeout)
