"""ff_executor: timed setpoint streaming of current profiles, and its action-server node.

Subpackages, layered ``bringup > ros > engine``:

- :mod:`ff_executor.engine`  — the streaming engine, no ROS (imported here).
- :mod:`ff_executor.ros`     — the action server node ``ff_executor`` (program
  ``ff-executor`` / ``python -m ff_executor.ros.executor_node``) and a client of the stack.
- :mod:`ff_executor.bringup` — the simulated stack as processes (``ff-bringup``), the demo
  (``ff-demo``) and the timing wrapper (``python -m ff_executor.bringup.timed``).

Importing this package does not import rclpy.
"""
from ff_executor import engine

__all__ = ["engine"]
