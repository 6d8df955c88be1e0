"""The 2-DOF SCARA arm of paper section 4.2 (table 3): dynamics in ABSOLUTE joint angles, an
event-aware compiled simulation with per-joint stick/slip, and exact (complex-step) sensitivities.

Model (derivation in docs/scara2-model.md). q1 = absolute angle of link 1, q2 = ABSOLUTE angle of
link 2 (motor 2 drives it through a parallel mechanism from the base), c = cos(q1 − q2),
s = sin(q1 − q2):

    [ A     B·c ] [q̈1]   [  B·s·q̇2² ]   [T1 − F1]        A = Jc1 + m1·lc1² + m2·l1²
    [ B·c   C   ] [q̈2] + [ −B·s·q̇1² ] = [T2 − F2]        B = m2·l1·lc2
                                                          C = Jc2 + m2·lc2²

T_j = n_j·kt_j·I_j (Nm) and F_j is Eq. 9 friction (``ff_planner.model.friction``) on the
ABSOLUTE velocity q̇_j; no friction acts between the links. Sliding: F_j = pv_j·q̇_j +
sign(q̇_j)·(pc_j + pt_j·|T_j|). Sticking (q̇_j = 0): F_j is whatever torque keeps q̈_j = 0 —
the *holding torque* H_j, computed from the dynamics with the other joint moving (the coupling
reaction included) — and the joint stays stuck while |H_j| ≤ L_j = pc_j + pt_j·|T_j|. So in
Eq. 9's min(pc + pt|T|, |T|)·sign(T), the |T| inside pt·|T| is the joint's own motor torque and
the torque to be balanced is H_j; for one joint alone H = T and this is exactly Eq. 9.

Simulation: classical RK4 on a grid that contains every current switch (default substep 1 ms),
restarted exactly at every event: a sliding joint's velocity reaching zero (it then sticks or
reverses, decided by a consistent mode selection over both joints) and a stuck joint's holding
torque reaching its limit (breakaway). Events are located by bracketed secant iteration on
the RK4 step length, then polished by chord-Newton steps in complex arithmetic, so the event time
is a smooth function of the inputs. Everything runs in complex arithmetic (decisions on real
parts), which gives complex-step derivatives — exact to rounding — of the final state with
respect to friction parameters and currents. Accuracy (tests/ff_planner/model/test_scara2.py): 4th order in the
substep; at 1 ms a profile with 5 stick/reverse events agrees with 0.125 ms to < 1e-9; while a
joint is stuck it stays exactly at rest and the other joint matches the exact 1-DOF solution
(``arm1dof``) to 1e-12, derivatives included.

Units: rad, rad/s, A, Nm, s. No rclpy here.
"""
from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from ff_planner.core.results import SimResult
from ff_planner.model.friction import (exceeds_stiction, friction_torque, sliding_friction, sliding_level,
                                       stiction_margin)
from ff_planner.model.params import ParameterError, Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanningError

__all__ = [
    "FRICTION_NAMES", "inertia_constants", "mass_matrix", "forward_dynamics", "Scara2Sim",
    "simulate_scara2", "rest_position_scara2", "advance", "sensitivities_scara2",
    "sensitivity_keys", "held_joint1_inertia", "DEFAULT_H", "simulate_detail",
    "current_sensitivities_scara2",
]

FRICTION_NAMES = ("pv1", "pc1", "pt1", "pv2", "pc2", "pt2")
DEFAULT_H = 1e-3          # s, RK4 substep
_MAX_EVENTS = 2000        # per simulation; more means chattering (reported as an error)
_CS_STEP = 1e-30          # complex-step size (relative to the parameter value)

# layout of the packed parameter vector P (complex128)
_PV1, _PV2, _PC1, _PC2, _PT1, _PT2, _A, _B, _C, _K1, _K2 = range(11)
_P_INDEX = {"pv1": _PV1, "pv2": _PV2, "pc1": _PC1, "pc2": _PC2, "pt1": _PT1, "pt2": _PT2}


# ----------------------------------------------------------------------------------------------
# model constants


def inertia_constants(p: Scara2Params) -> tuple[float, float, float]:
    """(A, B, C) in kg·m² of the absolute-angle mass matrix [[A, B·c], [B·c, C]]."""
    A = p.Jc1 + p.m1 * p.lc1 ** 2 + p.m2 * p.l1 ** 2
    B = p.m2 * p.l1 * p.lc2
    C = p.Jc2 + p.m2 * p.lc2 ** 2
    return A, B, C


def held_joint1_inertia(p: Scara2Params) -> float:
    """Inertia (kg·m²) joint 1 sees while link 2 is held still by stiction: A = Jc1 + m1·lc1² + m2·l1²."""
    return inertia_constants(p)[0]


