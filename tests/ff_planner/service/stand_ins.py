"""A plan function for the progress and cancel tests: module-level, so it pickles by reference to
the service's worker processes.

    python -m tests.ff_planner.service.stand_ins --ros-args --params-file planner.yaml

runs the ``ff_planner`` node (``ff_planner.ros.planner_node.main``) with :func:`progress_plan`.
"""
from __future__ import annotations

import sys
import time
from typing import Callable, Optional

import numpy as np

from ff_planner.model.profile import PlanResult
from ff_planner.optimize.planner import plan
from tests.support.stand_in_planners import Request, _plain, stub_plan

STEP_S = 0.01    # s between the progress reports of the stand-in


def progress_plan(checked: Request, progress: Optional[Callable[[dict], None]] = None,
                  initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """seed 0: the real planner facade. seed 1: ``starts`` progress reports STEP_S apart, then the
    instant stub plan. Any other seed: reports until the time budget is spent, then the stub."""
    request = _plain(checked)
    if request.seed == 0:
        return plan(checked, progress, initial_currents=initial_currents)
    end = time.monotonic() + (request.starts * STEP_S if request.seed == 1 else request.time_budget)
    i = 0
    while time.monotonic() < end:
        i += 1
        if progress is not None:
            progress({"stage": "stand-in", "starts_done": i, "best": 1.0 / i})
        time.sleep(STEP_S)
    return stub_plan(checked, progress, initial_currents)


if __name__ == "__main__":
    from ff_planner.ros.planner_node import main

    sys.exit(main(plan_fn=progress_plan))
