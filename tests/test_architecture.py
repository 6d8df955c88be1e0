"""The layering rules that the import contracts in pyproject.toml cannot state by themselves.

``lint-imports`` (run by ``./run test``) checks the contracts; these tests make sure the contracts
cover every folder a new module may land in, and that no module sidesteps them.
"""
from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import grimp
import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("ff_planner", "ff_executor", "ff_hwbridge", "ff_msgs_py")
#: where rclpy and the generated ROS interfaces may be imported
ROS_ALLOWED = ("ff_planner.ros", "ff_hwbridge.ros", "ff_executor.ros", "ff_executor.bringup", "ff_msgs_py")
ROS_MODULES = ("rclpy", "ff_msgs", "launch", "rosidl_runtime_py")


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph(*PACKAGES, include_external_packages=True, cache_dir=None)


@pytest.fixture(scope="module")
def contracts() -> list[dict]:
    with open(REPO / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["tool"]["importlinter"]["contracts"]


def _within(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def test_only_ros_folders_import_rclpy_or_the_interfaces(graph):
    assert "ff_hwbridge.ros.bridge_node" in graph.find_modules_that_directly_import("rclpy")  # graph sees ROS
    offenders = sorted(
        (importer, imported)
        for imported in ROS_MODULES if imported in graph.modules
        for importer in graph.find_modules_that_directly_import(imported)
        if _within(importer, PACKAGES) and not _within(importer, ROS_ALLOWED))
    assert not offenders, f"imports of ROS outside ros/, bring-up and ff_msgs_py: {offenders}"


def test_every_subpackage_is_placed_in_a_layers_contract(graph, contracts):
    """A new folder must be given its place in the layering (else no contract looks at it)."""
    layered: set[str] = set()
    for c in contracts:
        if c["type"] == "layers":
            for layer in c["layers"]:
                layered.update(m.strip() for m in layer.replace(":", "|").split("|"))
    for pkg in ("ff_planner", "ff_executor", "ff_hwbridge"):
        children = {m for m in graph.find_children(pkg) if (REPO / m.replace(".", "/")).is_dir()}
        assert children and children <= layered, f"{pkg}: not in any layer: {sorted(children - layered)}"


def test_the_ros_contract_names_every_library_layer(contracts, graph):
    """Every layer outside the ROS-facing ones is a source of the 'no rclpy' contract."""
    (ros,) = [c for c in contracts if set(c.get("forbidden_modules", ())) >= {"rclpy", "ff_msgs"}]
    for pkg in ("ff_planner", "ff_executor", "ff_hwbridge"):
        for child in graph.find_children(pkg):
            if (REPO / child.replace(".", "/")).is_dir() and not _within(child, ROS_ALLOWED):
                assert child in ros["source_modules"], f"{child} is not checked for rclpy imports"


def test_no_module_is_imported_by_name_at_run_time():
    """importlib/__import__ by name would hide a dependency from the import contracts."""
    found = []
    for pkg in PACKAGES:
        for path in (REPO / pkg).rglob("*.py"):
            text = path.read_text()
            if "import_module" not in text and "__import__" not in text:
                continue        # no call can unparse to either name: nothing to parse
            for node in ast.walk(ast.parse(text, str(path))):
                if isinstance(node, ast.Call):
                    name = ast.unparse(node.func)
                    if name.endswith("import_module") or name == "__import__":
                        found.append(f"{path.relative_to(REPO)}:{node.lineno} {name}")
    assert not found, found


#: what only the simulation does: the CAN hub's transmit schedule (frames handed over ahead and
#: put on the bus at their instant) and its modules; an import contract cannot see a method
#: patched onto a bus object, so the real driver's text is searched for them
SIMULATION_MARKS = ("send_at", "time_keeper", "TimedVirtualBus", "ff_hub", "keeper_stats", "ff_hwbridge.sim",
                    "can_hub", "send_scheduled", "transmit schedule")


def test_the_real_driver_has_no_simulation_behaviour():
    found = []
    for path in sorted((REPO / "ff_hwbridge" / "drive").rglob("*.py")):
        for lineno, line in enumerate(path.read_text().splitlines(), start=1):
            found += [f"{path.relative_to(REPO)}:{lineno}: {mark}" for mark in SIMULATION_MARKS if mark in line]
    assert not found, found
