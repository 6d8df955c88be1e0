"""One entry point to simulate any model: ``simulate``/``rest_position`` check their inputs and call
the model's functions from ``ff_planner.model.registry``.

arm1dof → ``ff_planner.model.arm1dof`` (exact, event-based, compiled); scara2 →
``ff_planner.model.scara2`` (event-aware RK4, compiled), both returning a SimResult.
Units: rad, rad/s, A, s.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ff_planner.core.results import SimResult
from ff_planner.model.params import ParameterError, Params
from ff_planner.model.profile import CurrentProfile, PlanningError
from ff_planner.model.registry import ModelSpec, model_spec


def _check(params: Params, profile: CurrentProfile,
           q0: ArrayLike) -> tuple[ModelSpec, np.ndarray]:
    spec = model_spec(params.model)
    nj = spec.n_joints
    q = np.atleast_1d(np.asarray(q0, dtype=float))
    if q.shape != (nj,):
        raise ParameterError(f"q0 needs {nj} value(s) for model '{params.model}', got {q.size}")
    if not np.all(np.isfinite(q)):
        raise ParameterError(f"q0 must be finite, got {q.tolist()}")
    if profile.n_joints != nj:
        raise PlanningError(f"profile has {profile.n_joints} current column(s); model "
                            f"'{params.model}' needs {nj}")
    profile.validate()
    return spec, q


def _rates(qd0: ArrayLike | None, nj: int) -> np.ndarray:
    return np.zeros(nj) if qd0 is None else np.atleast_1d(np.asarray(qd0, dtype=float))


def simulate(params: Params, profile: CurrentProfile, q0: ArrayLike,
             qd0: ArrayLike | None = None, *, trajectory: bool = False,
             **kwargs: Any) -> SimResult:
    """Simulate ``profile`` from rest (or ``qd0``) at ``q0``; returns the state at tf.

    ``trajectory=True`` adds sampled t, q, qd, current arrays (extra keyword arguments such as
    ``dt`` go to the model's simulator).
    """
    spec, q = _check(params, profile, q0)
    nj = spec.n_joints
    qd = _rates(qd0, nj)
    if qd.shape != (nj,) or not np.all(np.isfinite(qd)):
        raise ParameterError(f"qd0 needs {nj} finite value(s), got {qd.tolist()}")
    return spec.simulate(params, profile, q, qd, trajectory=trajectory, **kwargs)


def rest_position(params: Params, profile: CurrentProfile, q0: ArrayLike,
                  qd0: ArrayLike | None = None) -> np.ndarray:
    """Where the arm comes to rest (rad, (n_joints,)) with zero current after tf.

    This is the position users care about: under wrong friction the arm is often still moving at
    tf. nan where it never stops (negative viscous friction outrunning Coulomb friction).
    """
    spec, q = _check(params, profile, q0)
    qd = _rates(qd0, spec.n_joints)
    return np.asarray(spec.rest_position(params, profile, q, qd), dtype=float)
