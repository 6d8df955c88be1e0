"""Forward sensitivities of an arm's rest position with respect to its step currents and its
friction parameters, from Pinocchio's analytical RNEA derivatives along the simulated trajectory.

The compiled simulator (``ff_planner.arm.sim``) records every RK4 step and event of the move;
this module replays those steps in real arithmetic and carries the tangent S = ∂y/∂p (2n × P,
y = (θ, θ̇), p = (the N·n step currents, then pv, pc, pt of each joint)) through them:

    RK4 step in a mode (stuck set S, sliding directions s):  the same four stages on (y, S),
        f = (θ̇, θ̈),  M_FF·θ̈_F = T_F − F_F − b_F,  θ̈_S = 0, and its tangent
        M_FF·δθ̈_F = δT_F − δF_F − [∂τ/∂θ·δθ + ∂τ/∂θ̇·δθ̇]_F,
        τ(θ, θ̇, θ̈) = E⁻ᵀ·RNEA(q, q̇, q̈) + armature·θ̈,  ∂RNEA/∂q, ∂RNEA/∂q̇ and M from
        ``pinocchio.computeRNEADerivatives`` at (q, q̇, q̈) = E⁻¹·(θ, θ̇, θ̈);
        δF_j = pv_j·δθ̇_j + θ̇_j·δpv_j + s_j·(δpc_j + |T_j|·δpt_j + pt_j·sgn(T_j)·δT_j)
        (sgn 0 at T_j = 0, where |T| has a kink; the complex step takes +1 there).
    Event at τ_e where g(y, p) = 0 (a sliding velocity reaches zero: g = θ̇_j; a stuck joint
        breaks away: g = L_j − s·H_j, H_j = T_j − τ_j, L_j = pc_j + pt_j·|T_j|):
        δτ_e = −(∂g/∂y·S⁻ + ∂g/∂p) / (∂g/∂y·f⁻),  S⁺ = P·S⁻ + (P·f⁻ − f⁺)·δτ_e,
        P zeroing the velocities of the joints stuck after the event.

The rest position is θ at the last event (every joint stuck), so its derivative is S's θ rows
there. The tangent is that of the RK4 steps with the event times as smooth functions of p
(the complex-step derivatives of ``sim`` differentiate the discrete map exactly; the two differ
by the integrator's truncation error in the event jumps, measured ~1e-6 relative on arm3h).
Units: rad, rad/s, A, Nm, s; currents' columns are step k, joint j at k·n + j.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from ff_planner.arm import sim
from ff_planner.arm.model import UrdfArm
from ff_planner.core.errors import PlanningError
from ff_planner.model.profile import CurrentProfile


@dataclass(frozen=True)
class RestSensitivity:
    """The rest position (θ, rad) of a move and its derivatives: ``d_currents`` (n, N, n):
    ∂θ_rest,i/∂I_k,j (rad/A); ``d_friction`` (n, n, 3): ∂θ_rest,i/∂p_j,k (k: pv, pc, pt; rad
    per unit of the parameter); ``t_rest`` (s) when the last joint stuck; ``steps``: RK4 steps
    replayed."""

    rest: np.ndarray
    d_currents: np.ndarray
    d_friction: np.ndarray
    t_rest: float
    steps: int

    def jacobian_currents(self) -> np.ndarray:
        """∂θ_rest/∂x (n, N·n) for the flat current vector x (step-major, as ``currents.ravel()``)."""
        n = self.rest.shape[0]
        return self.d_currents.reshape(n, -1)


@njit(cache=True)
def _dyn(Pphi, Za, Zb, Ga, Gb, armature, th, thd, T, st, sd, fr):
    """M_θ, b_θ (closed form of ``PlanarConstants``), L and the accelerations a of the mode."""
    n = th.shape[0]
    phi = Pphi @ th
    w = Pphi @ thd
    Mphi = np.empty((n, n))
    cg = np.empty(n)
    for k in range(n):
        cg[k] = Ga[k] * np.cos(phi[k]) + Gb[k] * np.sin(phi[k])
        for m in range(n):
            d = phi[k] - phi[m]
            Mphi[k, m] = Za[k, m] * np.cos(d) - Zb[k, m] * np.sin(d)
            if m != k:
                cg[k] += (Za[k, m] * np.sin(d) + Zb[k, m] * np.cos(d)) * w[m] * w[m]
    M = Pphi.T @ Mphi @ Pphi
    for k in range(n):
        M[k, k] += armature[k]
    b = Pphi.T @ cg
    L = fr[1] + fr[2] * np.abs(T)
    a = np.zeros(n)
    idx = np.where(~st)[0]
    if idx.shape[0] > 0:
        r = T - fr[0] * thd - sd * L - b
        Mf = np.empty((idx.shape[0], idx.shape[0]))
        rf = np.empty(idx.shape[0])
        for u in range(idx.shape[0]):
            rf[u] = r[idx[u]]
            for v in range(idx.shape[0]):
                Mf[u, v] = M[idx[u], idx[v]]
        af = np.linalg.solve(Mf, rf)
        for u in range(idx.shape[0]):
            a[idx[u]] = af[u]
    return M, b, L, a


@njit(cache=True)
def _tan(M, Dq, Dv, T, dT, thd, dy, st, sd, fr, n_cur, fric):
    """δa, δH, δL (n, C) of the tangent dy (2n, C) and dT (n, C) (module docstring)."""
    n = T.shape[0]
    C = dy.shape[1]
    pv = fr[0]
    pt = fr[2]
    dL = np.empty((n, C))
    dF = np.empty((n, C))
    for j in range(n):
        sg = 1.0 if T[j] > 0.0 else (-1.0 if T[j] < 0.0 else 0.0)
        for c in range(C):
            dL[j, c] = pt[j] * sg * dT[j, c]
            dF[j, c] = pv[j] * dy[n + j, c] + sd[j] * dL[j, c]
        if fric:
            base = n_cur + 3 * j
            at = abs(T[j])
            dF[j, base] += thd[j]
            dF[j, base + 1] += sd[j]
            dF[j, base + 2] += sd[j] * at
            dL[j, base + 1] += 1.0
            dL[j, base + 2] += at
    rhs = dT - Dq @ np.ascontiguousarray(dy[:n]) - Dv @ np.ascontiguousarray(dy[n:])
    da = np.zeros((n, C))
    idx = np.where(~st)[0]
    nf = idx.shape[0]
    if nf > 0:
        Mf = np.empty((nf, nf))
        R = np.empty((nf, C))
        for u in range(nf):
            for c in range(C):
                R[u, c] = rhs[idx[u], c] - dF[idx[u], c]
            for v in range(nf):
                Mf[u, v] = M[idx[u], idx[v]]
        X = np.linalg.solve(Mf, R)
        for u in range(nf):
            for c in range(C):
                da[idx[u], c] = X[u, c]
    dH = rhs - M @ da
    return da, dH, dL


class _Tangent:
    """Accelerations and their tangent in one mode (see the module docstring)."""

    def __init__(self, arm: UrdfArm, fr: np.ndarray, n_cols: int, n_cur: int):
        import pinocchio as pin
        self.pin = pin
        self.arm = arm
        self.n = arm.n
        self.fr = np.ascontiguousarray(fr, float)    # (3, n) real: pv, pc, pt rows
        self.model = arm.pin_model
        self.data = self.model.createData()  # type: ignore[attr-defined]
        self.Einv = np.linalg.inv(arm.E)
        self.EinvT = np.ascontiguousarray(self.Einv.T)
        c = arm.constants
        self.G = tuple(np.ascontiguousarray(x, float) for x in (c.Pphi, c.Za, c.Zb, c.Ga, c.Gb,
                                                                  c.armature))
        self.P = n_cols
        self.n_cur = n_cur
        self.plain = self.model.nq == self.model.nv  # type: ignore[attr-defined]
        self.identity = bool(np.array_equal(arm.E, np.eye(arm.n)))

    def _config(self, theta: np.ndarray) -> np.ndarray:
        q = self.Einv @ theta
        if self.plain:
            return q
        pin = self.pin
        return pin.integrate(self.model, pin.neutral(self.model), q)

    def eval(self, y: np.ndarray, dy: np.ndarray, T: np.ndarray, dT: np.ndarray,
             st: np.ndarray, sd: np.ndarray, fric: bool = True) -> tuple:
        """(a, δa, H, δH, L, δL) at state y with tangent dy (2n, C), torques T with tangent dT
        (n, C); with ``fric`` the first P columns are the parameters' (their explicit friction
        terms added; columns beyond P are plain state directions)."""
        n = self.n
        th, thd = y[:n], y[n:]
        Pphi, Za, Zb, Ga, Gb, armature = self.G
        M, b, L, a = _dyn(Pphi, Za, Zb, Ga, Gb, armature, th, thd, T, st, sd, self.fr)
        # Pinocchio's analytical derivatives of the inverse dynamics at (q, q̇, q̈)
        if self.identity:
            self.pin.computeRNEADerivatives(self.model, self.data, self._config(th), thd, a)
            Dq = self.data.dtau_dq
            Dv = self.data.dtau_dv
        else:
            self.pin.computeRNEADerivatives(self.model, self.data, self._config(th),
                                            self.Einv @ thd, self.Einv @ a)
            Dq = self.EinvT @ self.data.dtau_dq @ self.Einv
            Dv = self.EinvT @ self.data.dtau_dv @ self.Einv
        da, dH, dL = _tan(M, np.ascontiguousarray(Dq), np.ascontiguousarray(Dv), T, dT, thd,
                          np.ascontiguousarray(dy), st, sd, self.fr, self.n_cur, fric)
        H = T - M @ a - b
        return a, da, H, dH, L, dL

    def f(self, y: np.ndarray, dy: np.ndarray, T: np.ndarray, dT: np.ndarray, st: np.ndarray,
          sd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a, da, *_ = self.eval(y, dy, T, dT, st, sd)
        n = self.n
        return np.concatenate([y[n:], a]), np.vstack([dy[n:], da])


def _mode(qd0: np.ndarray, qd1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stuck set and sliding directions of a recorded step from its end velocities (a stuck
    joint's velocity is exactly zero in the record)."""
    st = (qd0 == 0.0) & (qd1 == 0.0)
    sd = np.where(qd1 != 0.0, np.sign(qd1), np.where(qd0 != 0.0, np.sign(qd0), 1.0))
    return st, sd