def mass_matrix(p: Scara2Params, q: Sequence[float]) -> np.ndarray:
    """2×2 mass matrix (kg·m²) at absolute joint angles q (rad)."""
    A, B, C = inertia_constants(p)
    c = math.cos(q[0] - q[1])
    return np.array([[A, B * c], [B * c, C]])


def _pack(p: Scara2Params, overrides: Optional[dict] = None) -> np.ndarray:
    A, B, C = inertia_constants(p)
    P = np.array([p.pv1, p.pv2, p.pc1, p.pc2, p.pt1, p.pt2, A, B, C,
                  p.n1 * p.kt1, p.n2 * p.kt2], dtype=np.complex128)
    if overrides:
        for k, v in overrides.items():
            P[_P_INDEX[k]] = v
    return P


# ----------------------------------------------------------------------------------------------
# compiled core (complex128 throughout; branch decisions on real parts)


@njit(cache=True)
def _accel(y, T1, T2, s1, s2, st1, st2, P):
    """Accelerations and holding torques for a fixed mode.

    y = (q1, q2, qd1, qd2); s_j = sliding direction (±1); st_j = stuck flag.
    Returns (a1, a2, H1, H2, L1, L2): H_j = friction needed to hold a stuck joint (0 if sliding),
    L_j = pc_j + pt_j·|T_j| the stiction/sliding level.
    """
    pv1 = P[0]; pv2 = P[1]; pc1 = P[2]; pc2 = P[3]; pt1 = P[4]; pt2 = P[5]
    A = P[6]; B = P[7]; C = P[8]
    L1 = sliding_level(T1, pc1, pt1)
    L2 = sliding_level(T2, pc2, pt2)
    d = y[0] - y[1]
    c = np.cos(d)
    s = np.sin(d)
    qd1 = y[2]
    qd2 = y[3]
    zero = 0.0 * T1
    if (not st1) and (not st2):
        F1 = sliding_friction(qd1, s1, T1, pv1, pc1, pt1)
        F2 = sliding_friction(qd2, s2, T2, pv2, pc2, pt2)
        r1 = T1 - F1 - B * s * qd2 * qd2
        r2 = T2 - F2 + B * s * qd1 * qd1
        det = A * C - B * B * c * c
        a1 = (C * r1 - B * c * r2) / det
        a2 = (A * r2 - B * c * r1) / det
        return a1, a2, zero, zero, L1, L2
    elif st2 and (not st1):
        F1 = sliding_friction(qd1, s1, T1, pv1, pc1, pt1)
        a1 = (T1 - F1 - B * s * qd2 * qd2) / A
        H2 = T2 - B * c * a1 + B * s * qd1 * qd1
        return a1, zero, zero, H2, L1, L2
    elif st1 and (not st2):
        F2 = sliding_friction(qd2, s2, T2, pv2, pc2, pt2)
        a2 = (T2 - F2 + B * s * qd1 * qd1) / C
        H1 = T1 - B * c * a2 - B * s * qd2 * qd2
        return zero, a2, H1, zero, L1, L2
    else:
        H1 = T1 - B * s * qd2 * qd2
        H2 = T2 + B * s * qd1 * qd1
        return zero, zero, H1, H2, L1, L2


@njit(cache=True)
def _rk4(y, dt, T1, T2, s1, s2, st1, st2, P):
    k = np.empty((4, 4), dtype=np.complex128)
    yt = y.copy()
    for stage in range(4):
        if stage == 0:
            for i in range(4):
                yt[i] = y[i]
        else:
            f = 0.5 if stage < 3 else 1.0
            for i in range(4):
                yt[i] = y[i] + f * dt * k[stage - 1, i]
        a1, a2, H1, H2, L1, L2 = _accel(yt, T1, T2, s1, s2, st1, st2, P)
        k[stage, 0] = yt[2]
        k[stage, 1] = yt[3]
        k[stage, 2] = a1
        k[stage, 3] = a2
    out = np.empty(4, dtype=np.complex128)
    for i in range(4):
        out[i] = y[i] + dt / 6.0 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])
    if st1:
        out[2] = 0.0 * out[2]
    if st2:
        out[3] = 0.0 * out[3]
    return out


@njit(cache=True)
def _event_g(kind, j, sgn, y, T1, T2, s1, s2, st1, st2, P):
    """Event function, > 0 before the event: kind 0 = sliding velocity sgn·qd_j, kind 1 = stick
    margin L_j − sgn·H_j of a stuck joint."""
    if kind == 0:
        return sgn * y[2 + j]
    a1, a2, H1, H2, L1, L2 = _accel(y, T1, T2, s1, s2, st1, st2, P)
    if j == 0:
        return stiction_margin(H1, L1, sgn)
    return stiction_margin(H2, L2, sgn)


