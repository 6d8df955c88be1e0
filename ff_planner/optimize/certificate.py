"""The robustness certificate of a 1-DOF plan: its rest-position error over an uncertainty box.

``certify_1dof(params, profile, q0, qf, uncertain, box) -> RobustnessCertificate``. The rest
position (zero current after tf until the arm stops, exact model) is evaluated at the box's 2^k
corners, its centre, a 3^k grid and 256 seeded uniform points; from the four worst of them a
bounded local ascent of |rest − qf| (``_ascend``: projected gradient steps on the exact
∂q_rest/∂p of ``hd_sim``, the step doubled after a gain and quartered after a loss, at most
ASCENT_ITER simulations) looks for a larger error between the samples. Each parameter alone: a
41-point line plus the same ascent. Switch timing: central differences (±10 µs) of the rest
position in each switch time. Everything is compiled: a certificate is a few hundred exact
closed-form simulations and a handful of Python calls.

The excursion (``Excursion``): the lowest and the highest position and the peak |speed| from
t = 0 until the arm rests (``arm1dof.track_core``, exact: extremes sit at segment ends), at the
nominal friction and the worst over every box point simulated (samples, lines, the worst point
the ascents found). Units: rad, rad/s, s; scale factors dimensionless.
"""
from __future__ import annotations

import functools
import math
from typing import Mapping, Optional, Sequence

import numpy as np
from numba import njit

from ff_planner.model.arm1dof import (
    FRICTION,
    TR_MAX,
    TR_MIN,
    TR_REST,
    TR_SPEED,
    TR_VTF,
    TRACK_COLS,
    batch_core,
    track_batch,
)
from ff_planner.model.arm1dof_derivatives import Q_, hd_sim, workspace
from ff_planner.model.limits import Excursion
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
ASCENT_ITER = 30         # exact simulations (value and gradient) per ascent at most
ASCENT_MIN_STEP = 1e-5   # an ascent stops once its step (scale factor) is below this
LINE_POINTS = 41         # samples per parameter alone
SWITCH_H = 1e-5          # s, central-difference step of the switch timing


@njit(cache=True, nogil=True)
def _rest_grad(J, c, nominal, x, times, cur, tf, q0, qf, pw, W, g):
    """Rest error (rad) at scale factors x (3,) and its gradient w.r.t. x into g (3,)."""
    hd_sim(J, c, nominal[0] * x[0], nominal[1] * x[1], nominal[2] * x[2], times, cur, tf, q0,
           True, pw, W)
    for i in range(3):
        g[i] = W[Q_, 1 + i] * nominal[i]
    return W[Q_, 0] - qf


@njit(cache=True, nogil=True)
def _ascend(J, c, nominal, times, cur, tf, q0, qf, start, free, lo, hi, W, max_iter):
    """Bounded local maximum of |rest − qf| over the free scale factors from ``start`` (3,):
    projected steps along the exact gradient (its largest free component normalised), the step
    × 2 after a gain and × 0.25 after a loss, until it is below ASCENT_MIN_STEP or max_iter
    simulations. Returns (|error| (rad), scale factors (3,), simulations run)."""
    pw = np.abs(nominal)
    g = np.zeros(3)
    gn = np.zeros(3)
    x = start.copy()
    xn = start.copy()
    e = _rest_grad(J, c, nominal, x, times, cur, tf, q0, qf, pw, W, g)
    runs = 1
    if not math.isfinite(e):
        return 0.0, x, runs
    f = abs(e)
    width = 0.0
    for i in range(3):
        if free[i]:
            width = max(width, hi[i] - lo[i])
    step = 0.25 * width
    while runs < max_iter and step > ASCENT_MIN_STEP:
        sg = 1.0 if e >= 0.0 else -1.0
        big = 0.0
        for i in range(3):
            if free[i]:
                big = max(big, abs(g[i]))
        if not big > 0.0:
            break
        moved = 0.0
        for i in range(3):
            xn[i] = x[i]
            if free[i]:
                xn[i] = min(max(x[i] + step * sg * g[i] / big, lo[i]), hi[i])
                moved = max(moved, abs(xn[i] - x[i]))
        if moved < 1e-12:
            break           # at a corner (or face) the gradient points out of the box
        en = _rest_grad(J, c, nominal, xn, times, cur, tf, q0, qf, pw, W, gn)
        runs += 1
        if math.isfinite(en) and abs(en) > f:
            e = en
            f = abs(en)
            for i in range(3):
                x[i] = xn[i]
                g[i] = gn[i]
            step = min(2.0 * step, width)
        else:
            step *= 0.25
    return f, x, runs


