"""Exact derivatives of the 1-DOF event-based simulation (forward mode through the event times).

Every quantity of the simulation is carried as a truncated Taylor number in the friction parameters
p = (pv, pc, pt) and the step currents I_1..I_N (A):

    x = x0 + Σ_i x_pi·εp_i + Σ_j x_Ij·εI_j + Σ_ij x_piIj·εp_i·εI_j

i.e. its value, ∂x/∂p (3), ∂x/∂I (N) and the mixed ∂²x/∂p∂I (3×N) — exactly what the robust
optimiser needs: the sensitivities ∂q/∂p and their Jacobian w.r.t. the currents. Event times
(velocity zero crossings) are computed in closed form and carry their derivatives, so nothing is
finite-differenced. Row layout (length L = 4 + 4N): [value, d/dpv, d/dpc, d/dpt, d/dI_0..,
d²/dpv dI_0.., d²/dpc dI_0.., d²/dpt dI_0..]. Rows live in a preallocated workspace W (no
allocation inside the compiled loop); their arithmetic is ``ff_planner.model.taylor``, the
friction law on them ``friction.sliding_level_series``.

The model is non-smooth where a velocity zero crossing meets a current switch, or where a joint at
rest is exactly at breakaway. ``hd_sim`` returns the *kink radius*: a first-order estimate of the
smallest relative change of the uncertain parameters that reaches such a point. Derivatives are
one-sided beyond it; a plan with a small kink radius is not robust on both sides.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ff_planner.model.friction import breakaway_excess, exceeds_stiction, sliding_level_series
from ff_planner.model.series1d import phi12, psi
from ff_planner.model.taylor import NP, row_const, row_copy, row_len, row_lin, row_mul, row_uni

# workspace rows
A_, PC_, PT_, T_, ABST_, F_, B_, TIME_, Q_, V_, TAU_, Z_, P1_, P2_, EZ_, E1_, E2_ = range(17)
TMP1_, TMP2_, TMP3_, RB_, X_, TSTOP_, VC_ = range(17, 24)
N_ROWS = 24


def workspace(n: int) -> np.ndarray:
    """A workspace for N step currents."""
    return np.zeros((N_ROWS, row_len(n)))


@njit("void(float64[:, ::1], int64)", cache=True, nogil=True)
def _free(W, n):
    """(Q, V) ← state after TAU of v' = A·v + B."""
    row_mul(W, Z_, A_, TAU_, n)
    z = W[Z_, 0]
    f1, f1p, f1pp, f2, f2p, f2pp = phi12(z)
    ez = math.exp(z)
    row_uni(W, P1_, Z_, f1, f1p, f1pp, n)
    row_uni(W, P2_, Z_, f2, f2p, f2pp, n)
    row_uni(W, EZ_, Z_, ez, ez, ez, n)
    row_mul(W, E1_, TAU_, P1_, n)
    row_mul(W, E2_, TAU_, TAU_, n)
    row_mul(W, E2_, E2_, P2_, n)
    row_mul(W, TMP1_, V_, E1_, n)
    row_mul(W, TMP2_, B_, E2_, n)
    row_mul(W, TMP3_, V_, EZ_, n)
    row_lin(W, Q_, Q_, TMP1_, 1.0, 1.0, 0.0)
    row_lin(W, Q_, Q_, TMP2_, 1.0, 1.0, 0.0)
    row_mul(W, V_, B_, E1_, n)
    row_lin(W, V_, V_, TMP3_, 1.0, 1.0, 0.0)


@njit("float64(float64[:, ::1], int64)", cache=True, nogil=True)
def _cross_tau(W, n):
    """TAU ← time until V reaches zero under v' = A·v + B; returns its value (inf if never)."""
    v = W[V_, 0]
    b = W[B_, 0]
    if b == 0.0 or b * v >= 0.0:
        return math.inf
    x = v / b
    z = W[A_, 0] * x
    if z <= -1.0:
        return math.inf
    row_uni(W, RB_, B_, 1.0 / b, -1.0 / (b * b), 2.0 / (b * b * b), n)
    row_mul(W, X_, V_, RB_, n)
    row_mul(W, Z_, A_, X_, n)
    g, gp, gpp = psi(W[Z_, 0])
    row_uni(W, TAU_, Z_, g, gp, gpp, n)
    row_mul(W, TAU_, TAU_, X_, n)
    row_lin(W, TAU_, TAU_, TAU_, -1.0, 0.0, 0.0)
    return W[TAU_, 0]


@njit("float64(float64[:, ::1], int64, float64[::1], float64)", cache=True, nogil=True)
def _radius_of(W, r, pw, margin):
    """Relative parameter change (first order) that moves row r's value by ``margin``."""
    s = 0.0
    for i in range(NP):
        s = max(s, abs(W[r, 1 + i] * pw[i]))
    if s == 0.0:
        return math.inf
    return abs(margin) / s


_PHASE_SIG = ("float64(float64[:, ::1], int64, int64, float64, float64, float64, float64, float64, "
              "float64[::1], float64, boolean, boolean)")


