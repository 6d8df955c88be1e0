"""Numerically careful scalar kernels of the 1-DOF closed form (numba-compiled, no allocation).

Between events the 1-DOF arm obeys v' = a·v + b (a = −pv/J in 1/s, b in rad/s²), so over a time τ

    v(τ) = v0·e^{aτ} + b·E1,   q(τ) = q0 + v0·E1 + b·E2,
    E1 = τ·φ1(aτ),  E2 = τ²·φ2(aτ),  φ1(z) = (e^z − 1)/z,  φ2(z) = (e^z − 1 − z)/z².

A velocity zero crossing (v0 ≠ 0, b opposing v0) comes after τ = −x·ψ(a·x), x = v0/b,
ψ(z) = log1p(z)/z (no crossing when a·x ≤ −1: negative viscous friction outruns Coulomb).
Each kernel returns the value and the first two derivatives, evaluated by series near z = 0 (so
pv = 0 and tiny a·τ lose no digits) and by closed forms elsewhere.
"""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True)
def phi12(z: float):
    """(φ1, φ1', φ1'', φ2, φ2', φ2'') at z."""
    if abs(z) < 1.0:
        f1 = 0.0
        f1p = 0.0
        f1pp = 0.0
        f2 = 0.0
        f2p = 0.0
        f2pp = 0.0
        c1 = 1.0   # 1/(k+1)!
        c2 = 0.5   # 1/(k+2)!
        zk = 1.0
        zkm1 = 0.0
        zkm2 = 0.0
        for k in range(0, 24):
            f1 += c1 * zk
            f2 += c2 * zk
            f1p += k * c1 * zkm1
            f2p += k * c2 * zkm1
            f1pp += k * (k - 1) * c1 * zkm2
            f2pp += k * (k - 1) * c2 * zkm2
            zkm2 = zkm1
            zkm1 = zk
            zk *= z
            c1 /= (k + 2)
            c2 /= (k + 3)
        return f1, f1p, f1pp, f2, f2p, f2pp
    ez = math.exp(z)
    f1 = math.expm1(z) / z
    f1p = (ez - f1) / z
    f1pp = (ez - 2.0 * f1p) / z
    f2 = (f1 - 1.0) / z
    f2p = (f1p - f2) / z
    f2pp = (f1pp - 2.0 * f2p) / z
    return f1, f1p, f1pp, f2, f2p, f2pp


@njit(cache=True, nogil=True)
def phi12_value(z: float):
    """(e^z, φ1, φ2) at z, values only (the plain simulator's kernel)."""
    if abs(z) < 0.5:
        f1 = 0.0
        f2 = 0.0
        c1 = 1.0
        c2 = 0.5
        zk = 1.0
        for k in range(0, 18):
            f1 += c1 * zk
            f2 += c2 * zk
            zk *= z
            c1 /= (k + 2)
            c2 /= (k + 3)
        return 1.0 + z * f1, f1, f2
    em1 = math.expm1(z)
    f1 = em1 / z
    return em1 + 1.0, f1, (f1 - 1.0) / z


@njit(cache=True, nogil=True)
def psi(z: float):
    """(ψ, ψ', ψ'') at z > −1, ψ(z) = log1p(z)/z."""
    if abs(z) < 0.1:
        f = 0.0
        fp = 0.0
        fpp = 0.0
        zk = 1.0
        zkm1 = 0.0
        zkm2 = 0.0
        sgn = 1.0
        for k in range(0, 20):
            c = sgn / (k + 1)
            f += c * zk
            fp += k * c * zkm1
            fpp += k * (k - 1) * c * zkm2
            zkm2 = zkm1
            zkm1 = zk
            zk *= z
            sgn = -sgn
        return f, fp, fpp
    f = math.log1p(z) / z
    fp = (1.0 / (1.0 + z) - f) / z
    fpp = (-1.0 / ((1.0 + z) * (1.0 + z)) - 2.0 * fp) / z
    return f, fp, fpp


@njit(cache=True, nogil=True)
def psi_value(z: float) -> float:
    """ψ(z) = log1p(z)/z for z > −1 (value only)."""
    if abs(z) < 1e-3:
        return 1.0 - z / 2.0 + z * z / 3.0 - z * z * z / 4.0 + z * z * z * z / 5.0
    return math.log1p(z) / z
