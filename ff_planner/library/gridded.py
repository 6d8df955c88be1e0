"""Plans whose switch times lie on a time grid (the drives' SYNC period, e.g. 1 ms).

``GridPlanRequest`` (``ff_planner.model.profile``) is a PlanRequest with ``grid`` (s): the robust 1-DOF planners
(``ff_planner.optimize.robust1d``, ``box_robust``) read ``request.grid`` and round the switch
times to it, so a drive that applies setpoints at its SYNC applies the plan exactly.
``GRID_OBJECTIVES`` are the objectives whose planner does that; ``on_grid`` checks a profile.
No ROS here.
"""
from __future__ import annotations

import numpy as np

from ff_planner.model.profile import CurrentProfile, GridPlanRequest

GRID_OBJECTIVES = ("robust-derivative", "robust-sampled", "robust-box")   # arm1dof planners that grid switches
GRID_MODELS = ("arm1dof",)
GRID_TOL = 1e-9           # s: a switch time this close to a grid point is on the grid

__all__ = ["GRID_MODELS", "GRID_OBJECTIVES", "GRID_TOL", "GridPlanRequest", "applies", "on_grid"]


def applies(model: str, objective: str) -> bool:
    """Does the planner of (model, objective) put switch times on a grid?"""
    return model in GRID_MODELS and objective in GRID_OBJECTIVES


def on_grid(profile: CurrentProfile, grid: float) -> bool:
    """Are all switch times of ``profile`` (s) multiples of ``grid`` (s), within GRID_TOL?"""
    k = np.asarray(profile.step_times, dtype=float) / float(grid)
    return bool(np.all(np.abs(k - np.round(k)) * float(grid) <= GRID_TOL))
