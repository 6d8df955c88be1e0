"""The friction model of the paper, Eq. 9: viscous, Coulomb and torque-dependent, with sticking.

    T_p = pv·q̇ + sign(q̇)·(pc + pt·|T|)             for q̇ ≠ 0   (sliding)
    T_p = min(pc + pt·|T|, |T|)·sign(T)              for q̇ = 0   (sticking / breakaway)

T is the actuation torque on the joint (n·kt·I, Nm); T_p the friction torque (Nm) that opposes it.
At rest the joint stays stuck while |T| ≤ pc + pt·|T|, i.e. while |T|·(1 − pt) ≤ pc.
"""
from __future__ import annotations

import math


def friction_torque(qd: float, torque: float, pv: float, pc: float, pt: float) -> float:
    """Friction torque (Nm) at joint velocity ``qd`` (rad/s) under actuation ``torque`` (Nm)."""
    if qd != 0.0:
        return pv * qd + math.copysign(pc + pt * abs(torque), qd)
    return math.copysign(min(pc + pt * abs(torque), abs(torque)), torque) if torque != 0.0 else 0.0


def sliding_level(torque: float, pc: float, pt: float) -> float:
    """Magnitude (Nm) of the velocity-independent sliding friction pc + pt·|T|."""
    return pc + pt * abs(torque)


def breaks_away(torque: float, pc: float, pt: float) -> bool:
    """True if a joint at rest starts to move under ``torque`` (Nm): |T| > pc + pt·|T|."""
    return abs(torque) > pc + pt * abs(torque)


def breakaway_torque(pc: float, pt: float) -> float:
    """Smallest |T| (Nm) that moves a joint at rest: pc / (1 − pt); inf if pt ≥ 1."""
    return pc / (1.0 - pt) if pt < 1.0 else math.inf
