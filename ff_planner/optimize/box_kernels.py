"""Compiled terms of the robust-box minimax with free switch times (1-DOF arm).

Decisions x = (I_1..I_N, t_1..t_{N−1}): the step currents (A) and the interior switch times (s);
t_0 = 0 and t_N = tf − coast stay fixed. ``free_terms`` returns, in one compiled call,

- e (S,): rest-position errors q_rest(x; p_s) − qf (rad) at the friction samples p_s = p·scale_s,
  and their Jacobian (S, 2N − 1): exact in the currents (forward mode, ``hd_sim``), central
  differences (±h s) of the exact simulator in the switch times;
- the nominal equalities g (4,) = [q(tf) − qf, ∂q(tf)/∂p_i·s_i (pv, pc, pt; zero rows for
  parameters that are not uncertain)] and the coast-entry speed v_c (rad/s), with their
  Jacobians (5, 2N − 1), exact in the currents, central differences in the switch times.

The rest position is smooth in the switch times except where a velocity zero crossing meets a
switch (the kink radius of ``hd_sim``); there the central difference is the mean of the two
one-sided slopes. When the coast length is a decision too, ``end_column`` gives the column of
the coast-entry time t_N (central differences as for the switch times). Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ff_planner.model.arm1dof import sim_core
from ff_planner.model.arm1dof_derivatives import NP, Q_, VC_, hd_sim


@njit(cache=True, nogil=True)
def _rest_all(J, c, pvals, scales, times, cur, tf, q0, out, seg, ev):
    """Rest positions (rad) at each row of friction scale factors into ``out``."""
    for s in range(scales.shape[0]):
        q, _, _, _ = sim_core(J, c, pvals[0] * scales[s, 0], pvals[1] * scales[s, 1],
                              pvals[2] * scales[s, 2], times, cur, tf, q0, 0.0, True, seg, ev)
        out[s] = q


@njit(cache=True, nogil=True)
def _nominal(J, c, pvals, pscale, times, cur, tf, q0, goal, W, g):
    """g (5,) = [q(tf) − qf, ∂q/∂p_i·s_i (3), v_c] at the nominal friction; W holds the rows."""
    hd_sim(J, c, pvals[0], pvals[1], pvals[2], times, cur, tf, q0, False, pscale, W)
    g[0] = W[Q_, 0] - goal
    for i in range(NP):
        g[1 + i] = W[Q_, 1 + i] * pscale[i]
    g[4] = W[VC_, 0]


@njit(cache=True, nogil=True)
def free_terms(J, c, pvals, pscale, scales, times, cur, tf, q0, goal, h, W):
    """(e (S,), Ge (S, 2N−1), g (5,), Gg (5, 2N−1)) — see the module docstring."""
    n = cur.shape[0]
    m = scales.shape[0]
    nv = 2 * n - 1
    e = np.empty(m)
    Ge = np.zeros((m, nv))
    no_radius = np.zeros(NP)
    for s in range(m):
        hd_sim(J, c, pvals[0] * scales[s, 0], pvals[1] * scales[s, 1], pvals[2] * scales[s, 2],
               times, cur, tf, q0, True, no_radius, W)
        e[s] = W[Q_, 0] - goal
        for j in range(n):
            Ge[s, j] = W[Q_, 4 + j]
    g = np.empty(5)
    Gg = np.zeros((5, nv))
    _nominal(J, c, pvals, pscale, times, cur, tf, q0, goal, W, g)
    for j in range(n):
        Gg[0, j] = W[Q_, 4 + j]
        for i in range(NP):
            Gg[1 + i, j] = W[Q_, 4 + n + i * n + j] * pscale[i]
        Gg[4, j] = W[VC_, 4 + j]
    seg = np.empty((0, 7))
    ev = np.empty((0, 3))
    qp = np.empty(m)
    qm = np.empty(m)
    gp = np.empty(5)
    gm = np.empty(5)
    tt = times.copy()
    for j in range(1, n):
        tt[j] = times[j] + h
        _rest_all(J, c, pvals, scales, tt, cur, tf, q0, qp, seg, ev)
        _nominal(J, c, pvals, pscale, tt, cur, tf, q0, goal, W, gp)
        tt[j] = times[j] - h
        _rest_all(J, c, pvals, scales, tt, cur, tf, q0, qm, seg, ev)
        _nominal(J, c, pvals, pscale, tt, cur, tf, q0, goal, W, gm)
        tt[j] = times[j]
        for s in range(m):
            Ge[s, n + j - 1] = (qp[s] - qm[s]) / (2.0 * h)
        for r in range(5):
            Gg[r, n + j - 1] = (gp[r] - gm[r]) / (2.0 * h)
    return e, Ge, g, Gg


@njit(cache=True, nogil=True)
def rest_errors(J, c, pvals, scales, times, cur, tf, q0, goal):
    """Rest-position errors (rad) at each row of friction scale factors (nan: never stops)."""
    out = np.empty(scales.shape[0])
    _rest_all(J, c, pvals, scales, times, cur, tf, q0, out, np.empty((0, 7)), np.empty((0, 3)))
    for s in range(out.shape[0]):
        out[s] -= goal
    return out


@njit(cache=True, nogil=True)
def free_values(J, c, pvals, pscale, scales, times, cur, tf, q0, goal, W):
    """(e (S,), g (5,)) of ``free_terms`` without the Jacobians (one exact simulation per
    sample and one forward-mode simulation at the nominal friction)."""
    e = rest_errors(J, c, pvals, scales, times, cur, tf, q0, goal)
    g = np.empty(5)
    _nominal(J, c, pvals, pscale, times, cur, tf, q0, goal, W, g)
    return e, g


@njit(cache=True, nogil=True)
def end_column(J, c, pvals, pscale, scales, times, cur, tf, q0, goal, h, W):
    """(∂e/∂t_N (S,), ∂g/∂t_N (5,)): central differences (±h s) in the coast-entry time
    t_N = tf − coast, the column ``free_terms`` leaves out when the coast is a decision."""
    n = cur.shape[0]
    m = scales.shape[0]
    seg = np.empty((0, 7))
    ev = np.empty((0, 3))
    qp = np.empty(m)
    qm = np.empty(m)
    gp = np.empty(5)
    gm = np.empty(5)
    tt = times.copy()
    tt[n] = times[n] + h
    _rest_all(J, c, pvals, scales, tt, cur, tf, q0, qp, seg, ev)
    _nominal(J, c, pvals, pscale, tt, cur, tf, q0, goal, W, gp)
    tt[n] = times[n] - h
    _rest_all(J, c, pvals, scales, tt, cur, tf, q0, qm, seg, ev)
    _nominal(J, c, pvals, pscale, tt, cur, tf, q0, goal, W, gm)
    de = (qp - qm) / (2.0 * h)
    dg = (gp - gm) / (2.0 * h)
    return de, dg
