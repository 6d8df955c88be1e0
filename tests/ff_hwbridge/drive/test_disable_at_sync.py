"""A clean disconnect disables the drive at a SYNC before the per-cycle RPDO stops: with SYNC
going on from elsewhere afterwards (the hub, a PLC), the simulated EPOS4, which supervises the
interpolation period (EMCY 0x8250 when a SYNC interval has no target RPDO while enabled in CST),
ends in Switch on disabled, not in Fault."""
from __future__ import annotations

import time

from ff_hwbridge.protocol.cia402 import State
from tests.ff_hwbridge.drive.test_sync_player import PERIOD, SyncBench
from tests.support.canopen_helpers import waiter

wait_for = waiter(3.0)


def test_disconnect_leaves_operation_enabled_before_the_rpdos_stop():
    b = SyncBench()
    try:
        b.enable()
        b.master.command_currents([0.5])
        assert wait_for(lambda: b.drive.applied_current > 0.4)
        b.player.close()
        assert b.master.disable_at_sync() is True
        assert b.master.states() != [State.OPERATION_ENABLED]
        b.master.disconnect()                    # the RPDOs stop here; SYNC goes on
        time.sleep(10 * PERIOD)
        assert b.drive.state is State.SWITCH_ON_DISABLED, b.drive.state
        assert b.drive.interpolation_faults == 0
        assert b.drive.applied_current == 0.0
    finally:
        b.close()
