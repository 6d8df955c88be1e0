"""The executor's ROS side: the action server node and a client of the running stack.

- :mod:`.executor_node` — node ``ff_executor`` serving ``~/execute`` (ff_msgs/action/ExecuteProfile);
  a program (``ff-executor`` / ``python -m ff_executor.ros.executor_node``), so this package does
  not import it (``python -m`` would otherwise run it twice).
- :mod:`.client` — :class:`StackClient` (plan, reset the simulated arm, execute and record) and
  :class:`SafeActionClient`; re-exported here.
"""
from ff_executor.ros.client import MoveOutcome, Recording, SafeActionClient, StackCallError, StackClient

__all__ = ["MoveOutcome", "Recording", "SafeActionClient", "StackCallError", "StackClient"]
