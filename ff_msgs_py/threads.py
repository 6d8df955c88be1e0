"""Blocking work inside rclpy callbacks without tying up an executor thread.

A callback that blocks (a whole motion, a wait for a drive state) keeps one of rclpy's
MultiThreadedExecutor threads busy; measured here, the executor then busy-loops at ~95 % CPU with
the GIL held, which delays every other thread of the process (setpoint streaming, CAN heartbeats)
by up to seconds. Declare the callback ``async`` and ``await in_thread(fn, ...)`` instead: the
work runs on its own thread and the executor sleeps until it is done.
"""
from __future__ import annotations

import threading
from typing import Any, Callable


async def in_thread(fn: Callable[..., Any], *args: Any, name: str = "ff_blocking") -> Any:
    """Run ``fn(*args)`` on a new daemon thread; await and return its result (or raise its error)."""
    from rclpy.task import Future

    done = Future()

    def work() -> None:
        try:
            done.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting coroutine
            done.set_exception(exc)

    threading.Thread(target=work, name=name, daemon=True).start()
    return await done
