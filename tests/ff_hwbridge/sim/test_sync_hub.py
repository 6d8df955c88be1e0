"""SYNC from the CAN hub's process (``ff-can-hub --sync-period``) across processes: the master
(``sync_producer: external``) and its player in this process, the simulated EPOS + arm in
another (``ff-sim-rig --bus-url``): each setpoint is latched at a SYNC bus instant the master
saw, the one the player reports; the hub reports its SYNC jitter as JSON at exit."""
from __future__ import annotations

import json
import os
import re
import tempfile
from typing import Any, Optional, Sequence

import pytest

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.drive.placement import GRID_TOLERANCE
from ff_hwbridge.drive.player import SetpointPlayer
from ff_hwbridge.drive.player_process import ProcessPlayer
from ff_hwbridge.sim.rig_process import RigProcess, free_port, rig_master_config
from ff_msgs_py.launch import start_module, wait_for_line
from ff_hwbridge.protocol.cia402 import State
from tests.support.canopen_helpers import configure_and_enable, waiter

pytestmark = pytest.mark.integration

PERIOD = 0.01        # s, the supported rate: the simulated drive supervises it (0x8250), and
#                     these protocol checks must hold on a loaded 2-core machine
wait_for = waiter(5.0)


class HubBench:
    """``ff-can-hub`` sending SYNC every ``PERIOD``, the simulated rig joined to its bus (``rig_args``
    its extra options) and, in this process, an ``EposMaster`` (``sync_producer: external``,
    ``settings`` on top) connected to it. On exit: the ``player`` a test set closed, the master
    disconnected, the rig stopped, then the hub; its exit code in ``code``."""

    def __init__(self, ros_env: dict[str, str], rig_args: Sequence[str] = (), **settings: Any) -> None:
        self._env, self._rig_args, self._settings = ros_env, list(rig_args), settings
        self.rig: Optional[RigProcess] = None
        self.master: Optional[EposMaster] = None
        self.player: Any = None
        self.code: Optional[int] = None

    def __enter__(self) -> "HubBench":
        port = free_port()
        self.hub = start_module("can_hub", "ff_hwbridge.cli.can_hub",
                                ["--port", str(port), "--sync-period", str(PERIOD)], self._env)
        try:
            assert wait_for_line(self.hub, "CAN hub on ws://", 20.0), self.hub.output()
            url = f"ws://127.0.0.1:{port}/"
            self.rig = RigProcess(self._rig_args, port=port, host_hub=False, bus_url=url, env=self._env)
            self.master = EposMaster(rig_master_config(url, "epos4", 5.0, sync_period=PERIOD,
                                                       sync_producer="external", heartbeat_timeout=1.0,
                                                       feedback_timeout=1.0, sync_timeout=1.0,
                                                       **self._settings))
            self.master.connect()
        except BaseException:
            self.__exit__()
            raise
        return self

    def drive_caught_up(self, sync_ns: int, timeout: float = 10.0) -> bool:
        """Wait until the simulated drive has handled the SYNC at bus instant ``sync_ns`` (its
        process may lag this one under load; its record is written when the rig stops)."""

        def last() -> int:
            m = re.search(r"last_sync_ns=(\d+)", self.rig.cmd("info 1") if self.rig else "")
            return int(m.group(1)) if m else -1
        return waiter(timeout)(lambda: last() >= sync_ns)

    def __exit__(self, *exc: object) -> None:
        if self.player is not None:
            self.player.close()
        if self.master is not None:
            self.master.disconnect()
        if self.rig is not None:
            self.rig.stop(20)
        self.code = self.hub.stop()


@pytest.mark.parametrize("player_kind", [SetpointPlayer, ProcessPlayer],
                         ids=["thread", "process"])
def test_setpoints_latch_at_the_hub_sync_and_the_hub_reports_its_jitter(ros_env, player_kind):
    record = os.path.join(tempfile.mkdtemp(prefix="ff-sync-hub-"), "sim.json")
    syncs: list[int] = []
    with HubBench(ros_env, ["--record", record], setpoint_timeout=2.0) as bench:
        master = bench.master
        master.network.subscribe(0x80, lambda cid, data, ts: syncs.append(int(round(ts * 1e9))))
        configure_and_enable(master, 5.0)
        assert not master._sync_running                 # external: the master sends no SYNC
        player = bench.player = player_kind(master).start()
        assert wait_for(lambda: player.sync_grid() is not None)
        nominal, period = player.sync_grid()
        amps = [0.2, -0.3, 0.4, 0.0]
        stamps = [nominal + (20 + 4 * k) * period for k in range(len(amps))]
        for k, (s, a) in enumerate(zip(stamps, amps)):
            player.submit(s, [a], seq=k, profile_id="sync-hub", last=k == len(amps) - 1)
        got = []
        assert wait_for(lambda: got.extend(player.take_applied()) or len(got) == len(amps))
        # each reported at its stamp as placed on the SYNC grid: the grid's estimate may have
        # moved by tens of ns (wall clock against monotonic) since it was read above
        assert len(got) == len(stamps)
        for g, s in zip(got, stamps):
            assert abs(g.stamp_ns - s) <= period / GRID_TOLERANCE, (g.stamp_ns, s)
        for g in got:
            assert g.sent_ns in syncs                   # applied at a SYNC's bus instant
            assert g.rpdo_sent_ns < g.sent_ns and g.sent_ns >= g.stamp_ns - 0.1 * period
        assert bench.drive_caught_up(got[-1].sent_ns)
    assert bench.code == 0
    hub = bench.hub
    with open(record) as fh:
        log = json.load(fh)["setpoints"]["1"]            # [mono_ns, wall_ns, raw, A]
    units = master.units[0]
    for g, a in zip(got, amps[:3]):
        raw = units.amps_to_setpoint(a, limit=5.0)
        # the drive latched it at exactly the SYNC instant the player reported (then the
        # master repeats the value in force in every cycle: later records of it)
        assert next(r[1] for r in log if r[2] == raw) == g.sent_ns
    line = next(x for x in hub.output().splitlines() if x.startswith('{"sync"'))
    st = json.loads(line)["sync"]
    assert st["count"] > 50 and st["period_us"] == PERIOD * 1e6
    assert 0.0 <= st["jitter_p50_us"] <= st["jitter_p99_us"] <= st["jitter_max_us"]
    assert re.search(rf"SYNC every {PERIOD * 1000.0:g} ms", hub.output())


def test_a_dead_player_process_latches_the_safe_state_and_the_drive_stops(ros_env):
    """The player process killed mid-stream: the bridge latches the safe state with the reason
    and its own RPDOs carry the reaction (0 A, quick stop)."""
    with HubBench(ros_env, setpoint_timeout=5.0, player_process=True) as bench:
        master = bench.master
        configure_and_enable(master, 5.0)
        player = bench.player = ProcessPlayer(master).start()
        assert wait_for(lambda: player.sync_grid() is not None)
        nominal, period = player.sync_grid()
        player.submit(nominal + 20 * period, [0.8], seq=0, profile_id="dies")
        got: list = []
        assert wait_for(lambda: got.extend(player.take_applied()) or got)
        assert wait_for(lambda: abs(master.feedback()[0].current - 0.8) < 0.05), master.feedback()
        os.kill(player.pid, 9)
        assert wait_for(lambda: master.latched, 5.0)
        assert "player process" in master.fault_reason, master.fault_reason
        assert wait_for(lambda: abs(master.feedback()[0].current) < 0.05), master.feedback()
        assert wait_for(lambda: master.states()[0] is not State.OPERATION_ENABLED), master.states()
