"""A node's effective parameters, read from the node itself started in this process, with or
without parameters files — for tests that a node's code defaults agree with its shipped YAML.

    with_yaml = effective_parameters(lambda ctx: ExecutorNode(context=ctx), [config_path("executor")])
    without = effective_parameters(lambda ctx: ExecutorNode(context=ctx))
    assert parameter_differences(without, with_yaml) == {}

Any node class works whose constructor takes ``context=`` (rclpy ``Node`` keyword arguments).
``close`` ends what the node started besides itself (worker processes, threads) before it is
destroyed. rclpy is imported on use: the process's ROS environment (domain, discovery range,
log folder) must be set first (the ``ros_env`` fixture).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Optional, Sequence, Union

#: parameters every rclpy node has, not the node's own
ROS_BUILTIN = frozenset({"use_sim_time", "start_type_description_service"})


def effective_parameters(make_node: Callable[[Any], Any], params_files: Sequence[Union[str, Path]] = (),
                         close: Optional[Callable[[Any], None]] = None,
                         extra_args: Iterable[str] = ()) -> dict[str, Any]:
    """name -> value of every parameter the node declares (ROS built-ins left out) once
    ``make_node(context)`` returns, in a fresh rclpy context whose arguments are
    ``--ros-args --params-file F`` for each of ``params_files`` (none: the code's defaults) and
    ``extra_args`` (more ROS arguments, e.g. ``["-r", "__ns:=/arm_a"]``)."""
    import rclpy

    args = ["--ros-args"]
    for f in params_files:
        args += ["--params-file", str(f)]
    args += list(extra_args)
    ctx = rclpy.Context()
    rclpy.init(args=args, context=ctx)
    node = None
    try:
        node = make_node(ctx)
        names = sorted(n for n in node.list_parameters([], 0).names if n not in ROS_BUILTIN)
        return {n: _plain(p.value) for n, p in zip(names, node.get_parameters(names))}
    finally:
        if node is not None:
            if close is not None:
                close(node)
            node.destroy_node()
        rclpy.shutdown(context=ctx)


def _plain(value: Any) -> Any:
    """A parameter value as plain Python (arrays as lists)."""
    if isinstance(value, (list, tuple)) or type(value).__name__ == "array":
        return [_plain(v) for v in value]
    return value


def same_value(a: Any, b: Any) -> bool:
    """Parameter values equal: numbers as numbers (a bool only equals a bool; NaN equals NaN),
    lists element by element."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b))
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


MISSING = "<not declared>"


def parameter_differences(a: Mapping[str, Any], b: Mapping[str, Any]) -> dict[str, tuple[Any, Any]]:
    """name -> (value in a, value in b) for every name whose values differ, or that only one of
    them has (the other side :data:`MISSING`)."""
    out: dict[str, tuple[Any, Any]] = {}
    for name in sorted(set(a) | set(b)):
        x, y = a.get(name, MISSING), b.get(name, MISSING)
        if name not in a or name not in b or not same_value(x, y):
            out[name] = (x, y)
    return out


def yaml_parameters(path: Union[str, Path], node: str) -> dict[str, Any]:
    """The ``<node>: ros__parameters:`` mapping of a parameters file ({} when it has none)."""
    import yaml

    data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    section = data.get(node) or data.get(f"/{node}") or data.get("/**") or {}
    return dict(section.get("ros__parameters") or {})


def default_disagreements(make_node: Callable[[Any], Any], params_files: Sequence[Union[str, Path]],
                          close: Optional[Callable[[Any], None]] = None) -> dict[str, tuple[Any, Any]]:
    """name -> (value without a file, value with ``params_files``) where the node's code defaults
    and its shipped files disagree ({} = the files only restate the defaults)."""
    without = effective_parameters(make_node, (), close)
    with_files = effective_parameters(make_node, params_files, close)
    return parameter_differences(without, with_files)
