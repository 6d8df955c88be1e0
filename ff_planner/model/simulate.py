"""One entry point to simulate any model: ``simulate``/``rest_position`` dispatch on params.model.

arm1dof → ``ff_planner.model.arm1dof`` (exact, event-based, compiled); scara2 → ``ff_planner.model.scara2``
(``simulate_scara2`` returning the same SimResult). Units: rad, rad/s, A, s.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ff_planner.core.results import SimResult
from ff_planner.model.params import ParameterError, Params, n_joints
from ff_planner.model.profile import CurrentProfile, PlanningError


def _check(params: Params, profile: CurrentProfile, q0) -> np.ndarray:
    nj = n_joints(params.model)
    q0 = np.atleast_1d(np.asarray(q0, dtype=float))
    if q0.shape != (nj,):
        raise ParameterError(f"q0 needs {nj} value(s) for model '{params.model}', got {q0.size}")
    if not np.all(np.isfinite(q0)):
        raise ParameterError(f"q0 must be finite, got {q0.tolist()}")
    if profile.n_joints != nj:
        raise PlanningError(f"profile has {profile.n_joints} current column(s); model "
                            f"'{params.model}' needs {nj}")
    profile.validate()
    return q0


def simulate(params: Params, profile: CurrentProfile, q0: Sequence[float] | float,
             qd0: Sequence[float] | float | None = None, *, trajectory: bool = False,
             **kwargs) -> SimResult:
    """Simulate ``profile`` from rest (or ``qd0``) at ``q0``; returns the state at tf.

    ``trajectory=True`` adds sampled t, q, qd, current arrays (extra keyword arguments such as
    ``dt`` go to the model's simulator).
    """
    q0 = _check(params, profile, q0)
    nj = q0.shape[0]
    qd0 = np.zeros(nj) if qd0 is None else np.atleast_1d(np.asarray(qd0, dtype=float))
    if qd0.shape != (nj,) or not np.all(np.isfinite(qd0)):
        raise ParameterError(f"qd0 needs {nj} finite value(s), got {qd0.tolist()}")
    if params.model == "arm1dof":
        from ff_planner.model.arm1dof import simulate_arm1dof

        return simulate_arm1dof(params, profile, float(q0[0]), float(qd0[0]),
                                trajectory=trajectory, **kwargs)
    from . import scara2  # noqa: F401  (written by the scara2 owner)

    return scara2.simulate_scara2(params, profile, q0, qd0, trajectory=trajectory, **kwargs)


def rest_position(params: Params, profile: CurrentProfile, q0: Sequence[float] | float,
                  qd0: Sequence[float] | float | None = None) -> np.ndarray:
    """Where the arm comes to rest (rad, (n_joints,)) with zero current after tf.

    This is the position users care about: under wrong friction the arm is often still moving at
    tf. nan where it never stops (negative viscous friction outrunning Coulomb friction).
    """
    q0 = _check(params, profile, q0)
    nj = q0.shape[0]
    qd0 = np.zeros(nj) if qd0 is None else np.atleast_1d(np.asarray(qd0, dtype=float))
    if params.model == "arm1dof":
        from ff_planner.model.arm1dof import rest_position_arm1dof

        return np.array([rest_position_arm1dof(params, profile, float(q0[0]), float(qd0[0]))])
    from ff_planner.model import scara2

    return np.asarray(scara2.rest_position_scara2(params, profile, q0, qd0), dtype=float)
