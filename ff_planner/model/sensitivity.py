"""Sensitivities of the final state to the friction parameters, for any model.

``sensitivities(params, profile, q0, names, method)`` returns ∂q(tf)/∂p (rad per unit of p) and
∂q̇(tf)/∂p (rad/s per unit):
- method "exact": 1-DOF forward mode through the event times (``arm1dof.derivatives``); 2-DOF
  complex step through the event-aware integrator (``scara2.sensitivities_scara2``).
- "central": central differences via ``simulate`` (relative step, default 1e-6).
- "forward": the paper's forward quotient (relative step, default 1e-3 = 0.1 %). Beware: near a
  non-smooth point (breakaway, a stop at a switch time) it can read ~0 while the true one-sided
  derivatives are not; judge plans with "exact" and "central".

Keys, 1-DOF: "pc" = ∂q_f/∂pc, "qd/pc" = ∂q̇_f/∂pc (and with ``rest=True`` "qrest/pc", the
derivative of the rest position after tf). 2-DOF: "q1/pc2", "qd1/pc2", ... (see ff_planner.model.scara2).
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ff_planner.model.params import ParameterError, Params
from ff_planner.model.profile import CurrentProfile

METHODS = ("exact", "central", "forward")


def _finite_difference(params: Params, profile: CurrentProfile, q0, names, method, rel_step,
                       rest):
    from ff_planner.model.simulate import rest_position, simulate

    def outputs(p):
        r = simulate(p, profile, q0)
        vals = [r.q_f, r.qd_f]
        if rest:
            vals.append(rest_position(p, profile, q0))
        return np.concatenate(vals)

    f0 = outputs(params) if method == "forward" else None
    step = rel_step if rel_step is not None else (1e-3 if method == "forward" else 1e-6)
    if not step > 0.0:
        raise ParameterError(f"rel_step must be > 0, got {step}")
    out = {}
    for name in names:
        pval = float(getattr(params, name))
        h = step * (abs(pval) if pval != 0.0 else 1.0)
        fp = outputs(params.replace(**{name: pval + h}))
        if method == "forward":
            d = (fp - f0) / h
        else:
            fm = outputs(params.replace(**{name: pval - h}))
            d = (fp - fm) / (2.0 * h)
        out[name] = d
    return out


def sensitivities(params: Params, profile: CurrentProfile, q0: Sequence[float] | float,
                  names: Optional[Sequence[str]] = None, method: str = "exact",
                  rel_step: Optional[float] = None, *, rest: bool = False) -> dict[str, float]:
    """∂(final state)/∂p for friction parameters ``names`` (default: all of the model's)."""
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    names = list(params.friction_keys if names is None else names)
    bad = [n for n in names if n not in params.friction_keys]
    if bad:
        raise ParameterError(f"unknown friction parameter(s) {bad} for model '{params.model}'; "
                             f"choose from {', '.join(params.friction_keys)}")
    q0 = np.atleast_1d(np.asarray(q0, dtype=float))
    if params.model == "scara2":
        from ff_planner.model.scara2 import sensitivities_scara2

        return sensitivities_scara2(params, profile, q0, names, method=method,
                                    rel_step=rel_step, rest=rest)
    if q0.shape != (1,) or not np.isfinite(q0[0]):
        raise ParameterError(f"q0 needs 1 finite value for model 'arm1dof', got {q0.tolist()}")
    out: dict[str, float] = {}
    if method == "exact":
        from ff_planner.model.arm1dof import derivatives

        profile.validate()
        d = derivatives(params, profile, float(q0[0]), uncertain=names)
        for n in names:
            out[n] = d.dq_dp[n]
            out[f"qd/{n}"] = d.dqd_dp[n]
        if rest:
            dr = derivatives(params, profile, float(q0[0]), uncertain=names, to_rest=True)
            for n in names:
                out[f"qrest/{n}"] = dr.dq_dp[n]
        return out
    fd = _finite_difference(params, profile, q0, names, method, rel_step, rest)
    for n, d in fd.items():
        out[n] = float(d[0])
        out[f"qd/{n}"] = float(d[1])
        if rest:
            out[f"qrest/{n}"] = float(d[2])
    return out
