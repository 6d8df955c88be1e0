"""The planner node started with no parameters file declares exactly the keys of the shipped
config/planner.yaml, with its values, and runs the same configuration as with that file."""
from __future__ import annotations

import pytest

from ff_msgs_py.configs import config_path, node_parameters

pytestmark = pytest.mark.integration

ROS_BUILTIN = {"use_sim_time", "start_type_description_service"}


def _node(monkeypatch, tmp_path):
    """A PlannerNode in this process, its worker pool not started; HOME in tmp_path (the
    shipped library_path is under ~)."""
    from ff_planner.ros import planner_node
    from ff_planner.service.planner_service import PlannerService

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setattr(PlannerService, "start", lambda self, wait=0.0: None)
    return planner_node


def _declared(args, monkeypatch, tmp_path):
    import rclpy

    mod = _node(monkeypatch, tmp_path)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=args)
    try:
        node = mod.PlannerNode(context=ctx)
        try:
            values = {n: p.value for n, p in node._parameters.items() if n not in ROS_BUILTIN}
            return values, node.service.config
        finally:
            node.service.close()
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_no_file_is_the_shipped_yaml(monkeypatch, tmp_path, ros_env):
    from ff_planner.ros.planner_node import NODE_DEFAULTS

    shipped = {**node_parameters("planner.yaml", "ff_planner"), **NODE_DEFAULTS}
    bare, bare_cfg = _declared(None, monkeypatch, tmp_path)
    assert set(bare) == set(shipped), (sorted(set(bare) ^ set(shipped)))
    assert bare == shipped
    path = str(config_path("planner.yaml"))
    with_file, file_cfg = _declared(["--ros-args", "--params-file", path], monkeypatch, tmp_path)
    assert with_file == bare
    assert file_cfg == bare_cfg
    # the library lands in the user's home, made at start
    assert (tmp_path / ".ff" / "motions.sqlite").exists()
    assert bare_cfg.drive_config == shipped["drive_config"] and bare_cfg.drive_config


def test_descriptors_cover_every_shipped_key():
    from ff_planner.ros.planner_node import NODE_ONLY, PARAMETERS

    from ff_planner.ros.planner_node import NODE_DEFAULTS

    shipped = {**node_parameters("planner.yaml", "ff_planner"), **NODE_DEFAULTS}
    per_model = {k for k in shipped if k.endswith(".preset")}
    assert set(shipped) - per_model == set(PARAMETERS), sorted((set(shipped) - per_model) ^ set(PARAMETERS))
    assert set(NODE_ONLY) <= set(shipped)


def test_docs_table_is_the_shipped_yaml():
    from pathlib import Path

    from ff_planner.ros.planner_node import parameters_markdown

    page = (Path(__file__).resolve().parents[3] / "docs" / "parameters.md").read_text(encoding="utf-8")
    begin, end = "<!-- BEGIN ff_planner parameters -->\n", "<!-- END ff_planner parameters -->"
    assert page[page.index(begin) + len(begin):page.index(end)] == parameters_markdown()