@njit(cache=True)
def _locate(kind, j, sgn, y, dt, T1, T2, s1, s2, st1, st2, P):
    """Fraction theta in (0, 1] (complex: its imaginary part carries derivatives) of the RK4 step
    dt at which the event function crosses zero: secant iteration, bracketed on real parts."""
    lo = 0.0
    hi = 1.0
    g_lo = _event_g(kind, j, sgn, y, T1, T2, s1, s2, st1, st2, P)
    g_hi = _event_g(kind, j, sgn, _rk4(y, dt, T1, T2, s1, s2, st1, st2, P),
                    T1, T2, s1, s2, st1, st2, P)
    # real bracketing phase (Illinois)
    glo = g_lo.real
    ghi = g_hi.real
    side = 0
    th = 1.0
    for _it in range(200):
        if ghi == glo:
            th = 0.5 * (lo + hi)
        else:
            th = (lo * ghi - hi * glo) / (ghi - glo)
        if not (lo < th < hi):
            th = 0.5 * (lo + hi)
        g = _event_g(kind, j, sgn, _rk4(y, th * dt, T1, T2, s1, s2, st1, st2, P),
                     T1, T2, s1, s2, st1, st2, P).real
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
    # complex chord (Newton) polish from the converged real root: the real part stays put and the
    # imaginary part (derivatives) converges by a factor ~1e-7 per iteration
    x = 0.5 * (lo + hi) + 0.0j
    dl = 1e-7 if x.real > 0.5 else -1e-7
    ga = _event_g(kind, j, sgn, _rk4(y, (x.real + dl) * dt, T1, T2, s1, s2, st1, st2, P),
                  T1, T2, s1, s2, st1, st2, P).real
    gb = _event_g(kind, j, sgn, _rk4(y, (x.real - dl) * dt, T1, T2, s1, s2, st1, st2, P),
                  T1, T2, s1, s2, st1, st2, P).real
    slope = (ga - gb) / (2.0 * dl)
    x1 = x
    if slope != 0.0:
        for _it in range(3):
            g = _event_g(kind, j, sgn, _rk4(y, x1 * dt, T1, T2, s1, s2, st1, st2, P),
                         T1, T2, s1, s2, st1, st2, P)
            x1 = x1 - g / slope
    th_c = x1
    if th_c.real <= 0.0:
        th_c = 1e-300 + 0.0j * th_c
    if th_c.real > 1.0:
        th_c = 1.0 + 0.0j * th_c
    return th_c


@njit(cache=True)
def _select_mode(y, T1, T2, zero1, zero2, st1, st2, s1, s2, P):
    """Consistent stick/slip choice for the joints at zero velocity (zero_j true).

    Preference: stick, then slide in the direction of the holding torque, then the other one.
    A stuck joint needs |H_j| <= L_j; a joint starting to slide in direction d needs d·a_j > 0.
    Returns (st1, st2, s1, s2).
    """
    opts1 = 3 if zero1 else 1
    opts2 = 3 if zero2 else 1
    for o1 in range(opts1):
        for o2 in range(opts2):
            c_st1 = st1
            c_s1 = s1
            c_st2 = st2
            c_s2 = s2
            if zero1:
                c_st1 = o1 == 0
                if o1 > 0:
                    c_s1 = 1.0 if o1 == 1 else -1.0
            if zero2:
                c_st2 = o2 == 0
                if o2 > 0:
                    c_s2 = 1.0 if o2 == 1 else -1.0
            a1, a2, H1, H2, L1, L2 = _accel(y, T1, T2, c_s1, c_s2, c_st1, c_st2, P)
            ok = True
            if zero1:
                if c_st1:
                    ok = ok and not exceeds_stiction(H1, L1)
                else:
                    ok = ok and (c_s1 * a1.real > 0.0)
            if zero2:
                if c_st2:
                    ok = ok and not exceeds_stiction(H2, L2)
                else:
                    ok = ok and (c_s2 * a2.real > 0.0)
            if ok:
                return c_st1, c_st2, c_s1, c_s2
    # no consistent mode (should not happen for a positive-definite mass matrix): slide freely
    a1, a2, H1, H2, L1, L2 = _accel(y, T1, T2, s1, s2, False, False, P)
    r_s1 = s1
    r_s2 = s2
    if zero1:
        r_s1 = 1.0 if a1.real >= 0.0 else -1.0
    if zero2:
        r_s2 = 1.0 if a2.real >= 0.0 else -1.0
    return False, False, r_s1, r_s2


@njit(cache=True)
def _set_mode(y, T1, T2, z1, z2, st, sd, P):
    """The consistent stuck / sliding mode under torques T1, T2 (``_select_mode``; z1, z2: joint
    at zero velocity) into st / sd in place; a stuck joint's velocity (rad/s) set to 0 in y."""
    a, b, c1, c2 = _select_mode(y, T1, T2, z1, z2, st[0], st[1], sd[0], sd[1], P)
    st[0] = a
    st[1] = b
    sd[0] = c1
    sd[1] = c2
    if st[0]:
        y[2] = 0.0 * y[2]
    if st[1]:
        y[3] = 0.0 * y[3]


