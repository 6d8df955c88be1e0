"""Warm starts: re-optimise a request from known currents (a stored neighbour's), no multistart.

The planner is a plain callable ``plan_fn(request, progress, initial_currents=...)`` (the facade
``ff_planner.optimize.planner.plan`` or a stand-in) taking a PlanRequest or a CheckedRequest; it
raises WarmStartUnavailable when the request's model cannot start from given currents.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Optional

import numpy as np

from ff_planner.core.errors import WarmStartUnavailable
from ff_planner.model.profile import PlanRequest, PlanResult

if TYPE_CHECKING:   # the facade loads the compiled planners: not needed to hand currents over
    from ff_planner.optimize.planner import CheckedRequest

#: A plan function: ``plan_fn(request, progress=None, initial_currents=None) -> PlanResult``.
PlanFn = Callable[..., PlanResult]


def warm_plan(request: PlanRequest | CheckedRequest, initial_currents: Optional[np.ndarray], plan_fn: PlanFn,
              progress: Optional[Callable[[dict], None]] = None,
              warm_from: Optional[str] = None) -> PlanResult:
    """Plan ``request`` from ``initial_currents`` (A, shape (N, n_joints)) as its single start.

    Raises WarmStartUnavailable when there are no currents, when they do not fit the request
    (other step or joint count), or when the planner cannot take them. The result is marked
    ``warm_start``; ``warm_from`` (a library task key) is noted in ``extra``.
    """
    if initial_currents is None:
        raise WarmStartUnavailable(f"no currents to start from{f' in {warm_from}' if warm_from else ''}")
    init = np.asarray(initial_currents, dtype=float)
    req = request if isinstance(request, PlanRequest) else request.request
    need = (req.n_steps(), len(req.q0))
    if init.shape != need:
        raise WarmStartUnavailable(f"{'library entry ' + warm_from if warm_from else 'the start'} has "
                                   f"{init.shape} currents, the request needs {need}")
    result = plan_fn(request, progress, initial_currents=init)
    result.warm_start = True
    if warm_from is not None:
        result.extra = dict(result.extra or {}, warm_from=warm_from)
    return result
