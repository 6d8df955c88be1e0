"""The command lines in-process: ``ff-epos`` against the stand-in drive on a virtual bus, and the
exit code 2 of ``ff-can-hub`` / ``ff-sim-rig`` on settings they cannot use."""
from __future__ import annotations

import json

from ff_hwbridge.cli import can_hub, epos, sim_rig
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.units import DriveUnits
from tests.support.canopen_helpers import unique_channel
from tests.support.mini_drive import MiniEpos


def test_epos_configures_enables_holds_and_disables(tmp_path, capsys):
    channel = unique_channel("ff-cli")
    cfg = tmp_path / "bridge.yaml"
    cfg.write_text(f"bus: {{interface: virtual, channel: {channel}}}\n"
                   "sync_period: 0.005\nheartbeat_timeout: 1.0\nsetpoint_timeout: 1.0\n"
                   "joints:\n"
                   "  - {name: joint1, node_id: 1, family: epos4, current_limit: 10.0,\n"
                   "     units: {nominal_current: 3.0}}\n")
    drive = MiniEpos(channel, 1, DriveUnits(nominal_current=3.0))
    try:
        code = epos.main(["--config", str(cfg), "--enable", "--current", "1.5", "--hold", "0.1"])
    finally:
        drive.close()
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert code == 0
    assert lines[0] == {"configured": True, "joints": ["joint1"]}
    assert lines[1] == {"enabled": True, "reason": None}
    assert lines[-1]["joints"][0]["state"] == State.OPERATION_ENABLED.value
    assert 500 in [sp for _, sp in drive.rx_log]                 # 1.5 A / 3 A = 500 ‰
    assert 5 in drive.transitions[-2:]                            # disable operation, then
    assert drive.state is State.SWITCH_ON_DISABLED                # disable voltage on exit


def test_bad_settings_exit_2(capsys):
    assert can_hub.main(["--port", "0", "--host", "192.168.1.10"]) == 2
    assert "loopback" in capsys.readouterr().err
    assert can_hub.main(["--port", "0", "--rt-priority", "100"]) == 2
    assert "--rt-priority must be 0..99, got 50 / 100" in capsys.readouterr().err
    assert sim_rig.main(["--host-hub", "0", "--param", "no_such_key=1"]) == 2
    assert "ff-sim-rig" in capsys.readouterr().err
    assert sim_rig.main(["--host-hub", "0", "--nominal-current", "-2.5"]) == 2
    assert "nominal_current must be a finite number > 0" in capsys.readouterr().err
    assert sim_rig.main(["--host-hub", "0", "--boot-delay", "-1"]) == 2
    assert "--boot-delay must be >= 0 s" in capsys.readouterr().err
