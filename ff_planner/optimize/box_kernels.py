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
one-sided slopes. The switch-time columns cost little: each sample's differences resume from its
state at the step before the switch (``_switch_states``; the same sequence of floating-point
operations as a simulation from t = 0, so the same numbers), and the nominal g is differenced on
Taylor rows in the friction parameters only (``hd_sim_p``, no current columns). Measured (N = 12,
14 samples, loaded 2-core machine, best of 7): 0.74 → 0.48 ms per call. When the coast length
is a decision too, ``end_column`` gives the column of the coast-entry time t_N (central
differences as for the switch times).

The structured global stage over step durations (``box_robust._duration_search``) runs here
too: ``duration_draws`` (the compiled LM from one start per drawn duration vector, and the
corner worst of each plan it finds) and ``duration_walk`` (a (1+1) evolution strategy over the
durations, the coast and the LM start from a parent plan). Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ff_planner.model.arm1dof import sim_core
from ff_planner.model.arm1dof_derivatives import NP, Q_, VC_, hd_sim, hd_sim_p
from ff_planner.model.friction import stop_speed
from ff_planner.optimize.lm1d import OK, multistart


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
def _nominal_p(J, c, pvals, pscale, times, cur, tf, q0, goal, Wp, g):
    """g (5,) of ``_nominal`` from the friction-parameter rows only (Wp: ``workspace(0)``)."""
    hd_sim_p(J, c, pvals[0], pvals[1], pvals[2], times, cur, tf, q0, False, pscale, Wp)
    g[0] = Wp[Q_, 0] - goal
    for i in range(NP):
        g[1 + i] = Wp[Q_, 1 + i] * pscale[i]
    g[4] = Wp[VC_, 0]


@njit(cache=True, nogil=True)
def _switch_states(J, c, pvals, scales, times, cur, qs, vs, seg, ev):
    """States (q, v) at each step start times[0..N−1] for each row of friction scale factors
    into qs, vs (S, N): the points the switch-time differences resume from."""
    n = cur.shape[0]
    for s in range(scales.shape[0]):
        pv = pvals[0] * scales[s, 0]
        pc = pvals[1] * scales[s, 1]
        pt = pvals[2] * scales[s, 2]
        q = qs[s, 0]
        v = vs[s, 0]
        for j in range(1, n):
            q, v, _, _ = sim_core(J, c, pv, pc, pt, times[j - 1:j + 1], cur[j - 1:j],
                                  times[j], q, v, False, seg, ev)
            qs[s, j] = q
            vs[s, j] = v


@njit(cache=True, nogil=True)
def _time_column(J, c, pvals, pscale, scales, times, cur, tf, q0, goal, h, j, qs, vs, Wp,
                 de, dg, seg, ev):
    """Central differences (±h s) in the switch time times[j] (1 ≤ j ≤ N) of the rest errors
    (into de (S,)) and of g (into dg (5,)). Each sample resumes from its state at times[j − 1]
    (``_switch_states``): the steps before are the same on both sides."""
    tt = times[j - 1:].copy()
    cj = cur[j - 1:]
    for s in range(scales.shape[0]):
        pv = pvals[0] * scales[s, 0]
        pc = pvals[1] * scales[s, 1]
        pt = pvals[2] * scales[s, 2]
        tt[1] = times[j] + h
        qp, _, _, _ = sim_core(J, c, pv, pc, pt, tt, cj, tf, qs[s, j - 1], vs[s, j - 1], True,
                               seg, ev)
        tt[1] = times[j] - h
        qm, _, _, _ = sim_core(J, c, pv, pc, pt, tt, cj, tf, qs[s, j - 1], vs[s, j - 1], True,
                               seg, ev)
        de[s] = (qp - qm) / (2.0 * h)
    gp = np.empty(5)
    gm = np.empty(5)
    t2 = times.copy()
    t2[j] = times[j] + h
    _nominal_p(J, c, pvals, pscale, t2, cur, tf, q0, goal, Wp, gp)
    t2[j] = times[j] - h
    _nominal_p(J, c, pvals, pscale, t2, cur, tf, q0, goal, Wp, gm)
    for r in range(5):
        dg[r] = (gp[r] - gm[r]) / (2.0 * h)


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
    qs = np.full((m, n), q0)
    vs = np.zeros((m, n))
    _switch_states(J, c, pvals, scales, times, cur, qs, vs, seg, ev)
    Wp = np.zeros((W.shape[0], 4))
    de = np.empty(m)
    dg = np.empty(5)
    for j in range(1, n):
        _time_column(J, c, pvals, pscale, scales, times, cur, tf, q0, goal, h, j, qs, vs, Wp,
                     de, dg, seg, ev)
        for s in range(m):
            Ge[s, n + j - 1] = de[s]
        for r in range(5):
            Gg[r, n + j - 1] = dg[r]
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
    sample and one forward-mode simulation at the nominal friction, on Taylor rows in the
    friction parameters only: W's row count, 4 columns)."""
    e = rest_errors(J, c, pvals, scales, times, cur, tf, q0, goal)
    g = np.empty(5)
    _nominal_p(J, c, pvals, pscale, times, cur, tf, q0, goal, np.zeros((W.shape[0], 4)), g)
    return e, g


