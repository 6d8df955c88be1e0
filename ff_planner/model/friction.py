"""The friction model of the paper, Eq. 9: viscous, Coulomb and torque-dependent, with sticking.

    T_p = pv·q̇ + sign(q̇)·(pc + pt·|T|)             for q̇ ≠ 0   (sliding)
    T_p = min(pc + pt·|T|, |T|)·sign(T)              for q̇ = 0   (sticking / breakaway)

T is the actuation torque on the joint (n·kt·I, Nm); T_p the friction torque (Nm) that opposes it.
L = pc + pt·|T| is the sliding level; a joint at rest stays stuck while the torque it must hold,
H, satisfies |H| ≤ L (H = T for a joint alone; for a coupled arm H includes the reaction of the
other links, and the |T| inside L stays the joint's own motor torque). Units: rad/s, Nm,
Nm·s/rad; pt is a fraction.

This module is the one place the law is written. Every function is numba-compiled and works in
the number systems of the simulators: floats, and complex numbers for complex-step derivatives
(|·| and sign(·) go by the sign of the real part, so the imaginary part carries the derivative and
branch decisions are taken on real parts). ``sliding_level_series`` is the same law on the
truncated Taylor rows of ``ff_planner.model.taylor`` (the 1-DOF exact derivatives);
``friction_torque_array``, ``net_torque_array`` and ``sliding_level_array`` apply it
elementwise to float arrays.

Numba's on-disk cache of a kernel that calls these functions does not notice when this file
changes: after editing it, delete the ``*.nbi``/``*.nbc`` files of ff_planner/model/__pycache__
(or run with NUMBA_CACHE_DIR pointing at an empty directory).
"""
from __future__ import annotations

import math

from numba import njit, vectorize

from ff_planner.model.taylor import row_lin, row_mul


@njit(cache=True, nogil=True)
def real_abs(x):
    """|x| by the sign of the real part: x if Re x ≥ 0, else −x (abs(x) for a float)."""
    return x if x.real >= 0.0 else -x


@njit(cache=True, nogil=True)
def real_sign(x) -> float:
    """sign(Re x): 1.0, −1.0, or 0.0 at zero."""
    if x.real > 0.0:
        return 1.0
    if x.real < 0.0:
        return -1.0
    return 0.0


@njit(cache=True, nogil=True)
def sliding_level(torque, pc, pt):
    """L = pc + pt·|T| (Nm): the velocity-independent sliding friction and the stiction limit."""
    return pc + pt * real_abs(torque)


@njit(cache=True, nogil=True)
def sliding_friction(qd, direction, torque, pv, pc, pt):
    """Sliding friction pv·q̇ + s·(pc + pt·|T|) (Nm) for the direction of motion s = ±1."""
    return pv * qd + direction * sliding_level(torque, pc, pt)


@njit(cache=True, nogil=True)
def exceeds_stiction(held, level) -> bool:
    """True if a joint at rest that must hold torque ``held`` (Nm) breaks away: |H| > L."""
    return abs(held.real) > level.real


@njit(cache=True, nogil=True)
def breakaway_excess(held, level):
    """|H| − L (Nm): > 0 where a joint at rest breaks away, ≤ 0 where it sticks."""
    return real_abs(held) - level


@njit(cache=True, nogil=True)
def stiction_margin(held, level, direction):
    """L − s·H (Nm) for a stuck joint whose holding torque H pushes in direction s = ±1:
    positive while it sticks, zero at breakaway (a smooth event function)."""
    return level - direction * held


@njit(cache=True, nogil=True)
def static_friction(held, level):
    """Friction (Nm) of a joint at rest that must hold ``held``: min(L, |H|)·sign(H) — it
    balances H up to the level L and is ±L beyond (where the joint breaks away)."""
    if exceeds_stiction(held, level):
        return real_sign(held) * level
    return held + 0.0 * level


@njit(cache=True, nogil=True)
def friction_torque(qd, torque, pv, pc, pt):
    """Eq. 9: friction torque T_p (Nm) at joint velocity ``qd`` (rad/s) under actuation
    ``torque`` (Nm)."""
    if qd.real != 0.0:
        return sliding_friction(qd, real_sign(qd), torque, pv, pc, pt)
    return static_friction(torque, sliding_level(torque, pc, pt))


@njit(cache=True, nogil=True)
def net_torque(qd, torque, pv, pc, pt):
    """T − T_p (Nm), the torque that accelerates a single joint (J·q̈ = T − T_p); sliding it is
    evaluated as T − pv·q̇ − s·L, at rest as T − min(L, |T|)·sign(T) (exactly 0 while stuck)."""
    level = sliding_level(torque, pc, pt)
    if qd.real != 0.0:
        return torque - pv * qd - real_sign(qd) * level
    return torque - static_friction(torque, level)


@njit(cache=True, nogil=True)
def breaks_away(torque, pc, pt) -> bool:
    """True if a single joint at rest starts to move under ``torque`` (Nm): |T| > pc + pt·|T|."""
    return exceeds_stiction(torque, sliding_level(torque, pc, pt))


@njit(cache=True, nogil=True)
def breakaway_torque(pc, pt) -> float:
    """Smallest |T| (Nm) that moves a single joint at rest: pc / (1 − pt); inf if pt ≥ 1."""
    return pc / (1.0 - pt) if pt < 1.0 else math.inf


def stop_speed(J: float, pv: float, pc: float, tau: float) -> float:
    """Speed (rad/s) from which zero current stops a joint of inertia J (kg·m²) in exactly τ s:
    J·v̇ = −pv·v − pc·sign(v) gives |v| = (pc/J)·τ·φ1(pv·τ/J), φ1(z) = (e^z − 1)/z; 0 for τ ≤ 0."""
    if tau <= 0.0:
        return 0.0
    z = pv / J * tau
    phi1 = math.expm1(z) / z if z != 0.0 else 1.0
    return pc / J * tau * phi1


@vectorize(["float64(float64, float64, float64, float64, float64)"], cache=True, nopython=True)
def friction_torque_array(qd, torque, pv, pc, pt):
    """``friction_torque`` elementwise on float arrays (NumPy broadcasting)."""
    return friction_torque(qd, torque, pv, pc, pt)


@vectorize(["float64(float64, float64, float64, float64, float64)"], cache=True, nopython=True)
def net_torque_array(qd, torque, pv, pc, pt):
    """``net_torque`` elementwise on float arrays (NumPy broadcasting)."""
    return net_torque(qd, torque, pv, pc, pt)


@vectorize(["float64(float64, float64, float64)"], cache=True, nopython=True)
def sliding_level_array(torque, pc, pt):
    """``sliding_level`` elementwise on float arrays (NumPy broadcasting)."""
    return sliding_level(torque, pc, pt)


@njit("void(float64[:, ::1], int64, int64, int64, int64, int64, int64)", cache=True, nogil=True)
def sliding_level_series(W, o, t, pc, pt, abs_t, n):
    """Row ``o`` ← pc + pt·|T| on Taylor rows (``sliding_level`` in the series arithmetic).

    t, pc, pt: rows of the torque and the two friction parameters; ``abs_t`` receives |T| (the
    sign taken at T's value; 0 at T = 0); n: number of step currents.
    """
    x = W[t, 0]
    sg = 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)
    row_lin(W, abs_t, t, t, sg, 0.0, 0.0)
    row_mul(W, o, pt, abs_t, n)
    row_lin(W, o, o, pc, 1.0, 1.0, 0.0)
