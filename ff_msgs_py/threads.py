"""Blocking work inside rclpy callbacks without tying up an executor thread.

A callback that blocks (a whole motion, a wait for a drive state, a plan) keeps one of rclpy's
MultiThreadedExecutor threads busy; measured here, the executor then busy-loops at ~95 % CPU with
the GIL held, which delays every other thread of the process (setpoint streaming, CAN heartbeats)
by up to seconds. Declare the callback ``async`` and ``await in_thread(fn, ..., wake=...)``
instead: the work runs on its own thread and the executor sleeps until it is done. ``wake`` is a
guard condition of the node (``node.create_guard_condition(lambda: None)``): triggering it when
the work is done makes the executor resume the callback at once, not at its next wake-up.
"""
from __future__ import annotations

import threading
from typing import Any, Callable, Optional

from rclpy.task import Future


async def in_thread(fn: Callable[..., Any], *args: Any, wake: Optional[Any] = None,
                    name: str = "ff_blocking") -> Any:
    """Run ``fn(*args)`` on a new daemon thread; await and return its result (or raise its error)."""

    done = Future()

    def work() -> None:
        try:
            done.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting coroutine
            done.set_exception(exc)
        if wake is not None:
            wake.trigger()

    threading.Thread(target=work, name=name, daemon=True).start()
    return await done