@njit(cache=True, nogil=True)
def end_column(J, c, pvals, pscale, scales, times, cur, tf, q0, goal, h, W):
    """(∂e/∂t_N (S,), ∂g/∂t_N (5,)): central differences (±h s) in the coast-entry time
    t_N = tf − coast, the column ``free_terms`` leaves out when the coast is a decision."""
    n = cur.shape[0]
    m = scales.shape[0]
    seg = np.empty((0, 7))
    ev = np.empty((0, 3))
    qs = np.full((m, n), q0)
    vs = np.zeros((m, n))
    _switch_states(J, c, pvals, scales, times, cur, qs, vs, seg, ev)
    de = np.empty(m)
    dg = np.empty(5)
    _time_column(J, c, pvals, pscale, scales, times, cur, tf, q0, goal, h, n, qs, vs,
                 np.zeros((W.shape[0], 4)), de, dg, seg, ev)
    return de, dg


# --- the global stage over step durations (``box_robust._duration_search``) -----------------
_stop_speed = njit(cache=True, nogil=True)(stop_speed)


@njit(cache=True, nogil=True)
def _lm_one(J, c, pvals, umask, pscale, i_max, times, tf, q0, goal, vb, cur, W, lm, st, it, f, kk):
    """The compiled LM (``lm1d.multistart``) from the currents ``cur`` (1, N) at ``times``
    (modified in place); lm = [wpen, wq, lam0, tol_q, tol_d, min_kink, max_iter, abandon_iter,
    abandon_norm, max_reject, lam_down, lam_up]. Returns its status."""
    multistart(J, c, pvals[0], pvals[1], pvals[2], times, tf, q0, goal, umask, pscale, i_max,
               cur, W, vb, lm[0], lm[1], lm[2], lm[3], lm[4], lm[5], int(lm[6]), int(lm[7]),
               lm[8], int(lm[9]), lm[10], lm[11], False, st, it, f, kk)
    return st[0]


@njit(cache=True, nogil=True)
def _corner_worst(J, c, pvals, scales, times, cur, tf, q0, goal, out, seg, ev):
    """Largest |rest − qf| (rad) over the rows of friction scale factors (inf: one never
    stops)."""
    _rest_all(J, c, pvals, scales, times, cur, tf, q0, out, seg, ev)
    w = 0.0
    for s in range(out.shape[0]):
        e = abs(out[s] - goal)
        if not e < math.inf:       # nan: that sample never stops
            return math.inf
        w = max(w, e)
    return w


