"""The robustness certificate of a 2-DOF SCARA plan: its rest-position error over a friction box.

``certify_scara2(params, profile, q0, qf, uncertain, box) -> RobustnessCertificate``. The rest
position (zero current on both motors after tf until both links stop; the exact event-aware 2-DOF
simulation ``scara2.simulate_detail`` with ``settle``, RK4 substep CERT_H) is evaluated at the box's 2^k corners, its
centre, its 2k face centres and CERT_UNIFORM seeded uniform points. From the ASCENT_STARTS worst
of them a bounded local ascent of the largest joint error (L-BFGS-B, forward differences of the
simulation, at most ASCENT_EVALS simulations each) looks for a larger error between the samples.
Each parameter alone: LINE_POINTS points on its line (the others nominal) plus the same ascent
from the worst. Switch timing: central differences (±10 µs) of the rest position in each switch
time, per joint. A sample whose simulation fails (chatter) or that has not stopped 5 s after tf
counts as an infinite error (and an unbounded excursion). Excursion: per joint the lowest and
highest position and the peak |speed| until rest (``scara2.track_scara2``: every RK4 substep and
every event), at the nominal friction and the worst over every box point simulated. Units: rad,
rad/s, s; scale factors dimensionless.
"""
from __future__ import annotations

import math
from typing import Mapping, Optional, Sequence

import numpy as np
from scipy.optimize import minimize

from ff_planner.core.errors import PlanningError
from ff_planner.model import scara2
from ff_planner.model.limits import Excursion
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile, RobustnessCertificate
from ff_planner.optimize.sample_box import box_corners, box_faces, box_fractions, box_uniform

CERT_UNIFORM = 128       # uniform samples of the 2-DOF certificate
CERT_SEED = 7            # their seed (fixed: the certificate of a plan is reproducible)
ASCENT_STARTS = 2        # local ascents over the whole box, from the worst samples
ASCENT_EVALS = 40        # simulations per ascent (forward differences: k + 1 per gradient)
ASCENT_STEP = 1e-6       # forward-difference step of the ascent (scale factor)
LINE_POINTS = 11         # samples per parameter alone
SWITCH_H = 1e-5          # s, central-difference step of the switch timing
CERT_H = 4e-3            # s, RK4 substep of the certificate's simulations (events stay exact;
#                          measured: rest positions within 1.5e-8 rad of the 1 ms default)


