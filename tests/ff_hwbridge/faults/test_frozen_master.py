"""The master frozen (SIGSTOP) or killed while SYNC (the hub's, 10 ms) and the master's heartbeat
(``faults.HeartbeatKeeper``, standing for the kernel's broadcast manager on SocketCAN) go on:
the simulated EPOS4's interpolation supervision (0x60C2, EMCY 0x8250) must stop the drive within
0.5 s by its own stamp; with that supervision off, nothing does (the control)."""
from __future__ import annotations

import ast
import json
import signal

import pytest

from ff_hwbridge.sim import faults

pytestmark = pytest.mark.integration

STOP_BOUND_S = 0.5


@pytest.mark.parametrize("sig", [signal.SIGSTOP, signal.SIGKILL], ids=["sigstop", "sigkill"])
def test_a_frozen_master_is_stopped_by_the_drives_interpolation_supervision(sig):
    out = faults.frozen_master(sig)
    shown = json.dumps(out.as_dict(), indent=1, default=str)
    assert "tripped_before_the_signal" not in out.notes, shown      # not a measurement then
    assert out.stopped and (out.drive_state, out.drive_fault) == ("Fault", "0x8250"), shown
    assert out.out_of_enabled_s is not None and 0.0 <= out.out_of_enabled_s < STOP_BOUND_S, shown
    assert out.zero_current_s is not None and out.zero_current_s < STOP_BOUND_S + 0.5, shown
    # SYNC and the master's heartbeat went on: the drive's heartbeat consumer saw nothing wrong
    assert out.notes["sync_went_on"] and out.notes["heartbeats_kept"] >= 3, shown
    assert ast.literal_eval(out.notes["hb_age_after"])[127] < 0.3, shown


def test_without_the_supervision_a_frozen_master_keeps_the_drive_driving():
    """The control: the same freeze with the drive's supervision off leaves it in OPERATION
    ENABLED at 0.5 A for the second watched."""
    out = faults.frozen_master(signal.SIGSTOP, supervision=False, watch_s=1.0)
    shown = json.dumps(out.as_dict(), indent=1, default=str)
    assert not out.stopped and out.drive_state == "Operation enabled", shown
    assert out.drive_fault == "0x0000" and out.notes["supervision"] == "off", shown
    assert out.notes["current_a_after"] == pytest.approx(faults.HOLD_A, abs=0.003), shown
