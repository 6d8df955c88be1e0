"""rclpy inside a test: a context of its own, and nodes spun by a multi-threaded executor in a
daemon thread, both ended however the test ends. rclpy is imported on use (the tests that need
it are marked ``integration``)."""
from __future__ import annotations

import contextlib
import threading
from typing import Any, Iterator


@contextlib.contextmanager
def ros_context() -> Iterator[Any]:
    """A fresh initialised ``rclpy.Context``; shut down when the block ends."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        rclpy.shutdown(context=ctx)


@contextlib.contextmanager
def spinning(ctx: Any, *nodes: Any, threads: int = 3, destroy: bool = True) -> Iterator[Any]:
    """``nodes`` spun by a ``MultiThreadedExecutor`` of ``threads`` threads on ``ctx``, from a
    daemon thread. At the end the executor shuts down, then (``destroy``) the nodes are
    destroyed. Yields the executor."""
    from rclpy.executors import MultiThreadedExecutor

    ex = MultiThreadedExecutor(num_threads=threads, context=ctx)
    for node in nodes:
        ex.add_node(node)
    threading.Thread(target=ex.spin, daemon=True).start()
    try:
        yield ex
    finally:
        ex.shutdown()
        if destroy:
            for node in nodes:
                node.destroy_node()
