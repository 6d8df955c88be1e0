"""Clipping is a failed move: statusword bit 11 (internal limit active) seen during a motion is
latched per motion in the master's status (count and first instant) from the motion's first
setpoint until the next motion starts (its tail included); before any motion it is only the live
flag. Simulated EPOS4 whose own current
limit (1 A) is below the command, python-can virtual bus."""
from __future__ import annotations

import time

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.sim.drive import DriveConfig, SimEpos
from tests.support.canopen_helpers import configure_and_enable, mini_config, open_network, unique_channel, waiter

wait_for = waiter(3.0)


def test_internal_limit_during_a_motion_is_latched_until_the_next_motion():
    channel = unique_channel("ff-limit")
    net = open_network(channel)
    drive = SimEpos(DriveConfig(current_limit=1.0))          # clamps anything above 1 A
    drive.attach(net)
    drive.boot()
    master = EposMaster(mini_config(channel, sync_period=0.01, heartbeat_timeout=0.5,
                                    setpoint_timeout=5.0, joint={"write_current_limit": False}))
    try:
        master.connect()
        configure_and_enable(master, 3.0)
        master.command_currents([2.0])                      # no motion: the live flag only
        assert wait_for(lambda: master.status()["joint1.internal_limit_active"])
        time.sleep(0.05)
        assert master.motion_limits() == [(0, 0)]
        t0 = time.time_ns()
        master.note_setpoint(motion_running=True)           # a motion starts
        assert wait_for(lambda: master.motion_limits()[0][0] >= 2)
        count, first = master.motion_limits()[0]
        assert first >= t0 - 20_000_000                     # the sample instant of the first
        master.command_currents([0.5])                      # within the limit again
        master.guard.end_motion()
        time.sleep(0.1)
        st = master.status()
        assert not st["joint1.internal_limit_active"]
        assert st["joint1.motion_limited_count"] >= count and st["joint1.motion_limited_first_ns"] == first
        # the motion's tail: its setpoints have all arrived (they lead the drive), the drive
        # still applies them: clipping there counts for this motion too
        before = master.motion_limits()[0][0]
        master.command_currents([2.0])
        assert wait_for(lambda: master.motion_limits()[0][0] > before)
        assert master.motion_limits()[0][1] == first
        master.command_currents([0.5])
        assert wait_for(lambda: not master.status()["joint1.internal_limit_active"])
        time.sleep(0.05)                                    # the last clipped TPDO is in
        master.note_setpoint(motion_running=True)           # the next motion: a clean record
        assert master.motion_limits() == [(0, 0)]
        time.sleep(0.1)
        assert master.motion_limits() == [(0, 0)]
    finally:
        master.disconnect()
        drive.close()
        net.disconnect()
