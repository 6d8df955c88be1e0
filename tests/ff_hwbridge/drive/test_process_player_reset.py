"""Safe state means zero until told otherwise, with the player in its own process
(``player_process: true``): after a setpoint-watchdog trip and ``fault_reset()`` the drive is
enabled again at 0 A (not the current held before the trip), its interpolation supervision
content (the child repeats the value in force every SYNC cycle), until a setpoint stamped after
the reset. The CAN hub in its own process (``ff-can-hub``: a 10 ms SYNC, its threads under
SCHED_FIFO, as the simulated stack runs it: a bus forwards frames in µs, a hub at normal priority
on a loaded machine may not), the simulated EPOS4 + arm in another (``ff-sim-rig``); the master
here, the player process on the same hub."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time

import pytest

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.drive.player import SetpointRejected
from ff_hwbridge.drive.player_process import ProcessPlayer
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.sim.rig_process import RigProcess, free_port, rig_master_config
from tests.support.canopen_helpers import configure_and_enable, waiter

pytestmark = pytest.mark.integration
wait_for = waiter(5.0)


def _current(rig: RigProcess) -> float:
    """A, the simulated drive's current now."""
    return float(re.search(r"i=\[([^\],]*)", rig.cmd("state")).group(1))


@pytest.fixture
def hub_url():
    port = free_port()
    hub = subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.cli.can_hub", "--port", str(port),
                            "--sync-period", "0.01", "--rt-priority", "49"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert hub.stdout is not None and "CAN hub on" in hub.stdout.readline()
        yield f"ws://127.0.0.1:{port}/"
    finally:
        hub.terminate()
        hub.wait(5)


def test_fault_reset_after_a_watchdog_trip_keeps_zero_until_a_newer_setpoint(hub_url):
    rig = RigProcess(["--q0", "0.0"], host_hub=False, bus_url=hub_url, env=dict(os.environ),
                     stderr=tempfile.TemporaryFile("w+"))
    master = EposMaster(rig_master_config(rig.url, "epos4", 5.0, sync_period=0.01,
                                          sync_producer="external", player_process=True,
                                          heartbeat_timeout=1.0, setpoint_timeout=0.3,
                                          master_heartbeat_timeout_ms=2000))
    player = None
    try:
        master.connect()
        configure_and_enable(master, 5.0)
        player = ProcessPlayer(master).start()
        assert player.exit_reason is None
        player.submit(time.time_ns() + 50_000_000, [0.25], profile_id="")   # held: a manual step
        assert wait_for(lambda: abs(_current(rig) - 0.25) < 0.01), _current(rig)
        assert wait_for(lambda: master.latched, 3.0)                       # no fresh setpoint
        assert "setpoint watchdog" in (master.fault_reason or "")
        t_trip = time.time_ns()
        assert wait_for(lambda: _current(rig) == 0.0)
        master.fault_reset()
        assert master.wait_for_state(State.OPERATION_ENABLED, 3.0), master.fault_reason
        with pytest.raises(SetpointRejected, match="before the latest safe state"):
            player.submit(t_trip, [0.25])
        samples = []
        for _ in range(10):                                                # 0.5 s enabled
            samples.append(_current(rig))
            time.sleep(0.05)
        assert samples == [0.0] * 10
        assert master.states() == [State.OPERATION_ENABLED] and not master.latched
        player.submit(time.time_ns() + 50_000_000, [0.1], profile_id="")   # told otherwise
        assert wait_for(lambda: abs(_current(rig) - 0.1) < 0.01), _current(rig)
        player.submit(time.time_ns() + 20_000_000, [0.0], profile_id="")
        assert wait_for(lambda: _current(rig) == 0.0)
    finally:
        if player is not None:
            player.close()
        master.disconnect()
        rig.stop()
