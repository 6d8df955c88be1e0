"""The bridge node's flat parameters take their defaults from BridgeConfig (ff_hwbridge.drive.config):
a bridge started with no parameters file runs exactly the configuration a bridge YAML with only a
bus and one joint gives, and the shipped parameter file sets only declared parameters."""
from __future__ import annotations

import dataclasses

import yaml

from ff_hwbridge.drive.config import BridgeConfig, config_from_mapping
from ff_hwbridge.protocol.units import DriveUnits
from ff_hwbridge.ros.bridge_node import FLAT_DRIVE_KEYS, PARAMS, _flat_config
from ff_msgs_py.configs import config_path, node_parameters


def test_every_config_backed_default_is_bridgeconfigs_own():
    fields = {f.name: f.default for f in dataclasses.fields(BridgeConfig) if f.default is not dataclasses.MISSING}
    backed = [k for k in PARAMS if k in fields]
    # the ones the lead's report named among them, and every flat drive key
    assert {"master_heartbeat_timeout_ms", "rpdo_timeout_ms", "boot_wait", "sdo_timeout",
            "heartbeat_timeout"} <= set(backed)
    assert set(FLAT_DRIVE_KEYS) <= set(backed)
    for k in backed:
        expected = -1 if fields[k] is None else fields[k]
        assert PARAMS[k][0] == expected and type(PARAMS[k][0]) is type(expected), (k, PARAMS[k][0], expected)
    units = DriveUnits()
    assert PARAMS["nominal_currents"][0] == [units.nominal_current]
    assert PARAMS["torque_constants"][0] == [units.torque_constant]
    assert PARAMS["counts_per_rev"][0] == [units.counts_per_rev]
    assert PARAMS["gear_ratios"][0] == [units.gear_ratio]
    assert PARAMS["families"][0] == [units.family]


def test_no_parameters_file_gives_the_configs_defaults():
    from_defaults = config_from_mapping(_flat_config(lambda k: PARAMS[k][0]))
    minimal = config_from_mapping({"bus": {"interface": "virtual", "channel": "ff-bridge"},
                                   "joints": [{"name": "joint1", "node_id": 1, "family": "epos4",
                                               "current_limit": 10.0, "units": {}}]})
    assert dataclasses.asdict(from_defaults) == dataclasses.asdict(minimal)


def test_the_shipped_parameter_file_sets_only_declared_parameters():
    values = node_parameters("bridge_ros_params_sim_1dof.yaml", "ff_hwbridge")
    assert values and set(values) <= set(PARAMS), sorted(set(values) - set(PARAMS))
    assert yaml.safe_load(config_path("bridge_ros_params_sim_1dof.yaml").read_text())


def test_docs_table_is_the_declaration():
    from pathlib import Path

    from ff_hwbridge.ros.bridge_node import parameters_markdown

    page = (Path(__file__).resolve().parents[3] / "docs" / "parameters.md").read_text(encoding="utf-8")
    begin, end = "<!-- BEGIN ff_hwbridge parameters -->\n", "<!-- END ff_hwbridge parameters -->"
    assert page[page.index(begin) + len(begin):page.index(end)] == parameters_markdown()
