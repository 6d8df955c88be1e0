"""The executor killed mid-motion on the simulated ROS stack: the drive stops (``executor_kill``)."""
from __future__ import annotations

import pytest

from tests.ff_hwbridge.faults import executor_kill

pytestmark = pytest.mark.integration

#: s: the stack's bridge watchdog (setpoint_timeout 0.5 s) runs out at most 0.5 s after the last
#: setpoint the executor sent before the kill (it repeats the present current every 0.25 s);
#: then the bridge's monitor, its quick stop and one 10 ms SYNC until the drive reports it
BOUND_S = 0.5 + 0.2


def test_executor_killed_mid_motion_stops_the_drive(tmp_path):
    out = executor_kill.run(str(tmp_path))
    assert out["moving_at_kill"], out
    assert out["out_of_enabled_s"] is not None and out["out_of_enabled_s"] < BOUND_S, out
    # 0 A after the quick-stop ramp (10000 rpm/s of the motor: < 0.1 s from the move's speed)
    assert out["zero_current_s"] is not None and out["zero_current_s"] < BOUND_S + 0.3, out
    assert "setpoint watchdog" in out["reason"], out
    assert out["bridge_alive"], out
