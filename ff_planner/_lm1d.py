"""Compiled multistart Levenberg–Marquardt for the 1-DOF robust-derivative problem.

Unknowns: the N step currents I (A), box |I| ≤ i_max (projected steps). Equations (all in rad):

    r_0     = wq · (q(tf) − q_goal)
    r_i     = ∂q(tf)/∂p_i · s_i     for each uncertain p_i (s_i = |p_i|, a default if p_i = 0)
    r_pen   = w · max(0, |q̇(tf − coast)| − v_bound)   (one-sided rest condition)

v_bound is the coast-entry speed from which zero current stops the arm a margin before tf, so
once the penalty is zero the arm is at rest at tf on both sides of the nominal parameters
(q(tf) = the rest position, q̇(tf) = 0 exactly). Jacobians are exact (``_deriv1d``: forward mode
with the mixed ∂²q/∂p∂I). The step is the minimum-norm LM step δ = −Jᵀ(JJᵀ + λI)⁻¹r
(m = k+2 rows ≤ N columns), projected onto the box. Starts whose residual is still large after a
few iterations are abandoned; a converged start whose plan lies within MIN_KINK of a
non-smooth point is reported as KINK, not OK.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._deriv1d import NP, Q_, VC_, hd_sim

# status codes of one start
OK, NO_CONVERGENCE, ABANDONED, KINK, BAD_START = 0, 1, 2, 3, 4


_RESIDUAL_SIG = ("Tuple((boolean, float64, float64, float64, float64))(float64, float64, float64, "
                 "float64, float64, float64[::1], float64, float64, float64, float64[::1], "
                 "float64[::1], float64[::1], float64[:, ::1], float64, float64, float64, int64, "
                 "float64[::1], float64[:, ::1])")


@njit(_RESIDUAL_SIG, cache=True, nogil=True)
def residual(J, c, pv, pc, pt, times, tf, q0, goal, pw, pvals, cur, W, vb, wpen, wq,
             pen_mode, r, Jm):
    """Fill r (m,) and Jm (m, N).

    pen_mode 0: one-sided penalty w·max(0, |v_c| − vb); 1: equality w·(|v_c| − vb);
    2: penalty row off (zero). Returns (finite, kink radius, max |∂q/∂p_i|, |q − goal|, |v_c|).
    """
    n = cur.shape[0]
    kink, tf_radius = hd_sim(J, c, pv, pc, pt, times, cur, tf, q0, False, pw, W)
    q = W[Q_, 0]
    if not math.isfinite(q):
        return False, kink, math.inf, math.inf, math.inf
    base = 4 + n
    r[0] = wq * (q - goal)
    for j in range(n):
        Jm[0, j] = wq * W[Q_, 4 + j]
    row = 1
    dmax = 0.0
    for i in range(NP):
        if pw[i] != 0.0:
            dmax = max(dmax, abs(W[Q_, 1 + i]))
            r[row] = W[Q_, 1 + i] * pvals[i]
            for j in range(n):
                Jm[row, j] = W[Q_, base + i * n + j] * pvals[i]
            row += 1
    vc = W[VC_, 0]
    if (pen_mode == 0 and abs(vc) > vb) or pen_mode == 1:
        sg = 1.0 if vc > 0.0 else -1.0
        r[row] = wpen * (abs(vc) - vb)
        for j in range(n):
            Jm[row, j] = wpen * sg * W[VC_, 4 + j]
    else:
        r[row] = 0.0
        for j in range(n):
            Jm[row, j] = 0.0
    return True, kink, dmax, abs(q - goal), abs(vc)


@njit(cache=True, nogil=True)
def _norm2(r):
    s = 0.0
    for i in range(r.shape[0]):
        s += r[i] * r[i]
    return s


@njit(cache=True, nogil=True)
def _lm_step(Jm, r, lam, A, y, delta):
    """delta = −Jᵀ (J Jᵀ + λ I)⁻¹ r by Cholesky (m×m, in place in A)."""
    m, n = Jm.shape
    for a in range(m):
        for b in range(a + 1):
            s = 0.0
            for j in range(n):
                s += Jm[a, j] * Jm[b, j]
            A[a, b] = s
            A[b, a] = s
        A[a, a] += lam
    # Cholesky (lower) in place
    for a in range(m):
        s = A[a, a]
        for k in range(a):
            s -= A[a, k] * A[a, k]
        if s <= 0.0:
            return False
        d = math.sqrt(s)
        A[a, a] = d
        for b in range(a + 1, m):
            s = A[b, a]
            for k in range(a):
                s -= A[b, k] * A[a, k]
            A[b, a] = s / d
    for a in range(m):          # forward: L z = r
        s = r[a]
        for k in range(a):
            s -= A[a, k] * y[k]
        y[a] = s / A[a, a]
    for a in range(m - 1, -1, -1):   # back: Lᵀ y = z
        s = y[a]
        for k in range(a + 1, m):
            s -= A[k, a] * y[k]
        y[a] = s / A[a, a]
    for j in range(n):
        s = 0.0
        for a in range(m):
            s -= Jm[a, j] * y[a]
        delta[j] = s
    return True


@njit(cache=True, nogil=True)
def solve_start(J, c, pv, pc, pt, times, tf, q0, goal, pvals, i_max, I, W, vb, wpen, wq, lam0,
                tol_q, tol_d, min_kink, max_iter, abandon_iter, abandon_norm, max_reject,
                lam_down, lam_up, pw, r, Jm, r2, Jm2, A, y, delta, trial):
    """LM from the currents in I (modified in place). Returns (status, iterations, |r|², kink).

    The rest condition is the one-sided penalty row (pen_mode 0). Work arrays are passed in.
    """
    n = I.shape[0]
    ok, kink, dmax, qerr, vca = residual(J, c, pv, pc, pt, times, tf, q0, goal, pw, pvals, I,
                                         W, vb, wpen, wq, 0, r, Jm)
    if not ok:
        return BAD_START, 0, math.inf, kink
    f = _norm2(r)
    lam = lam0
    for it in range(max_iter):
        if qerr <= tol_q and dmax <= tol_d and vca <= vb:
            if kink >= min_kink:
                return OK, it, f, kink
            return KINK, it, f, kink
        if it >= abandon_iter and f > abandon_norm:
            return ABANDONED, it, f, kink
        accepted = False
        for _ in range(max_reject):
            if not _lm_step(Jm, r, lam, A, y, delta):
                lam *= 10.0
                continue
            for j in range(n):
                x = I[j] + delta[j]
                trial[j] = min(max(x, -i_max), i_max)
            ok2, kink2, dmax2, qerr2, vca2 = residual(J, c, pv, pc, pt, times, tf, q0, goal,
                                                      pw, pvals, trial, W, vb, wpen, wq, 0, r2,
                                                      Jm2)
            f2 = _norm2(r2) if ok2 else math.inf
            if f2 < f:
                for j in range(n):
                    I[j] = trial[j]
                r[:] = r2
                Jm[:, :] = Jm2
                f = f2
                kink, dmax, qerr, vca = kink2, dmax2, qerr2, vca2
                lam = max(lam * lam_down, 1e-14)
                accepted = True
                break
            lam *= lam_up
        if not accepted:
            return NO_CONVERGENCE, it, f, kink
    if qerr <= tol_q and dmax <= tol_d and vca <= vb:
        return (OK if kink >= min_kink else KINK), max_iter, f, kink
    return NO_CONVERGENCE, max_iter, f, kink


@njit(cache=True, nogil=True)
def multistart(J, c, pv, pc, pt, times, tf, q0, goal, umask, pvals, i_max, starts, W, vb,
               wpen, wq, lam0, tol_q, tol_d, min_kink, max_iter, abandon_iter, abandon_norm,
               max_reject, lam_down, lam_up, stop_first, out_status, out_iter, out_f, out_kink):
    """Run LM from each row of ``starts`` (modified in place into the end points).

    Stops after the first success when ``stop_first``. Returns the number of starts run.
    """
    ns = starts.shape[0]
    n = starts.shape[1]
    k = 0
    pw = np.zeros(NP)
    for i in range(NP):
        if umask[i]:
            k += 1
            pw[i] = pvals[i]
    m = k + 2
    r = np.empty(m)
    Jm = np.empty((m, n))
    r2 = np.empty(m)
    Jm2 = np.empty((m, n))
    A = np.empty((m, m))
    y = np.empty(m)
    delta = np.empty(n)
    trial = np.empty(n)
    for s in range(ns):
        st, it, f, kink = solve_start(J, c, pv, pc, pt, times, tf, q0, goal, pvals, i_max,
                                      starts[s], W, vb, wpen, wq, lam0, tol_q, tol_d, min_kink,
                                      max_iter, abandon_iter, abandon_norm, max_reject, lam_down,
                                      lam_up, pw, r, Jm, r2, Jm2, A, y, delta, trial)
        out_status[s] = st
        out_iter[s] = it
        out_f[s] = f
        out_kink[s] = kink
        if stop_first and st == OK:
            return s + 1
    return ns


@njit(cache=True, nogil=True)
def sampled_terms(J, c, pvals, scales, times, cur, tf, q0, goal, W):
    """Rest-position errors e (S,) at friction pvals·scales[s] and their Jacobian G (S, N)
    w.r.t. the currents (robust-sampled objective, one compiled call)."""
    n = cur.shape[0]
    m = scales.shape[0]
    e = np.empty(m)
    G = np.empty((m, n))
    pw = np.zeros(NP)
    for s in range(m):
        hd_sim(J, c, pvals[0] * scales[s, 0], pvals[1] * scales[s, 1], pvals[2] * scales[s, 2],
               times, cur, tf, q0, True, pw, W)
        e[s] = W[Q_, 0] - goal
        for j in range(n):
            G[s, j] = W[Q_, 4 + j]
    return e, G
