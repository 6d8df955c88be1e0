"""ff-ctl and ff-record against a running stack (ff_executor.bringup.stack.Stack)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter

import pytest
from mcap.reader import make_reader

from ff_executor.ros import ctl
from tests.ff_executor.ros.test_plotjuggler_layout import layout_plots, plotjuggler_series
from tests.ff_msgs_py.test_definitions import decoder
from tests.support.stacks import running_stack

pytestmark = pytest.mark.integration

NODES = ("/ff_sim_driver", "/ff_hwbridge", "/ff_planner", "/ff_executor")


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("toolbox"))


def run_ctl(stack, capsys, *argv: str) -> tuple[int, str]:
    code = ctl.main([*argv, "--domain-id", stack.env["ROS_DOMAIN_ID"]])
    cap = capsys.readouterr()
    return code, cap.out + cap.err


def test_graph_lists_the_four_nodes_topics_and_the_action(stack):
    out = subprocess.run([sys.executable, "-m", "ff_executor.ros.ctl", "graph", "--json", "--wait", "30",
                          "--expect", *NODES],
                         env=stack.env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    g = json.loads(out.stdout)
    assert g["domain_id"] == int(stack.env["ROS_DOMAIN_ID"])
    assert set(NODES) <= set(g["nodes"]), g["nodes"]
    topics = {t["name"]: t["types"] for t in g["topics"]}
    assert topics["/ff_hwbridge/joint_states"] == ["sensor_msgs/msg/JointState"]
    assert topics["/ff_hwbridge/setpoints"] == ["ff_msgs/msg/CurrentSetpoint"]
    assert {"name": "/ff_planner/plan", "types": ["ff_msgs/srv/PlanTrajectory"]} in g["services"]
    assert {"name": "/ff_executor/execute", "types": ["ff_msgs/action/ExecuteProfile"]} in g["actions"]


def test_lifecycle_get_says_active_and_a_bad_transition_fails(stack, capsys):
    code, out = run_ctl(stack, capsys, "lifecycle", "get", "ff_hwbridge")
    assert code == 0 and out.splitlines()[0] == "active", out
    code, out = run_ctl(stack, capsys, "lifecycle", "set", "ff_hwbridge", "configure")
    assert code == 1 and "deactivate" in out, out
    code, out = run_ctl(stack, capsys, "lifecycle", "get", "ff_planner")
    assert code == 1 and "not a running lifecycle node" in out


def test_param_get_set_and_refusals(stack, capsys):
    code, out = run_ctl(stack, capsys, "param", "get", "ff_executor", "lead_time")
    assert code == 0 and float(out) == 0.8    # the bring-up's override of config/executor.yaml
    code, out = run_ctl(stack, capsys, "param", "set", "ff_executor", "feedback_rate", "25")
    assert code == 0, out
    code, out = run_ctl(stack, capsys, "param", "get", "ff_executor", "feedback_rate")
    assert code == 0 and float(out) == 25.0
    code, out = run_ctl(stack, capsys, "param", "get", "ff_executor", "no_such_parameter")
    assert code == 1 and "no parameter" in out
    code, out = run_ctl(stack, capsys, "param", "set", "ff_executor", "lead_time", "0.2")
    assert code == 1 and "read-only" in out.lower(), out     # it only applies at start
    code, out = run_ctl(stack, capsys, "param", "describe", "ff_executor", "lead_time")
    assert code == 0 and "range: 0 .. 10" in out and "read only: yes" in out, out
    code, out = run_ctl(stack, capsys, "param", "describe", "ff_planner", "default_starts")
    assert code == 0 and "multistart" in out and "read only: yes" in out, out


def test_diag_shows_the_bridge_and_the_planner(stack, capsys):
    code, out = run_ctl(stack, capsys, "diag", "--duration", "3", "--brief")
    assert code == 0, out
    assert "ff_hwbridge" in out and "ff_planner" in out


def test_plan_then_execute_a_motion_file_while_recording(stack, capsys, tmp_path):
    bag = tmp_path / "run_bag"
    rec = subprocess.Popen([sys.executable, "-u", "-m", "ff_executor.ros.record", "-o", str(bag)], env=stack.env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        end = time.monotonic() + 60
        while time.monotonic() < end:
            lines.append(rec.stdout.readline())
            if "recording" in lines[-1] or rec.poll() is not None:
                break
        assert "recording" in lines[-1], "".join(lines)
        motion = tmp_path / "move.json"
        code, out = run_ctl(stack, capsys, "plan", "--qf", "1", "--tf", "1", "--uncertain", "pv", "pc", "pt",
                            "-o", str(motion))
        assert code == 0 and motion.is_file(), out
        code, out = run_ctl(stack, capsys, "execute", str(motion), "--tolerance", "0")
        executed = out
        t_done = time.time_ns()
        assert code == 0, f"{out}\n{stack.log_tails()}"
        assert "execute succeeded" in out and out.count("  t = ") >= 5, out   # live feedback lines
        time.sleep(0.5)
    finally:
        rec.send_signal(signal.SIGTERM)
        tail, _ = rec.communicate(timeout=30)
    assert rec.returncode == 0, tail
    assert (bag / "metadata.yaml").is_file()
    (mcap,) = bag.glob("*.mcap")
    counts: Counter[str] = Counter()
    measured, feedback, js_times = [], [], []
    series: set[str] = set()
    with open(mcap, "rb") as f:
        decoders = {}
        for schema, channel, message in make_reader(f).iter_messages():
            if schema.id not in decoders:
                decoders[schema.id] = decoder(schema.name, schema.data.decode())
            m = decoders[schema.id](message.data)    # every message decodes
            counts[channel.topic] += 1
            series |= plotjuggler_series(channel.topic, m)
            if channel.topic == "/ff_hwbridge/joint_states":
                measured.append(m.position[0])
                js_times.append(message.log_time)
            if channel.topic == "/ff_executor/execute/_action/feedback":
                feedback.append(m.feedback.elapsed)
    bridge = next(p for p in stack.procs if p.name == "ff_hwbridge")
    # stamped on reception (system clock) and drained on stop: the bag reaches past the move's end
    assert max(js_times) >= t_done, ((t_done - max(js_times)) / 1e9, len(js_times))
    # the recorded joint states show the move (the bridge's measured position, rad)
    assert max(abs(q) for q in measured) > 0.2, (f"the arm did not move ({len(measured)} samples); "
                                             f"ff-ctl:\n{executed}\nbridge:\n{bridge.output()[-1500:]}")
    for topic in ("/ff_hwbridge/joint_states", "/ff_hwbridge/setpoints", "/ff_hwbridge/applied",
                  "/ff_sim_driver/ground_truth", "/diagnostics", "/ff_executor/execute/_action/feedback",
                  "/ff_executor/execute/_action/status"):
        assert counts[topic] > 0, (topic, tail)
    assert counts["/ff_hwbridge/setpoints"] >= 6          # 5 steps + the final zero
    assert max(feedback) >= 0.9
    # config/plotjuggler/ff_run.xml plots series that this bag has
    missing = [c for cs in layout_plots().values() for c in cs if c not in series]
    assert not missing, (missing, sorted(s for s in series if not s.startswith("/rosout")))
    assert os.path.getsize(mcap) > 10_000
    # the library that wrote the bag reads every message of every topic back, checking each
    # topic's recorded type hash against the embedded definition
    from rosbags.highlevel import AnyReader

    again: Counter[str] = Counter()
    with AnyReader([bag]) as reader:
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            again[conn.topic] += 1
    assert again == counts, (again, counts)