def rest_sensitivity(arm: UrdfArm, profile: CurrentProfile, q0: ArrayLike, *,
                     h: float = sim.DEFAULT_H, friction_scale: Optional[np.ndarray] = None,
                     i_rest: Optional[ArrayLike] = None) -> RestSensitivity:
    """Rest position of the move from rest at q0 (θ, rad) and its forward sensitivities (see the
    module docstring). PlanningError if the arm chatters or is not at rest SETTLE_MAX s after tf."""
    n = arm.n
    rec = sim.simulate(arm, profile, q0, settle=True, record=True, h=h,
                       friction_scale=friction_scale, i_rest=i_rest)
    if rec.q_rest is None:
        raise PlanningError(f"arm '{arm.name}' is not at rest {sim.SETTLE_MAX:g} s after tf",
                            "INTERNAL_ERROR")
    assert rec.t is not None and rec.q is not None and rec.qd is not None
    assert rec.event_kind is not None
    t, Y, kind = rec.t, np.hstack([rec.q, rec.qd]), rec.event_kind
    if not np.allclose(Y[-1, :n], rec.q_rest, rtol=0.0, atol=1e-12):
        raise PlanningError("the simulation record ended before rest (record too short)",
                            "INTERNAL_ERROR")
    N = profile.n_steps
    n_cur = N * n
    P = n_cur + 3 * n
    fr = arm.friction.T.copy() if friction_scale is None else (
        arm.friction * np.asarray(friction_scale, float)).T.copy()
    tg = _Tangent(arm, fr, P, n_cur)
    K = np.asarray(arm.torque_per_amp, float)
    ir = np.zeros(n) if i_rest is None else np.asarray(i_rest, float)
    cur = np.asarray(profile.currents, float)
    edges = np.asarray(profile.step_times, float)
    S = np.zeros((2 * n, P))
    steps = 0
    for i in range(len(t) - 1):
        t0, t1 = float(t[i]), float(t[i + 1])
        dt = t1 - t0
        if dt <= 0.0:
            continue
        tm = 0.5 * (t0 + t1)
        k = int(np.searchsorted(edges, tm, side="right")) - 1
        dT = np.zeros((n, P))
        if 0 <= k < N:
            T = K * cur[k]
            for j in range(n):
                dT[j, k * n + j] = K[j]
        else:
            T = K * ir
        st, sd = _mode(Y[i, n:], Y[i + 1, n:])
        y = Y[i]
        # RK4 tangent of the recorded step
        k1, d1 = tg.f(y, S, T, dT, st, sd)
        k2, d2 = tg.f(y + 0.5 * dt * k1, S + 0.5 * dt * d1, T, dT, st, sd)
        k3, d3 = tg.f(y + 0.5 * dt * k2, S + 0.5 * dt * d2, T, dT, st, sd)
        k4, d4 = tg.f(y + dt * k3, S + dt * d3, T, dT, st, sd)
        S = S + dt / 6.0 * (d1 + 2.0 * d2 + 2.0 * d3 + d4)
        S[n:][st] = 0.0
        steps += 1
        code = int(kind[i + 1])
        if code < 10:
            continue
        # event at the end of this step: the jump of the tangent
        j = code % 10
        ye = Y[i + 1].copy()
        if i + 2 < len(t):
            st_after, sd_after = _mode(Y[i + 1, n:], Y[i + 2, n:])
        else:
            st_after, sd_after = np.ones(n, bool), sd.copy()
        f_minus = np.concatenate([ye[n:], tg.eval(ye, np.zeros((2 * n, 0)), T, np.zeros((n, 0)),
                                                  st, sd, False)[0]])
        if code < 30:    # sliding velocity of joint j reached zero: g = θ̇_j
            g_y_S = S[n + j]
            g_p = np.zeros(P)
            gdot = f_minus[n + j]
        else:            # joint j broke away: g = L_j − s·H_j in the stuck mode
            cols = np.hstack([S, f_minus[:, None]])
            dTc = np.hstack([dT, np.zeros((n, 1))])
            _, _, H, dH, _, dL = tg.eval(ye, cols, T, dTc, st, sd)
            sgn = 1.0 if H[j] > 0.0 else -1.0
            g_y_S = dL[j, :P] - sgn * dH[j, :P]
            g_p = np.zeros(P)
            gdot = dL[j, P] - sgn * dH[j, P]
        if gdot == 0.0:
            raise PlanningError("an event of the simulation is tangential: no sensitivity",
                                "INTERNAL_ERROR")
        dtau = -(g_y_S + g_p) / gdot
        f_plus = np.concatenate([ye[n:], tg.eval(ye, np.zeros((2 * n, 0)), T, np.zeros((n, 0)),
                                                 st_after, sd_after, False)[0]])
        Pm = np.ones(2 * n)
        Pm[n:][st_after] = 0.0
        S = Pm[:, None] * S + (Pm * f_minus - f_plus)[:, None] * dtau[None, :]
    rest = Y[-1, :n].copy()
    d = S[:n]
    return RestSensitivity(rest=rest, d_currents=d[:, :n_cur].reshape(n, N, n).copy(),
                           d_friction=d[:, n_cur:].reshape(n, n, 3).copy(),
                           t_rest=float(rec.t_rest), steps=steps)
