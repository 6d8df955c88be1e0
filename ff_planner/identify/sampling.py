"""The exact 1-DOF simulator sampled at given times: the model output the fit compares with data.

Uses the compiled kernels of ``ff_planner.model.arm1dof`` (``sim_core`` records the closed-form
segments, ``eval_segments`` evaluates them), so a sample is exact at any time, events included.
Units: rad, rad/s, A, s, Nm.
"""
from __future__ import annotations

import numpy as np

from ff_planner.model import arm1dof
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile

#: columns of a segment row of the simulator (t0, t1, q0, v0, a, b, moving)
_SEG_COLS = 7


def sample_trajectory(J: float, torque_per_amp: float, pv: float, pc: float, pt: float,
                      profile: CurrentProfile, q0: float, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q rad, q̇ rad/s) at ``times`` (s, ascending) of the arm starting at rest at q0 at t = 0
    under ``profile`` (zero current after its last step); q0 before t = 0."""
    times = np.asarray(times, dtype=float)
    st = np.ascontiguousarray(profile.step_times, dtype=float)
    cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
    horizon = max(float(times[-1]), float(st[-1])) + 1e-9
    cap = 3 * (cur.shape[0] + 3) + 4
    seg = np.zeros((cap, _SEG_COLS))
    ev = np.empty((0, 3))
    _, _, nseg, _ = arm1dof.sim_core(J, torque_per_amp, pv, pc, pt, st, cur, horizon, float(q0), 0.0,
                                     False, seg, ev)
    q = np.full(times.shape, float(q0))
    v = np.zeros(times.shape)
    after = times >= 0.0
    if np.any(after):
        qs, vs = arm1dof.eval_segments(seg, min(nseg, cap), np.ascontiguousarray(times[after]))
        q[after], v[after] = qs, vs
    return q, v


def sample_params(params: Arm1DofParams, profile: CurrentProfile, q0: float,
                  times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``sample_trajectory`` with the values of ``params``."""
    return sample_trajectory(float(params.J), float(params.torque_per_amp), float(params.pv),
                             float(params.pc), float(params.pt), profile, q0, times)
