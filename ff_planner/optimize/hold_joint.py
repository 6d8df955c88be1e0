"""Holding one SCARA joint in stiction while the other moves as an exact 1-DOF arm.

The toolkit of the held-joint 2-DOF planners (``robust2d``, ``robust2d_sequential``,
``robust2d_refine``): the 1-DOF arm each joint is while the other is held (``joint1_params``,
``joint2_params``), the joint-1 problem with an optional hold condition (``Joint1Problem``:
least squares on [q1(tf) − q1f, ∂q1(tf)/∂p_i, stop inside the coast, hold margin, and, with
``limits``, the moving joint's limit violations at the box corners]), and the
held motor's torque that cancels the moving link's reaction step by step (``hold_torques``,
``joint2_hold_currents``): the midpoint of the reaction's range on each step, which maximises
the stiction margin. The reaction on the held joint is, with d = q1 − q2,

    link 2 held:  R2 = B·cos(d)·q̈1 − B·sin(d)·q̇1²
    joint 1 held: R1 = B·cos(d)·q̈2 + B·sin(d)·q̇2²

and the hold fraction of a phase is (L − max |T_h − R|) / L with the held joint's stiction
level L = pc + pt·|T_h| (1 = unloaded, 0 = on the edge, < 0 = slips). Units: rad, A, Nm, s.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from scipy.optimize import least_squares

from ff_planner.model import arm1dof, scara2
from ff_planner.model.friction import net_torque_array, sliding_level, sliding_level_array, stop_speed
from ff_planner.model.params import Arm1DofParams, Scara2Params
from ff_planner.model.profile import CurrentProfile
from ff_planner.optimize.limits1d import LIMIT_SCALE, Limits1D

STOP_MARGIN = 0.005      # s, final stop at least this far inside the coast (both ends)
HOLD_MIN = 0.25          # aim: joint 2 still holds with its friction 25 % lower
_FD_REL = 1e-5           # relative step of the inner central differences (1-DOF, smooth region)


def joint1_params(p: Scara2Params) -> Arm1DofParams:
    """The 1-DOF arm that joint 1 is while link 2 is held still: J = A, joint-1 motor and friction."""
    return Arm1DofParams(J=scara2.held_joint1_inertia(p), kt=p.kt1, n=p.n1, i_max=p.i_max1,
                         pv=p.pv1, pc=p.pc1, pt=p.pt1)


def joint2_params(p: Scara2Params) -> Arm1DofParams:
    """The 1-DOF arm that link 2 is while joint 1 is held still: J = C, motor-2 and friction."""
    _, _, C = scara2.inertia_constants(p)
    return Arm1DofParams(J=C, kt=p.kt2, n=p.n2, i_max=p.i_max2, pv=p.pv2, pc=p.pc2, pt=p.pt2)


class Joint1Problem:
    """Residuals of the joint-1 problem on a uniform grid of N steps (currents are the unknowns)."""

    def __init__(self, p1: Arm1DofParams, q0: float, qf: float, tf: float, coast: float, N: int,
                 names: tuple[str, ...], p2: Optional[Scara2Params] = None, q2: float = 0.0,
                 hold_min: float = HOLD_MIN, samples: int = 24, held: int = 2,
                 zero_coast: bool = True, limits: Optional[Limits1D] = None):
        self.J, self.c = p1.J, p1.n * p1.kt
        self.fr = {"pv": p1.pv, "pc": p1.pc, "pt": p1.pt}
        self.q0, self.qf, self.tf, self.coast, self.N = q0, qf, tf, coast, N
        self.names = names
        self.limits = limits     # the moving joint's limits as this 1-DOF arm's (None: none)
        self.times = np.linspace(0.0, tf - coast, N + 1)
        self.tN = float(self.times[-1])
        self.v_lo = stop_speed(p1.J, p1.pv, p1.pc, STOP_MARGIN)
        self.v_hi = stop_speed(p1.J, p1.pv, p1.pc, coast - STOP_MARGIN)
        self.seg = np.empty((0, 7))
        self.ev = np.empty((0, 3))
        self.i_max = p1.i_max
        self.p2 = p2
        if p2 is not None:   # sample grid for link 2's holding torque, one-sided inside each step
            self.q2, self.hold_min = q2, hold_min
            ends = np.append(self.times, tf)
            grids, idx = [], []
            for k in range(N + 1):
                g = np.linspace(ends[k], ends[k + 1], samples)
                g[0] += 1e-12
                g[-1] -= 1e-12
                grids.append(g)
                idx.append(np.full(samples, k))
            self.grid = np.concatenate(grids)
            self.gidx = np.concatenate(idx)
            self.starts_idx = np.arange(N + 1) * samples
            self.A, self.B, _ = scara2.inertia_constants(p2)
            # the held joint's motor and stiction (link 2 by default; joint 1 when link 2 moves)
            self.held, self.zero_coast = held, zero_coast
            if held == 2:
                self.K2, self.imax_h, self.pch, self.pth = p2.n2 * p2.kt2, p2.i_max2, p2.pc2, p2.pt2
            else:
                self.K2, self.imax_h, self.pch, self.pth = p2.n1 * p2.kt1, p2.i_max1, p2.pc1, p2.pt1
            self.rseg = np.zeros((3 * (N + 3) + 4, 7))
            self.rev = np.zeros((3 * (N + 3) + 4, 3))

    def hold(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per phase (N steps + coast): the held motor's torque (Nm) = midpoint of the moving
        link's reaction, and the hold fraction (unused stiction / stiction level) of the held joint."""
        _, _, nseg, _ = arm1dof.sim_core(self.J, self.c, self.fr["pv"], self.fr["pc"],
                                         self.fr["pt"], self.times, x, self.tf, self.q0, 0.0,
                                         False, self.rseg, self.rev)
        qs, vs = arm1dof.eval_segments(self.rseg, min(nseg, self.rseg.shape[0]), self.grid)
        T1 = self.c * np.append(x, 0.0)[self.gidx]
        acc = net_torque_array(vs, T1, self.fr["pv"], self.fr["pc"], self.fr["pt"]) / self.J
        if self.held == 2:
            d = qs - self.q2
            R = self.B * np.cos(d) * acc - self.B * np.sin(d) * vs * vs
        else:
            d = self.q2 - qs
            R = self.B * np.cos(d) * acc + self.B * np.sin(d) * vs * vs
        rmin = np.minimum.reduceat(R, self.starts_idx)
        rmax = np.maximum.reduceat(R, self.starts_idx)
        T2 = np.clip(0.5 * (rmin + rmax), -self.K2 * self.imax_h, self.K2 * self.imax_h)
        if self.zero_coast:
            T2[-1] = 0.0
        L2 = sliding_level_array(T2, self.pch, self.pth)
        frac = (L2 - np.maximum(T2 - rmin, rmax - T2)) / L2
        return T2, frac

    def final_state(self, x: np.ndarray, tend: float, pv: float, pc: float, pt: float
                    ) -> tuple[float, float, int, int]:
        """1-DOF simulation of the step currents x (A) to ``tend`` (s) with friction (pv, pc, pt):
        ``arm1dof.sim_core``'s (q (rad), q̇ (rad/s), segments, events)."""
        return arm1dof.sim_core(self.J, self.c, pv, pc, pt, self.times, x, tend, self.q0, 0.0,
                                False, self.seg, self.ev)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """[q(tf) − qf, ∂q(tf)/∂p_i (central differences), stop-speed bounds, hold margins,
        limit violations (rad, rad/s) at ``limits.corners``]."""
        x = np.ascontiguousarray(x, dtype=float)
        pv, pc, pt = self.fr["pv"], self.fr["pc"], self.fr["pt"]
        qT, vT, _, _ = self.final_state(x, self.tf, pv, pc, pt)
        _, vN, _, _ = self.final_state(x, self.tN, pv, pc, pt)
        r = [qT - self.qf]
        for n in self.names:
            h = _FD_REL * abs(self.fr[n])
            fp = dict(self.fr); fp[n] += h
            fm = dict(self.fr); fm[n] -= h
            qp = self.final_state(x, self.tf, fp["pv"], fp["pc"], fp["pt"])[0]
            qm = self.final_state(x, self.tf, fm["pv"], fm["pc"], fm["pt"])[0]
            r.append((qp - qm) / (2.0 * h))
        s = abs(vN)
        r.append(10.0 * max(0.0, self.v_lo - s))
        r.append(10.0 * max(0.0, s - self.v_hi))
        if self.p2 is not None:
            _, frac = self.hold(x)
            r.extend(np.maximum(0.0, self.hold_min - frac))
        if self.limits is not None:
            g = self.limits.values(self.times, x, self.limits.corners) / LIMIT_SCALE
            r.extend(np.maximum(0.0, -g))
        return np.array(r)

    def solve(self, x0: np.ndarray, max_nfev: int = 60) -> tuple[np.ndarray, np.ndarray, int]:
        """Bounded least squares (|I| ≤ i_max) from x0: (currents (A), residuals, evaluations)."""
        res = least_squares(self.residuals, x0, bounds=(-self.i_max, self.i_max), method="dogbox",
                            diff_step=1e-6, xtol=1e-15, ftol=1e-15, gtol=1e-15,
                            max_nfev=max_nfev)
        return res.x, res.fun, res.nfev


