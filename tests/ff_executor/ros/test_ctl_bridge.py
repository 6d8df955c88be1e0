"""ff-ctl against a bridge node (in this process, namespaced, on a virtual bus with the stand-in
drive): a failed configure's reason in ``status`` and ``diag``; claim / release / fault-reset as
the owner; ``echo`` and ``call`` on the suite's own interfaces; a missing extra named in one line."""
from __future__ import annotations

import re

import pytest
import yaml

from ff_executor.ros import ctl
from ff_hwbridge.protocol.units import DriveUnits
from ff_msgs_py.extras import missing_extra
from tests.support.canopen_helpers import unique_channel, waiter
from tests.support.ros_harness import ros_context, spinning

_wait = waiter(5.0, 0.01)


def test_a_missing_extra_is_one_line_naming_it(capsys, monkeypatch):
    assert "pip install 'ff-suite[record]'" in missing_extra(ModuleNotFoundError("x", name="rosbags"))
    assert "[cluster]" in missing_extra(ModuleNotFoundError("x", name="distributed.security"))
    assert "mcap-ros2-support" in missing_extra(ModuleNotFoundError("x", name="mcap_ros2"))

    def no_rosbags(s, a, prog=""):
        raise ModuleNotFoundError("No module named 'rosbags'", name="rosbags")
    monkeypatch.setattr(ctl, "run_record", no_rosbags)
    monkeypatch.setenv("ROS_DOMAIN_ID", "231")
    assert ctl.main(["record", "-o", "never_written", "--duration", "0.1"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "[record] extra" in err and "Traceback" not in err, err


@pytest.mark.integration
def test_status_claim_echo_call_in_a_namespace(ros_env, tmp_path, capsys):
    from rclpy.parameter import Parameter

    from ff_hwbridge.ros.bridge_node import BridgeNode
    from tests.support.mini_drive import MiniEpos

    bad = tmp_path / "bad_bridge.yaml"
    bad.write_text("bus: {interface: virtual}\njoints: []\n")
    channel = unique_channel("ff-ctl")
    drive = MiniEpos(channel, 1, DriveUnits(nominal_current=3.0))
    params = [Parameter("config_file", value=str(bad))]
    ns = ["--namespace", "arm_a"]
    try:
        with ros_context() as ctx:
            node = BridgeNode(context=ctx, namespace="arm_a", parameter_overrides=params)
            with spinning(ctx, node):
                try:
                    node.trigger_configure()
                    assert node.master is None and "joints" in node.config_error
                    # the reason of the failed configure, through ff-ctl
                    assert ctl.main(["status", *ns]) == 1
                    out, err = capsys.readouterr()
                    assert "/arm_a/ff_hwbridge: unconfigured" in out and "configure failed" in out, (out, err)
                    assert "joints must be a non-empty list" in out, out
                    assert ctl.main(["diag", "--duration", "3"]) == 0
                    out = capsys.readouterr().out
                    assert "arm_a/ff_hwbridge: drive group: configure failed" in out, out

                    # a good configuration: the flat parameters on the stand-in drive
                    from rclpy.parameter import Parameter as P
                    node.set_parameters([P("config_file", value=""), P("bus_interface", value="virtual"),
                                         P("bus_channel", value=channel), P("heartbeat_timeout", value=2.0),
                                         P("sync_timeout", value=2.0), P("missed_cycle_tolerance", value=100),
                                         P("sync_period", value=0.008)])
                    node.trigger_configure()
                    assert node.master is not None
                    node.trigger_activate()
                    assert node.active
                    assert ctl.main(["status", *ns]) == 0
                    out = capsys.readouterr().out
                    assert "active" in out and "owner: /arm_a/ff_executor (default owner" in out, out

                    # claim as a script would, owner reset with the token, release
                    assert ctl.main(["claim", *ns, "--lease", "60", "--client", "/operator"]) == 0
                    out = capsys.readouterr().out
                    token = re.search(r"token ([0-9a-f]{32})", out).group(1)
                    assert node.ownership.owner == "/operator"
                    assert ctl.main(["fault-reset", *ns]) == 1           # not the owner
                    assert "claimed by /operator" in capsys.readouterr().out
                    assert ctl.main(["fault-reset", *ns, "--token", token]) == 0
                    assert "fault reset done" in capsys.readouterr().out

                    # echo the typed status, call the claim service with a YAML request
                    assert ctl.main(["echo", "ff_hwbridge/status", *ns, "--count", "1"]) == 0
                    doc = yaml.safe_load(capsys.readouterr().out.split("---")[0])
                    assert doc["owner"] == "/operator" and doc["claimed"] is True and doc["state"] == 2
                    assert ctl.main(["call", "ff_hwbridge/claim", "{action: 0, client: /intruder}", *ns]) == 0
                    res = yaml.safe_load(capsys.readouterr().out)
                    assert res["success"] is False and "claimed by /operator" in res["message"]
                    assert ctl.main(["call", "ff_hwbridge/claim", "{action: 0, nope: 1}", *ns]) == 2
                    assert "no field 'nope'" in capsys.readouterr().err
                    assert ctl.main(["release", *ns, "--token", token]) == 0
                    assert "released by /operator" in capsys.readouterr().out
                    assert _wait(lambda: not node.ownership.claimed)
                finally:
                    node.teardown()
    finally:
        drive.close()
