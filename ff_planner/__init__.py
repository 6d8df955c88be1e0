"""ff_planner: robust feedforward current planning (numpy/scipy/numba; no ROS).

The public face, by layer (see docs/architecture.md):

- ``ff_planner.core``: ``ParameterError``, ``PlanningError``, ``WarmStartUnavailable``, ``SimResult``.
- ``ff_planner.model``: parameters (``Arm1DofParams``, ``Scara2Params``, ``preset``, ``load_params``),
  ``CurrentProfile``, ``PlanRequest``, ``PlanResult``, the model registry (``model_spec``) and the
  simulators (``ff_planner.model.simulate.simulate`` / ``rest_position``).
- ``ff_planner.optimize``: the facade ``plan(request)`` and ``check(request)``.
- ``ff_planner.export``: motion files (``write_motion``, ``read_motion``, ``verify_motion``).

``import ff_planner`` stays light (no compiled code is loaded); ``plan``, ``check`` and
``CheckedRequest`` load the facade on first access.
"""
from __future__ import annotations

from typing import Any

from ff_planner.core.errors import ParameterError, PlanningError, WarmStartUnavailable
from ff_planner.core.results import SimResult
from ff_planner.model.params import Arm1DofParams, Scara2Params, default_params, load_params, preset
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult
from ff_planner.model.registry import model_spec

#: Loaded on first access: importing the facade loads the compiled planners (about 2 s).
_FACADE = ("CheckedRequest", "check", "plan")

__all__ = ["Arm1DofParams", "CheckedRequest", "CurrentProfile", "ParameterError", "PlanRequest",
           "PlanResult", "PlanningError", "Scara2Params", "SimResult", "WarmStartUnavailable", "check",
           "default_params", "load_params", "model_spec", "plan", "preset"]


def __getattr__(name: str) -> Any:
    """The facade's names, imported on first access (PEP 562)."""
    if name in _FACADE:
        from ff_planner.optimize import planner

        value = getattr(planner, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'ff_planner' has no attribute {name!r}")
