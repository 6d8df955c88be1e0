"""The way out of a node's console script: a last best-effort action, the node destroyed, rclpy
shut down (the ``finally`` every ``main()`` of the suite's nodes ends with)."""
from __future__ import annotations

from typing import Callable, Optional, TypeVar

import rclpy
from rclpy.node import Node

N = TypeVar("N", bound=Node)


def shut_down(node: Optional[N], last: Optional[Callable[[N], object]] = None) -> None:
    """``last(node)`` (e.g. zero current; an exception from it is ignored: the process ends
    anyway), then ``node.destroy_node()``, then ``rclpy.shutdown()`` of the default context
    unless it is down already. ``node`` None (its constructor failed): only the shutdown."""
    if node is not None:
        if last is not None:
            try:
                last(node)
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
        node.destroy_node()
    if rclpy.ok():
        rclpy.shutdown()
