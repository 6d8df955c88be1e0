"""``ff-bringup --namespace``: what each process of a namespaced stack is given (nothing started)."""
from __future__ import annotations

import pytest
import yaml

from ff_executor.bringup.stack import Stack, StackOptions, check_namespace, main


def test_namespace_names_are_checked():
    assert check_namespace("") == "" and check_namespace("arm_a") == "/arm_a" == check_namespace("/arm_a/")
    assert check_namespace("cell1/arm_a") == "/cell1/arm_a"
    for bad in ("1arm", "arm-a", "arm a", "a//b"):
        with pytest.raises(ValueError, match="--namespace"):
            check_namespace(bad)


def test_every_node_gets_the_namespace_and_its_parameters_under_the_namespaced_name(tmp_path):
    stack = Stack(StackOptions(namespace="arm_a", run_dir=str(tmp_path)), log=lambda _m: None)
    files, over = stack.executor_files()
    args = stack._node_args("ff_executor", files, over, tmp_path / "executor.yaml")
    assert args[:3] == ["--ros-args", "-r", "__ns:=/arm_a"]
    data = yaml.safe_load((tmp_path / "executor.yaml").read_text())
    params = data["/arm_a/ff_executor"]["ros__parameters"]
    # the shipped files' values, merged (a plain "ff_executor" key would match only the root node)
    assert params["lead_time"] == 0.8 and params["keepalive"] == 0.25
    assert params["setpoint_topic"] == "/arm_a/ff_hwbridge/setpoints"
    assert params["joint_state_topic"] == "/arm_a/ff_hwbridge/joint_states"
    assert params["applied_topic"] == "/arm_a/ff_hwbridge/applied"
    assert params["bridge_node"] == "ff_hwbridge"       # relative: found in the executor's namespace
    assert stack.name("ff_hwbridge") == "/arm_a/ff_hwbridge"
    # the root stack is unchanged: the shipped files as they are, overrides keyed by the plain name
    root = Stack(StackOptions(run_dir=str(tmp_path / "root")), log=lambda _m: None)
    files, over = root.executor_files()
    args = root._node_args("ff_executor", files, over, tmp_path / "root.yaml")
    assert "-r" not in args and args.count("--params-file") == len(files) + 1
    assert over.get("setpoint_topic") is None
    assert "ff_executor" in yaml.safe_load((tmp_path / "root.yaml").read_text())


def test_bringup_refuses_a_bad_namespace_and_record_with_one(capsys):
    assert main(["--namespace", "arm-a", "--print-config"]) == 2
    assert "--namespace" in capsys.readouterr().err
    assert main(["--namespace", "arm_a", "--record", "/nonexistent/bag", "--print-config"]) == 2
    assert "--record" in capsys.readouterr().err


def test_print_config_shows_the_namespace(capsys):
    assert main(["--namespace", "arm_b", "--no-planner", "--print-config"]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    assert cfg["namespace"] == "/arm_b"
    assert cfg["ff_executor"]["parameters"]["setpoint_topic"] == "/arm_b/ff_hwbridge/setpoints"