@njit(cache=True, nogil=True)
def _ascents(J, c, nominal, times, cur, tf, q0, qf, starts, free, lo, hi, max_iter, W):
    """``_ascend`` from each row of ``starts`` (M, 3); returns (best |error|, its scale factors,
    simulations run)."""
    best = -1.0
    where = starts[0].copy()
    runs = 0
    for m in range(starts.shape[0]):
        f, x, r = _ascend(J, c, nominal, times, cur, tf, q0, qf, starts[m].copy(), free, lo, hi,
                          W, max_iter)
        runs += r
        if f > best:
            best = f
            where = x
    return best, where, runs


class _Plan:
    """The compiled kernels' arguments for one plan."""

    def __init__(self, params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float):
        self.J = float(params.J)
        self.c = float(params.n * params.kt)
        self.nominal = np.array([params.pv, params.pc, params.pt], dtype=float)
        self.times = np.ascontiguousarray(profile.step_times, dtype=float)
        self.cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
        self.tf = float(profile.tf)
        self.q0 = float(q0)
        self.qf = float(qf)
        self.count = 0

    def track(self, scales: np.ndarray) -> np.ndarray:
        """(S, TRACK_COLS) of ``arm1dof.track_batch`` at the scale factors (S, 3)."""
        out = np.empty((scales.shape[0], TRACK_COLS))
        track_batch(self.J, self.c, self.nominal, np.ascontiguousarray(scales, dtype=float),
                    self.times, self.cur, self.tf, self.q0, out)
        self.count += scales.shape[0]
        return out

    def ascend(self, starts: np.ndarray, free: np.ndarray, lo: np.ndarray, hi: np.ndarray
               ) -> tuple[float, np.ndarray]:
        f, x, runs = _ascents(self.J, self.c, self.nominal, self.times, self.cur, self.tf,
                              self.q0, self.qf, np.ascontiguousarray(starts, dtype=float), free,
                              lo, hi, ASCENT_ITER, workspace(self.cur.shape[0]))
        self.count += int(runs)
        return float(f), np.asarray(x)


def _magnitudes(rest: np.ndarray, qf: float) -> np.ndarray:
    """|rest − qf| (rad), inf where the arm never stops."""
    e = np.abs(rest - qf)
    return np.where(np.isfinite(e), e, math.inf)


def excursion_of(tracks: np.ndarray, nominal: np.ndarray) -> Excursion:
    """The Excursion of one joint from ``track_batch`` rows over box points (S, TRACK_COLS) and
    the nominal row (TRACK_COLS,); a point that never stops counts as an unbounded excursion."""
    ok = np.all(np.isfinite(tracks[:, [TR_MIN, TR_MAX, TR_SPEED]]), axis=1)
    if ok.all():
        lo, hi = float(tracks[:, TR_MIN].min()), float(tracks[:, TR_MAX].max())
        sp = float(tracks[:, TR_SPEED].max())
    else:
        lo, hi, sp = -math.inf, math.inf, math.inf
    return Excursion(nominal_min=[float(nominal[TR_MIN])], nominal_max=[float(nominal[TR_MAX])],
                     nominal_speed=[float(nominal[TR_SPEED])], worst_min=[lo], worst_max=[hi],
                     worst_speed=[sp])


@functools.lru_cache(maxsize=64)
def _design(box_items: tuple[tuple[str, float], ...]) -> tuple[np.ndarray, ...]:
    """The certificate's box points for the fractions ``box_items`` (cached; callers must not
    modify them): (all points (S, 3): nominal, corners + centre, 3^k grid, uniform, then
    LINE_POINTS per uncertain parameter; lo (3,); hi (3,); rows of the moving-at-tf figure;
    first row of each line)."""
    fr = dict(box_items)
    lo, hi = np.ones(3), np.ones(3)
    for u, f in fr.items():
        lo[FRICTION.index(u)] = 1.0 - f
        hi[FRICTION.index(u)] = 1.0 + f
    corners = box_corners(fr, FRICTION)
    uniform = box_uniform(fr, FRICTION, CERT_UNIFORM, CERT_SEED)
    parts = [np.ones((1, 3)), corners, box_grid(fr, FRICTION, 3), uniform]
    n_samples = sum(p.shape[0] for p in parts)
    line_rows: list[int] = []
    for u in fr:
        j = FRICTION.index(u)
        line = np.ones((LINE_POINTS, 3))
        line[:, j] = np.linspace(lo[j], hi[j], LINE_POINTS)
        line_rows.append(n_samples + LINE_POINTS * len(line_rows))
        parts.append(line)
    moving = np.r_[np.arange(1, 1 + corners.shape[0]),
                   np.arange(n_samples - uniform.shape[0], n_samples)]
    out = (np.ascontiguousarray(np.vstack(parts)), lo, hi, moving,
           np.array(line_rows, dtype=np.int64), np.array([n_samples]))
    for a in out:
        a.setflags(write=False)
    return out