@njit(cache=True)
def _record(t, y, code, rec_t, rec_y, rec_i, nrec, counters):
    """Append (t s, y, ``code``) to the record while it has room (counters[1] = entries so far)."""
    if counters[1] < nrec:
        k = counters[1]
        rec_t[k] = t.real
        for m in range(4):
            rec_y[k, m] = y[m].real
        rec_i[k] = code
        counters[1] += 1


@njit(cache=True)
def _segment(y, t, t_end, T1, T2, st, sd, P, h, rec, rec_t, rec_y, rec_i, nrec, counters,
             stop_at_rest):
    """Integrate from t to t_end (real) under constant torques T1, T2. st/sd: stuck flags and
    sliding directions (arrays of 2, updated in place). counters[0] = events so far.
    Returns (y, t)."""
    # modes at the segment start (torques changed)
    z1 = st[0] or y[2].real == 0.0
    z2 = st[1] or y[3].real == 0.0
    if z1 or z2:
        _set_mode(y, T1, T2, z1, z2, st, sd, P)
    span = t_end - t.real
    if span <= 0.0:
        return y, t
    nsub = int(math.ceil(span / h - 1e-9))
    if nsub < 1:
        nsub = 1
    hh = span / nsub
    t0 = t.real
    for i in range(1, nsub + 1):
        t_grid = t0 + i * hh if i < nsub else t_end
        while True:
            if stop_at_rest and st[0] and st[1]:
                return y, t
            dt = t_grid - t
            if dt.real <= 0.0:
                break
            y1 = _rk4(y, dt, T1, T2, sd[0], sd[1], st[0], st[1], P)
            # a joint that just left rest must keep its direction over the step: if it comes
            # back through zero within the step, shorten the step until it does not (the
            # crossing is then caught as an ordinary event from a nonzero velocity)
            shrink = 0
            for j in range(2):
                while ((not st[j]) and y[2 + j].real == 0.0 and sd[j] * y1[2 + j].real < 0.0
                       and shrink < 60):
                    dt = 0.5 * dt
                    shrink += 1
                    y1 = _rk4(y, dt, T1, T2, sd[0], sd[1], st[0], st[1], P)
            # earliest event in this step
            best = 2.0
            bth = 1.0 + 0.0j
            bkind = -1
            bj = -1
            bsgn = 1.0
            for j in range(2):
                if st[j]:
                    a1, a2, H1, H2, L1, L2 = _accel(y1, T1, T2, sd[0], sd[1], st[0], st[1], P)
                    H = H1 if j == 0 else H2
                    L = L1 if j == 0 else L2
                    if exceeds_stiction(H, L):
                        sg = 1.0 if H.real > 0.0 else -1.0
                        th = _locate(1, j, sg, y, dt, T1, T2, sd[0], sd[1], st[0], st[1], P)
                        if th.real < best:
                            best = th.real
                            bkind = 1
                            bj = j
                            bsgn = sg
                            bth = th
                else:
                    if sd[j] * y1[2 + j].real <= 0.0 and sd[j] * y[2 + j].real > 0.0:
                        th = _locate(0, j, sd[j], y, dt, T1, T2, sd[0], sd[1], st[0], st[1], P)
                        if th.real < best:
                            best = th.real
                            bkind = 0
                            bj = j
                            bsgn = sd[j]
                            bth = th
            if bkind < 0:
                y = y1
                t = t + dt
                if rec:
                    _record(t, y, 0, rec_t, rec_y, rec_i, nrec, counters)
                break
            counters[0] += 1
            if counters[0] > _MAX_EVENTS:
                return y, t
            y = _rk4(y, bth * dt, T1, T2, sd[0], sd[1], st[0], st[1], P)
            t = t + bth * dt
            if bkind == 0:
                y[2 + bj] = 0.0 * y[2 + bj]
                st[bj] = True
            else:   # breakaway: the joint slides off in the direction of its holding torque
                st[bj] = False
                sd[bj] = bsgn
            _set_mode(y, T1, T2, st[0], st[1], st, sd, P)
            if rec:
                # 30 + j: breakaway of joint j, 10 + j: it stuck, 20 + j: it slid on
                code = 30 + bj if bkind == 1 else (10 + bj if st[bj] else 20 + bj)
                _record(t, y, code, rec_t, rec_y, rec_i, nrec, counters)
    return y, t


