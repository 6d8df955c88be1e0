"""The planner's models by name: each model's parameter class and its simulator functions.

``model_spec(name)`` returns the ``ModelSpec`` of a model id (``MODELS``: "arm1dof", "scara2").
Its functions share one calling convention, per-joint values of shape (n_joints,) in rad, rad/s,
A and s (a 1-DOF model also takes plain numbers):

    simulate(params, profile, q0, qd0=None, *, trajectory=False, **options) -> SimResult
    rest_position(params, profile, q0, qd0=None) -> (n_joints,) rad (nan: never stops)
    sensitivities(params, profile, q0, names, method="exact", rel_step=None, *, rest=False)
        -> {"q1/pc2": ∂q1(tf)/∂pc2, ...} (the model's keys, see ``ff_planner.model.sensitivity``)
    advance(params, q, qd, currents, dt) -> (q, qd) after dt s of constant currents
        (``advance_exact``: exact for any dt, e.g. the 1-DOF arm's event-exact Eq. 9 motion;
        otherwise to be called with steps of at most the parameters' ``plant_step``)

``simulate`` takes the model's own options (``dt``, ``t_end``; scara2 also ``h``, ``settle``).
``ff_planner.model.simulate`` and ``ff_planner.model.sensitivity`` validate inputs and call these.

Model names, joint counts and parameter classes come from ``ff_planner.model.params``; the
simulator modules (numba kernels) are imported on the first ``model_spec`` call, so that code
that only reads names and parameters does not load them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ff_planner.core.errors import ParameterError
from ff_planner.core.results import SimResult
from ff_planner.model.params import MODELS as _PARAMS_CLASSES
from ff_planner.model.params import Arm1DofParams, Params, Scara2Params

#: the model ids
MODELS: tuple[str, ...] = tuple(_PARAMS_CLASSES)


@dataclass(frozen=True)
class ModelSpec:
    """One model: its id, joint count, parameter class and simulator functions (see module)."""

    name: str
    n_joints: int
    params_class: type[Params]
    simulate: Callable[..., SimResult]
    rest_position: Callable[..., np.ndarray]
    sensitivities: Callable[..., dict[str, float]]
    advance: Callable[..., tuple[np.ndarray, np.ndarray]]
    advance_exact: bool = False


_SPECS: dict[str, ModelSpec] = {}


def _load_specs() -> dict[str, ModelSpec]:
    # imported here, not at module level: the simulators load their compiled numba kernels
    # (about 0.5 s), which model names and parameters do not need
    from ff_planner.model import arm1dof, scara2

    specs = (
        ModelSpec(name=Arm1DofParams.model, n_joints=Arm1DofParams.n_joints,
                  params_class=Arm1DofParams, simulate=arm1dof.simulate_arm1dof,
                  rest_position=arm1dof.rest_position_arm1dof,
                  sensitivities=arm1dof.sensitivities_arm1dof, advance=arm1dof.advance_joints,
                  advance_exact=True),
        ModelSpec(name=Scara2Params.model, n_joints=Scara2Params.n_joints,
                  params_class=Scara2Params, simulate=scara2.simulate_scara2,
                  rest_position=scara2.rest_position_scara2,
                  sensitivities=scara2.sensitivities_scara2, advance=scara2.advance),
    )
    return {s.name: s for s in specs}


def model_spec(name: str) -> ModelSpec:
    """The ModelSpec of model id ``name``; ParameterError (UNKNOWN_MODEL) naming the known ones."""
    if name not in MODELS:
        raise ParameterError(f"unknown model {name!r}; known models: {', '.join(MODELS)}",
                             code="UNKNOWN_MODEL")
    if not _SPECS:
        _SPECS.update(_load_specs())
    return _SPECS[name]
