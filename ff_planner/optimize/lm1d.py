"""Compiled multistart Levenberg–Marquardt for the 1-DOF robust-derivative problem.

Unknowns: the N step currents I (A), box |I| ≤ i_max (projected steps). Equations (all in rad):

    r_0     = wq · (q(tf) − q_goal)
    r_i     = ∂q(tf)/∂p_i · s_i     for each uncertain p_i (s_i = |p_i|, a default if p_i = 0)
    r_pen   = w · max(0, |q̇(tf − coast)| − v_bound)   (one-sided rest condition)

v_bound is the coast-entry speed from which zero current stops the arm a margin before tf, so
once the penalty is zero the arm is at rest at tf on both sides of the nominal parameters
(q(tf) = the rest position, q̇(tf) = 0 exactly). Jacobians are exact (``_deriv1d``: forward mode
with the mixed ∂²q/∂p∂I). The step is the minimum-norm LM step δ = −Jᵀ(JJᵀ + λI)⁻¹r
(m = k+2 rows ≤ N columns), projected onto the box; currents at a bound whose step would leave
the box are held there and the step is recomputed for the free ones. Starts whose residual is
still large after a few iterations are abandoned; a converged start whose plan lies within
MIN_KINK of a non-smooth point is reported as KINK, not OK. A stall with the rest row switching
on and off across its bound turns that row into an equality just inside the bound.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ff_planner.model.arm1dof import sim_core
from ff_planner.model.arm1dof_derivatives import N_ROWS, NP, Q_, TSTOP_, V_, VC_, hd_sim

# status codes of one start
OK, NO_CONVERGENCE, ABANDONED, KINK, BAD_START = 0, 1, 2, 3, 4
# stall on the rest bound (see solve_start): |r|² below STALL_F with |v_c| within STALL_BAND·vb
# of vb switches the rest row to an equality at STALL_INSIDE·vb
STALL_F, STALL_BAND, STALL_INSIDE = 1e-4, 0.05, 0.999


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
                lam_down, lam_up, pw, r, Jm, r2, Jm2, A, y, delta, trial, Jf):
    """LM from the currents in I (modified in place). Returns (status, iterations, |r|², kink).

    The rest condition is the one-sided penalty row (pen_mode 0). Bounds: currents at ±i_max
    whose step would leave the box are held there (their Jacobian columns dropped, the step
    recomputed) — robust plans of long moves saturate the middle current. Work arrays are
    passed in.
    """
    n = I.shape[0]
    ok, kink, dmax, qerr, vca = residual(J, c, pv, pc, pt, times, tf, q0, goal, pw, pvals, I,
                                         W, vb, wpen, wq, 0, r, Jm)
    if not ok:
        return BAD_START, 0, math.inf, kink
    f = _norm2(r)
    lam = lam0
    pm = 0          # penalty mode of the rest row: one-sided, until a stall on its boundary
    vbe = vb
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
            held = False
            for j in range(n):
                if (I[j] >= i_max and delta[j] > 0.0) or (I[j] <= -i_max and delta[j] < 0.0):
                    held = True
            if held:        # active bounds: solve for the free currents only
                for j in range(n):
                    out = (I[j] >= i_max and delta[j] > 0.0) or (I[j] <= -i_max
                                                                 and delta[j] < 0.0)
                    for a in range(Jm.shape[0]):
                        Jf[a, j] = 0.0 if out else Jm[a, j]
                if not _lm_step(Jf, r, lam, A, y, delta):
                    lam *= 10.0
                    continue
            for j in range(n):
                x = I[j] + delta[j]
                trial[j] = min(max(x, -i_max), i_max)
            ok2, kink2, dmax2, qerr2, vca2 = residual(J, c, pv, pc, pt, times, tf, q0, goal,
                                                      pw, pvals, trial, W, vbe, wpen, wq, pm, r2,
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
            # a stall close to the rest bound (the one-sided row switching on and off across
            # the solution, which then lies on |v_c| = vb): make the row an equality just
            # inside the bound and go on; otherwise give up
            if pm == 0 and f < STALL_F and abs(vca - vb) < STALL_BAND * vb:
                pm = 1
                vbe = STALL_INSIDE * vb
                ok, kink, dmax, qerr, vca = residual(J, c, pv, pc, pt, times, tf, q0, goal, pw,
                                                     pvals, I, W, vbe, wpen, wq, pm, r, Jm)
                f = _norm2(r)
                lam = lam0
                continue
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
    Jf = np.empty((m, n))
    for s in range(ns):
        st, it, f, kink = solve_start(J, c, pv, pc, pt, times, tf, q0, goal, pvals, i_max,
                                      starts[s], W, vb, wpen, wq, lam0, tol_q, tol_d, min_kink,
                                      max_iter, abandon_iter, abandon_norm, max_reject, lam_down,
                                      lam_up, pw, r, Jm, r2, Jm2, A, y, delta, trial, Jf)
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


@njit(cache=True, nogil=True)
def sweep_size(k, n_changes):
    """Simulations in one verification sweep for k uncertain parameters (see ``verify_core``)."""
    groups = k + (1 if k > 1 else 0)
    return 1 + 3 * k + 2 * n_changes * groups


@njit(cache=True, nogil=True)
def verify_core(J, c, pv, pc, pt, times, cur, tf, q0, pscale, changes, W, out):
    """Everything the verification of a plan needs, in one compiled call; fills ``out``.

    pscale (3,): |p_i| (a default where p_i = 0) for uncertain parameters, 0 for the others.
    Layout of out: [0] kink radius, [1] tf radius, [2] t_stop (s), [3:6] exact ∂q(tf)/∂p,
    [6:9] exact ∂q̇(tf)/∂p (pv, pc, pt), [9] max |current| (A), then M = sweep_size(k, C) final
    positions and M final velocities of the sweep: row 0 nominal; per uncertain p (order pv, pc,
    pt): p + h, p − h (h = 1e-6·scale, central), p + 1e-3·scale (the paper's 0.1 % forward
    quotient); then per group (each uncertain p alone, then all together when k > 1) and per
    change ch: (q(tf), rest position) with the group's parameters times (1 + ch).
    """
    kink, tf_radius = hd_sim(J, c, pv, pc, pt, times, cur, tf, q0, False, pscale, W)
    out[0] = kink
    out[1] = tf_radius
    out[2] = W[TSTOP_, 0]
    for i in range(NP):
        out[3 + i] = W[Q_, 1 + i]
        out[6 + i] = W[V_, 1 + i]
    amax = 0.0
    for j in range(cur.shape[0]):
        amax = max(amax, abs(cur[j]))
    out[9] = amax
    k = 0
    for i in range(NP):
        if pscale[i] != 0.0:
            k += 1
    nc = changes.shape[0]
    m = sweep_size(k, nc)
    seg = np.empty((0, 7))
    ev = np.empty((0, 3))
    base = np.array([pv, pc, pt])
    p = base.copy()
    oq = 10
    ov = 10 + m
    row = 0
    q, v, _, _ = sim_core(J, c, pv, pc, pt, times, cur, tf, q0, 0.0, False, seg, ev)
    out[oq + row] = q
    out[ov + row] = v
    row += 1
    for i in range(NP):
        if pscale[i] == 0.0:
            continue
        for step in (1e-6, -1e-6, 1e-3):
            p[:] = base
            p[i] += step * pscale[i]
            q, v, _, _ = sim_core(J, c, p[0], p[1], p[2], times, cur, tf, q0, 0.0, False, seg,
                                  ev)
            out[oq + row] = q
            out[ov + row] = v
            row += 1
    for g in range(NP + 1):
        if g < NP and pscale[g] == 0.0:
            continue
        if g == NP and k <= 1:
            continue
        for ci in range(nc):
            p[:] = base
            for i in range(NP):
                if (g == NP and pscale[i] != 0.0) or i == g:
                    p[i] *= 1.0 + changes[ci]
            for rest in (False, True):
                q, v, _, _ = sim_core(J, c, p[0], p[1], p[2], times, cur, tf, q0, 0.0, rest,
                                      seg, ev)
                out[oq + row] = q
                out[ov + row] = v
                row += 1


@njit(cache=True, nogil=True)
def draw_starts(seed_key, spread, direction, mid_lo, mid_hi, starts):
    """Fill ``starts`` (m, N) uniformly in ±spread (A), seeded by ``seed_key`` (uint32; numba's
    per-thread generator is re-seeded, so a chunk depends on its key only). direction ≠ 0 (the
    sign of the move): the first and last currents oppose the move; and with mid_hi > 0 the
    inner currents push the move, direction·U(mid_lo, mid_hi) A (long moves)."""
    np.random.seed(seed_key)
    m, n = starts.shape
    for s in range(m):
        for j in range(n):
            starts[s, j] = np.random.uniform(-spread, spread)
        if direction != 0.0 and n >= 2:
            starts[s, 0] = -direction * abs(starts[s, 0])
            starts[s, n - 1] = -direction * abs(starts[s, n - 1])
            if mid_hi > 0.0:
                for j in range(1, n - 1):
                    starts[s, j] = direction * np.random.uniform(mid_lo, mid_hi)


@njit(cache=True, nogil=True)
def plan_chunk(J, c, pv, pc, pt, times, tf, q0, goal, umask, pscale, i_max, vb, cfg, seed_key,
               spread, direction, mid_lo, mid_hi, draw, stop_first, changes, starts, st, it, f,
               kk, counts, ver_out):
    """One chunk of the robust-derivative multistart, compiled end to end: draw the starts
    (when ``draw``: ``draw_starts``), run LM from each (``starts`` becomes the end points), and
    — when ``stop_first`` and a start succeeded — verify that plan (``verify_core`` into
    ver_out).

    cfg: [wpen, wq, lam0, tol_q, tol_d, min_kink, max_iter, abandon_iter, abandon_norm,
    max_reject, lam_down, lam_up]. counts (5,) accumulates the status codes.
    Returns (starts run, verified: ver_out holds the verification of starts[done − 1]).
    """
    if draw:
        draw_starts(seed_key, spread, direction, mid_lo, mid_hi, starts)
    n = starts.shape[1]
    W = np.zeros((N_ROWS, 4 + 4 * n))
    done = multistart(J, c, pv, pc, pt, times, tf, q0, goal, umask, pscale, i_max, starts, W,
                      vb, cfg[0], cfg[1], cfg[2], cfg[3], cfg[4], cfg[5], int(cfg[6]),
                      int(cfg[7]), cfg[8], int(cfg[9]), cfg[10], cfg[11], stop_first, st, it, f,
                      kk)
    for s in range(done):
        counts[st[s]] += 1
    if stop_first and done > 0 and st[done - 1] == OK:
        verify_core(J, c, pv, pc, pt, times, starts[done - 1], tf, q0, pscale, changes, W,
                    ver_out)
        return done, True
    return done, False