@njit(cache=True)
def _simulate(P, step_times, currents, tf, y0, h, rec, nrec, settle, settle_max):
    """Whole move: currents[k] (complex, A) on [step_times[k], step_times[k+1]), zero until tf;
    with settle, continue with zero current until both joints stick (at most settle_max s).
    Returns (y_tf, y_rest, t_rest, n_events, rec_t, rec_y, rec_i, n_rec, sticks_tf, error)."""
    y = y0.copy()
    st = np.zeros(2, dtype=np.bool_)
    sd = np.ones(2)
    for j in range(2):
        if y[2 + j].real == 0.0:
            st[j] = True
        else:
            sd[j] = 1.0 if y[2 + j].real > 0.0 else -1.0
    counters = np.zeros(2, dtype=np.int64)
    rec_t = np.zeros(nrec)
    rec_y = np.zeros((nrec, 4))
    rec_i = np.zeros(nrec, dtype=np.int64)
    t = 0.0 + 0.0j
    K1 = P[9]
    K2 = P[10]
    if rec:
        _record(t, y, 0, rec_t, rec_y, rec_i, nrec, counters)
    N = currents.shape[0]
    for k in range(N):
        y, t = _segment(y, t, step_times[k + 1], K1 * currents[k, 0], K2 * currents[k, 1],
                        st, sd, P, h, rec, rec_t, rec_y, rec_i, nrec, counters, False)
        if counters[0] > _MAX_EVENTS:
            break
    zc = 0.0 * K1
    if counters[0] <= _MAX_EVENTS:
        y, t = _segment(y, t, tf, zc, zc, st, sd, P, h, rec, rec_t, rec_y, rec_i, nrec,
                        counters, False)
    y_tf = y.copy()
    stf = np.zeros(2, dtype=np.bool_)
    stf[0] = st[0]
    stf[1] = st[1]
    t_rest = tf + 0.0j
    if settle and counters[0] <= _MAX_EVENTS:
        if st[0] and st[1]:
            t_rest = tf + 0.0j
        else:
            y, t = _segment(y, t, tf + settle_max, zc, zc, st, sd, P, h, rec, rec_t, rec_y,
                            rec_i, nrec, counters, True)
            t_rest = t
    err = 0
    if counters[0] > _MAX_EVENTS:
        err = 1
    elif settle and not (st[0] and st[1]):
        err = 2
    return y_tf, y, t_rest, counters[0], rec_t, rec_y, rec_i, counters[1], stf, err


# ----------------------------------------------------------------------------------------------
# public API


@dataclass
class Scara2Sim:
    """Result of a 2-DOF simulation (rad, rad/s, s). ``stuck_tf``: which joints stick at tf."""

    q_f: np.ndarray
    qd_f: np.ndarray
    q_rest: Optional[np.ndarray] = None
    t_rest: Optional[float] = None
    stuck_tf: tuple[bool, bool] = (False, False)
    n_events: int = 0
    t: Optional[np.ndarray] = None
    q: Optional[np.ndarray] = None
    qd: Optional[np.ndarray] = None
    current: Optional[np.ndarray] = None
    # per record: 0 grid; 10+j stick, 20+j reverse, 30+j breakaway of joint j (0-based)
    event_kind: Optional[np.ndarray] = None


def _check_inputs(params, profile: CurrentProfile, q0, qd0):
    if not isinstance(params, Scara2Params):
        raise ParameterError(f"scara2 simulation needs Scara2Params, got {type(params).__name__}")
    if profile.n_joints != 2:
        raise PlanningError(f"scara2 needs currents for 2 joints, got {profile.n_joints}")
    profile.validate()
    q0 = np.asarray(q0, dtype=float).reshape(-1)
    qd0 = np.zeros(2) if qd0 is None else np.asarray(qd0, dtype=float).reshape(-1)
    if q0.shape != (2,) or qd0.shape != (2,):
        raise PlanningError("q0 and qd0 need 2 values each (rad, rad/s)")
    if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
        raise PlanningError("q0 and qd0 must be finite")
    return q0, qd0


def _run(P, profile: CurrentProfile, y0, h, record=False, settle=False, settle_max=5.0,
         currents=None):
    cur = (np.asarray(profile.currents, dtype=np.complex128) if currents is None
           else np.asarray(currents, dtype=np.complex128))
    st_times = np.asarray(profile.step_times, dtype=float)
    nrec = 1
    if record:
        nrec = int(profile.tf / h) + 4 * profile.n_steps + 64 + (int(settle_max / h) if settle else 0)
        nrec += 2000
    return _simulate(P, st_times, cur, float(profile.tf), np.asarray(y0, dtype=np.complex128),
                     float(h), record, nrec, settle, float(settle_max))


