"""Spin an rclpy executor until it or its context shuts down, outliving a race in rclpy 7.x.

A publisher or subscription destroyed from another thread (with it the QoS event handlers rclpy
gives it by default) while the executor builds its wait set makes ``spin_once`` raise
``InvalidHandle`` (from ``EventHandler.add_to_wait_set``, after the entity was taken into the
wait set but before it was added). ``Executor.spin`` then ends, and every node of the executor
stops being served without an error anywhere but that thread's traceback: its services go
silent, its timers stop. The entity is gone from its node by then, so the next pass builds the
wait set without it: :func:`spin` carries on. Every node of the suite spins through it.
"""
from __future__ import annotations

import time
from typing import Any, Optional

from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException

def spin(executor: Any, logger: Optional[Any] = None) -> int:
    """``executor.spin()`` until the executor is shut down or its context is; an
    ``InvalidHandle`` from an entity destroyed meanwhile is logged (``logger``: an rclpy logger,
    at debug level) and spinning goes on. Returns how many times that happened."""
    races = 0
    while True:
        try:
            executor.spin()
            return races
        except ExternalShutdownException:
            return races
        except InvalidHandle as exc:
            races += 1
            if logger is not None:
                logger.debug(f"an entity was destroyed while the wait set was built ({exc}); "
                             "spinning on")
            time.sleep(0.001)    # a pass that kept failing must not spin hot
