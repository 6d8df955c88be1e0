"""An independent, slow reference simulation of an arm from a URDF, for checks (tests,
benchmarks): Pinocchio's own dynamics at every evaluation (CRBA mass matrix, RNEA bias) instead of
the compiled simulator's fitted planar constants, and an adaptive 8th-order Runge-Kutta (scipy
``solve_ivp``, DOP853, rtol RTOL) with its own event location instead of fixed-step RK4
with secant events. The friction law and the stick/slip rule are Eq. 9 as in ``sim`` (the same
physics, written again here in plain Python): a stuck joint stays while |H_j| ≤ pc_j + pt_j·|T_j|;
a joint whose velocity reaches zero sticks if it can, else slides along its holding torque.
Units: rad, rad/s, A, Nm, s.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np
from scipy.integrate import solve_ivp

from ff_planner.arm.model import UrdfArm
from ff_planner.model.profile import CurrentProfile

RTOL = 1e-9
ATOL = 1e-10
SETTLE_MAX = 5.0
NUDGE = 1e-7            # s stepped over a grazing reversal without events


class _Dyn:
    def __init__(self, arm: UrdfArm, friction: np.ndarray):
        import pinocchio as pin
        self.pin = pin
        self.arm = arm
        self.model = arm.pin_model
        self.data = self.model.createData()  # type: ignore[attr-defined]
        self.Einv = np.linalg.inv(arm.E)
        self.fr = friction     # (n, 3)
        self.K = arm.torque_per_amp
        self.arm_diag = np.diag(arm.constants.armature)
        self.n = arm.n

    def mb(self, th: np.ndarray, thd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """M_θ and b_θ from Pinocchio (q = E⁻¹θ, q̇ = E⁻¹θ̇)."""
        pin = self.pin
        q = self.Einv @ th
        v = self.Einv @ thd
        qc = pin.integrate(self.model, pin.neutral(self.model), q)
        n = self.n
        M = np.asarray(pin.crba(self.model, self.data, qc)).reshape(n, n)
        M = np.triu(M) + np.triu(M, 1).T
        b = np.asarray(pin.rnea(self.model, self.data, qc, v, np.zeros(n))).reshape(n)
        Mt = self.Einv.T @ M @ self.Einv + self.arm_diag
        bt = self.Einv.T @ b
        return Mt, bt

    def accel(self, th, thd, T, stuck, sd):
        """θ̈, holding torques H (stuck joints) and levels L."""
        M, b = self.mb(th, thd)
        pv, pc, pt = self.fr[:, 0], self.fr[:, 1], self.fr[:, 2]
        L = pc + pt * np.abs(T)
        free = ~stuck
        a = np.zeros(self.n)
        if free.any():
            F = pv * thd + sd * L
            r = T - F - b
            a[free] = np.linalg.solve(M[np.ix_(free, free)], r[free])
        H = np.where(stuck, T - b - M @ a, 0.0)
        return a, H, L


def _choose(dyn: _Dyn, th, thd, T, zero, stuck, sd):
    """Mode for the joints in ``zero`` (at zero velocity): first consistent of stick / + / −
    per joint (first joint slowest)."""
    idx = np.flatnonzero(zero)
    for combo in range(3 ** len(idx)):
        st = stuck.copy()
        s = sd.copy()
        digits = [(combo // 3 ** (len(idx) - 1 - p)) % 3 for p in range(len(idx))]
        for j, o in zip(idx, digits):
            st[j] = o == 0
            if o:
                s[j] = 1.0 if o == 1 else -1.0
        a, H, L = dyn.accel(th, np.where(st, 0.0, thd), T, st, s)
        ok = all((abs(H[j]) <= L[j]) if st[j] else (s[j] * a[j] > 0.0) for j in idx)
        if ok:
            return st, s
    st = stuck.copy()
    st[idx] = False
    a, _, _ = dyn.accel(th, thd, T, st, sd)
    s = sd.copy()
    s[idx] = np.where(a[idx] >= 0.0, 1.0, -1.0)
    return st, s


def _stick_event(dyn: _Dyn, j: int, T: np.ndarray, st_c: np.ndarray, sd_c: np.ndarray):
    """L_j − |H_j| of stuck joint j: reaches 0 from above at breakaway."""
    n = dyn.n

    def ev(_t, y):
        _, H, L = dyn.accel(y[:n], y[n:], T, st_c, sd_c)
        return L[j] - abs(H[j])
    ev.terminal = True       # type: ignore[attr-defined]
    ev.direction = -1        # type: ignore[attr-defined]
    return ev


def _slide_event(j: int, n: int, sd_c: np.ndarray):
    """s_j·θ̇_j of sliding joint j: reaches 0 from above when it stops."""
    def ev(_t, y):
        return sd_c[j] * y[n + j]
    ev.terminal = True       # type: ignore[attr-defined]
    ev.direction = -1        # type: ignore[attr-defined]
    return ev


def _segment(dyn: _Dyn, th, thd, t0, t1, T, stuck, sd, stop_at_rest, track):
    n = dyn.n
    zero = stuck | (thd == 0.0)
    if zero.any():
        stuck, sd = _choose(dyn, th, thd, T, zero, stuck, sd)
        thd = np.where(stuck, 0.0, thd)
    t = t0
    stalled = 0
    for _ in range(10000):
        if stop_at_rest and stuck.all():
            return th, thd, t, stuck, sd
        if t >= t1:
            break
        st_c, sd_c = stuck.copy(), sd.copy()

        def rhs(_t, y, st_c=st_c, sd_c=sd_c):
            a, _, _ = dyn.accel(y[:n], y[n:], T, st_c, sd_c)
            return np.concatenate([np.where(st_c, 0.0, y[n:]), a])

        events = []
        for j in range(n):
            events.append(_stick_event(dyn, j, T, st_c, sd_c) if stuck[j] else _slide_event(j, n, sd_c))
        sol = solve_ivp(rhs, (t, t1), np.concatenate([th, thd]), method="DOP853", rtol=RTOL,
                        atol=ATOL, events=events, dense_output=False)
        ys = sol.y
        track[0] = np.minimum(track[0], ys[:n].min(axis=1))
        track[1] = np.maximum(track[1], ys[:n].max(axis=1))
        track[2] = np.maximum(track[2], np.abs(ys[n:]).max(axis=1))
        y = ys[:, -1].copy()
        t = float(sol.t[-1])
        th, thd = y[:n], y[n:]
        if sol.status != 1:
            break
        hit = [j for j in range(n) if len(sol.t_events[j])]
        stalled = stalled + 1 if float(sol.t[-1]) - float(sol.t[0]) < 1e-12 else 0
        if stalled > 1:
            # a grazing reversal: the joint leaves zero speed with an acceleration that changes
            # sign at once, and the integrator finds the zero it starts from again. Step over it
            # (NUDGE s without events), then slide each joint the way it is moving.
            if stalled > 5:
                raise RuntimeError(f"reference simulation stalled at t = {t:.9f} s (joint {hit[0] + 1})")
            t_n = min(t + NUDGE, t1)
            nud = solve_ivp(rhs, (t, t_n), np.concatenate([th, thd]), method="DOP853", rtol=RTOL,
                            atol=ATOL)
            y = nud.y[:, -1].copy()
            t = float(nud.t[-1])
            th, thd = y[:n], y[n:]
            sd = np.where(~stuck & (thd != 0.0), np.sign(thd), sd)
            continue
        j = hit[0]
        if stuck[j]:          # breakaway along the holding torque
            _, H, _ = dyn.accel(th, thd, T, stuck, sd)
            stuck = stuck.copy()
            stuck[j] = False
            sd = sd.copy()
            sd[j] = 1.0 if H[j] > 0.0 else -1.0
            zero = stuck.copy()
        else:                 # velocity reached zero
            thd = thd.copy()
            thd[j] = 0.0
            zero = stuck.copy()
            zero[j] = True
        stuck, sd = _choose(dyn, th, thd, T, zero, stuck, sd)
        thd = np.where(stuck, 0.0, thd)
    return th, thd, t, stuck, sd


def reference_rest(arm: UrdfArm, profile: CurrentProfile, q0: Sequence[float],
                   friction_scale: Optional[np.ndarray] = None,
                   i_rest: Optional[Sequence[float]] = None) -> tuple[np.ndarray, np.ndarray]:
    """(rest position θ (rad, nan if not at rest SETTLE_MAX s after tf), excursion (3, n):
    lowest / highest θ and peak |θ̇| at the integrator's steps)."""
    fr = arm.friction if friction_scale is None else arm.friction * np.asarray(friction_scale)
    dyn = _Dyn(arm, fr)
    n = arm.n
    th = np.asarray(q0, float).copy()
    thd = np.zeros(n)
    stuck = np.ones(n, dtype=bool)
    sd = np.ones(n)
    track = np.vstack([th, th, np.zeros(n)])
    st = profile.step_times
    for k in range(profile.n_steps):
        T = arm.torque_per_amp * profile.currents[k]
        th, thd, _, stuck, sd = _segment(dyn, th, thd, st[k], st[k + 1], T, stuck, sd, False, track)
    T = arm.torque_per_amp * (np.zeros(n) if i_rest is None else np.asarray(i_rest, float))
    th, thd, _, stuck, sd = _segment(dyn, th, thd, st[-1], profile.tf, T, stuck, sd, False, track)
    if not stuck.all():
        th, thd, _, stuck, sd = _segment(dyn, th, thd, profile.tf, profile.tf + SETTLE_MAX, T,
                                         stuck, sd, True, track)
    rest = th if stuck.all() else np.full(n, math.nan)
    return rest, track
