"""Plan functions standing in for the planner facade, and the planner node run with one of them.

Each is a module-level function ``fn(request, progress=None, initial_currents=None) -> PlanResult``
taking a PlanRequest or a CheckedRequest (as the facade does), so it pickles by reference to pebble
and Dask worker processes (which import this module).

    python -m tests.support.stand_in_planners --ros-args --params-file planner.yaml

runs the ``ff_planner`` node (``ff_planner.ros.planner_node.main``) with :func:`slow_plan`.
"""
from __future__ import annotations

import os
import sys
import time
from typing import Callable, Optional, Union

import numpy as np

from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult
from ff_planner.optimize.planner import CheckedRequest, plan

SLOW_S = 2.0     # s, how long the stand-in 2-DOF planner of slow_plan works
DELAY_S = 0.25   # s, how much delayed_plan slows the real planner down

Progress = Optional[Callable[[dict], None]]
Request = Union[PlanRequest, CheckedRequest]


def _plain(request: Request) -> PlanRequest:
    return request.request if isinstance(request, CheckedRequest) else request


def _result(request: PlanRequest, currents: np.ndarray, message: str, **kw) -> PlanResult:
    prof = CurrentProfile.uniform(currents, request.tf, request.coast)
    return PlanResult(success=True, message=message, profile=prof, model=request.model,
                      params=request.resolved_params(), q0=np.asarray(request.q0, float),
                      qf=np.asarray(request.qf, float), uncertain=list(request.uncertain),
                      objective=request.objective, **kw)


def slow_plan(checked: Request, progress: Progress = None,
              initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """The real planner (with warm starts) for arm1dof; for scara2 a stand-in that works SLOW_S s.

    scara2 with seed 666 ignores its time budget (sleeps 60 s), to test that the node enforces it;
    with seed 777 it works until the file $FF_TEST_RELEASE exists (or its budget is spent).
    """
    request = _plain(checked)
    if request.model != "scara2":
        return plan(checked, progress, initial_currents=initial_currents)
    if request.seed == 777:
        end = time.monotonic() + request.time_budget
        while not os.path.exists(os.environ["FF_TEST_RELEASE"]) and time.monotonic() < end:
            time.sleep(0.01)
    else:
        time.sleep(60.0 if request.seed == 666 else min(SLOW_S, request.time_budget))
    return _result(request, np.zeros((request.n_steps(), 2)), "stand-in 2-DOF plan",
                   q_final=np.asarray(request.q0, float), qd_final=np.zeros(2), robust=False, starts_tried=1)


def stub_plan(checked: Request, progress: Progress = None,
              initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """Instant robust 'plan' that echoes the warm-start currents it was given (else 0.5 A everywhere)."""
    request = _plain(checked)
    cur = (np.asarray(initial_currents, float) if initial_currents is not None
           else np.full((request.n_steps(), len(request.q0)), 0.5))
    return _result(request, cur, "stub", q_final=np.asarray(request.qf, float),
                   qd_final=np.zeros(len(request.q0)), sensitivities={u: 0.0 for u in request.uncertain},
                   robust=True, starts_tried=0 if initial_currents is not None else request.starts,
                   extra={"got_initial": initial_currents is not None})


def delayed_plan(request: Request, progress: Progress = None,
                 initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """The real planner, DELAY_S s late (so that a worker can be killed while it plans)."""
    time.sleep(DELAY_S)
    return plan(request, progress, initial_currents=initial_currents)


def broken_plan(request: Request, progress: Progress = None,
                initial_currents: Optional[np.ndarray] = None) -> PlanResult:
    """A planner with a bug: always raises RuntimeError("planner exploded")."""
    raise RuntimeError("planner exploded")


if __name__ == "__main__":
    from ff_planner.ros.planner_node import main
    from tests.support.stand_in_planners import slow_plan as importable_slow_plan  # not __main__.slow_plan

    sys.exit(main(plan_fn=importable_slow_plan))
