"""rclpy inside a test: a context of its own, and nodes spun by a multi-threaded executor in a
daemon thread, both ended however the test ends. rclpy is imported on use (the tests that need
it are marked ``integration``)."""
from __future__ import annotations

import contextlib
import sys
import threading
import traceback
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
    daemon thread (through ``ff_msgs_py.spin.spin``, as the suite's nodes are). At the end the
    executor shuts down, then (``destroy``) the nodes are destroyed. Yields the executor.

    An exception that ended the spinning thread fails the block with it: the nodes stopped being
    served at that point, and whatever the test saw afterwards (a service that never answered)
    follows from it."""
    from rclpy.executors import MultiThreadedExecutor

    from ff_msgs_py.spin import spin

    ex = MultiThreadedExecutor(num_threads=threads, context=ctx)
    for node in nodes:
        ex.add_node(node)
    died: list[BaseException] = []

    def run() -> None:
        try:
            spin(ex)
        except BaseException as exc:  # noqa: BLE001 - handed to the test below
            if ctx.ok() and not getattr(ex, "_is_shutdown", False):
                died.append(exc)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        yield ex
    finally:
        ex.shutdown()
        th.join(5.0)
        if died:        # shown with the test's own failure, if it has one
            traceback.print_exception(died[0], file=sys.stderr)
        if destroy:
            for node in nodes:
                node.destroy_node()
    if died:
        raise RuntimeError(f"the executor's thread died while the test ran: {died[0]!r}") from died[0]
