"""ff-bringup: options, generated configuration, and the four processes started and stopped by PID."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from ff_executor.bringup.stack import Stack, StackOptions, bridge_config, build_parser, main
from ff_planner.model.params import ParameterError


def test_true_friction_scales_and_sets():
    o = StackOptions(true_scale={"pc": 1.2}, true_params={"pt": 0.3})
    assert o.true_friction() == pytest.approx({"pc": 0.228, "pt": 0.3})
    with pytest.raises(ParameterError, match="unknown parameter"):
        StackOptions(true_scale={"pz": 1.2}).true_friction()
    with pytest.raises(ParameterError):
        StackOptions(true_params={"pc": -1.0}).true_friction()


def test_cli_refuses_bad_options_with_exit_2(capsys):
    assert main(["--true-scale", "pc"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err
    assert main(["--true-param", "pc=abc"]) == 2
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--model", "nope"])


def test_bridge_config_is_valid_for_the_bridge_and_loopback():
    from ff_hwbridge.drive.config import config_from_mapping

    for model, nj in (("arm1dof", 1), ("scara2", 2)):
        data = bridge_config(model, "ws://127.0.0.1:50000/")
        cfg = config_from_mapping(data)
        assert len(cfg.joints) == nj
        assert data["bus"]["channel"].startswith("ws://127.0.0.1:")


@pytest.mark.integration
def test_stack_starts_all_four_and_stops_them_by_pid(tmp_path):
    stack = Stack(StackOptions(true_scale={"pc": 1.2}, run_dir=str(tmp_path)), log=lambda s: None)
    stack.start()
    try:
        names = [p.name for p in stack.procs]
        # the CAN hub in its own process produces SYNC; then the four nodes
        assert names == ["ff_can_hub", "ff_sim_driver", "ff_hwbridge", "ff_planner", "ff_executor"]
        assert all(p.alive() for p in stack.procs)
        env = stack.env
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
        assert stack.hub_url.startswith("ws://127.0.0.1:")
        assert stack.has_service("/ff_planner/plan")
        assert stack.lifecycle_state("ff_hwbridge") == "active"
        stack.set_true_params({"pc": 0.25})
        with pytest.raises(ParameterError):
            stack.set_true_params({"nope": 1.0})
        procs = list(stack.procs)
    finally:
        codes = stack.stop()
    assert set(codes) == {"ff_can_hub", "ff_sim_driver", "ff_hwbridge", "ff_planner", "ff_executor"}
    assert not any(p.alive() for p in procs)


@pytest.mark.integration
def test_ff_bringup_stops_everything_when_a_child_dies(tmp_path, ros_env):
    env = dict(ros_env)
    bag = tmp_path / "run_bag"
    proc = subprocess.Popen([sys.executable, "-u", "-m", "ff_executor.bringup.stack", "--no-planner",
                             "--run-dir", str(tmp_path), "--record", str(bag)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        end = time.monotonic() + 120
        while time.monotonic() < end:
            line = proc.stdout.readline()
            lines.append(line)
            if "all up" in line or proc.poll() is not None:
                break
        assert any("all up" in l for l in lines), "".join(lines)
        # kill the executor child (by its PID, found in the log line "ff_executor up ... pid N")
        pid = int(next(l for l in lines if "ff_executor up" in l).rsplit("pid", 1)[1])
        os.kill(pid, signal.SIGKILL)
        out, _ = proc.communicate(timeout=60)
        assert proc.returncode == 1
        assert "ff_executor died" in out and "stopped" in out
        assert "ff_record (0)" in out, out          # the recorder closed its bag on the way out
        assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))
        for l in lines:
            if " up (" in l:
                child = int(l.rsplit("pid", 1)[1])
                with pytest.raises(ProcessLookupError):
                    os.kill(child, 0)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(30)


@pytest.mark.integration
def test_timed_wrapper_runs_the_module_with_a_fine_switch_interval(tmp_path):
    mod = tmp_path / "probe_mod.py"
    mod.write_text("import sys\nprint('interval', round(sys.getswitchinterval() * 1e6), sys.argv[1:])\n")
    env = dict(os.environ, PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    out = subprocess.run([sys.executable, "-m", "ff_executor.bringup.timed", "--switch-interval", "0.0002",
                          "probe_mod", "--x", "1"], env=env, capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    assert "interval 200 ['--x', '1']" in out.stdout
    bad = subprocess.run([sys.executable, "-m", "ff_executor.bringup.timed", "--switch-interval", "5",
                          "probe_mod"], env=env, capture_output=True, text=True, timeout=30)
    assert bad.returncode != 0 and "switch-interval" in bad.stderr


def test_environment_is_honoured_when_set_and_isolation_is_the_default(tmp_path):
    from ff_executor.bringup.stack import environment_options

    a = build_parser().parse_args([])
    assert environment_options(a, {}) == {"domain_id": None, "run_dir": None, "log_dir": None, "record": None}
    got = environment_options(a, {"ROS_DOMAIN_ID": "42", "ROS_LOG_DIR": str(tmp_path)})
    assert got["domain_id"] == 42 and got["log_dir"] == str(tmp_path)
    a = build_parser().parse_args(["--domain-id", "7", "--record", str(tmp_path / "bag")])
    got = environment_options(a, {"ROS_DOMAIN_ID": "42"})
    assert got["domain_id"] == 7 and got["record"] == str(tmp_path / "bag")
    with pytest.raises(ValueError, match="exists"):
        environment_options(build_parser().parse_args(["--record", str(tmp_path)]), {})
    with pytest.raises(ValueError, match="whole number"):
        environment_options(build_parser().parse_args([]), {"ROS_DOMAIN_ID": "abc"})


def test_print_config_shows_the_values_from_config(capsys, tmp_path, monkeypatch):
    import yaml

    from ff_executor.bringup import demo
    from ff_executor.bringup.stack import CONFIG_DIR, COUNTS_PER_REV

    monkeypatch.setenv("ROS_DOMAIN_ID", "17")
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path / "logs"))
    assert main(["--print-config", "--run-dir", str(tmp_path / "run")]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    assert cfg["ros"] == {"ROS_DOMAIN_ID": "17", "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                          "ROS_LOG_DIR": str(tmp_path / "logs")}
    sim_cfg = yaml.safe_load((CONFIG_DIR / "sim_arm1dof.yaml").read_text())["ff_sim_driver"]["ros__parameters"]
    exe_sim = yaml.safe_load((CONFIG_DIR / "executor_sim.yaml").read_text())["ff_executor"]["ros__parameters"]
    assert cfg["ff_sim_driver"]["parameters"]["counts_per_rev"] == sim_cfg["counts_per_rev"] == COUNTS_PER_REV
    assert cfg["ff_hwbridge"]["config"]["joints"][0]["units"]["counts_per_rev"] == COUNTS_PER_REV
    assert cfg["ff_executor"]["parameters"]["lead_time"] == exe_sim["lead_time"]
    assert cfg["ff_executor"]["parameters"]["keepalive"] == 0.25     # from config/executor.yaml
    assert demo.main(["--print-config", "--domain-id", "5"]) == 0
    assert yaml.safe_load(capsys.readouterr().out)["ros"]["ROS_DOMAIN_ID"] == "5"


def test_robot_bridge_config_is_the_shipped_file_with_only_its_bus_on_the_hub(tmp_path):
    import yaml

    from ff_executor.bringup.stack import CONFIG_DIR, robot_bridge_config

    shipped = CONFIG_DIR / "bridge_epos4_1dof.yaml"
    data = robot_bridge_config(shipped, "arm1dof", "ws://127.0.0.1:50000/")
    original = yaml.safe_load(shipped.read_text())
    assert data["bus"] == {"interface": "remote", "channel": "ws://127.0.0.1:50000/", "bitrate": 1_000_000}
    # SocketCAN + sync_producer master: the kernel sends SYNC on a robot, the hub's timer here
    assert original["bus"]["interface"] == "socketcan" and original["sync_producer"] == "master"
    assert data["sync_producer"] == "external"
    assert ({k: v for k, v in data.items() if k not in ("bus", "sync_producer")}
            == {k: v for k, v in original.items() if k not in ("bus", "sync_producer")})
    stack = Stack(StackOptions(bridge_config_file=str(shipped), run_dir=str(tmp_path)), log=lambda s: None)
    # the robot's mode: in-process player, SYNC every 10 ms from a timer outside the bridge
    assert not stack.bridge_data().get("player_process")
    assert stack.hub_syncs and stack.sync_period == 0.01
    assert stack.sim_parameters()["nominal_current"] == original["joints"][0]["units"]["nominal_current"]
    assert stack.planner_files()[1]["current_quantum"] == pytest.approx(0.003)
    # with a SYNC producer elsewhere, the hub produces it at the file's period; on a bus whose
    # SYNC comes from the master's own thread (pcan), the bridge produces it, none from the hub
    ext = tmp_path / "external.yaml"
    ext.write_text(yaml.safe_dump(dict(original, sync_producer="external", sync_period=0.02)))
    stack = Stack(StackOptions(bridge_config_file=str(ext), run_dir=str(tmp_path)), log=lambda s: None)
    assert stack.hub_syncs and stack.sync_period == 0.02
    pcan = tmp_path / "pcan.yaml"
    pcan.write_text(yaml.safe_dump(dict(original, bus={"interface": "pcan", "channel": "PCAN_USBBUS1"})))
    stack = Stack(StackOptions(bridge_config_file=str(pcan), run_dir=str(tmp_path)), log=lambda s: None)
    assert stack.bridge_data()["sync_producer"] == "master" and not stack.hub_syncs


@pytest.mark.parametrize("change, text", [
    ({"joints": [{"node_id": 3}]}, "node ids [3]"),
    ({"joints": [{"units": {"torque_constant": 0.05}}]}, "units.torque_constant is 0.05"),
    ({"joints": [{"units": {"gear_ratio": 100.0}}]}, "units.gear_ratio is 100.0"),
    ({"sync_period": -1.0}, "sync_period"),
])
def test_a_robot_config_that_cannot_run_on_the_simulation_is_refused_with_the_key(tmp_path, capsys, change, text):
    import yaml

    from ff_executor.bringup.stack import CONFIG_DIR, robot_bridge_config

    data = yaml.safe_load((CONFIG_DIR / "bridge_epos4_1dof.yaml").read_text())
    for key, value in change.items():
        if key == "joints":
            joint = data["joints"][0]
            for k, v in value[0].items():
                joint[k] = dict(joint[k], **v) if isinstance(v, dict) else v
        else:
            data[key] = value
    bad = tmp_path / "robot.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ValueError, match="robot.yaml") as exc:
        robot_bridge_config(bad, "arm1dof", "ws://127.0.0.1:50000/")
    assert text in str(exc.value)
    # ff-bringup: one line, exit 2, nothing started
    assert main(["--bridge-config", str(bad), "--run-dir", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ff-bringup: bridge config") and text in err and not (tmp_path / "run").exists()


def test_the_one_dof_robot_config_does_not_run_the_two_dof_simulation(capsys):
    from ff_executor.bringup.stack import CONFIG_DIR

    assert main(["--model", "scara2", "--bridge-config", str(CONFIG_DIR / "bridge_epos4_1dof.yaml")]) == 2
    assert "cannot run on the simulated scara2: its joints have node ids [1]" in capsys.readouterr().err
    assert main(["--bridge-config", "no/such.yaml"]) == 2
    assert "cannot read it" in capsys.readouterr().err