def simulate_scara2(params: Scara2Params, profile: CurrentProfile, q0: Sequence[float],
                    qd0: Optional[Sequence[float]] = None, trajectory: bool = False, *,
                    h: float = DEFAULT_H, settle: bool = False, dt: Optional[float] = None,
                    t_end: Optional[float] = None):
    """Simulate the move; return ff_planner.model.simulate.SimResult (q_f, qd_f at tf; on request the
    trajectory t, q, qd, current, recorded every substep h (≤ 1 ms, or ``dt`` if finer) and at
    every event). ``t_end`` > tf extends the recorded trajectory with zero current. ``settle``:
    also report where the arm comes to rest with zero current after tf (``q_rest``)."""
    q0, qd0 = _check_inputs(params, profile, q0, qd0)
    if dt is not None:
        if not (math.isfinite(float(dt)) and float(dt) > 0.0):
            raise PlanningError(f"dt must be a finite number > 0 s, got {dt}")
        h = min(float(h), float(dt))
    sim = _simulate_raw(params, profile, q0, qd0, trajectory and t_end is None, h=h,
                        settle=settle)
    if trajectory and t_end is not None:
        t_end = float(t_end)
        if not (math.isfinite(t_end) and t_end >= profile.tf):
            raise PlanningError(f"t_end must be >= tf = {profile.tf} s, got {t_end}")
        longer = CurrentProfile(profile.step_times, profile.currents, t_end,
                                t_end - float(profile.step_times[-1]))
        ext = _simulate_raw(params, longer, q0, qd0, True, h=h)
        sim.t, sim.q, sim.qd, sim.current, sim.event_kind = (ext.t, ext.q, ext.qd, ext.current,
                                                             ext.event_kind)
    return _to_simresult(sim, profile)


def simulate_detail(params: Scara2Params, profile: CurrentProfile, q0: Sequence[float],
                    qd0: Optional[Sequence[float]] = None, *, trajectory: bool = False,
                    h: float = DEFAULT_H, settle: bool = False) -> Scara2Sim:
    """The full 2-DOF result (Scara2Sim): final state, which joints stick at tf, the number of
    stick/slip events, with ``settle`` the rest position and time, with ``trajectory`` every
    substep and event (``event_kind``). h: RK4 substep (s)."""
    q0, qd0 = _check_inputs(params, profile, q0, qd0)
    return _simulate_raw(params, profile, q0, qd0, trajectory, h=h, settle=settle)


def _simulate_raw(params, profile, q0, qd0, trajectory=False, *, h=DEFAULT_H, settle=False,
                  overrides=None) -> Scara2Sim:
    P = _pack(params, overrides)
    y0 = np.concatenate([q0, qd0])
    (y_tf, y_r, t_r, nev, rec_t, rec_y, rec_i, nrec, stf, err) = _run(
        P, profile, y0, h, record=trajectory, settle=settle)
    if err == 1:
        raise PlanningError(f"scara2 simulation chattered: more than {_MAX_EVENTS} stick/slip "
                            "events; use smaller currents or a finer substep", "INTERNAL_ERROR")
    out = Scara2Sim(q_f=y_tf[:2].real.copy(), qd_f=y_tf[2:].real.copy(),
                    stuck_tf=(bool(stf[0]), bool(stf[1])), n_events=int(nev))
    if settle:
        out.q_rest = y_r[:2].real.copy()
        out.t_rest = float(t_r.real)
        if err == 2:
            out.t_rest = math.inf
    if trajectory:
        n = int(nrec)
        out.t = rec_t[:n].copy()
        out.q = rec_y[:n, :2].copy()
        out.qd = rec_y[:n, 2:].copy()
        out.event_kind = rec_i[:n].copy()
        out.current = np.array([profile.current_at(tt) if tt < profile.tf else np.zeros(2)
                                for tt in out.t]).reshape(-1, 2)
        # the record at a switch time belongs to the step that ends there: show the new current
    return out


def _to_simresult(sim: Scara2Sim, profile: CurrentProfile) -> SimResult:
    """The model-independent SimResult of a scara2 simulation (events named stick1, reverse2, ...)."""
    events: list = []
    if sim.t is not None and sim.event_kind is not None:
        kinds = {1: "stick", 2: "reverse", 3: "breakaway"}
        events = [(float(tt), f"{kinds[int(kk) // 10]}{int(kk) % 10 + 1}")
                  for tt, kk in zip(sim.t, sim.event_kind) if kk]
    return SimResult(q_f=sim.q_f, qd_f=sim.qd_f, t=sim.t, q=sim.q, qd=sim.qd, current=sim.current,
                     events=events)


def rest_position_scara2(params: Scara2Params, profile: CurrentProfile, q0: Sequence[float],
                         qd0: Optional[Sequence[float]] = None, *, h: float = DEFAULT_H) -> np.ndarray:
    """Where the arm comes to rest (rad) when the current stays zero after tf; nan for a joint
    still moving 5 s after tf."""
    q0, qd0 = _check_inputs(params, profile, q0, qd0)
    sim = _simulate_raw(params, profile, q0, qd0, settle=True, h=h)
    if sim.q_rest is None or sim.t_rest is None or not math.isfinite(sim.t_rest):
        return np.full(2, np.nan)
    return sim.q_rest


