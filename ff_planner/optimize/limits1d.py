"""Position and speed limits of a 1-DOF move as constraints of the planners (rad, rad/s).

A request's ``MotionLimits`` hold along the whole motion — powered part, coast, and the
zero-current slide after tf until the arm rests — at every friction point of the box. For a plan
(step times t (s), currents I (A)) and friction scale factors p_s, ``arm1dof.track_core`` gives
exactly the lowest position q_min,s, the highest q_max,s and the peak speed v_s; the constraints
are

    g_s = [q_min,s − position_min,  position_max − q_max,s,  velocity_max − v_s] ≥ 0

(only the limits given). ``limit_terms`` returns them with their Jacobian in the decisions
(currents, interior switch times, optionally the coast-entry time) by forward differences of the
exact simulation (the extremes are piecewise smooth in the decisions). ``Limits1D.excess`` is the
check every planner makes before it answers: the largest violation over the certificate's own
box points (``certificate.design_points``), so that the returned plan's certified excursion
stays within the limits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence

import numpy as np
from numba import njit

from ff_planner.model.arm1dof import (
    FRICTION,
    TR_MAX,
    TR_MIN,
    TR_SPEED,
    TRACK_COLS,
    track_capacity,
    track_core,
)
from ff_planner.model.limits import MotionLimits
from ff_planner.model.params import Arm1DofParams
from ff_planner.optimize.certificate import design_points
from ff_planner.optimize.sample_box import box_corners, box_fractions

LIMIT_H_CURRENT = 1e-6   # A, forward-difference step of the current columns
LIMIT_H_TIME = 1e-7      # s, forward-difference step of the switch-time columns
LIMIT_SCALE = 1e3        # constraint rows in mrad (mrad/s): SLSQP's tolerances suit O(1) values


@njit(cache=True, nogil=True)
def _excess_one(row, lo, hi, vmax):
    """Largest violation (rad or rad/s) of one ``track_core`` row; inf if it never stops."""
    if not (math.isfinite(row[TR_MIN]) and math.isfinite(row[TR_MAX])
            and math.isfinite(row[TR_SPEED])):
        return math.inf
    return max(0.0, lo - row[TR_MIN], row[TR_MAX] - hi, row[TR_SPEED] - vmax)


@njit(cache=True, nogil=True)
def excess_batch(J, c, pvals, scales, times, cur, tf, q0, lo, hi, vmax):
    """Largest violation (rad or rad/s, 0 = within the limits, inf = a point never stops) of
    [lo, hi] (rad) and |q̇| ≤ vmax (rad/s) over the rows of friction scale factors (S, 3)."""
    seg = np.empty((track_capacity(cur.shape[0]), 7))
    ev = np.empty((0, 3))
    row = np.empty(TRACK_COLS)
    worst = 0.0
    for s in range(scales.shape[0]):
        track_core(J, c, pvals[0] * scales[s, 0], pvals[1] * scales[s, 1],
                   pvals[2] * scales[s, 2], times, cur, tf, q0, seg, ev, row)
        worst = max(worst, _excess_one(row, lo, hi, vmax))
        if worst == math.inf:
            break
    return worst


@njit(cache=True, nogil=True)
def excess_each(J, c, pvals, scales, times, cur, tf, q0, lo, hi, vmax):
    """``excess_batch`` per row of friction scale factors: (S,) rad or rad/s."""
    seg = np.empty((track_capacity(cur.shape[0]), 7))
    ev = np.empty((0, 3))
    row = np.empty(TRACK_COLS)
    out = np.empty(scales.shape[0])
    for s in range(scales.shape[0]):
        track_core(J, c, pvals[0] * scales[s, 0], pvals[1] * scales[s, 1],
                   pvals[2] * scales[s, 2], times, cur, tf, q0, seg, ev, row)
        out[s] = _excess_one(row, lo, hi, vmax)
    return out


@njit(cache=True, nogil=True)
def _values(J, c, pvals, scales, times, cur, tf, q0, lo, hi, vmax, seg, ev, row, out):
    """Constraint values g (S·3,) ≥ 0 (see the module docstring) into ``out``; a point that
    never stops gives −1e3 rad in each row (infeasible, finite for SLSQP)."""
    for s in range(scales.shape[0]):
        track_core(J, c, pvals[0] * scales[s, 0], pvals[1] * scales[s, 1],
                   pvals[2] * scales[s, 2], times, cur, tf, q0, seg, ev, row)
        ok = math.isfinite(row[TR_MIN]) and math.isfinite(row[TR_MAX]) and \
            math.isfinite(row[TR_SPEED])
        out[3 * s] = row[TR_MIN] - lo if ok else -1e3
        out[3 * s + 1] = hi - row[TR_MAX] if ok else -1e3
        out[3 * s + 2] = vmax - row[TR_SPEED] if ok else -1e3


@njit(cache=True, nogil=True)
def limit_values(J, c, pvals, scales, times, cur, tf, q0, lo, hi, vmax):
    """g (S·3,) of ``limit_terms`` without the Jacobian."""
    seg = np.empty((track_capacity(cur.shape[0]), 7))
    ev = np.empty((0, 3))
    row = np.empty(TRACK_COLS)
    g = np.empty(3 * scales.shape[0])
    _values(J, c, pvals, scales, times, cur, tf, q0, lo, hi, vmax, seg, ev, row, g)
    return g


@njit(cache=True, nogil=True)
def limit_terms(J, c, pvals, scales, times, cur, tf, q0, lo, hi, vmax, n_times, hc, ht):
    """(g (S·3,), ∂g/∂x (S·3, N + n_times)): the limit constraints at the plan and their forward-
    difference Jacobian in x = (I_1..I_N, t_1..t_{n_times}) (A, s). Rows of an absent limit
    (±inf) are large positive constants with zero gradient."""
    n = cur.shape[0]
    m = 3 * scales.shape[0]
    seg = np.empty((track_capacity(n), 7))
    ev = np.empty((0, 3))
    row = np.empty(TRACK_COLS)
    g = np.empty(m)
    _values(J, c, pvals, scales, times, cur, tf, q0, lo, hi, vmax, seg, ev, row, g)
    G = np.zeros((m, n + n_times))
    gp = np.empty(m)
    cc = cur.copy()
    for j in range(n):
        cc[j] = cur[j] + hc
        _values(J, c, pvals, scales, times, cc, tf, q0, lo, hi, vmax, seg, ev, row, gp)
        cc[j] = cur[j]
        for r in range(m):
            G[r, j] = (gp[r] - g[r]) / hc
    tt = times.copy()
    for j in range(n_times):
        tt[j + 1] = times[j + 1] + ht
        _values(J, c, pvals, scales, tt, cur, tf, q0, lo, hi, vmax, seg, ev, row, gp)
        tt[j + 1] = times[j + 1]
        for r in range(m):
            G[r, n + j] = (gp[r] - g[r]) / ht
    return g, G


def limit_bounds(limits: Optional[MotionLimits], joint: int = 0) -> tuple[float, float, float]:
    """(position_min, position_max, velocity_max) of one joint; ±inf where not limited."""
    if limits is None:
        return -math.inf, math.inf, math.inf
    lo = limits.position_min[joint] if limits.position_min else -math.inf
    hi = limits.position_max[joint] if limits.position_max else math.inf
    vm = limits.velocity_max[joint] if limits.velocity_max else math.inf
    return float(lo), float(hi), float(vm)


@dataclass
class Limits1D:
    """The limits of a 1-DOF request and the box points they are held at.

    lo, hi: position range (rad); vmax: speed limit (rad/s) (±inf: none); kinds: the limits
    given, in the order of the constraint rows (0 position_min, 1 position_max, 2 velocity_max);
    design: the certificate's box points (scale factors (S, 3)); corners: the 2^k corners and
    the centre, where the optimisers start holding the limits."""

    params: Arm1DofParams
    tf: float
    q0: float
    lo: float
    hi: float
    vmax: float
    design: np.ndarray
    corners: np.ndarray
    pvals: np.ndarray = field(init=False)    # (pv, pc, pt) nominal values
    _masks: dict = field(init=False, repr=False, compare=False, default_factory=dict)

    @classmethod
    def of(cls, limits: Optional[MotionLimits], params: Arm1DofParams, q0: float, tf: float,
           uncertain: Sequence[str], box: Optional[Mapping[str, float]] = None
           ) -> Optional["Limits1D"]:
        """None when ``limits`` limit nothing."""
        if limits is None or limits.empty:
            return None
        lo, hi, vm = limit_bounds(limits)
        fr = box_fractions([u for u in FRICTION if u in uncertain], box)
        return cls(params, float(tf), float(q0), lo, hi, vm, design_points(fr),
                   np.ascontiguousarray(box_corners(fr, FRICTION)))

    def __post_init__(self) -> None:
        p = self.params
        self.pvals = np.array([p.pv, p.pc, p.pt], dtype=float)

    @property
    def rows(self) -> np.ndarray:
        """Indices of the constraint rows of the limits given, per box point of 3 rows."""
        return np.array([k for k, v in enumerate((self.lo, self.hi, self.vmax))
                         if math.isfinite(v)], dtype=np.int64)

    def excess(self, times: np.ndarray, cur: np.ndarray,
               scales: Optional[np.ndarray] = None) -> float:
        """Largest violation (rad or rad/s; 0 = within) over ``scales`` (default: ``design``)."""
        p = self.params
        return float(excess_batch(float(p.J), float(p.n * p.kt), self.pvals,
                                  self.design if scales is None else scales,
                                  np.ascontiguousarray(times, dtype=float),
                                  np.ascontiguousarray(cur, dtype=float), self.tf, self.q0,
                                  self.lo, self.hi, self.vmax))

    def ok(self, times: np.ndarray, cur: np.ndarray) -> bool:
        return self.excess(times, cur) <= 0.0

    def terms(self, times: np.ndarray, cur: np.ndarray, scales: np.ndarray, n_times: int
              ) -> tuple[np.ndarray, np.ndarray]:
        """(g, ∂g/∂x) of ``limit_terms`` for the limits given only, in mrad (mrad/s)."""
        p = self.params
        g, G = limit_terms(float(p.J), float(p.n * p.kt), self.pvals,
                           np.ascontiguousarray(scales), np.ascontiguousarray(times, dtype=float),
                           np.ascontiguousarray(cur, dtype=float), self.tf, self.q0, self.lo,
                           self.hi, self.vmax, int(n_times), LIMIT_H_CURRENT, LIMIT_H_TIME)
        sel = self._select(g.shape[0])
        return LIMIT_SCALE * g[sel], LIMIT_SCALE * G[sel]

    def values(self, times: np.ndarray, cur: np.ndarray, scales: np.ndarray) -> np.ndarray:
        """g of ``terms`` without the Jacobian (mrad, mrad/s)."""
        p = self.params
        g = limit_values(float(p.J), float(p.n * p.kt), self.pvals, np.ascontiguousarray(scales),
                         np.ascontiguousarray(times, dtype=float),
                         np.ascontiguousarray(cur, dtype=float), self.tf, self.q0, self.lo,
                         self.hi, self.vmax)
        return LIMIT_SCALE * g[self._select(g.shape[0])]

    def _select(self, m: int) -> np.ndarray:
        """Mask of the constraint rows of the limits given among m = 3·S rows (kept per m: the
        solvers ask for it at every evaluation)."""
        mask = self._masks.get(m)
        if mask is None:
            mask = np.any((np.arange(m) % 3)[:, None] == self.rows[None, :], axis=1)
            self._masks[m] = mask
        return mask

    def worst_points(self, times: np.ndarray, cur: np.ndarray, count: int) -> np.ndarray:
        """The ``count`` design points of largest violation (> 0) (scale factors)."""
        p = self.params
        out = excess_each(float(p.J), float(p.n * p.kt), self.pvals, self.design,
                          np.ascontiguousarray(times, dtype=float),
                          np.ascontiguousarray(cur, dtype=float), self.tf, self.q0, self.lo,
                          self.hi, self.vmax)
        order = np.argsort(-out)[:count]
        return self.design[order[out[order] > 0.0]]

    def describe(self) -> str:
        parts = []
        if math.isfinite(self.lo):
            parts.append(f"position_min {self.lo:g} rad")
        if math.isfinite(self.hi):
            parts.append(f"position_max {self.hi:g} rad")
        if math.isfinite(self.vmax):
            parts.append(f"velocity_max {self.vmax:g} rad/s")
        return ", ".join(parts)

    def advice(self) -> str:
        """What a user can change when no plan keeps within the limits."""
        return (f"no plan found that keeps within {self.describe()} over the whole motion at "
                f"every box point; widen the position range, raise velocity_max, give a longer "
                f"move time, a smaller friction box, or more steps")
