"""Current quantisation: the profile as the drive will apply it.

A drive takes its current setpoint in integer units — an EPOS4 in cyclic synchronous torque mode
in per mille of the motor's nominal current (CiA 402 target torque 0x6071), e.g. 3 mA for a 3 A
motor; an EPOS2 in current mode in mA (0x2030). ``quantize_profile`` rounds a profile's currents
to such a grid (A, never beyond the current limit); ``quantize_result`` does it to a plan and
recomputes what depends on the currents for the rounded profile: the nominal state at tf, the
rest position and, for the 1-DOF arm, the largest exact and central derivative ∂q(tf)/∂p of
``robust1d.verify``. Units: A, rad, s.
"""
from __future__ import annotations

import math
from dataclasses import replace as dc_replace
from typing import Optional, Sequence

import numpy as np

from ff_planner.model.params import Arm1DofParams, Params
from ff_planner.model.profile import CurrentProfile, PlanResult
from ff_planner.model.simulate import rest_position, simulate
from ff_planner.optimize.robust1d import verify


def quantize_profile(profile: CurrentProfile, quantum: float,
                     limits: Optional[Sequence[float]] = None) -> CurrentProfile:
    """``profile`` with every current rounded to the nearest multiple of ``quantum`` (A > 0);
    a rounded value beyond its joint's limit (A) goes one quantum back inside."""
    if not (math.isfinite(quantum) and quantum > 0.0):
        raise ValueError(f"current quantum must be a finite number > 0 A, got {quantum}")
    cur = np.round(np.asarray(profile.currents, dtype=float) / quantum) * quantum
    if limits is not None:
        lim = np.asarray(limits, dtype=float).reshape(1, -1)
        inside = np.floor(lim / quantum + 1e-9) * quantum
        cur = np.clip(cur, -inside, inside)
    return dc_replace(profile, currents=cur)


def _limits(params: Params, n_joints: int) -> list[float]:
    if isinstance(params, Arm1DofParams):
        return [float(params.i_max)]
    return [float(getattr(params, f"i_max{j + 1}")) for j in range(n_joints)]


def quantize_result(result: PlanResult, params: Params, quantum: float,
                    uncertain: Sequence[str] = ()) -> dict:
    """Round ``result.profile``'s currents to ``quantum`` (A) in place and recompute q_final,
    qd_final and ``extra["rest_position"]`` for the rounded profile (nominal parameters); the
    certificate is dropped (the facade certifies the rounded profile). Returns the figures
    stored in ``extra["current_quantum"]``: quantum (A), largest change of a current (A), rest
    position moved by the rounding (rad per joint), and for the 1-DOF arm the largest
    |∂q(tf)/∂p| of ``verify`` and the error of q(tf) (rad) of the rounded profile."""
    prof = result.profile
    if prof is None:
        return {"quantum": float(quantum)}
    nj = prof.currents.shape[1]
    q0 = [float(x) for x in result.q0]
    before = rest_position(params, prof, q0)
    rounded = quantize_profile(prof, quantum, _limits(params, nj))
    info: dict = {"quantum": float(quantum),
                  "max_change_A": float(np.max(np.abs(rounded.currents - prof.currents)))}
    result.profile = rounded
    end = simulate(params, rounded, q0)
    result.q_final = np.asarray(end.q_f, dtype=float).ravel()
    result.qd_final = np.asarray(end.qd_f, dtype=float).ravel()
    after = rest_position(params, rounded, q0)
    result.extra = dict(result.extra or {})
    result.extra["rest_position"] = [float(x) for x in after]
    info["rest_shift_rad"] = [float(a - b) for a, b in zip(after, before)]
    if isinstance(params, Arm1DofParams) and uncertain:
        ver = verify(params, rounded, q0[0], float(result.qf[0]), list(uncertain))
        info["max_abs_derivative"] = float(ver["max_abs_derivative"])
        info["q_tf_error_rad"] = float(ver["q_tf"]) - float(result.qf[0])
    result.certificate = None
    return info