class _Rest2:
    """Rest-position errors (rad, per joint) of one SCARA plan at friction scale factors."""

    def __init__(self, params: Scara2Params, profile: CurrentProfile, q0: Sequence[float],
                 qf: Sequence[float], keys: Sequence[str]):
        self.p = params
        self.profile = profile
        self.q0 = [float(x) for x in q0]
        self.qf = np.asarray(qf, dtype=float)
        self.keys = list(keys)
        self.nominal = {k: float(getattr(params, k)) for k in self.keys}
        self.count = 0
        # excursion over every point simulated: lowest, highest position, peak |speed|
        self.lo = np.full(2, math.inf)
        self.hi = np.full(2, -math.inf)
        self.speed = np.zeros(2)

    def one(self, scale: np.ndarray, profile: Optional[CurrentProfile] = None
            ) -> tuple[np.ndarray, bool]:
        """(rest − qf per joint (inf where it never stops or the simulation fails), both links
        at rest at tf) at the scale factors ``scale`` (one per key)."""
        pp = self.p.replace(**{k: self.nominal[k] * float(s) for k, s in zip(self.keys, scale)})
        self.count += 1
        try:
            tr = scara2.track_scara2(pp, profile or self.profile, self.q0, h=CERT_H)
        except (PlanningError, ArithmeticError, ValueError):
            tr = None
        if tr is None or tr.q_rest is None:
            if profile is None:     # never stops (or chatters): an unbounded excursion
                self.lo[:] = -math.inf
                self.hi[:] = math.inf
                self.speed[:] = math.inf
            return np.full(2, math.inf), False
        if profile is None:
            self.lo = np.minimum(self.lo, tr.q_min)
            self.hi = np.maximum(self.hi, tr.q_max)
            self.speed = np.maximum(self.speed, tr.speed)
        return tr.q_rest - self.qf, bool(tr.stuck_tf[0] and tr.stuck_tf[1])

    def many(self, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """|rest − qf| (S, 2) and at-rest-at-tf flags (S,) for the rows of ``scales``."""
        err = np.empty((scales.shape[0], 2))
        still = np.empty(scales.shape[0], dtype=bool)
        for i, s in enumerate(scales):
            e, r = self.one(s)
            err[i] = np.abs(e)
            still[i] = r
        return err, still


def _ascend(rest: _Rest2, start: np.ndarray, cols: Sequence[int], lo: np.ndarray,
            hi: np.ndarray) -> tuple[float, np.ndarray]:
    """Bounded local maximum of the largest joint error over the columns ``cols`` from ``start``
    (at most ASCENT_EVALS simulations); returns (error (rad), scale factors)."""
    cols = list(cols)
    top = [0.0]
    where = [start.copy()]

    def fun(x: np.ndarray) -> float:
        s = start.copy()
        s[cols] = x
        e, _ = rest.one(s)
        m = float(np.max(np.abs(e)))
        if not math.isfinite(m):
            return 0.0
        if m > top[0]:
            top[0], where[0] = m, s
        return -m

    try:
        minimize(fun, start[cols], method="L-BFGS-B", bounds=list(zip(lo[cols], hi[cols])),
                 options={"maxfun": ASCENT_EVALS, "eps": ASCENT_STEP})
    except (ValueError, ArithmeticError):
        pass
    return top[0], where[0]


def switch_timing_scara2(params: Scara2Params, profile: CurrentProfile, q0: Sequence[float]
                         ) -> list[list[float]]:
    """Rest-position change (rad, per joint) per 100 µs delay of each switch time t_1..t_N
    (t_N: the start of the coast), central differences ±SWITCH_H on the nominal model; rows
    per switch, columns per joint (nan where a shifted simulation fails)."""
    times = np.asarray(profile.step_times, dtype=float)
    out: list[list[float]] = []
    for j in range(1, times.shape[0]):
        qs = []
        for h in (SWITCH_H, -SWITCH_H):
            t = times.copy()
            t[j] = min(t[j] + h, profile.tf - profile.coast)
            shifted = CurrentProfile(t, profile.currents, profile.tf, profile.coast)
            try:
                qs.append(scara2.rest_position_scara2(params, shifted, q0, h=CERT_H))
            except (PlanningError, ArithmeticError, ValueError):
                qs.append(np.full(2, math.nan))
        width = float(min(times[j] + SWITCH_H, profile.tf - profile.coast) - (times[j] - SWITCH_H))
        out.append([float(x) for x in (qs[0] - qs[1]) / width * 1e-4])
    return out


def certify_scara2(params: Scara2Params, profile: CurrentProfile, q0: Sequence[float],
                   qf: Sequence[float], uncertain: Sequence[str],
                   box: Optional[Mapping[str, float]] = None) -> RobustnessCertificate:
    """The rest-position error of a SCARA ``profile`` over the ±``box`` fractions (default ±20 %)
    of the ``uncertain`` friction parameters (see the module docstring). ``worst_rest_error``:
    the largest joint error; ``worst_per_joint``: each joint's own worst (rad), found over the
    same samples; ``switch_timing``: per switch, the joint change of largest magnitude (signed),
    ``switch_timing_per_joint`` both."""
    unc = [u for u in scara2.FRICTION_NAMES if u in uncertain]
    fr = box_fractions(unc, box)
    lo = np.array([1.0 - fr[u] for u in unc])
    hi = np.array([1.0 + fr[u] for u in unc])
    rest = _Rest2(params, profile, q0, qf, unc)
    corners = box_corners(fr, unc)
    uniform = box_uniform(fr, unc, CERT_UNIFORM, seed=CERT_SEED)
    scales = np.vstack([corners, box_faces(fr, unc), uniform])
    err, still = rest.many(scales)
    moving_rows = np.r_[np.arange(corners.shape[0]),
                        np.arange(scales.shape[0] - uniform.shape[0], scales.shape[0])]
    moving = float(np.mean(~still[moving_rows]))
    mag = err.max(axis=1)
    per_joint = [float(x) for x in err.max(axis=0)]
    order = np.argsort(-mag)
    worst, where = float(mag[order[0]]), scales[order[0]].copy()
    cols = list(range(len(unc)))
    if math.isfinite(worst):
        for i in order[:ASCENT_STARTS]:
            w, s = _ascend(rest, scales[i], cols, lo, hi)
            if w > worst:
                worst, where = w, s
                e, _ = rest.one(s)
                per_joint = [max(a, float(abs(b))) for a, b in zip(per_joint, e)]
    per: dict[str, float] = {}
    for j, u in enumerate(unc):
        line = np.ones((LINE_POINTS, len(unc)))
        line[:, j] = np.linspace(lo[j], hi[j], LINE_POINTS)
        el, _ = rest.many(line)
        ml = el.max(axis=1)
        w1 = float(ml.max())
        if math.isfinite(w1) and w1 > 0.0:
            w2, _ = _ascend(rest, line[int(np.argmax(ml))], [j], lo, hi)
            w1 = max(w1, w2)
        per[u] = w1
    per_switch = switch_timing_scara2(params, profile, q0)
    flat = [row[int(np.argmax(np.abs(np.nan_to_num(row, nan=0.0))))] for row in per_switch]
    return RobustnessCertificate(
        box=fr, worst_rest_error=worst, worst_at={u: float(where[j]) for j, u in enumerate(unc)},
        per_parameter=per, moving_at_tf=moving, switch_timing=flat, samples=rest.count,
        worst_per_joint=per_joint, switch_timing_per_joint=per_switch,
        excursion=_excursion(params, profile, q0, rest))


def _excursion(params: Scara2Params, profile: CurrentProfile, q0: Sequence[float],
               rest: _Rest2) -> Optional[Excursion]:
    """Nominal excursion (``scara2.track_scara2``) and the worst over the points ``rest``
    simulated; None if the nominal simulation fails."""
    try:
        nom = scara2.track_scara2(params, profile, [float(x) for x in q0], h=CERT_H)
    except (PlanningError, ArithmeticError, ValueError):
        return None
    f = lambda a: [float(x) for x in a]  # noqa: E731
    return Excursion(nominal_min=f(nom.q_min), nominal_max=f(nom.q_max),
                     nominal_speed=f(nom.speed), worst_min=f(np.minimum(rest.lo, nom.q_min)),
                     worst_max=f(np.maximum(rest.hi, nom.q_max)),
                     worst_speed=f(np.maximum(rest.speed, nom.speed)))
