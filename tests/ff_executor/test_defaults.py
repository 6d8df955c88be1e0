"""The executor's parameter table is the one source of its defaults: the engine's EngineConfig, the
node's declared parameters and descriptors, config/executor.yaml, the overlays and
docs/parameters.md all agree with it, and the node started without a parameters file has the
parameters it has with config/executor.yaml."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest
import yaml

from ff_executor.engine.config import EXECUTOR_PARAMETERS, EngineConfig
from ff_executor.engine.paramgen import DOCS_FILE, executor_yaml, generated_section, main, with_section
from ff_executor.engine.paramspec import ParamSpec, ParamTable, yaml_value
from tests.ff_executor.node_params import (effective_parameters, parameter_differences, same_value,
                                           yaml_parameters)

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config"
TABLE = EXECUTOR_PARAMETERS
OVERLAYS = ("executor_sim.yaml", "executor_scara2.yaml")


def test_engine_config_defaults_are_the_tables():
    cfg = EngineConfig()
    for f in dataclasses.fields(EngineConfig):
        assert getattr(cfg, f.name) == TABLE.default(f.name), f.name
    assert EngineConfig.from_parameters(TABLE.defaults()) == cfg


def test_keepalive_default_feeds_the_bridge_watchdog():
    from ff_hwbridge.drive.config import BridgeConfig

    watchdog = {f.name: f.default for f in dataclasses.fields(BridgeConfig)}["setpoint_timeout"]
    assert 0.0 < EngineConfig().keepalive < watchdog


def test_shipped_yaml_is_the_table_written_out():
    text = (CONFIG / "executor.yaml").read_text(encoding="utf-8")
    assert yaml_parameters(CONFIG / "executor.yaml", "ff_executor") == TABLE.defaults()
    assert text == executor_yaml(), "run: python -m ff_executor.engine.paramgen yaml -o config/executor.yaml"


@pytest.mark.parametrize("name", OVERLAYS)
def test_overlays_set_known_keys_and_say_why_they_differ(name):
    path = CONFIG / name
    values = yaml_parameters(path, "ff_executor")
    assert values, f"{name} sets no ff_executor parameter"
    lines = {m.group(1): line for line in path.read_text(encoding="utf-8").splitlines()
             if (m := re.match(r"\s+(\w+):", line))}
    for key, value in values.items():
        assert key in TABLE, f"{name}: {key} is not an executor parameter"
        default = TABLE[key].ros_default
        assert type(value) is type(default), f"{name}: {key} = {value!r} has another type than {default!r}"
        if isinstance(default, list):
            assert all(type(v) is type(default[0]) for v in value), f"{name}: {key} = {value!r}"
        TABLE[key].check(value)
        if not same_value(value, default):
            assert "#" in lines[key], f"{name}: {key} differs from the default {default!r} without a comment why"
    EngineConfig.from_parameters({**TABLE.defaults(), **values})   # a valid configuration


def test_docs_table_is_the_table_written_out():
    assert generated_section(DOCS_FILE.read_text(encoding="utf-8"), TABLE) == TABLE.markdown(), (
        "run: python -m ff_executor.engine.paramgen markdown -o docs/parameters.md")
    assert main(["check"]) == 0


def test_markdown_section_is_replaced_in_place_and_appended_when_missing():
    page = "# t\n\nprose\n"
    once = with_section(page, TABLE)
    assert once.startswith(page) and generated_section(once, TABLE) == TABLE.markdown()
    edited = once.replace("| `lead_time` | `0.1`", "| `lead_time` | `9.9`") + "\nafter\n"
    again = with_section(edited, TABLE)
    assert again == once + "\nafter\n"


def test_yaml_values_read_back_with_their_type():
    for value in (0.0001, 1e-5, 1e20, 2.5, 10000, True, False, "a \"quoted\" name", ["a", "b"],
                  [1.0, 2.0], float("inf")):
        text = yaml_value(value)
        back = yaml.safe_load(f"x: {text}")["x"]
        assert type(back) is type(value) and back == value, (value, text)


def test_spec_refuses_defaults_outside_its_range_or_choices_and_checks_values():
    with pytest.raises(ValueError, match="within"):
        ParamSpec("t", 5.0, "s", "x", (0.0, 1.0))
    with pytest.raises(ValueError, match="one of"):
        ParamSpec("m", "c", "", "x", choices=("a", "b"))
    with pytest.raises(ValueError, match="twice"):
        ParamTable("n", (ParamSpec("a", 1, "", "x"), ParamSpec("a", 2, "", "y")))
    with pytest.raises(ValueError, match=r"within \[0.0, 60.0\] s"):
        TABLE["keepalive"].check(-1.0)
    with pytest.raises(ValueError, match="abort"):
        TABLE["refuse_mode"].check("queue")
    assert TABLE.differences({"lead_time": 0.8, "keepalive": 0.25, "max_steps": 10000.0}) == {
        "lead_time": (0.1, 0.8)}


def test_node_descriptors_follow_the_table():
    from ff_executor.ros.executor_node import descriptor

    for spec in TABLE:
        d = descriptor(spec.name)
        assert d.description.startswith(spec.text()), spec.name
        assert d.read_only == spec.read_at_start, spec.name
        if spec.range is not None and isinstance(spec.default, float):
            r = d.floating_point_range[0]
            assert (r.from_value, r.to_value) == spec.range, spec.name
        if spec.range is not None and isinstance(spec.default, int) and not isinstance(spec.default, bool):
            r = d.integer_range[0]
            assert (r.from_value, r.to_value) == spec.range, spec.name
        for choice in spec.choices:
            assert choice in d.additional_constraints


@pytest.mark.integration
def test_node_without_a_parameters_file_has_the_shipped_yamls_parameters(ros_env):
    from ff_executor.ros.executor_node import ExecutorNode

    def make(ctx):
        return ExecutorNode(context=ctx)

    without = effective_parameters(make)
    shipped = effective_parameters(make, [CONFIG / "executor.yaml"])
    assert parameter_differences(without, shipped) == {}
    assert parameter_differences(without, TABLE.defaults()) == {}
    # the files are read: the simulated stack's overlay changes exactly what it sets
    sim = effective_parameters(make, [CONFIG / "executor.yaml", CONFIG / "executor_sim.yaml"])
    assert parameter_differences(shipped, sim) == {"lead_time": (0.1, 0.8), "start_margin": (0.25, 1.0)}


@pytest.mark.integration
def test_runtime_change_outside_the_choices_is_refused(ros_env):
    from rclpy.parameter import Parameter

    from ff_executor.ros.executor_node import ExecutorNode
    from tests.support.ros_harness import ros_context

    with ros_context() as ctx:
        node = ExecutorNode(context=ctx)
        try:
            bad = node.set_parameters([Parameter("refuse_mode", value="queue")])[0]
            assert not bad.successful and "abort" in bad.reason
            assert node.set_parameters([Parameter("refuse_mode", value="reject")])[0].successful
            assert not node.set_parameters([Parameter("keepalive", value=0.0)])[0].successful  # read at start
        finally:
            node.destroy_node()