@dataclass
class Scara2Track:
    """Where a SCARA move takes the arm from t = 0 until both links rest (zero current after
    tf): rest position (rad, None if it has not stopped ``settle_max`` s after tf), whether both
    joints stick at tf, and per joint the lowest / highest position (rad) and the peak |speed|
    (rad/s). Positions and speeds are taken at every RK4 substep and every stick/slip event
    (position extremes sit at velocity zero crossings, which are events)."""

    q_rest: Optional[np.ndarray]
    stuck_tf: tuple[bool, bool]
    q_min: np.ndarray
    q_max: np.ndarray
    speed: np.ndarray


def track_scara2(params: Scara2Params, profile: CurrentProfile, q0: Sequence[float], *,
                 h: float = DEFAULT_H, settle_max: float = 5.0) -> Scara2Track:
    """Simulate to rest and report the excursion (``Scara2Track``); PlanningError when the
    simulation chatters."""
    q0a, qd0 = _check_inputs(params, profile, q0, None)
    P = _pack(params)
    (_, y_r, t_r, _, _, rec_y, _, nrec, stf, err) = _run(
        P, profile, np.concatenate([q0a, qd0]), h, record=True, settle=True,
        settle_max=settle_max)
    if err == 1:
        raise PlanningError(f"scara2 simulation chattered: more than {_MAX_EVENTS} stick/slip "
                            "events; use smaller currents or a finer substep", "INTERNAL_ERROR")
    ys = rec_y[:int(nrec)]
    q_rest = y_r[:2].real.copy() if err == 0 else None
    pos = np.vstack([ys[:, :2], y_r[:2].real.reshape(1, 2)])
    return Scara2Track(q_rest=q_rest, stuck_tf=(bool(stf[0]), bool(stf[1])),
                       q_min=pos.min(axis=0), q_max=pos.max(axis=0),
                       speed=np.abs(ys[:, 2:]).max(axis=0))


def advance(params: Scara2Params, q: Sequence[float], qd: Sequence[float],
            currents: Sequence[float], dt: float, *, h: float = DEFAULT_H) -> tuple[np.ndarray, np.ndarray]:
    """State (rad, rad/s) after dt s of constant motor currents (A) from (q, qd): the drive
    emulator's physics step. Same model and event handling as simulate_scara2."""
    dt = float(dt)
    if not (math.isfinite(dt) and dt >= 0.0):
        raise PlanningError(f"dt must be a finite number >= 0 s, got {dt}")
    cur = np.asarray(currents, dtype=float).reshape(1, 2)
    y0 = np.concatenate([np.asarray(q, float).reshape(2), np.asarray(qd, float).reshape(2)])
    if not np.all(np.isfinite(y0)) or not np.all(np.isfinite(cur)):
        raise PlanningError("state and currents must be finite")
    if dt == 0.0:
        return y0[:2].copy(), y0[2:].copy()
    P = _pack(params)
    out = _simulate(P, np.array([0.0, dt]), cur.astype(np.complex128), dt,
                    y0.astype(np.complex128), min(float(h), dt), False, 1, False, 0.0)
    y = out[0]
    return y[:2].real.copy(), y[2:].real.copy()


def sensitivity_keys(names: Sequence[str] = FRICTION_NAMES, rate: bool = False) -> list[str]:
    """Keys of the 2-DOF sensitivities: 'q1/pc2' = ∂q1(tf)/∂pc2 (and 'qd1/pc2' with rate)."""
    out = [f"q{j}/{n}" for n in names for j in (1, 2)]
    if rate:
        out += [f"qd{j}/{n}" for n in names for j in (1, 2)]
    return out


