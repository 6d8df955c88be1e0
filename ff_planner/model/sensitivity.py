"""Sensitivities of the final state to the friction parameters, for any model.

``sensitivities(params, profile, q0, names, method)`` returns ∂q(tf)/∂p (rad per unit of p) and
∂q̇(tf)/∂p (rad/s per unit), computed by the model's function from ``ff_planner.model.registry``:
- method "exact": 1-DOF forward mode through the event times (``arm1dof.derivatives``); 2-DOF
  complex step through the event-aware integrator (``scara2.sensitivities_scara2``).
- "central": central differences (relative step, default 1e-6).
- "forward": the paper's forward quotient (relative step, default 1e-3 = 0.1 %). Beware: near a
  non-smooth point (breakaway, a stop at a switch time) it can read ~0 while the true one-sided
  derivatives are not; judge plans with "exact" and "central".

Keys, 1-DOF: "pc" = ∂q_f/∂pc, "qd/pc" = ∂q̇_f/∂pc (and with ``rest=True`` "qrest/pc", the
derivative of the rest position after tf). 2-DOF: "q1/pc2", "qd1/pc2", ... (see
ff_planner.model.scara2).
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ff_planner.model.params import ParameterError, Params
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.registry import model_spec

METHODS = ("exact", "central", "forward")


def sensitivities(params: Params, profile: CurrentProfile, q0: Sequence[float] | float,
                  names: Optional[Sequence[str]] = None, method: str = "exact",
                  rel_step: Optional[float] = None, *, rest: bool = False) -> dict[str, float]:
    """∂(final state)/∂p for friction parameters ``names`` (default: all of the model's)."""
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    chosen = list(params.friction_keys if names is None else names)
    bad = [n for n in chosen if n not in params.friction_keys]
    if bad:
        raise ParameterError(f"unknown friction parameter(s) {bad} for model '{params.model}'; "
                             f"choose from {', '.join(params.friction_keys)}")
    spec = model_spec(params.model)
    return spec.sensitivities(params, profile, np.atleast_1d(np.asarray(q0, dtype=float)),
                              chosen, method, rel_step, rest=rest)
