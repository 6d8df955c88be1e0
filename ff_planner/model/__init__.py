"""The arm models of the planner: parameters, current profiles and requests, the model registry.

Exported here (cheap to import: no compiled code): the parameter classes and presets
(``params``), the current profile, plan request and result (``profile``), and the registry of
models (``registry``: ``MODELS``, ``ModelSpec``, ``model_spec``). Imported on their own:
``simulate`` (``simulate``, ``rest_position`` for any model) and ``sensitivity``
(``sensitivities``), which load the compiled models on first use, and the numba-compiled modules
``friction`` (the friction law, Eq. 9), ``arm1dof`` (with ``arm1dof_derivatives``, ``series1d``,
``taylor``) and ``scara2``. Units: rad, rad/s, A, Nm, s.
"""
from ff_planner.model.params import (DEFAULT_PRESET, PRESETS, Arm1DofParams, Params, Scara2Params,
                                     check_model, default_params, friction_scaled, load_params, n_joints,
                                     preset)
from ff_planner.model.profile import (DEFAULT_COAST, OBJECTIVES, CurrentProfile, PlanRequest, PlanResult)
from ff_planner.model.registry import MODELS, ModelSpec, model_spec

__all__ = [
    "DEFAULT_COAST", "DEFAULT_PRESET", "MODELS", "OBJECTIVES", "PRESETS", "Arm1DofParams",
    "CurrentProfile", "ModelSpec", "Params", "PlanRequest", "PlanResult", "Scara2Params",
    "check_model", "default_params", "friction_scaled", "load_params", "model_spec", "n_joints",
    "preset",
]