def sensitivities_scara2(params: Scara2Params, profile: CurrentProfile, q0: ArrayLike,
                         names: Sequence[str] = FRICTION_NAMES, method: str = "complex",
                         rel_step: Optional[float] = None, *, h: float = DEFAULT_H,
                         rest: bool = False) -> dict[str, float]:
    """∂q_j(tf)/∂p and ∂q̇_j(tf)/∂p (rad or rad/s per unit of p) for friction parameters ``names``.

    method: "complex" (complex step through the event-aware integrator: exact to rounding for
    the discretised model), "exact" (alias), "central" or "forward" finite differences with a
    relative step (default 1e-6 central, 1e-3 forward = the paper's 0.1 %). ``rest``: also
    'qrest1/pc2' = derivative of the rest position after tf.
    Keys 'q1/pc2', 'q2/pc2', 'qd1/pc2', 'qd2/pc2' (+ 'qrest1/...').
    """
    q0, qd0 = _check_inputs(params, profile, q0, None)
    bad = [n for n in names if n not in FRICTION_NAMES]
    if bad:
        raise ParameterError(f"unknown friction parameter(s) {bad}; choose from {FRICTION_NAMES}")
    y0 = np.concatenate([q0, qd0])
    out: dict[str, float] = {}

    def outputs(P):
        r = _run(P, profile, y0, h, settle=rest)
        if r[-1] == 1:
            raise PlanningError("simulation chattered while computing sensitivities", "INTERNAL_ERROR")
        vals = list(r[0])
        if rest:
            vals += list(r[1][:2])
        return np.array(vals)

    base = _pack(params)
    method = {"exact": "complex"}.get(method, method)
    if method not in ("complex", "central", "forward"):
        raise ParameterError(f"unknown method {method!r}; use complex, central or forward")
    f0 = outputs(base).real if method == "forward" else None
    for n in names:
        i = _P_INDEX[n]
        pval = base[i].real
        scale = abs(pval) if pval != 0.0 else 1.0
        if method == "complex":
            P = base.copy()
            hs = _CS_STEP * scale
            P[i] += 1j * hs
            d = outputs(P).imag / hs
        elif method == "central":
            hs = (rel_step or 1e-6) * scale
            Pp = base.copy(); Pp[i] += hs
            Pm = base.copy(); Pm[i] -= hs
            d = (outputs(Pp).real - outputs(Pm).real) / (2 * hs)
        else:
            hs = (rel_step or 1e-3) * scale
            Pp = base.copy(); Pp[i] += hs
            d = (outputs(Pp).real - f0) / hs
        out[f"q1/{n}"] = float(d[0]); out[f"q2/{n}"] = float(d[1])
        out[f"qd1/{n}"] = float(d[2]); out[f"qd2/{n}"] = float(d[3])
        if rest:
            out[f"qrest1/{n}"] = float(d[4]); out[f"qrest2/{n}"] = float(d[5])
    return out


def current_sensitivities_scara2(params: Scara2Params, profile: CurrentProfile,
                                 q0: Sequence[float], *, h: float = DEFAULT_H) -> np.ndarray:
    """∂(q1, q2, q̇1, q̇2)(tf)/∂I for every step current, (N, 2, 4): entry [k, j] is the
    derivative w.r.t. motor j's current in step k (rad/A, rad/s/A), by complex step through the
    event-aware integrator (from rest at q0)."""
    q0, qd0 = _check_inputs(params, profile, q0, None)
    base = _pack(params)
    y0 = np.concatenate([q0, qd0]).astype(np.complex128)
    out = np.zeros((profile.n_steps, 2, 4))
    for k in range(profile.n_steps):
        for j in range(2):
            cur = profile.currents.astype(np.complex128)
            cur[k, j] += 1j * _CS_STEP
            r = _run(base, profile, y0, h, currents=cur)
            if r[-1] == 1:
                raise PlanningError("simulation chattered while computing sensitivities",
                                    "INTERNAL_ERROR")
            out[k, j] = r[0].imag / _CS_STEP
    return out


def forward_dynamics(params: Scara2Params, q: Sequence[float], qd: Sequence[float],
                     currents: Sequence[float]) -> np.ndarray:
    """Accelerations (rad/s²) with both joints sliding in the direction of their velocity
    (velocities must be nonzero): a reference for tests and documentation."""
    A, B, C = inertia_constants(params)
    q1, q2 = q
    w1, w2 = qd
    T1 = params.n1 * params.kt1 * currents[0]
    T2 = params.n2 * params.kt2 * currents[1]
    F1 = friction_torque(w1, T1, params.pv1, params.pc1, params.pt1)
    F2 = friction_torque(w2, T2, params.pv2, params.pc2, params.pt2)
    c, s = math.cos(q1 - q2), math.sin(q1 - q2)
    M = np.array([[A, B * c], [B * c, C]])
    rhs = np.array([T1 - F1 - B * s * w2 ** 2, T2 - F2 + B * s * w1 ** 2])
    return np.linalg.solve(M, rhs)


def warm_up() -> float:
    """Compile (or load from numba's on-disk cache) every kernel of this module; returns the
    seconds it took. Call at install time or node start so no user request pays for it."""

    t = _time.perf_counter()
    p = Scara2Params()
    prof = CurrentProfile.uniform([[3.0, 1.0], [-2.0, 0.5], [0.0, 0.2]], 0.4)
    _simulate_raw(p, prof, np.array([-0.5, 0.0]), np.zeros(2), trajectory=True, settle=True)
    sensitivities_scara2(p, prof, [-0.5, 0.0], ("pc1",))
    advance(p, [0.0, 0.0], [0.0, 0.0], [1.0, 1.0], 1e-3)
    return _time.perf_counter() - t
