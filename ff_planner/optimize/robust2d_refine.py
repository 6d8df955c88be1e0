"""Refine a held-link-2 robust plan for finite friction errors (section 6.2's sampled idea).

Among joint-1 current profiles that keep every ∂q1(tf)/∂p_i = 0, q1(tf) = q1f, the final stop
inside the coast and link 2 held with margin, SLSQP minimises the sum of squared REST-position
errors of joint 1 with each uncertain joint-1 friction parameter at ±10 % and ±20 % alone and all
of them at the ±20 % corners together. Joint 2 is held, so joint-2 friction changes do not move
either joint while the hold margin lasts. Units: rad, A, s.
"""
from __future__ import annotations

import time
from typing import Optional, Sequence

import numpy as np
from scipy.optimize import minimize

from ff_planner.model import arm1dof
from ff_planner.model.arm1dof import FRICTION
from ff_planner.optimize.hold_joint import Joint1Problem
from ff_planner.optimize.limits1d import Limits1D
from ff_planner.optimize.sample_box import sample_scales


def joint1_scales(names: Sequence[str]) -> np.ndarray:
    """(S, 3) scale factors for joint 1's (pv, pc, pt): ``sample_box.sample_scales`` of the
    uncertain joint-1 parameters ``names``, the + sign first in each pair."""
    return sample_scales(names, FRICTION, signs=(1.0, -1.0))


def rest_errors(hp: Joint1Problem, x: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Joint-1 rest-position errors (rad) at the sampled friction scales."""
    x = np.ascontiguousarray(x, dtype=float)
    base = np.array([hp.fr["pv"], hp.fr["pc"], hp.fr["pt"]])
    out = np.empty(scales.shape[0])
    for i, sc in enumerate(scales):
        pv, pc, pt = base * sc
        q, _, _, _ = arm1dof.sim_core(hp.J, hp.c, pv, pc, pt, hp.times, x, hp.tf, hp.q0, 0.0,
                                      True, hp.seg, hp.ev)
        out[i] = q - hp.qf
    return out


def refine_sampled(hp: Joint1Problem, x0: np.ndarray, names: Sequence[str], deadline: float,
                   tol: float) -> np.ndarray | None:
    """Joint-1 currents with smaller sampled rest errors that still meet every constraint of
    ``hp`` (a ``hold_joint.Joint1Problem`` with the link-2 hold), or None if no improvement."""
    scales = joint1_scales(names)
    k = len(hp.names)

    def obj(x):
        if time.perf_counter() > deadline:
            raise TimeoutError
        e = rest_errors(hp, x, scales)
        return float(e @ e)

    def eq(x):
        return hp.residuals(x)[: 1 + k] * 1e2

    def ineq(x):
        xs = np.ascontiguousarray(x, dtype=float)
        _, vN, _, _ = hp.final_state(xs, hp.tN, hp.fr["pv"], hp.fr["pc"], hp.fr["pt"])
        s = abs(vN)
        _, frac = hp.hold(xs)
        return np.concatenate([[s - hp.v_lo, hp.v_hi - s], frac - hp.hold_min])

    f0 = obj(x0)
    try:
        res = minimize(obj, x0, method="SLSQP", bounds=[(-hp.i_max, hp.i_max)] * len(x0),
                       constraints=[{"type": "eq", "fun": eq}, {"type": "ineq", "fun": ineq}],
                       options={"maxiter": 60, "ftol": 1e-12, "eps": 1e-7})
        x = res.x
    except TimeoutError:
        return None
    # polish the equalities exactly (least squares from the SLSQP point stays nearby)
    x2, fun, _ = hp.solve(x, max_nfev=40)
    if float(np.max(np.abs(fun))) > 0.1 * tol or obj(x2) >= f0:
        return None
    return x2


BOX_ITER = 80            # SLSQP iterations of the held-link-2 box minimax
HOLD_SLACK = 0.005       # the minimax keeps this much hold margin above hp.hold_min, so the
#                          final least-squares polish onto the robust set meets hp.hold_min


def refine_box(hp: Joint1Problem, x0: np.ndarray, scales: np.ndarray, deadline: float,
               tol: float, maxiter: int = BOX_ITER, limits: Optional[Limits1D] = None
               ) -> tuple[np.ndarray, float] | None:
    """Minimax for the box: among joint-1 currents that keep every constraint of ``hp`` (zero
    ∂q1(tf)/∂p_i, q1(tf) = q1f, stop inside the coast, link 2 held with ``hp.hold_min``), the
    least worst joint-1 REST error over the friction ``scales`` (S, 3) of (pv, pc, pt) — the
    box's corners, centre and face centres. Epigraph form: min w s.t. −w ≤ e_s ≤ w (w in mrad).
    Returns (currents (A), worst sampled error (rad)) if it improved on ``x0``, else None.

    ``limits`` (joint 1's position range / speed limit as the held 1-DOF arm, ``limits1d``):
    also g_s ≥ 0 at the box corners and centre (``Limits1D.corners``, mrad) as SLSQP rows; the
    answer must keep within them at every certificate box point (``Limits1D.ok``), and from a
    start outside them any such answer counts as an improvement."""
    scales = np.ascontiguousarray(scales, dtype=float)
    k = len(hp.names)
    n = len(x0)
    w0 = float(np.max(np.abs(rest_errors(hp, x0, scales))))

    def errs(z):
        if time.perf_counter() > deadline:
            raise TimeoutError
        return rest_errors(hp, z[:n], scales) * 1e3

    def eq(z):
        return hp.residuals(z[:n])[: 1 + k] * 1e2

    def ineq(z):
        xs = np.ascontiguousarray(z[:n], dtype=float)
        _, vN, _, _ = hp.final_state(xs, hp.tN, hp.fr["pv"], hp.fr["pc"], hp.fr["pt"])
        s = abs(vN)
        _, frac = hp.hold(xs)
        e = errs(z)
        lim = (limits.values(hp.times, xs, limits.corners) if limits is not None
               else np.empty(0))
        return np.concatenate([[s - hp.v_lo, hp.v_hi - s], frac - hp.hold_min - HOLD_SLACK,
                               z[n] - e, z[n] + e, lim])

    z0 = np.append(np.asarray(x0, dtype=float), 1e3 * w0)
    try:
        res = minimize(lambda z: z[n], z0, jac=lambda z: np.eye(n + 1)[n], method="SLSQP",
                       bounds=[(-hp.i_max, hp.i_max)] * n + [(0.0, None)],
                       constraints=[{"type": "eq", "fun": eq}, {"type": "ineq", "fun": ineq}],
                       options={"maxiter": maxiter, "ftol": 1e-6, "eps": 1e-7})
        x = res.x[:n]
    except TimeoutError:
        return None
    x2, fun, _ = hp.solve(x, max_nfev=40)
    if float(np.max(np.abs(fun))) > 0.1 * tol:
        return None
    if limits is not None and not limits.ok(hp.times, x2):
        return None
    w = float(np.max(np.abs(rest_errors(hp, x2, scales))))
    start_inside = limits is None or limits.ok(hp.times, np.ascontiguousarray(x0, dtype=float))
    return (x2, w) if (w < w0 or not start_inside) else None