def design_points(fractions: Mapping[str, float]) -> np.ndarray:
    """The certificate's box points (scale factors (S, 3) of pv, pc, pt) for ± ``fractions``:
    nominal, corners + centre, the 3^k grid, the uniform points and the per-parameter lines
    (read-only, shared)."""
    return _design(tuple((u, float(f)) for u, f in fractions.items()))[0]


def certify_1dof(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float,
                 uncertain: Sequence[str], box: Optional[Mapping[str, float]] = None
                 ) -> RobustnessCertificate:
    """The rest-position error of ``profile`` over the ±``box`` fractions (default ±20 %) of the
    ``uncertain`` friction parameters, and its excursion (see the module docstring)."""
    unc = [u for u in FRICTION if u in uncertain]
    fr = box_fractions(unc, box)
    plan = _Plan(params, profile, q0, qf)
    points, lo, hi, moving_rows, line_rows, n_arr = _design(tuple(fr.items()))
    n_samples = int(n_arr[0])
    tr = plan.track(points)
    moving = float(np.mean(tr[moving_rows, TR_VTF] != 0.0))
    mag = _magnitudes(tr[:, TR_REST], plan.qf)
    order = np.argsort(-mag[:n_samples])
    worst, where = float(mag[order[0]]), points[order[0]].copy()
    cols = [FRICTION.index(u) for u in unc]
    free = np.zeros(3, dtype=np.bool_)
    free[cols] = True
    tracks = [tr]
    if math.isfinite(worst) and cols:
        w, s = plan.ascend(points[order[:CERT_ASCENTS]], free, lo, hi)
        if w > worst:
            worst, where = w, s.copy()
            tracks.append(plan.track(where.reshape(1, 3)))
    per: dict[str, float] = {}
    for u, r0 in zip(unc, line_rows):
        ml = mag[r0:r0 + LINE_POINTS]
        w1 = float(ml.max())
        if math.isfinite(w1):
            one = np.zeros(3, dtype=np.bool_)
            one[FRICTION.index(u)] = True
            w2, _ = plan.ascend(points[r0 + int(np.argmax(ml))].reshape(1, 3), one, lo, hi)
            w1 = max(w1, w2)
        per[u] = w1
    return RobustnessCertificate(
        box=fr, worst_rest_error=worst, worst_at={u: float(where[FRICTION.index(u)]) for u in unc},
        per_parameter=per, moving_at_tf=moving, switch_timing=switch_timing_1dof(
            params, profile, q0), samples=plan.count,
        excursion=excursion_of(tracks[0] if len(tracks) == 1 else np.vstack(tracks), tr[0]))


def switch_timing_1dof(params: Arm1DofParams, profile: CurrentProfile, q0: float) -> list[float]:
    """Rest-position change (rad) per 100 µs delay of each switch time t_1..t_N (t_N: the start
    of the coast), central differences ±SWITCH_H on the nominal model."""
    times = np.ascontiguousarray(profile.step_times, dtype=float)
    cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
    c = float(params.n * params.kt)
    one = np.array([[params.pv, params.pc, params.pt]], dtype=float)
    return [float(x) for x in _switch_timing(float(params.J), c, one, times, cur,
                                             float(profile.tf), float(q0), SWITCH_H)]


@njit(cache=True, nogil=True)
def _switch_timing(J, c, friction, times, cur, tf, q0, h):
    """Central differences (±h s, a shifted switch capped at tf) of the rest position per
    100 µs, for each switch time t_1..t_N."""
    n = times.shape[0] - 1
    out = np.empty(n)
    flag = np.ones(1, dtype=np.bool_)
    t = times.copy()
    for j in range(1, n + 1):
        t[j] = min(times[j] + h, tf)
        qp, _ = batch_core(J, c, friction, flag, t, cur, tf, q0)
        t[j] = min(times[j] - h, tf)
        qm, _ = batch_core(J, c, friction, flag, t, cur, tf, q0)
        t[j] = times[j]
        out[j - 1] = (qp[0] - qm[0]) / (2.0 * h) * 1e-4
    return out