@njit(cache=True, nogil=True)
def duration_draws(J, c, pvals, umask, pscale, i_max, tf, q0, goal, margin, times, starts,
                   lm, scales, W, status, worst):
    """LM from each start (M, K, N) A at the step times of its draw (M, N + 1) s (the coast
    tf − times[m, N]; its stopping bound with ``margin`` s), the starts modified in place into
    the end points; status (M, K) of each (``lm1d`` codes) and, where it is OK, the worst
    |rest − qf| (rad) over the friction scale factors ``scales`` into worst (M, K), else inf.
    Returns the LM iterations run."""
    m = starts.shape[0]
    k = starts.shape[1]
    n = starts.shape[2]
    st = np.zeros(1, np.int64)
    it = np.zeros(1, np.int64)
    f = np.zeros(1)
    kk = np.zeros(1)
    cur = np.empty((1, n))
    out = np.empty(scales.shape[0])
    seg = np.empty((0, 7))
    ev = np.empty((0, 3))
    iters = 0
    for a in range(m):
        t = np.ascontiguousarray(times[a])
        vb = _stop_speed(J, pvals[0], pvals[1], tf - t[n] - margin)
        for b in range(k):
            for j in range(n):
                cur[0, j] = starts[a, b, j]
            status[a, b] = _lm_one(J, c, pvals, umask, pscale, i_max, t, tf, q0, goal, vb,
                                   cur, W, lm, st, it, f, kk)
            iters += it[0]
            for j in range(n):
                starts[a, b, j] = cur[0, j]
            worst[a, b] = math.inf
            if status[a, b] == OK:
                worst[a, b] = _corner_worst(J, c, pvals, scales, t, cur[0], tf, q0, goal, out,
                                            seg, ev)
    return iters


@njit(cache=True, nogil=True)
def duration_walk(J, c, pvals, umask, pscale, i_max, tf, q0, goal, margin, min_step,
                  coast_lo, coast_hi, coast_step, current_step, sigma0, times, cur, worst, noise,
                  lm, scales, W):
    """A (1+1) evolution strategy over the step durations and the coast of each parent p:
    a child scales the N durations of times[p] (s) by exp(σ·noise[p, i, :N]) and moves the coast
    by σ·coast_step·noise[p, i, N] (clipped into [coast_lo, coast_hi] s), the durations then
    filling tf − coast again (each at least ``min_step`` s, else the child is skipped); the LM
    from the parent's currents cur[p] (A) moved by σ·current_step·noise[p, i, N + 1:] (clipped
    to ±i_max) puts it on the robust set, and it replaces the parent
    when its worst |rest − qf| over ``scales`` (rad) is less than worst[p]. σ starts at
    ``sigma0``, × 1.5 after a success, × 0.9 otherwise. times, cur and worst are updated in
    place. Returns (children on the robust set, LM iterations run)."""
    P = times.shape[0]
    n = cur.shape[1]
    kids = noise.shape[1]
    st = np.zeros(1, np.int64)
    it = np.zeros(1, np.int64)
    f = np.zeros(1)
    kk = np.zeros(1)
    trial = np.empty((1, n))
    t = np.empty(n + 1)
    d = np.empty(n)
    out = np.empty(scales.shape[0])
    seg = np.empty((0, 7))
    ev = np.empty((0, 3))
    ok = 0
    iters = 0
    for p in range(P):
        sigma = sigma0
        for i in range(kids):
            coast = tf - times[p, n] + sigma * coast_step * noise[p, i, n]
            coast = min(max(coast, coast_lo), coast_hi)
            s = 0.0
            for j in range(n):
                d[j] = (times[p, j + 1] - times[p, j]) * math.exp(sigma * noise[p, i, j])
                s += d[j]
            scale = (tf - coast) / s
            short = False
            t[0] = 0.0
            for j in range(n):
                d[j] *= scale
                short = short or d[j] < min_step
                t[j + 1] = t[j] + d[j]
            t[n] = tf - coast
            if short:
                sigma *= 0.9
                continue
            for j in range(n):
                trial[0, j] = min(max(cur[p, j] + sigma * current_step * noise[p, i, n + 1 + j],
                                      -i_max), i_max)
            vb = _stop_speed(J, pvals[0], pvals[1], coast - margin)
            status = _lm_one(J, c, pvals, umask, pscale, i_max, t, tf, q0, goal, vb, trial, W,
                             lm, st, it, f, kk)
            iters += it[0]
            w = math.inf
            if status == OK:
                ok += 1
                w = _corner_worst(J, c, pvals, scales, t, trial[0], tf, q0, goal, out, seg, ev)
            if w < worst[p]:
                worst[p] = w
                for j in range(n):
                    cur[p, j] = trial[0, j]
                for j in range(n + 1):
                    times[p, j] = t[j]
                sigma *= 1.5
            else:
                sigma *= 0.9
    return ok, iters