@njit(_PHASE_SIG, cache=True, nogil=True)
def _phase(W, n, j, c, J, torque, t_start, t_end, pw, kink, rest_phase, track_end):
    """Advance the Taylor state (TIME, Q, V) under constant torque from t_start until t_end.

    j: index of the step current (−1: zero current). track_end: count a zero crossing near
    t_end (or motion at t_end) as a kink. Returns the updated kink radius.
    """
    row_const(W, T_, torque)
    if j >= 0:
        W[T_, 4 + j] = c
    sliding_level_series(W, F_, T_, PC_, PT_, ABST_, n)   # F = pc + pt·|T| (Eq. 9)
    fric = W[F_, 0]
    gap = breakaway_excess(torque, fric)           # > 0: a joint at rest breaks away
    breaks = exceeds_stiction(torque, fric)
    gscale = max(abs(pw[1]), abs(pw[2]) * abs(torque))
    while W[TIME_, 0] < t_end:
        if W[V_, 0] == 0.0:
            if gscale > 0.0:
                kink = min(kink, abs(gap) / gscale)
            if not breaks:
                row_const(W, TIME_, t_end)            # stuck: q constant until the phase end
                return kink
            s = 1.0 if torque > 0.0 else -1.0
            row_const(W, TSTOP_, math.inf)
        else:
            s = 1.0 if W[V_, 0] > 0.0 else -1.0
        row_lin(W, B_, T_, F_, 1.0 / J, -s / J, 0.0)   # B = (T − s·F)/J
        t_now = W[TIME_, 0]
        at_switch = t_now == t_start
        tau = _cross_tau(W, n)
        if t_now + tau < t_end:
            # velocity zero crossing inside the phase: how far from the switch times?
            if track_end and not math.isinf(t_end):
                row_lin(W, TMP1_, TIME_, TAU_, 1.0, 1.0, 0.0)
                kink = min(kink, _radius_of(W, TMP1_, pw, t_end - (t_now + tau)))
            if at_switch:
                kink = min(kink, _radius_of(W, TAU_, pw, tau))
            _free(W, n)
            row_lin(W, TIME_, TIME_, TAU_, 1.0, 1.0, 0.0)
            row_const(W, V_, 0.0)
            if rest_phase:
                row_copy(W, TSTOP_, TIME_)
                row_const(W, TIME_, t_end)
                return kink
            if gscale > 0.0:
                kink = min(kink, abs(gap) / gscale)
            if not breaks or torque * s >= 0.0:
                row_copy(W, TSTOP_, TIME_)            # sticks until the phase end
                row_const(W, TIME_, t_end)
                return kink
            continue                               # moves on the other way
        if math.isinf(t_end):                      # never stops: signal with nan
            row_const(W, Q_, math.nan)
            row_const(W, V_, math.nan)
            row_const(W, TIME_, t_end)
            return kink
        row_lin(W, TAU_, TIME_, TIME_, -1.0, 0.0, t_end)
        _free(W, n)
        row_const(W, TIME_, t_end)
        if track_end:
            # moving at the switch: a nearby zero crossing would sit on the switch time
            kink = min(kink, _radius_of(W, V_, pw, W[V_, 0]))
    return kink


@njit(cache=True, nogil=True)
def hd_sim(J, c, pv, pc, pt, times, cur, tf, q0, to_rest, pw, W):
    """Forward-mode simulation. Results in W rows Q_ (position), V_ (velocity), TSTOP_, VC_.

    to_rest: the final zero-current phase runs past tf until the arm stops (Q_ = rest position,
    smooth in the parameters); otherwise Q_, V_ are the state at tf. TSTOP_: time the arm came to
    rest for good (value inf while moving). VC_: velocity entering the coast. pw: weights (p_i if
    p_i is uncertain, else 0) for the radii.

    Returns (kink, tf_radius): kink = relative parameter change (first order) that reaches a
    non-smooth point of q (a zero crossing at a switch time, a breakaway edge); tf_radius = the
    change after which the arm is no longer at rest at tf (q(tf) stays C¹ there, q̇(tf) does not;
    the rest position is smooth through it). inf: none nearby.
    """
    return _hd(J, c, pv, pc, pt, times, cur, tf, q0, to_rest, pw, W, cur.shape[0])


@njit(cache=True, nogil=True)
def hd_sim_p(J, c, pv, pc, pt, times, cur, tf, q0, to_rest, pw, W):
    """``hd_sim`` in the friction parameters only (no current columns): W from
    ``workspace(0)``, rows of length 4 = [value, d/dpv, d/dpc, d/dpt]; ~10x cheaper than the
    full rows for N = 12 when only q, ∂q/∂p and v_c are wanted."""
    return _hd(J, c, pv, pc, pt, times, cur, tf, q0, to_rest, pw, W, 0)


@njit(cache=True, nogil=True)
def _hd(J, c, pv, pc, pt, times, cur, tf, q0, to_rest, pw, W, cols):
    """``hd_sim`` with Taylor rows of ``cols`` step currents (0: the friction parameters only)."""
    n = cur.shape[0]
    row_const(W, A_, -pv / J)
    W[A_, 1] = -1.0 / J
    row_const(W, PC_, pc)
    W[PC_, 2] = 1.0
    row_const(W, PT_, pt)
    W[PT_, 3] = 1.0
    row_const(W, TIME_, times[0])
    row_const(W, Q_, q0)
    row_const(W, V_, 0.0)
    row_const(W, TSTOP_, times[0])
    kink = math.inf
    for j in range(n):
        kink = _phase(W, cols, j if cols > 0 else -1, c, J, c * cur[j], times[j], times[j + 1],
                      pw, kink, False, True)
    row_copy(W, VC_, V_)
    tf_radius = math.inf
    if to_rest:
        kink = _phase(W, cols, -1, c, J, 0.0, times[n], math.inf, pw, kink, True, True)
        ts = W[TSTOP_, 0]
        if ts >= tf:
            tf_radius = 0.0
        elif ts > times[n]:
            tf_radius = _radius_of(W, TSTOP_, pw, tf - ts)
    else:
        if tf > times[n]:
            kink = _phase(W, cols, -1, c, J, 0.0, times[n], tf, pw, kink, False, False)
        if W[V_, 0] != 0.0:
            tf_radius = 0.0
        elif W[TSTOP_, 0] > times[n]:
            tf_radius = _radius_of(W, TSTOP_, pw, tf - W[TSTOP_, 0])
    return kink, tf_radius
