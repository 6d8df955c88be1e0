"""The bridge configuration's drive-side safety keys: fail-safe defaults, the shipped configs, and
clear refusals."""
from __future__ import annotations

import pytest
import yaml

from ff_hwbridge.drive.config import ConfigError, load_config

BASE = {"bus": {"interface": "virtual", "channel": "x"},
        "joints": [{"name": "j", "node_id": 1, "current_limit": 5.0}]}


def test_defaults_are_fail_safe():
    c = load_config(BASE)
    assert c.master_heartbeat_ms == 100 and c.master_heartbeat_timeout_ms == 300
    assert c.rpdo_timeout_ms == 500
    slow = load_config({**BASE, "heartbeat_timeout": 1.0})   # as patient with the master as with drives
    assert (slow.master_heartbeat_timeout_ms, slow.rpdo_timeout_ms) == (1000, 2000)
    assert load_config({**BASE, "rpdo_timeout_ms": 0}).rpdo_timeout_ms == 0      # off
    assert (c.quick_stop_option, c.fault_reaction_option, c.abort_connection_option,
            c.communication_error_behaviour) == (2, 2, 1, 0)
    assert c.scaling_source == "check" and c.check_identity and c.boot_wait == 10.0


def test_timeouts_are_derived_from_the_producers_periods_with_a_margin():
    """3 periods of the producer + timeout_margin (0.1 s); SYNC and feedback at least as
    patient as the heartbeat."""
    c = load_config(BASE)
    assert c.sync_period == 0.01                                  # the supported default
    assert c.heartbeat_timeout == pytest.approx(3 * 0.010 + 0.1)  # 10 ms heartbeat producer
    assert c.sync_timeout == pytest.approx(3 * 0.01 + 0.1)
    assert c.feedback_timeout == pytest.approx(3 * 0.01 + 0.1)
    slow = load_config({**BASE, "heartbeat_producer_ms": 50, "feedback_every": 10, "timeout_margin": 0.2})
    assert slow.heartbeat_timeout == pytest.approx(3 * 0.05 + 0.2)
    assert slow.feedback_timeout == pytest.approx(3 * 0.01 * 10 + 0.2)
    assert slow.sync_timeout == pytest.approx(slow.heartbeat_timeout)      # as patient
    set_ = load_config({**BASE, "heartbeat_timeout": 0.5, "sync_timeout": 0.2})
    assert (set_.heartbeat_timeout, set_.sync_timeout) == (0.5, 0.2)      # given: kept
    with pytest.raises(ConfigError, match="timeout_margin must be 0 .. 10 s"):
        load_config({**BASE, "timeout_margin": -1})


def test_the_shipped_robot_config_runs_the_supported_mode():
    c = load_config("config/bridge_epos4_1dof.yaml")
    assert c.sync_period == 0.01 and c.synchronous and not c.player_process
    assert c.heartbeat_timeout >= 0.1 and c.sync_timeout >= 0.1 and c.feedback_timeout >= 0.1


@pytest.mark.parametrize("path", ["config/bridge_epos4_1dof.yaml", "config/bridge_sim_scara2.yaml"])
def test_shipped_configs_stop_the_drive_when_the_bridge_dies(path):
    c = load_config(path)
    assert c.master_heartbeat_ms > 0 and 0 < c.master_heartbeat_timeout_ms <= 500
    assert c.rpdo_timeout_ms > 0 and c.abort_connection_option == 1


def test_ros_params_sim_config_has_the_master_heartbeat_on():
    p = yaml.safe_load(open("config/bridge_ros_params_sim_1dof.yaml"))["ff_hwbridge"]["ros__parameters"]
    assert p["master_heartbeat_ms"] > 0 and p["rpdo_timeout_ms"] > 0


@pytest.mark.parametrize("key, value, words", [
    ("quick_stop_option", 9, "quick_stop_option must be an integer 0..8"),
    ("abort_connection_option", -1, "abort_connection_option must be an integer 0..3"),
    ("scaling_source", "yaml", "scaling_source must be one of"),
    ("master_heartbeat_timeout_ms", 50, "master_heartbeat_timeout_ms must be an integer ms above"),
    ("boot_wait", -1, "boot_wait must be"),
    ("stall_dump", -0.1, r"stall_dump must be 0 \.\. 3600 s"),
])
def test_bad_drive_settings_are_refused(key, value, words):
    with pytest.raises(ConfigError, match=words):
        load_config({**BASE, key: value})


def test_envelope_keys():
    j = load_config({**BASE, "joints": [{**BASE["joints"][0], "position_limits": [-1, 2],
                                         "velocity_limit": 3}]}).joints[0]
    assert j.position_limits == (-1.0, 2.0) and j.velocity_limit == 3.0
    with pytest.raises(ConfigError, match=r"joints\[0\].position_limits must be finite with low < high"):
        load_config({**BASE, "joints": [{**BASE["joints"][0], "position_limits": [2, 1]}]})
