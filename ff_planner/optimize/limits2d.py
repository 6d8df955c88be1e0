"""Per-joint limits of a SCARA move in its held-joint planners (rad, rad/s).

While one link is held in stiction, the moving joint is exactly a 1-DOF arm
(``hold_joint.joint1_params`` / ``joint2_params``), so its excursion is the exact 1-DOF one and its
limits are a ``limits1d.Limits1D`` over the box of its own uncertain parameters
(``joint_limits``), held LIMITS_MARGIN2 inside the request's. The held model does not see the held
link slip where its friction is below the hold, so a plan within them is also simulated on the
full 2-DOF model at the nominal friction and the corners of the whole box (``corner_excess_2dof``,
both joints) before a planner takes it.
"""
from __future__ import annotations

import math
from dataclasses import replace as dc_replace
from typing import Optional

import numpy as np

from ff_planner.model import scara2
from ff_planner.model.limits import MotionLimits
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest
from ff_planner.optimize.certificate2d import CERT_H
from ff_planner.optimize.hold_joint import joint1_params, joint2_params
from ff_planner.optimize.limits1d import Limits1D, limit_bounds
from ff_planner.optimize.sample_box import box_corners, box_fractions

LIMITS_MARGIN2 = 1e-3    # rad, rad/s: joint 1's limits are held this much inside the request's
#                          (the held 1-DOF excursion ignores link 2 slipping where joint-2
#                          friction is below the hold; measured: a minimax plan on the held
#                          model's bound reached 7e-7 rad beyond it in the 2-DOF certificate)


def shrink_limits(lim: Limits1D, margin: float) -> Limits1D:
    """``lim`` held ``margin`` (rad, rad/s) inside on every side."""
    return dc_replace(lim, lo=lim.lo + margin, hi=lim.hi - margin, vmax=lim.vmax - margin)


def corner_excess_2dof(request: PlanRequest, p: Scara2Params, profile: CurrentProfile) -> float:
    """Largest violation (rad or rad/s; 0 = within, inf = a point never stops) of the request's
    limits (both joints) on the full 2-DOF model (``scara2.track_scara2``, the certificate's
    substep) at the nominal friction and the corners of the box of all uncertain parameters —
    where the held 1-DOF model of joint 1 does not see link 2 slip."""
    limits = request.limits
    if limits is None or limits.empty:
        return 0.0
    unc = [u for u in scara2.FRICTION_NAMES if u in request.uncertain]
    fr = box_fractions(unc, request.box)
    scales = np.vstack([np.ones((1, len(unc))), box_corners(fr, unc)])
    bounds = [limit_bounds(limits, j) for j in range(2)]
    worst = 0.0
    for sc in scales:
        pp = p.replace(**{u: getattr(p, u) * float(f) for u, f in zip(unc, sc)})
        try:
            tr = scara2.track_scara2(pp, profile, [float(v) for v in request.q0], h=CERT_H)
        except (PlanningError, ArithmeticError, ValueError):
            return math.inf
        if tr.q_rest is None:
            return math.inf
        for j, (lo, hi, vm) in enumerate(bounds):
            worst = max(worst, lo - float(tr.q_min[j]), float(tr.q_max[j]) - hi,
                        float(tr.speed[j]) - vm)
    return worst


def joint_limits(request: PlanRequest, p: Scara2Params, joint: int = 1, q0: Optional[float] = None,
                 tf: Optional[float] = None) -> Optional[Limits1D]:
    """The limits of ``joint`` (1 or 2) of ``request`` as the held 1-DOF arm's
    (``limits1d.Limits1D`` over the box of that joint's uncertain parameters), LIMITS_MARGIN2
    inside the request's; a phase of the move starts at ``q0`` (rad) and lasts ``tf`` (s)
    (default: the request's). None when the joint has none."""
    suffix = str(joint)
    names = [u[:-1] for u in request.uncertain if u.endswith(suffix)]
    box = {u[:-1]: f for u, f in box_fractions(list(request.uncertain), request.box).items()
           if u.endswith(suffix)}
    lo, hi, vm = limit_bounds(request.limits, joint - 1)
    if not (math.isfinite(lo) or math.isfinite(hi) or math.isfinite(vm)):
        return None
    one = MotionLimits.of([lo] if math.isfinite(lo) else None, [hi] if math.isfinite(hi) else None,
                          [vm] if math.isfinite(vm) else None)
    arm = joint1_params(p) if joint == 1 else joint2_params(p)
    lim = Limits1D.of(one, arm, float(request.q0[joint - 1]) if q0 is None else float(q0),
                      float(request.tf) if tf is None else float(tf), names, box)
    return None if lim is None else shrink_limits(lim, LIMITS_MARGIN2)


def joint1_limits(request: PlanRequest, p: Scara2Params) -> Optional[Limits1D]:
    """``joint_limits`` of joint 1 over the whole move (link 2 held)."""
    return joint_limits(request, p, 1)
