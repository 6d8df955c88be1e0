"""The simulated stack as processes, the demo, and the timing wrapper.

- :mod:`.stack` — ``Stack`` / ``StackOptions``: CAN hub (SYNC producer), sim driver, bridge, planner
  and executor started and stopped by PID; program ``ff-bringup`` / ``python -m ff_executor.bringup.stack``.
- :mod:`.demo`  — ``run_motions``: robust vs baseline motion on the simulated arm; program ``ff-demo``.
- :mod:`.timed` — ``python -m ff_executor.bringup.timed [--switch-interval S] MODULE [ARGS...]``.

Each module is a program, so this package imports none of them (``python -m`` would otherwise
run a module twice); import the names from the modules.
"""

__all__: list[str] = []
