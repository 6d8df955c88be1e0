"""The PlotJuggler layout (config/plotjuggler/ff_run.xml): well-formed, three plots (q, current,
switch error), every curve named as PlotJuggler names the series of the suite's topics. The
integration test in test_toolbox.py checks every curve against the series of a recorded bag."""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Iterator

import yaml

REPO = Path(__file__).resolve().parents[3]
LAYOUT = REPO / "config" / "plotjuggler" / "ff_run.xml"


def layout_plots() -> dict[str, list[str]]:
    """Dock area title -> the curve names of its plot."""
    root = ET.parse(LAYOUT).getroot()
    return {area.get("name", ""): [c.get("name", "") for c in area.iter("curve")] for area in root.iter("DockArea")}


def _leaves(prefix: str, value: Any) -> Iterator[str]:
    """PlotJuggler's generic names: nested fields joined by '/', array items as [i], numbers only."""
    if isinstance(value, bool) or isinstance(value, (int, float)):
        if not isinstance(value, float) or math.isfinite(value):
            yield prefix
    elif isinstance(value, (list, tuple)) or type(value).__name__ == "ndarray":
        for i, item in enumerate(value):
            yield from _leaves(f"{prefix}[{i}]", item)
    elif hasattr(value, "__slots__"):
        for name in value.__slots__:
            yield from _leaves(f"{prefix}/{name.lstrip('_')}", getattr(value, name))


def plotjuggler_series(topic: str, msg: Any) -> set[str]:
    """The series PlotJuggler's ROS 2 parsers make of one decoded message: JointState per joint
    name (``topic/joint/position``), DiagnosticArray per status and numeric key
    (``topic/hardware_id/name/key``), anything else field by field."""
    names = set()
    if hasattr(msg, "name") and hasattr(msg, "position") and hasattr(msg, "effort"):
        for field in ("position", "velocity", "effort"):
            for joint, _v in zip(msg.name, getattr(msg, field)):
                names.add(f"{topic}/{joint}/{field}")
        return names
    if hasattr(msg, "status") and all(hasattr(s, "values") for s in msg.status):
        for s in msg.status:
            for kv in s.values:
                try:
                    float(kv.value)
                except ValueError:
                    continue
                head = f"{topic}/{s.hardware_id}/{s.name}" if s.hardware_id else f"{topic}/{s.name}"
                names.add(f"{head}/{kv.key}")
        return names
    return set(_leaves(topic, msg))


def _method(text: str, name: str) -> str:
    """The source of every method ``name`` in a module's text (up to the next def at its indent)."""
    return "".join(m.group(0) for m in re.finditer(rf"(?ms)^( +)def {name}\(.*?(?=^\1def |\Z)", text))


def test_layout_has_the_three_plots_with_curves():
    plots = layout_plots()
    assert len(plots) == 3, plots
    q, current, switch = plots.values()
    assert "/ff_hwbridge/joint_states/joint1/position" in q
    assert {"/ff_hwbridge/applied/currents[0]", "/ff_hwbridge/motor_currents/joint1/effort",
            "/ff_executor/execute/_action/feedback/feedback/commanded_currents[0]"} <= set(current)
    assert any(c.endswith("/switch_p99_us") for c in switch) and any(c.endswith("/switch_max_us") for c in switch)


def test_layout_names_match_the_suites_joints_bridge_status_and_diagnostic_keys():
    # the modules' text, not the modules: importing the nodes (rclpy, the models) is slow
    bridge, sim, player, player_process = (
        (REPO / "ff_hwbridge" / f).read_text() for f in ("ros/bridge_node.py", "ros/sim_driver_node.py",
                                                         "drive/player.py", "drive/player_process.py"))
    joints = yaml.safe_load((REPO / "config" / "executor.yaml").read_text())["ff_executor"]["ros__parameters"][
        "joint_names"]
    curves = [c for cs in layout_plots().values() for c in cs]
    for c in curves:
        if c.startswith(("/ff_hwbridge/joint_states/", "/ff_hwbridge/motor_currents/", "/ff_sim_driver/ground_truth/")):
            assert c.split("/")[-2] in joints, c
    # the drive group's status is named after the node's full name: "ff_hwbridge: drive group"
    # without a namespace
    assert 'NODE_NAME = "ff_hwbridge"' in bridge and 'super().__init__(NODE_NAME' in bridge
    assert "return f\"{self.get_fully_qualified_name().lstrip('/')}: drive group\"" in bridge
    keys = "".join(_method(text, name) for text in (player, player_process)
                   for name in ("diagnostics", "_switch_diagnostics"))
    sim = _method(sim, "_publish_diagnostics")
    assert 'f"ff_sim_driver: drive {d.node_id}"' in sim and 'f"{d.family} node {d.node_id} (simulated)"' in sim
    for c in curves:
        if c.startswith("/diagnostics/"):
            _, _, hw, status, key = c.split("/")
            if hw.endswith("(simulated)"):
                assert (hw, status) == ("epos4 node 1 (simulated)", "ff_sim_driver: drive 1"), c
                assert f'"{key}"' in sim, c
            else:
                assert hw == "node1" and status == "ff_hwbridge: drive group", c
                assert f'"{key}"' in keys, c


def test_series_naming_follows_plotjuggler():
    class Kv:
        __slots__ = ("key", "value")

        def __init__(self, k, v):
            self.key, self.value = k, v

    class Status:
        __slots__ = ("name", "hardware_id", "values")

        def __init__(self):
            self.name, self.hardware_id, self.values = "b: g", "node1", [Kv("a_us", "12.5"), Kv("s", "text")]

    class Diag:
        __slots__ = ("status",)

        def __init__(self):
            self.status = [Status()]

    class Setpoint:
        __slots__ = ("currents", "seq")

        def __init__(self):
            self.currents, self.seq = [1.0, 2.0], 3

    assert plotjuggler_series("/diagnostics", Diag()) == {"/diagnostics/node1/b: g/a_us"}
    assert plotjuggler_series("/t", Setpoint()) == {"/t/currents[0]", "/t/currents[1]", "/t/seq"}
