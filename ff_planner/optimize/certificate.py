"""The robustness certificate of a 1-DOF plan: its rest-position error over an uncertainty box.

``certify_1dof(params, profile, q0, qf, uncertain, box) -> RobustnessCertificate``. The rest
position (zero current after tf until the arm stops, exact model) is evaluated at the box's 2^k
corners, its centre, a 3^k grid and 256 seeded uniform points; from the four worst of them a
bounded local ascent of |rest − qf| (L-BFGS-B on the exact ∂q_rest/∂p of ``hd_sim``) looks for a
larger error between the samples. Each parameter alone: a 41-point line plus the same ascent.
Switch timing: central differences (±10 µs) of the rest position in each switch time. Units: rad,
s; scale factors dimensionless.
"""
from __future__ import annotations

import math
from typing import Mapping, Optional, Sequence

import numpy as np
from scipy.optimize import minimize

from ff_planner.model.arm1dof import FRICTION, batch_core
from ff_planner.model.arm1dof_derivatives import Q_, hd_sim, workspace
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile, RobustnessCertificate
from ff_planner.optimize.sample_box import (
    box_corners,
    box_fractions,
    box_grid,
    box_uniform,
)

CERT_UNIFORM = 256       # uniform samples of the certificate
CERT_SEED = 7            # their seed (fixed: the certificate of a plan is reproducible)
CERT_ASCENTS = 4         # local ascents, from the worst samples
LINE_POINTS = 41         # samples per parameter alone
SWITCH_H = 1e-5          # s, central-difference step of the switch timing


class _Rest:
    """Rest-position errors of one plan at friction scale factors (pv, pc, pt)."""

    def __init__(self, params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float):
        self.p = params
        self.c = float(params.n * params.kt)
        self.nominal = np.array([params.pv, params.pc, params.pt], dtype=float)
        self.times = np.ascontiguousarray(profile.step_times, dtype=float)
        self.cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
        self.tf = float(profile.tf)
        self.q0 = float(q0)
        self.qf = float(qf)
        self.W = workspace(self.cur.shape[0])
        self.count = 0

    def errors(self, scales: np.ndarray, to_rest: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(rest − qf (or q(tf) − qf), velocity at the end) per row of ``scales`` (S, 3)."""
        fr = np.ascontiguousarray(scales * self.nominal)
        q, v = batch_core(self.p.J, self.c, fr, np.full(fr.shape[0], to_rest), self.times,
                          self.cur, self.tf, self.q0)
        self.count += fr.shape[0]
        return q - self.qf, v

    def grad(self, scale: np.ndarray) -> tuple[float, np.ndarray]:
        """Rest error at ``scale`` and its exact gradient w.r.t. the three scale factors."""
        p = scale * self.nominal
        hd_sim(self.p.J, self.c, p[0], p[1], p[2], self.times, self.cur, self.tf, self.q0, True,
               np.abs(self.nominal), self.W)
        self.count += 1
        return float(self.W[Q_, 0] - self.qf), self.W[Q_, 1:4] * self.nominal


def _ascend(rest: _Rest, start: np.ndarray, cols: Sequence[int], lo: np.ndarray,
            hi: np.ndarray) -> tuple[float, np.ndarray]:
    """Bounded local maximum of |rest error| over the columns ``cols`` from ``start``."""
    x0 = start[list(cols)]

    def fun(x):
        s = start.copy()
        s[list(cols)] = x
        e, g = rest.grad(s)
        if not math.isfinite(e):
            return 0.0, np.zeros(len(cols))
        sg = 1.0 if e >= 0.0 else -1.0
        return -abs(e), -sg * g[list(cols)]

    try:
        res = minimize(fun, x0, jac=True, method="L-BFGS-B",
                       bounds=list(zip(lo[list(cols)], hi[list(cols)])),
                       options={"maxiter": 30})
    except (ValueError, ArithmeticError):
        return 0.0, start
    best = start.copy()
    best[list(cols)] = res.x
    return float(-res.fun), best


def certify_1dof(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float,
                 uncertain: Sequence[str], box: Optional[Mapping[str, float]] = None
                 ) -> RobustnessCertificate:
    """The rest-position error of ``profile`` over the ±``box`` fractions (default ±20 %) of the
    ``uncertain`` friction parameters (see the module docstring)."""
    unc = [u for u in FRICTION if u in uncertain]
    fr = box_fractions(unc, box)
    rest = _Rest(params, profile, q0, qf)
    lo, hi = np.ones(3), np.ones(3)
    for u, f in fr.items():
        lo[FRICTION.index(u)] = 1.0 - f
        hi[FRICTION.index(u)] = 1.0 + f
    uniform = box_uniform(fr, FRICTION, CERT_UNIFORM, CERT_SEED)
    scales = np.vstack([box_corners(fr, FRICTION), box_grid(fr, FRICTION, 3), uniform])
    e, _ = rest.errors(scales)
    _, v_tf = rest.errors(np.vstack([box_corners(fr, FRICTION), uniform]), to_rest=False)
    moving = float(np.mean(v_tf != 0.0))
    mag = np.where(np.isfinite(e), np.abs(e), math.inf)
    order = np.argsort(-mag)
    worst, where = float(mag[order[0]]), scales[order[0]].copy()
    cols = [FRICTION.index(u) for u in unc]
    if math.isfinite(worst):
        for i in order[:CERT_ASCENTS]:
            w, s = _ascend(rest, scales[i], cols, lo, hi)
            if w > worst:
                worst, where = w, s
    per: dict[str, float] = {}
    for u in unc:
        j = FRICTION.index(u)
        line = np.ones((LINE_POINTS, 3))
        line[:, j] = np.linspace(lo[j], hi[j], LINE_POINTS)
        el, _ = rest.errors(line)
        ml = np.where(np.isfinite(el), np.abs(el), math.inf)
        w1 = float(ml.max())
        if math.isfinite(w1):
            w2, _ = _ascend(rest, line[int(np.argmax(ml))], [j], lo, hi)
            w1 = max(w1, w2)
        per[u] = w1
    return RobustnessCertificate(
        box=fr, worst_rest_error=worst, worst_at={u: float(where[FRICTION.index(u)]) for u in unc},
        per_parameter=per, moving_at_tf=moving, switch_timing=switch_timing_1dof(
            params, profile, q0), samples=rest.count)


def switch_timing_1dof(params: Arm1DofParams, profile: CurrentProfile, q0: float) -> list[float]:
    """Rest-position change (rad) per 100 µs delay of each switch time t_1..t_N (t_N: start of
    the coast), central differences ±SWITCH_H on the nominal model."""
    times = np.ascontiguousarray(profile.step_times, dtype=float)
    cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
    c = float(params.n * params.kt)
    out = []
    one = np.array([[params.pv, params.pc, params.pt]], dtype=float)
    flag = np.ones(1, dtype=bool)
    for j in range(1, times.shape[0]):
        qs = []
        for h in (SWITCH_H, -SWITCH_H):
            t = times.copy()
            t[j] = min(t[j] + h, profile.tf)
            q, _ = batch_core(params.J, c, one, flag, t, cur, float(profile.tf), float(q0))
            qs.append(float(q[0]))
        out.append((qs[0] - qs[1]) / (2.0 * SWITCH_H) * 1e-4)
    return out
