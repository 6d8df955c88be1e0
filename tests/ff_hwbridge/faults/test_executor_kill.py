"""The executor killed mid-motion on the simulated ROS stack: the drive stops (``executor_kill``)."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from tests.ff_hwbridge.faults import executor_kill

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[3]

#: s, how far ahead of its stamp the simulated stack's executor publishes a setpoint
LEAD_S = float(yaml.safe_load((ROOT / "config" / "executor_sim.yaml").read_text())
               ["ff_executor"]["ros__parameters"]["lead_time"])
#: s: the bridge plays the setpoints already sent, stamped at most LEAD_S after the kill; its
#: watchdog (setpoint_timeout 0.5 s) runs out at most 0.5 s after the last of them (the executor
#: repeats the present current every 0.25 s); then the bridge's monitor, its quick stop and one
#: 10 ms SYNC until the drive reports it
BOUND_S = LEAD_S + 0.5 + 0.2


def test_executor_killed_mid_motion_stops_the_drive(tmp_path):
    out = executor_kill.run(str(tmp_path))
    assert out["moving_at_kill"], out
    assert out["out_of_enabled_s"] is not None and out["out_of_enabled_s"] < BOUND_S, out
    # 0 A after the quick-stop ramp (10000 rpm/s of the motor: < 0.1 s from the move's speed)
    assert out["zero_current_s"] is not None and out["zero_current_s"] < BOUND_S + 0.3, out
    assert "setpoint watchdog" in out["reason"], out
    assert out["bridge_alive"], out
