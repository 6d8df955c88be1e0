"""in_thread: a coroutine awaiting blocking work resumes when the work ends, on an executor that
nothing else wakes (rclpy does not wake it when a future is completed from another thread)."""
from __future__ import annotations

import threading
import time

import pytest
import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future

import ff_msgs_py.threads as threads


class SlowCheckFuture(Future):
    """A future whose awaiting coroutine is held up between its check and its yield, as a thread
    preempted there would be: the work completes (and wakes the executor) in that window."""

    hold = 0.3   # s

    def __await__(self):
        while self._pending():
            time.sleep(self.hold)
            yield
        return self.result()


@pytest.fixture(scope="module")
def idle_executor(ros_env):
    """A node with nothing but a guard condition, spun by a MultiThreadedExecutor on a thread."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("ff_threads_test", context=ctx)
    ex = MultiThreadedExecutor(num_threads=2, context=ctx)
    ex.add_node(node)
    spin = threading.Thread(target=ex.spin, daemon=True)
    spin.start()
    try:
        yield ex, node, node.create_guard_condition(lambda: None)
    finally:
        ex.shutdown(timeout_sec=2.0)
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def _run(ex, coro_fn, timeout: float) -> tuple[bool, float]:
    done = threading.Event()
    took = [float("nan")]

    async def job():
        t0 = time.monotonic()
        await coro_fn()
        took[0] = time.monotonic() - t0
        done.set()

    ex.create_task(job)
    return done.wait(timeout), took[0]


def test_the_awaiting_callback_resumes_when_the_work_is_done(idle_executor):
    ex, _node, wake = idle_executor
    out = []

    async def call():
        out.append(await threads.in_thread(lambda: time.sleep(0.05) or 42, wake=wake))

    ok, took = _run(ex, call, timeout=5.0)
    assert ok and out == [42]
    assert took < 1.0      # 0.05 s of work; nothing else wakes this executor


def test_errors_of_the_work_reach_the_awaiting_callback(idle_executor):
    ex, _node, wake = idle_executor
    caught = []

    def fail():
        raise ValueError("drive did not answer")

    async def call():
        try:
            await threads.in_thread(fail, wake=wake)
        except ValueError as exc:
            caught.append(str(exc))

    ok, _ = _run(ex, call, timeout=5.0)
    assert ok and caught == ["drive did not answer"]


def test_resumes_when_the_wake_up_comes_while_the_awaiting_task_runs(idle_executor, monkeypatch):
    # the work ends (and triggers the guard condition) while the awaiting task is between its
    # check of the future and its yield: the executor skips the running task on that wake-up, so
    # one trigger alone leaves the callback waiting for an unrelated event, here forever
    ex, _node, wake = idle_executor
    monkeypatch.setattr(threads, "Future", SlowCheckFuture)
    out = []

    async def call():
        # the work ends 50 ms into the 300 ms the awaiting task spends between check and yield
        out.append(await threads.in_thread(lambda: time.sleep(0.05) or "done", wake=wake))

    ok, took = _run(ex, call, timeout=3.0)
    assert ok and out == ["done"], "the awaiting callback never resumed"
    assert took < 2.0
