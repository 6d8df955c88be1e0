"""Blocking work inside rclpy callbacks without tying up an executor thread.

A callback that blocks (a whole motion, a wait for a drive state, a plan) keeps the executor's
thread busy: on the suite's nodes, which spin one SingleThreadedExecutor, nothing else of the node
runs meanwhile; on a MultiThreadedExecutor (measured here) the executor busy-loops at ~95 % CPU
with the GIL held, delaying every other thread of the process (setpoint streaming, CAN
heartbeats) by up to seconds. Declare the callback ``async`` and ``await in_thread(fn, ...,
wake=...)`` instead: the work runs on its own thread and the executor sleeps until it is done.

Waking the executor. rclpy (7.x, Jazzy) resumes a coroutine that awaits a future only when its
executor wakes up for some other reason: completing the future from another thread wakes nothing
(ros2/rclpy#1467), so the callback would sit until the next message or timer of the node, which
is a second or more on a quiet node. ``wake`` is a guard condition of the node
(``node.create_guard_condition(lambda: None)``); the worker triggers it when the work is done. One
trigger is not enough on a MultiThreadedExecutor: when the awaiting task happens to be running at
that moment (resumed by an unrelated wake-up, between its check of the future and its yield), the
executor skips it and goes back to sleep. So the worker triggers the guard condition every
``RETRIGGER_PERIOD`` s until the awaiting coroutine has actually resumed (at most ``RETRIGGER_FOR``
s, in case it was cancelled).
"""
from __future__ import annotations

import threading
import time
from typing import Any, Callable, Optional

from rclpy.task import Future

#: s, the worker re-triggers ``wake`` at this period until the awaiting coroutine has resumed
RETRIGGER_PERIOD = 0.002
#: s, and gives up after this long (the awaiting callback was cancelled or its executor stopped)
RETRIGGER_FOR = 10.0


async def in_thread(fn: Callable[..., Any], *args: Any, wake: Optional[Any] = None,
                    name: str = "ff_blocking") -> Any:
    """Run ``fn(*args)`` on a new daemon thread; await and return its result (or raise its error).

    ``wake``: a guard condition of the node whose executor runs the awaiting callback; without one
    the callback resumes only at the executor's next unrelated wake-up (see the module docstring).
    """

    done = Future()
    resumed = threading.Event()

    def work() -> None:
        try:
            done.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting coroutine
            done.set_exception(exc)
        if wake is None:
            return
        give_up = time.monotonic() + RETRIGGER_FOR
        while not resumed.is_set() and time.monotonic() < give_up:
            try:
                wake.trigger()
            except Exception:  # noqa: BLE001 - the guard condition was destroyed with its node
                return
            resumed.wait(RETRIGGER_PERIOD)

    threading.Thread(target=work, name=name, daemon=True).start()
    try:
        return await done
    finally:
        resumed.set()
