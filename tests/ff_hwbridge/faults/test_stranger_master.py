"""A stranger's CiA 402 master (``stranger.py``: the canopen library and the EPOS4 EDS only)
against the simulated EPOS4 in its own process, through the loopback CAN hub: on a freshly
started drive and on one left idle for two minutes."""
from __future__ import annotations

import os
import time
from importlib import resources

import pytest

from tests.ff_hwbridge.faults import stranger
from tests.support.canopen_helpers import RigProcess

pytestmark = pytest.mark.integration

EDS = str(resources.files("ff_hwbridge.sim") / "epos4.eds")
IDLE_S = 120.0
QUICK_STOP_ACTIVE_MASK, QUICK_STOP_ACTIVE = 0x6F, 0x07


def _check(seen: dict) -> None:
    assert seen["device_type"] & 0xFFFF == 402 and seen["vendor_id"] == 0x000000FB
    assert seen["reactions"] == (6, 2, 3, 0)                  # maxon's factory settings
    assert seen["supported_modes"] & (1 << 9)                 # CST
    assert seen["interpolation"] == (10, -3)
    assert seen["tpdo1_cob_id"] & 0x7FF == 0x181
    assert seen["mode_display"] == 10
    assert seen["enabled"] == "OPERATION ENABLED"
    moved, speed, torque = seen["positive"]
    assert moved > 0 and speed > 0 and torque == 300
    assert seen["negative_speed"] < 0
    assert seen["state_after_quick_stop"] == "QUICK STOP ACTIVE"      # 0x605A = 6: stays
    assert seen["after_disable_voltage"] == "SWITCH ON DISABLED"
    assert seen["re_enabled"] == "OPERATION ENABLED" and seen["torque_after_re_enable"] == 100
    # the drive consumes the master's heartbeat (300 ms) and reacts by 0x6007 = 3 (quick stop)
    assert seen["heartbeat_emcy"] == 0x8130
    # by itself, its consumer time after the last heartbeat (sent up to one period before the
    # stop); timed under load by the fault tests and the benchmark, here the EMCY crosses two busy
    # processes on a shared machine
    low = CONSUMER_S - stranger.HEARTBEAT_S - 0.02
    assert low < seen["heartbeat_emcy_after_s"] < CONSUMER_S + 2.0, seen
    assert seen["statusword_after_heartbeat_loss"] & QUICK_STOP_ACTIVE_MASK == QUICK_STOP_ACTIVE
    assert seen["nmt_after_heartbeat_loss"] == "PRE-OPERATIONAL"        # 0x1029:01 = 0


CONSUMER_S = stranger.CONSUMER_MS / 1000.0


def _bus(rig: RigProcess) -> dict:
    return {"interface": "remote", "channel": rig.url, "bitrate": 1_000_000}


def test_a_strangers_master_sets_up_and_drives_a_fresh_drive():
    rig = RigProcess(["--model", "arm1dof", "--node-ids", "1"], stderr=open(os.devnull, "w"),
                     ready_timeout=120.0)
    try:
        _check(stranger.run(_bus(rig), 1, EDS))
    finally:
        rig.stop()


def test_a_strangers_master_on_a_drive_left_idle_for_two_minutes(idle_rig):
    rig, started = idle_rig
    left = IDLE_S - (time.monotonic() - started)
    if left > 0:
        time.sleep(left)
    assert time.monotonic() - started >= IDLE_S
    _check(stranger.run(_bus(rig), 1, EDS))
