"""A real master process killed mid-motion (SIGKILL): the simulated EPOS4 (own process) stops
by itself, through the master heartbeat it consumes, within half a second."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import pytest
import yaml

from ff_hwbridge.sim.rig import RigConfig
from tests.support.canopen_helpers import RigProcess

pytestmark = pytest.mark.integration


def _info(rig: RigProcess) -> tuple[str, int, float, float]:
    """(state, fault code, applied A, monotonic s of the drive's latest error) of node 1."""
    reply = rig.cmd("info 1")
    state = re.search(r"state='([^']*)'", reply).group(1)
    fault = int(re.search(r"fault=0x([0-9A-F]{4})", reply).group(1), 16)
    amps = float(re.search(r" i=([-0-9.e]+)", reply).group(1))
    t_err = float(re.search(r"error_t=([0-9.]+)", reply).group(1))
    return state, fault, amps, t_err


def test_sigkill_of_the_master_stops_the_drive_within_half_a_second(tmp_path):
    rig = RigProcess(["--model", "arm1dof", "--node-ids", "1"], stderr=open(os.devnull, "w"))
    d = RigConfig().drive_configs()[0]
    cfg = tmp_path / "bridge.yaml"
    cfg.write_text(yaml.safe_dump({
        "bus": {"interface": "remote", "channel": rig.url}, "sync_period": 0.002,
        "heartbeat_producer_ms": 50, "heartbeat_timeout": 1.0, "setpoint_timeout": 10.0,
        "sdo_timeout": 2.0,
        # the hardware example's values (config/bridge_epos4_1dof.yaml); RPDO deadline off: the
        # heartbeat alone must do it
        "master_heartbeat_ms": 100, "master_heartbeat_timeout_ms": 300, "rpdo_timeout_ms": 0,
        "joints": [{"name": "joint1", "node_id": 1, "family": "epos4", "current_limit": 10.0,
                    "units": {"nominal_current": d.nominal_current, "torque_constant": d.torque_constant,
                              "counts_per_rev": d.counts_per_rev, "gear_ratio": d.gear_ratio}}]}))
    master = subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.cli.epos", "--config", str(cfg),
                               "--enable", "--current", "0.5", "--hold", "60"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        end = time.monotonic() + 30.0
        while time.monotonic() < end:
            line = master.stdout.readline()
            assert line or master.poll() is None, "ff-epos exited before it enabled the drive"
            if '"enabled": true' in line:
                break
        held = lambda: _info(rig)[2] == pytest.approx(0.5, abs=0.003)   # noqa: E731
        end = time.monotonic() + 5.0
        while not held() and time.monotonic() < end:
            time.sleep(0.01)
        assert held()
        time.sleep(0.3)                                   # the drive has seen the master's heartbeat
        t_kill = time.monotonic()
        os.kill(master.pid, signal.SIGKILL)
        while _info(rig)[2] != 0.0 and time.monotonic() - t_kill < 3.0:
            time.sleep(0.005)
        state, fault, amps, t_err = _info(rig)
        # the drive's own stamp of its error (CLOCK_MONOTONIC is system-wide), at which its
        # current went to 0: the bound is on the drive, not on how fast this test polls
        dt = t_err - t_kill
        assert amps == 0.0 and 0.0 < dt < 0.5, (dt, state, fault)
        assert state == "Fault" and fault == 0x8130       # what the user reads: heartbeat error
    finally:
        if master.poll() is None:
            master.kill()
        master.wait(5)
        rig.stop()
