"""Compiled n-joint simulation of an arm from a URDF (``ff_planner.arm.model``) with Eq. 9
friction at every joint, per-joint stick/slip and exact events, and complex-step derivatives.

State y = (θ, θ̇) in motor angles (rad, rad/s). In a mode (set S of stuck joints, sliding
directions s_j of the others, set F):

    M_FF·θ̈_F = T_F − F_F − b_F,   θ̈_S = 0,
    F_j = pv_j·θ̇_j + s_j·(pc_j + pt_j·|T_j|)                       (j ∈ F, Eq. 9 sliding)
    H_j = T_j − b_j − Σ_{l∈F} M_jl·θ̈_l                              (j ∈ S, holding torque)

and a stuck joint stays stuck while |H_j| ≤ L_j = pc_j + pt_j·|T_j| (Eq. 9 at rest, ``friction``).
This is the SCARA model's scheme (``ff_planner.model.scara2``) for any number of joints: classical
RK4 on a grid holding every current switch (substep h), restarted at each event — a sliding
joint's velocity reaching zero (then a consistent mode is chosen over all joints at rest: stick,
else slide along the holding torque, else the other way, first joint first) or a stuck joint's
holding torque reaching its level (breakaway) — located by bracketed secant iteration on the RK4
step length and polished by chord-Newton steps in complex arithmetic, so that event times are
smooth functions of the inputs and the imaginary parts carry complex-step derivatives (exact to
rounding) of the final state and the rest position with respect to friction parameters and
currents. After the last step the motors hold ``i_rest`` (A; zero by default: the arm coasts).

Units: rad, rad/s, A, Nm, s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from numpy.typing import ArrayLike

import numpy as np
from numba import njit

from ff_planner.arm.model import UrdfArm
from ff_planner.core.errors import PlanningError
from ff_planner.model.friction import exceeds_stiction, sliding_friction, sliding_level, stiction_margin
from ff_planner.model.profile import CurrentProfile

DEFAULT_H = 1e-3          # s, RK4 substep
MAX_EVENTS = 4000         # per simulation; more means chattering (an error)
SETTLE_MAX = 5.0          # s after tf to come to rest
_CS_STEP = 1e-30          # complex-step size (relative)

# error codes of the kernel
OK, CHATTER, NOT_AT_REST = 0, 1, 2


@njit(cache=True)
def _accel(y, T, st, sd, G, fr, a, H, L):
    """Accelerations ``a`` (θ̈), holding torques ``H`` (stuck joints, else 0) and levels ``L``
    (in place) in the mode (st, sd) under motor torques T. G = (Pphi, Za, Zb, Ga, Gb, arm)."""
    Pphi, Za, Zb, Ga, Gb, arm = G
    n = T.shape[0]
    zero = 0.0 * T[0]
    phi = np.zeros(n, dtype=np.complex128)
    w = np.zeros(n, dtype=np.complex128)
    for k in range(n):
        for i in range(n):
            if Pphi[k, i] != 0.0:
                phi[k] += Pphi[k, i] * y[i]
                w[k] += Pphi[k, i] * y[n + i]
    Mphi = np.zeros((n, n), dtype=np.complex128)
    cg = np.zeros(n, dtype=np.complex128)
    for k in range(n):
        cg[k] = Ga[k] * np.cos(phi[k]) + Gb[k] * np.sin(phi[k])
        for l in range(n):
            if k == l:
                Mphi[k, l] = Za[k, k] + zero
            else:
                d = phi[k] - phi[l]
                c = np.cos(d)
                s = np.sin(d)
                Mphi[k, l] = Za[k, l] * c - Zb[k, l] * s
                cg[k] += (Za[k, l] * s + Zb[k, l] * c) * w[l] * w[l]
    M = np.zeros((n, n), dtype=np.complex128)
    b = np.zeros(n, dtype=np.complex128)
    for i in range(n):
        for k in range(n):
            if Pphi[k, i] != 0.0:
                b[i] += Pphi[k, i] * cg[k]
        for j in range(n):
            acc = zero
            for k in range(n):
                if Pphi[k, i] != 0.0:
                    for l in range(n):
                        if Pphi[l, j] != 0.0:
                            acc += Pphi[k, i] * Mphi[k, l] * Pphi[l, j]
            M[i, j] = acc
        M[i, i] += arm[i]
    # free set: solve M_FF a_F = r_F by Gaussian elimination (M is positive definite)
    idx = np.zeros(n, dtype=np.int64)
    nf = 0
    for j in range(n):
        L[j] = sliding_level(T[j], fr[1, j], fr[2, j])
        a[j] = zero
        H[j] = zero
        if not st[j]:
            idx[nf] = j
            nf += 1
    if nf > 0:
        Af = np.zeros((nf, nf + 1), dtype=np.complex128)
        for r in range(nf):
            j = idx[r]
            F = sliding_friction(y[n + j], sd[j], T[j], fr[0, j], fr[1, j], fr[2, j])
            Af[r, nf] = T[j] - F - b[j]
            for c2 in range(nf):
                Af[r, c2] = M[j, idx[c2]]
        for p in range(nf):
            for r in range(p + 1, nf):
                f = Af[r, p] / Af[p, p]
                for c2 in range(p, nf + 1):
                    Af[r, c2] -= f * Af[p, c2]
        for p in range(nf - 1, -1, -1):
            acc = Af[p, nf]
            for c2 in range(p + 1, nf):
                acc -= Af[p, c2] * a[idx[c2]]
            a[idx[p]] = acc / Af[p, p]
    for j in range(n):
        if st[j]:
            h = T[j] - b[j]
            for r in range(nf):
                h -= M[j, idx[r]] * a[idx[r]]
            H[j] = h


@njit(cache=True)
def _rk4(y, dt, T, st, sd, G, fr):
    n = T.shape[0]
    m = 2 * n
    k = np.empty((4, m), dtype=np.complex128)
    yt = y.copy()
    a = np.empty(n, dtype=np.complex128)
    H = np.empty(n, dtype=np.complex128)
    L = np.empty(n, dtype=np.complex128)
    for stage in range(4):
        if stage > 0:
            f = 0.5 if stage < 3 else 1.0
            for i in range(m):
                yt[i] = y[i] + f * dt * k[stage - 1, i]
        _accel(yt, T, st, sd, G, fr, a, H, L)
        for i in range(n):
            k[stage, i] = yt[n + i]
            k[stage, n + i] = a[i]
    out = np.empty(m, dtype=np.complex128)
    for i in range(m):
        out[i] = y[i] + dt / 6.0 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])
    for j in range(n):
        if st[j]:
            out[n + j] = 0.0 * out[n + j]
    return out


@njit(cache=True)
def _event_g(kind, j, sgn, y, T, st, sd, G, fr):
    """> 0 before the event: kind 0 = sliding velocity sgn·θ̇_j; kind 1 = stick margin
    L_j − sgn·H_j of a stuck joint."""
    n = T.shape[0]
    if kind == 0:
        return sgn * y[n + j]
    a = np.empty(n, dtype=np.complex128)
    H = np.empty(n, dtype=np.complex128)
    L = np.empty(n, dtype=np.complex128)
    _accel(y, T, st, sd, G, fr, a, H, L)
    return stiction_margin(H[j], L[j], sgn)


@njit(cache=True)
def _locate(kind, j, sgn, y, dt, T, st, sd, G, fr):
    """Fraction θ ∈ (0, 1] (complex: the imaginary part carries derivatives) of the RK4 step dt
    at which the event function crosses zero: Illinois secant on real parts, complex polish."""
    lo = 0.0
    hi = 1.0
    glo = _event_g(kind, j, sgn, y, T, st, sd, G, fr).real
    ghi = _event_g(kind, j, sgn, _rk4(y, dt, T, st, sd, G, fr), T, st, sd, G, fr).real
    side = 0
    for _it in range(200):
        if ghi == glo:
            th = 0.5 * (lo + hi)
        else:
            th = (lo * ghi - hi * glo) / (ghi - glo)
        if not (lo < th < hi):
            th = 0.5 * (lo + hi)
        g = _event_g(kind, j, sgn, _rk4(y, th * dt, T, st, sd, G, fr), T, st, sd, G, fr).real
        if g > 0.0:
            lo = th
            glo = g
            if side == 1:
                ghi *= 0.5
            side = 1
        elif g < 0.0:
            hi = th
            ghi = g
            if side == -1:
                glo *= 0.5
            side = -1
        else:
            lo = th
            hi = th
            break
        if hi - lo < 1e-15:
            break
    x = 0.5 * (lo + hi) + 0.0j
    dl = 1e-7 if x.real > 0.5 else -1e-7
    ga = _event_g(kind, j, sgn, _rk4(y, (x.real + dl) * dt, T, st, sd, G, fr), T, st, sd, G, fr).real
    gb = _event_g(kind, j, sgn, _rk4(y, (x.real - dl) * dt, T, st, sd, G, fr), T, st, sd, G, fr).real
    slope = (ga - gb) / (2.0 * dl)
    x1 = x
    if slope != 0.0:
        for _it in range(3):
            g = _event_g(kind, j, sgn, _rk4(y, x1 * dt, T, st, sd, G, fr), T, st, sd, G, fr)
            x1 = x1 - g / slope
    if x1.real <= 0.0:
        x1 = 1e-300 + 0.0j * x1
    if x1.real > 1.0:
        x1 = 1.0 + 0.0j * x1
    return x1


@njit(cache=True)
def _set_mode(y, T, zero, st, sd, G, fr):
    """Consistent stuck / sliding choice for the joints at zero velocity (``zero``), in place in
    st / sd: stick, then slide along +, then −, the first joint varying slowest (the SCARA
    model's order). A stuck joint needs |H_j| ≤ L_j, a starting one s_j·θ̈_j > 0. Stuck
    velocities are set to 0 in y."""
    n = T.shape[0]
    nz = 0
    for j in range(n):
        if zero[j]:
            nz += 1
    a = np.empty(n, dtype=np.complex128)
    H = np.empty(n, dtype=np.complex128)
    L = np.empty(n, dtype=np.complex128)
    c_st = st.copy()
    c_sd = sd.copy()
    total = 3 ** nz
    found = False
    for combo in range(total):
        pos = 0
        for j in range(n):
            if zero[j]:
                o = (combo // 3 ** (nz - 1 - pos)) % 3
                pos += 1
                c_st[j] = o == 0
                if o > 0:
                    c_sd[j] = 1.0 if o == 1 else -1.0
                else:
                    c_sd[j] = sd[j]
            else:
                c_st[j] = st[j]
                c_sd[j] = sd[j]
        _accel(y, T, c_st, c_sd, G, fr, a, H, L)
        ok = True
        for j in range(n):
            if zero[j]:
                if c_st[j]:
                    ok = ok and not exceeds_stiction(H[j], L[j])
                else:
                    ok = ok and (c_sd[j] * a[j].real > 0.0)
        if ok:
            found = True
            break
    if not found:   # no consistent mode (not for a positive-definite mass matrix): slide freely
        for j in range(n):
            c_st[j] = False if zero[j] else st[j]
            c_sd[j] = sd[j]
        _accel(y, T, c_st, c_sd, G, fr, a, H, L)
        for j in range(n):
            if zero[j]:
                c_sd[j] = 1.0 if a[j].real >= 0.0 else -1.0
    for j in range(n):
        st[j] = c_st[j]
        sd[j] = c_sd[j]
        if st[j]:
            y[n + j] = 0.0 * y[n + j]


@njit(cache=True)
def _note(t, y, code, rec_t, rec_y, rec_i, counters, track):
    """Record (t, y, code) while there is room; update the excursion ``track`` (3, n): lowest,
    highest θ and peak |θ̇| (real parts)."""
    n = track.shape[1]
    for j in range(n):
        v = y[j].real
        if v < track[0, j]:
            track[0, j] = v
        if v > track[1, j]:
            track[1, j] = v
        s = abs(y[n + j].real)
        if s > track[2, j]:
            track[2, j] = s
    k = counters[1]
    if k < rec_t.shape[0]:
        rec_t[k] = t.real
        for m in range(2 * n):
            rec_y[k, m] = y[m].real
        rec_i[k] = code
        counters[1] += 1


@njit(cache=True)
def _segment(y, t, t_end, T, st, sd, G, fr, h, rec_t, rec_y, rec_i, counters, track,
             stop_at_rest):
    """Integrate from t to t_end under constant torques T; st / sd updated in place;
    counters[0] = events so far. Returns (y, t)."""
    n = T.shape[0]
    zero = np.zeros(n, dtype=np.bool_)
    anyz = False
    for j in range(n):
        zero[j] = st[j] or y[n + j].real == 0.0
        anyz = anyz or zero[j]
    if anyz:
        _set_mode(y, T, zero, st, sd, G, fr)
    span = t_end - t.real
    if span <= 0.0:
        return y, t
    nsub = int(math.ceil(span / h - 1e-9))
    if nsub < 1:
        nsub = 1
    hh = span / nsub
    t0 = t.real
    a = np.empty(n, dtype=np.complex128)
    H = np.empty(n, dtype=np.complex128)
    L = np.empty(n, dtype=np.complex128)
    for i in range(1, nsub + 1):
        t_grid = t0 + i * hh if i < nsub else t_end
        while True:
            if stop_at_rest:
                all_st = True
                for j in range(n):
                    all_st = all_st and st[j]
                if all_st:
                    return y, t
            dt = t_grid - t
            if dt.real <= 0.0:
                break
            y1 = _rk4(y, dt, T, st, sd, G, fr)
            shrink = 0
            for j in range(n):
                while ((not st[j]) and y[n + j].real == 0.0 and sd[j] * y1[n + j].real < 0.0
                       and shrink < 60):
                    dt = 0.5 * dt
                    shrink += 1
                    y1 = _rk4(y, dt, T, st, sd, G, fr)
            best = 2.0
            bth = 1.0 + 0.0j
            bkind = -1
            bj = -1
            bsgn = 1.0
            need_h = True
            for j in range(n):
                if st[j]:
                    if need_h:
                        _accel(y1, T, st, sd, G, fr, a, H, L)
                        need_h = False
                    if exceeds_stiction(H[j], L[j]):
                        sg = 1.0 if H[j].real > 0.0 else -1.0
                        th = _locate(1, j, sg, y, dt, T, st, sd, G, fr)
                        if th.real < best:
                            best = th.real
                            bkind = 1
                            bj = j
                            bsgn = sg
                            bth = th
                else:
                    if sd[j] * y1[n + j].real <= 0.0 and sd[j] * y[n + j].real > 0.0:
                        th = _locate(0, j, sd[j], y, dt, T, st, sd, G, fr)
                        if th.real < best:
                            best = th.real
                            bkind = 0
                            bj = j
                            bsgn = sd[j]
                            bth = th
            if bkind < 0:
                y = y1
                t = t + dt
                _note(t, y, 0, rec_t, rec_y, rec_i, counters, track)
                break
            counters[0] += 1
            if counters[0] > MAX_EVENTS:
                return y, t
            y = _rk4(y, bth * dt, T, st, sd, G, fr)
            t = t + bth * dt
            if bkind == 0:
                y[n + bj] = 0.0 * y[n + bj]
                st[bj] = True
            else:
                st[bj] = False
                sd[bj] = bsgn
            for j in range(n):
                zero[j] = st[j]
            _set_mode(y, T, zero, st, sd, G, fr)
            code = 30 + bj if bkind == 1 else (10 + bj if st[bj] else 20 + bj)
            _note(t, y, code, rec_t, rec_y, rec_i, counters, track)
    return y, t


@njit(cache=True)
def simulate_core(G, fr, K, step_times, currents, i_rest, tf, y0, h, settle, settle_max, nrec):
    """Whole move: currents[k] (A, complex) on [step_times[k], step_times[k+1]), ``i_rest``
    until tf and, with ``settle``, after tf until every joint sticks (at most settle_max s).
    Returns (y_tf, y_rest, t_rest, n_events, rec_t, rec_y, rec_i, n_rec, stuck_tf, track, err)."""
    n = K.shape[0]
    y = y0.copy()
    st = np.zeros(n, dtype=np.bool_)
    sd = np.ones(n)
    for j in range(n):
        if y[n + j].real == 0.0:
            st[j] = True
        else:
            sd[j] = 1.0 if y[n + j].real > 0.0 else -1.0
    counters = np.zeros(2, dtype=np.int64)
    rec_t = np.zeros(nrec)
    rec_y = np.zeros((nrec, 2 * n))
    rec_i = np.zeros(nrec, dtype=np.int64)
    track = np.zeros((3, n))
    for j in range(n):
        track[0, j] = math.inf
        track[1, j] = -math.inf
    t = 0.0 + 0.0j
    _note(t, y, 0, rec_t, rec_y, rec_i, counters, track)
    T = np.empty(n, dtype=np.complex128)
    for k in range(currents.shape[0]):
        for j in range(n):
            T[j] = K[j] * currents[k, j]
        y, t = _segment(y, t, step_times[k + 1], T, st, sd, G, fr, h, rec_t, rec_y, rec_i,
                        counters, track, False)
        if counters[0] > MAX_EVENTS:
            break
    for j in range(n):
        T[j] = K[j] * i_rest[j]
    if counters[0] <= MAX_EVENTS:
        y, t = _segment(y, t, tf, T, st, sd, G, fr, h, rec_t, rec_y, rec_i, counters, track,
                        False)
    y_tf = y.copy()
    stf = st.copy()
    t_rest = tf + 0.0j
    if settle and counters[0] <= MAX_EVENTS:
        all_st = True
        for j in range(n):
            all_st = all_st and st[j]
        if not all_st:
            y, t = _segment(y, t, tf + settle_max, T, st, sd, G, fr, h, rec_t, rec_y, rec_i,
                            counters, track, True)
            t_rest = t
    err = OK
    all_st = True
    for j in range(n):
        all_st = all_st and st[j]
    if counters[0] > MAX_EVENTS:
        err = CHATTER
    elif settle and not all_st:
        err = NOT_AT_REST
    return y_tf, y, t_rest, counters[0], rec_t, rec_y, rec_i, counters[1], stf, track, err


# ----------------------------------------------------------------------------------------------


def _geometry(arm: UrdfArm) -> tuple:
    c = arm.constants
    return (np.ascontiguousarray(c.Pphi, float), np.ascontiguousarray(c.Za, float),
            np.ascontiguousarray(c.Zb, float), np.ascontiguousarray(c.Ga, float),
            np.ascontiguousarray(c.Gb, float), np.ascontiguousarray(c.armature, float))


def friction_array(arm: UrdfArm, scale: Optional[np.ndarray] = None) -> np.ndarray:
    """(3, n) complex rows pv, pc, pt, optionally scaled elementwise by ``scale`` (n, 3)."""
    fr = arm.friction if scale is None else arm.friction * np.asarray(scale, float)
    return np.ascontiguousarray(fr.T, dtype=np.complex128)


@dataclass
class ArmSim:
    """Result of a simulation (rad, rad/s, s) in motor angles θ: state at tf, which joints stick
    at tf, events, with ``settle`` the rest position and time (None / inf if not at rest within
    SETTLE_MAX s), the excursion (lowest / highest θ and peak |θ̇| per joint, every substep and
    event), with ``record`` every substep and event (t, q, qd, event codes: 10+j stick,
    20+j reverse, 30+j breakaway of joint j, 0-based)."""

    q_f: np.ndarray
    qd_f: np.ndarray
    stuck_tf: tuple[bool, ...]
    n_events: int
    q_rest: Optional[np.ndarray]
    t_rest: float
    q_min: np.ndarray
    q_max: np.ndarray
    speed: np.ndarray
    t: Optional[np.ndarray] = None
    q: Optional[np.ndarray] = None
    qd: Optional[np.ndarray] = None
    event_kind: Optional[np.ndarray] = None


def _check(arm: UrdfArm, profile: CurrentProfile, q0: ArrayLike,
           qd0: Optional[ArrayLike]) -> tuple[np.ndarray, np.ndarray]:
    n = arm.n
    if profile.n_joints != n:
        raise PlanningError(f"arm '{arm.name}' needs currents for {n} joints, got {profile.n_joints}")
    profile.validate()
    q0a = np.asarray(q0, float).reshape(-1)
    qd0a = np.zeros(n) if qd0 is None else np.asarray(qd0, float).reshape(-1)
    if q0a.shape != (n,) or qd0a.shape != (n,):
        raise PlanningError(f"q0 and qd0 need {n} values each (rad, rad/s)")
    if not (np.all(np.isfinite(q0a)) and np.all(np.isfinite(qd0a))):
        raise PlanningError("q0 and qd0 must be finite")
    return q0a, qd0a


def run(arm: UrdfArm, profile: CurrentProfile, q0: np.ndarray, qd0: Optional[np.ndarray] = None,
        *, fr: Optional[np.ndarray] = None, currents: Optional[np.ndarray] = None,
        i_rest: Optional[np.ndarray] = None, h: float = DEFAULT_H, settle: bool = False,
        record: bool = False, settle_max: float = SETTLE_MAX) -> tuple:
    """The raw kernel call (complex results); ``fr`` (3, n) complex friction, ``currents`` (N, n)
    complex currents override the arm's / the profile's."""
    n = arm.n
    y0 = np.concatenate([np.asarray(q0, float), np.zeros(n) if qd0 is None else np.asarray(qd0, float)])
    cur = profile.currents if currents is None else currents
    ir = np.zeros(n) if i_rest is None else i_rest
    nrec = 1
    if record:
        nrec = int(profile.tf / h) + 4 * profile.n_steps + 2000 + (int(settle_max / h) if settle else 0)
    return simulate_core(_geometry(arm), friction_array(arm) if fr is None else fr,
                         np.ascontiguousarray(arm.torque_per_amp, float),
                         np.ascontiguousarray(profile.step_times, float),
                         np.ascontiguousarray(cur, dtype=np.complex128),
                         np.ascontiguousarray(ir, dtype=np.complex128), float(profile.tf),
                         y0.astype(np.complex128), float(h), bool(settle), float(settle_max), nrec)


def simulate(arm: UrdfArm, profile: CurrentProfile, q0: ArrayLike,
             qd0: Optional[ArrayLike] = None, *, settle: bool = True, record: bool = False,
             h: float = DEFAULT_H, friction_scale: Optional[np.ndarray] = None,
             i_rest: Optional[ArrayLike] = None) -> ArmSim:
    """Simulate a move from (q0, qd0) (motor angles θ, rad, rad/s); ``friction_scale`` (n, 3)
    multiplies the nominal (pv, pc, pt) of each joint. PlanningError if it chatters."""
    q0a, qd0a = _check(arm, profile, q0, qd0)
    fr = None if friction_scale is None else friction_array(arm, friction_scale)
    ir = None if i_rest is None else np.asarray(i_rest, float)
    (y_tf, y_r, t_r, nev, rec_t, rec_y, rec_i, nrec, stf, track, err) = run(
        arm, profile, q0a, qd0a, fr=fr, i_rest=ir, h=h, settle=settle, record=record)
    if err == CHATTER:
        raise PlanningError(f"simulation of arm '{arm.name}' chattered: more than {MAX_EVENTS} "
                            "stick/slip events", "INTERNAL_ERROR")
    n = arm.n
    out = ArmSim(q_f=y_tf[:n].real.copy(), qd_f=y_tf[n:].real.copy(),
                 stuck_tf=tuple(bool(x) for x in stf), n_events=int(nev),
                 q_rest=(y_r[:n].real.copy() if settle and err == OK else None),
                 t_rest=(float(t_r.real) if err == OK else math.inf),
                 q_min=track[0].copy(), q_max=track[1].copy(), speed=track[2].copy())
    if settle and out.q_rest is not None:
        out.q_min = np.minimum(out.q_min, out.q_rest)
        out.q_max = np.maximum(out.q_max, out.q_rest)
    if record:
        k = int(nrec)
        out.t = rec_t[:k].copy()
        out.q = rec_y[:k, :n].copy()
        out.qd = rec_y[:k, n:].copy()
        out.event_kind = rec_i[:k].copy()
    return out


def rest_position(arm: UrdfArm, profile: CurrentProfile, q0: ArrayLike, *,
                  h: float = DEFAULT_H, friction_scale: Optional[np.ndarray] = None,
                  i_rest: Optional[ArrayLike] = None) -> np.ndarray:
    """Where the arm comes to rest (θ, rad) after tf with ``i_rest`` (default zero current); nan
    for every joint if it has not stopped SETTLE_MAX s after tf."""
    sim = simulate(arm, profile, q0, settle=True, h=h, friction_scale=friction_scale,
                   i_rest=i_rest)
    return sim.q_rest if sim.q_rest is not None else np.full(arm.n, np.nan)


def rest_sensitivities(arm: UrdfArm, profile: CurrentProfile, q0: ArrayLike, *,
                       h: float = DEFAULT_H, i_rest: Optional[ArrayLike] = None) -> np.ndarray:
    """∂θ_rest/∂p (n, n, 3): entry [i, j, k] = derivative of joint i's rest angle (rad) with
    respect to joint j's friction parameter k (pv, pc, pt; per unit of it), by complex step
    through the event-aware integrator (exact to rounding for the discretised model)."""
    q0a, qd0a = _check(arm, profile, q0, None)
    n = arm.n
    base = friction_array(arm)
    ir = None if i_rest is None else np.asarray(i_rest, float)
    out = np.zeros((n, n, 3))
    for j in range(n):
        for k in range(3):
            fr = base.copy()
            scale = abs(fr[k, j].real) or 1.0
            hs = _CS_STEP * scale
            fr[k, j] += 1j * hs
            r = run(arm, profile, q0a, qd0a, fr=fr, i_rest=ir, h=h, settle=True)
            if r[-1] != OK:
                raise PlanningError("simulation chattered or did not come to rest while computing "
                                    "sensitivities", "INTERNAL_ERROR")
            out[:, j, k] = r[1][:n].imag / hs
    return out


def warm_up() -> float:
    """Compile (or load from numba's on-disk cache) this module's kernels on a small 2-joint arm
    built without a URDF; returns the seconds it took (call at install time or node start)."""
    import time as _time
    t = _time.perf_counter()
    n = 2
    G = (np.eye(n), np.array([[0.3, 0.2], [0.2, 0.3]]), np.zeros((n, n)), np.zeros(n), np.zeros(n),
         np.zeros(n))
    fr = np.array([[0.01, 0.01], [0.1, 0.1], [0.1, 0.1]], dtype=np.complex128)
    cur = np.array([[1.0, -1.0], [-1.0, 1.0]], dtype=np.complex128)
    simulate_core(G, fr, np.ones(n), np.array([0.0, 0.2, 0.4]), cur, np.zeros(n, dtype=np.complex128),
                  0.5, np.zeros(2 * n, dtype=np.complex128), 1e-3, True, 1.0, 10)
    return _time.perf_counter() - t