# ----------------------------------------------------------------------------------------------
# motor 2: cancel link 1's reaction step by step


def hold_torques(p: Scara2Params, held: int, profile: CurrentProfile, q_moving0: float,
                 q_held: float, samples_per_step: int = 200, zero_coast: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Torques (Nm) for the motor of the HELD joint (1 or 2) that keep it in stiction while the
    other joint runs ``profile`` (its 1-DOF currents; inertia A for joint 1, C for joint 2) from
    rest at ``q_moving0``: per phase (N steps, then the coast) the midpoint of the reaction's
    range, which maximises the margin. Returns (torques (N+1,), hold fractions (N+1,)): unused
    stiction / stiction level per phase (1 = unloaded, 0 = on the edge, < 0 = slips). With
    ``zero_coast`` the coast torque is 0 (the move's final coast)."""
    A, B, C = scara2.inertia_constants(p)
    if held == 2:
        pm = joint1_params(p)
        Kh, imax_h, pch, pth = p.n2 * p.kt2, p.i_max2, p.pc2, p.pt2
    else:
        pm = joint2_params(p)
        Kh, imax_h, pch, pth = p.n1 * p.kt1, p.i_max1, p.pc1, p.pt1
    Km = pm.n * pm.kt
    times = profile.step_times
    N = profile.n_steps
    seg = np.zeros((3 * (N + 3) + 4, 7))
    ev = np.zeros((3 * (N + 3) + 4, 3))
    cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
    _, _, nseg, _ = arm1dof.sim_core(pm.J, Km, pm.pv, pm.pc, pm.pt, times, cur, profile.tf,
                                     float(q_moving0), 0.0, False, seg, ev)
    T = np.zeros(N + 1)
    frac = np.zeros(N + 1)
    for k in range(N + 1):
        t0, t1 = (times[k], times[k + 1]) if k < N else (times[N], profile.tf)
        Tm = Km * cur[k] if k < N else 0.0
        tg = np.linspace(t0, t1, samples_per_step)
        tg[0] += 1e-12          # one-sided limits inside the phase
        tg[-1] -= 1e-12
        qs, vs = arm1dof.eval_segments(seg, min(nseg, seg.shape[0]), tg)
        acc = net_torque_array(vs, Tm, pm.pv, pm.pc, pm.pt) / pm.J
        if held == 2:           # link 2 held: H2 = T2 - (B c a1 - B s v1^2), d = q1 - q2
            d = qs - q_held
            R = B * np.cos(d) * acc - B * np.sin(d) * vs * vs
        else:                   # joint 1 held: H1 = T1 - (B c a2 + B s v2^2), d = q1 - q2
            d = q_held - qs
            R = B * np.cos(d) * acc + B * np.sin(d) * vs * vs
        if k == N and zero_coast:
            Th = 0.0
        else:
            Th = float(np.clip(0.5 * (R.min() + R.max()), -Kh * imax_h, Kh * imax_h))
        L = sliding_level(Th, pch, pth)
        T[k] = Th
        frac[k] = (L - np.max(np.abs(Th - R))) / L
    return T, frac


def joint2_hold_currents(p: Scara2Params, profile1: CurrentProfile, q0: np.ndarray,
                         samples_per_step: int = 200) -> tuple[np.ndarray, float]:
    """Motor-2 currents (A, one per step) that keep link 2 (absolute angle q0[1]) in stiction
    while joint 1 runs ``profile1`` (joint-1 currents only) to the end of the move (zero current
    in the coast), and the smallest hold fraction over the move."""
    T, frac = hold_torques(p, 2, profile1, float(q0[0]), float(q0[1]), samples_per_step)
    return T[:-1] / (p.n2 * p.kt2), float(frac.min())
