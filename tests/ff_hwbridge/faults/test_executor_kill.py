"""The executor killed mid-motion on the simulated ROS stack: the drive stops (``executor_kill``)."""
from __future__ import annotations

import pytest

from tests.ff_hwbridge.faults import executor_kill

pytestmark = pytest.mark.integration


def test_executor_killed_mid_motion_stops_the_drive(tmp_path):
    out = executor_kill.run(str(tmp_path))
    bound = out["stop_bound_s"]   # the executor's lead + the bridge's setpoint watchdog + 0.2 s
    assert out["moving_at_kill"], out
    assert out["out_of_enabled_s"] is not None and out["out_of_enabled_s"] < bound, out
    # 0 A after the quick-stop ramp (10000 rpm/s of the motor: < 0.1 s from the move's speed)
    assert out["zero_current_s"] is not None and out["zero_current_s"] < bound + 0.3, out
    assert "setpoint watchdog" in out["reason"], out
    assert out["bridge_alive"], out
