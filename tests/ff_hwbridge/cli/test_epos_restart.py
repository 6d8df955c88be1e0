"""``ff-epos`` against the simulated EPOS4 (in-process, python-can virtual bus): a clean exit
disarms the drive's consumer of the master's heartbeat, so that a second start on the same drive
works; a drive found in Fault is reported with its error code and reset with ``--fault-reset``;
the states stop once the safe state latches."""
from __future__ import annotations

import json
import os
import time

import pytest

from ff_hwbridge.cli import epos
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.sim.drive import DriveConfig, SimEpos
from tests.support.canopen_helpers import open_network, unique_channel, waiter

wait_for = waiter(3.0)
CONSUMER_S = 0.3          # the drive's consumer time of the master heartbeat (3 x 100 ms)


class Rig:
    """One SimEpos on a private virtual channel and a bridge YAML for ``ff-epos`` (10 ms SYNC,
    the master's heartbeat consumed by the drive, derived timeouts)."""

    def __init__(self, tmp_path) -> None:
        self.channel = unique_channel("ff-cli-sim")
        self.net = open_network(self.channel)
        self.drive = SimEpos(DriveConfig())
        self.drive.attach(self.net)
        self.drive.boot()
        self.cfg = tmp_path / "bridge.yaml"
        self.cfg.write_text(f"bus: {{interface: virtual, channel: {self.channel}}}\n"
                            "sync_period: 0.01\nsetpoint_timeout: 1.0\nsdo_timeout: 2.0\n"
                            "master_heartbeat_ms: 100\nmaster_heartbeat_timeout_ms: 300\n"
                            "joints:\n"
                            "  - {name: joint1, node_id: 1, family: epos4, current_limit: 10.0,\n"
                            "     units: {nominal_current: 3.0, torque_constant: 0.0267,\n"
                            "             counts_per_rev: 2048, gear_ratio: 54}}\n")

    def run(self, capsys, *extra: str) -> tuple[int, list[dict], str]:
        code = epos.main(["--config", str(self.cfg), *extra])
        out = capsys.readouterr()
        return code, [json.loads(x) for x in out.out.splitlines() if x.startswith("{")], out.err

    def close(self) -> None:
        self.drive.close()
        self.net.disconnect()


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)
    yield r
    r.close()


def test_start_clean_exit_and_start_again_on_the_same_drive(rig, capsys):
    before = os.sched_getscheduler(0)
    code, lines, err = rig.run(capsys, "--enable", "--current", "0.5", "--hold", "0.3")
    assert code == 0, err
    assert os.sched_getscheduler(0) == before        # its SCHED_FIFO ended with it
    assert lines[1] == {"enabled": True, "reason": None}
    assert int(rig.drive.node.sdo[0x1016][1].raw) == 0          # disarmed on the way out
    time.sleep(2 * CONSUMER_S)                                   # a consumer still armed would fault now
    assert rig.drive.state is not State.FAULT
    code, lines, err = rig.run(capsys, "--enable", "--current", "0.5", "--hold", "0.3")
    assert code == 0, err
    assert lines[1] == {"enabled": True, "reason": None}
    assert lines[-1]["joints"][0]["state"] == State.OPERATION_ENABLED.value


def test_a_drive_in_fault_at_start_is_reported_and_reset_on_request(rig, capsys):
    rig.drive.raise_emcy(0x2310)                                # over current before any master
    code, lines, err = rig.run(capsys, "--enable", "--hold", "0.1")
    assert code == 1
    assert lines[1]["fault"] == "joint1" and "0x603F: 0x2310 over current" in lines[1]["error"]
    assert "--fault-reset" in err
    assert not any("enabled" in x for x in lines)
    code, lines, err = rig.run(capsys, "--fault-reset", "--enable", "--current", "0.2", "--hold", "0.3")
    assert code == 0, err
    assert "0x2310" in lines[1]["error"]
    assert lines[2]["fault_reset"] is True
    assert {"enabled": True, "reason": None} in lines
    assert lines[-1]["joints"][0]["state"] == State.OPERATION_ENABLED.value


def test_the_states_stop_once_the_drive_faulted(rig, capsys, monkeypatch):
    real_sleep = time.sleep
    calls = {"n": 0}

    def sleep(s: float) -> None:                # the hold loop's 2nd wait: the drive faults
        calls["n"] += s == 0.2
        if s == 0.2 and calls["n"] == 2 and rig.drive.state is State.OPERATION_ENABLED:
            rig.drive.raise_emcy(0x2310)
        real_sleep(s)

    monkeypatch.setattr(epos.time, "sleep", sleep)
    code, lines, _ = rig.run(capsys, "--enable", "--current", "0.3", "--hold", "2.0")
    assert code == 1
    after = lines[[i for i, x in enumerate(lines) if "fault" in x][0]:]
    assert "0x2310" in after[0]["error"]
    assert after[1]["safe_state"] and "0x2310" in after[1]["safe_state"]
    assert len(after) == 2                      # no state line after the fault
