"""The 1-DOF arm (paper Eq. 22 with the friction of Eq. 9): exact event-based simulation.

    J·q̈ = T − pv·q̇ − sign(q̇)·(pc + pt·|T|),   T = n·kt·I        (q̇ ≠ 0)
    q̇ = 0 and |T| ≤ pc + pt·|T|  →  the joint sticks (until the current changes)

The friction law comes from ``ff_planner.model.friction``. Between events (current switches,
velocity zero crossings) the motion v' = a·v + b, a = −pv/J, b = (T − s·L)/J, has a closed form
(see ``series1d``); zero crossings are found in closed form too. No ODE solver. The compiled
kernels here ARE the suite's 1-DOF simulator: ``simulate`` (final state, optional trajectory),
``rest_position`` (where the arm stops with zero current after tf) and ``advance`` (one constant
current interval; the simulated drive uses it). Units: rad, rad/s, A, Nm, s.

Exact derivatives (forward mode through the event times) live in ``arm1dof_derivatives``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from numba import njit

from ff_planner.core.errors import ParameterError, PlanningError
from ff_planner.core.results import SimResult
from ff_planner.model.arm1dof_derivatives import NP, Q_, TSTOP_, V_, hd_sim, workspace
from ff_planner.model.friction import breakaway_excess, exceeds_stiction, sliding_level
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.series1d import phi12_value, psi_value

# event kinds recorded by the simulator
EV_BREAKAWAY = 1   # leaves rest (start, or a current switch while stuck)
EV_STICK = 2       # velocity reaches zero and the joint sticks
EV_REVERSE = 3     # velocity reaches zero and the joint moves on the other way
EV_REST = 4        # comes to rest after tf (zero current)
EVENT_NAMES = {EV_BREAKAWAY: "breakaway", EV_STICK: "stick", EV_REVERSE: "reverse", EV_REST: "rest"}

# seg rows: t0, t1, q0, v0, a, b, moving(1)/stuck(0)
_SEG_COLS = 7


@njit("UniTuple(float64, 2)(float64, float64, float64, float64, float64)", cache=True, nogil=True)
def _free(q: float, v: float, tau: float, a: float, b: float):
    """State after τ s of v' = a·v + b from (q, v)."""
    ez, f1, f2 = phi12_value(a * tau)
    e1 = tau * f1
    return q + v * e1 + b * tau * tau * f2, v * ez + b * e1


@njit("float64(float64, float64, float64)", cache=True, nogil=True)
def _cross_time(v: float, a: float, b: float) -> float:
    """Time until v' = a·v + b brings v to zero (inf if never); needs b opposing v."""
    if b == 0.0 or b * v >= 0.0:
        return math.inf
    x = v / b
    z = a * x
    if z <= -1.0:
        return math.inf
    return -x * psi_value(z)


@njit("int64(float64[:, ::1], int64, float64, float64, float64, float64, float64, float64, float64)",
      cache=True, nogil=True)
def _record(seg, nseg, t0, t1, q, v, a, b, moving):
    """Store one segment row (t0, t1, q0, v0, a, b, moving) if there is room; returns nseg + 1."""
    if nseg < seg.shape[0]:
        seg[nseg, 0] = t0
        seg[nseg, 1] = t1
        seg[nseg, 2] = q
        seg[nseg, 3] = v
        seg[nseg, 4] = a
        seg[nseg, 5] = b
        seg[nseg, 6] = moving
    return nseg + 1


_PHASE_SIG = ("Tuple((float64, float64, float64, int64, int64))(float64, float64, float64, "
              "float64, float64, float64, float64, float64, float64, float64[:, ::1], int64, "
              "float64[:, ::1], int64, int64)")


@njit(_PHASE_SIG, cache=True, nogil=True)
def _phase(t, q, v, torque, t_end, J, a, pc, pt, seg, nseg, ev, nev, rest_kind):
    """Advance the state under constant ``torque`` from t to t_end (may be inf).

    Records segments/events when the arrays have room (size 0 arrays: no recording).
    Returns (t, q, v, nseg, nev).
    """
    fric = sliding_level(torque, pc, pt)
    breaks = exceeds_stiction(torque, fric)
    rel = breakaway_excess(torque, fric) / fric if fric > 0.0 else math.inf
    reversed_ = False
    while t < t_end:
        if v == 0.0:
            if not breaks:                      # sticks (Eq. 9, q̇ = 0 branch)
                nseg = _record(seg, nseg, t, t_end, q, 0.0, a, 0.0, 0.0)
                return t_end, q, 0.0, nseg, nev
            s = 1.0 if torque > 0.0 else -1.0
            if not reversed_ and nev < ev.shape[0]:
                ev[nev, 0] = t
                ev[nev, 1] = EV_BREAKAWAY
                ev[nev, 2] = rel
            if not reversed_:
                nev += 1
        else:
            s = 1.0 if v > 0.0 else -1.0
        b = (torque - s * fric) / J
        tau = _cross_time(v, a, b)
        t_next = t + tau
        if t_next < t_end:
            q1, v1 = _free(q, v, tau, a, b)
            kind = EV_REVERSE
            if not breaks or torque * s >= 0.0:
                kind = EV_STICK
            if math.isinf(t_end) and torque == 0.0:
                kind = rest_kind
        else:
            t_next = t_end
            if math.isinf(t_end):   # runs away (negative viscous friction beats Coulomb)
                nseg = _record(seg, nseg, t, t_end, q, v, a, b, 1.0)
                if a < 0.0 and b == 0.0:    # pure viscous decay: comes to rest at infinity
                    return t_end, q - v / a, 0.0, nseg, nev
                return t_end, math.nan, math.nan, nseg, nev
            q1, v1 = _free(q, v, t_end - t, a, b)
            kind = 0
        nseg = _record(seg, nseg, t, t_next, q, v, a, b, 1.0)
        t, q, v = t_next, q1, v1
        if kind != 0:
            v = 0.0
            if nev < ev.shape[0]:
                ev[nev, 0] = t
                ev[nev, 1] = kind
                ev[nev, 2] = rel
            nev += 1
            if kind == EV_REST:
                return t_end, q, 0.0, nseg, nev
            reversed_ = kind == EV_REVERSE
    return t, q, v, nseg, nev


@njit(cache=True, nogil=True)
def sim_core(J, c, pv, pc, pt, times, cur, tf, q0, v0, to_rest, seg, ev):
    """Simulate a piecewise-constant current profile (A) from (q0, v0) at times[0].

    Phases: cur[i] on [times[i], times[i+1]), zero current on [times[-1], tf), and with
    ``to_rest`` zero current after tf until the arm stops. Returns (q, v, nseg, nev): the state
    at tf (or at rest; nan if it never stops), and the number of segments/events.
    """
    a = -pv / J
    t = times[0]
    q = q0
    v = v0
    nseg = 0
    nev = 0
    for i in range(cur.shape[0]):
        t, q, v, nseg, nev = _phase(t, q, v, c * cur[i], times[i + 1], J, a, pc, pt,
                                    seg, nseg, ev, nev, EV_STICK)
    if tf > t:
        t, q, v, nseg, nev = _phase(t, q, v, 0.0, tf, J, a, pc, pt, seg, nseg, ev, nev,
                                    EV_STICK)
    if to_rest:
        t, q, v, nseg, nev = _phase(t, q, v, 0.0, math.inf, J, a, pc, pt, seg, nseg, ev,
                                    nev, EV_REST)
    return q, v, nseg, nev


@njit(cache=True, nogil=True)
def batch_core(J, c, friction, to_rest, times, cur, tf, q0):
    """Final states (q, v) for each row (pv, pc, pt) of ``friction`` (M, 3), with the matching
    ``to_rest`` flag (M,): one compiled call for a verification sweep."""
    m = friction.shape[0]
    qs = np.empty(m)
    vs = np.empty(m)
    seg = np.empty((0, _SEG_COLS))
    ev = np.empty((0, 3))
    for i in range(m):
        q, v, _, _ = sim_core(J, c, friction[i, 0], friction[i, 1], friction[i, 2], times, cur,
                              tf, q0, 0.0, to_rest[i], seg, ev)
        qs[i] = q
        vs[i] = v
    return qs, vs


#: columns of ``track_core``'s output row: where the arm rests (rad), its velocity at tf
#: (rad/s), the lowest and the highest position (rad) and the peak |speed| (rad/s) from t = 0
#: until rest
TRACK_COLS = 5
TR_REST, TR_VTF, TR_MIN, TR_MAX, TR_SPEED = range(TRACK_COLS)


@njit(cache=True, nogil=True)
def track_capacity(n: int) -> int:
    """Segment rows ``track_core`` needs for N steps: at most 3 per constant-current phase (a
    slide to zero speed, a reversal, a stuck rest), N steps + the coast + the rest phase."""
    return 3 * (n + 2) + 4


@njit(cache=True, nogil=True)
def track_core(J, c, pv, pc, pt, times, cur, tf, q0, seg, ev, out):
    """Simulate to rest and write ``out`` (TRACK_COLS,): rest position, velocity at tf, lowest /
    highest position and peak |speed| from t = 0 until the arm stops (nan if it never stops or
    ``seg`` has too few rows, see ``track_capacity``).

    Exact: within a recorded segment v' = a·v + b keeps v monotone (v' = (a·v0 + b)·e^{aτ} has
    one sign) and of one sign (every zero crossing ends a segment), so q is monotone too, and
    the extremes of q and |v| over the motion lie at segment ends — each one the start of the
    next segment, the last one the rest position (v = 0)."""
    q, v, nseg, _ = sim_core(J, c, pv, pc, pt, times, cur, tf, q0, 0.0, True, seg, ev)
    if nseg > seg.shape[0] or not math.isfinite(q):
        for k in range(TRACK_COLS):
            out[k] = math.nan
        out[TR_REST] = q
        return
    lo = q
    hi = q
    sp = 0.0
    vtf = 0.0
    seen_tf = False
    for k in range(nseg):
        qk = seg[k, 2]
        vk = abs(seg[k, 3])
        if qk < lo:
            lo = qk
        if qk > hi:
            hi = qk
        if vk > sp:
            sp = vk
        if not seen_tf and seg[k, 0] >= tf:
            seen_tf = True
            vtf = seg[k, 3] if seg[k, 6] != 0.0 else 0.0
    out[TR_REST] = q
    out[TR_VTF] = vtf
    out[TR_MIN] = lo
    out[TR_MAX] = hi
    out[TR_SPEED] = sp


@njit(cache=True, nogil=True)
def track_batch(J, c, pvals, scales, times, cur, tf, q0, out):
    """``track_core`` at each row of friction scale factors (S, 3) (parameters pvals·scale):
    out (S, TRACK_COLS)."""
    seg = np.empty((track_capacity(cur.shape[0]), _SEG_COLS))
    ev = np.empty((0, 3))
    for s in range(scales.shape[0]):
        track_core(J, c, pvals[0] * scales[s, 0], pvals[1] * scales[s, 1],
                   pvals[2] * scales[s, 2], times, cur, tf, q0, seg, ev, out[s])


def track(params: Arm1DofParams, profile: CurrentProfile, q0: float,
          scales: Optional[np.ndarray] = None) -> np.ndarray:
    """``track_batch`` for a profile: (S, TRACK_COLS) at the friction scale factors ``scales``
    (S, 3) of (pv, pc, pt) (default: the nominal friction only). rad, rad/s."""
    sc = np.ones((1, 3)) if scales is None else np.ascontiguousarray(scales, dtype=float)
    times, cur = _profile_arrays(profile)
    out = np.empty((sc.shape[0], TRACK_COLS))
    track_batch(float(params.J), float(params.n * params.kt),
                np.array([params.pv, params.pc, params.pt], dtype=float), sc, times, cur,
                float(profile.tf), float(q0), out)
    return out


@njit(cache=True, nogil=True)
def advance_core(J, c, pv, pc, pt, q, v, current, dt):
    """State after ``dt`` s of constant ``current`` (A) from (q, v)."""
    seg = np.empty((0, _SEG_COLS))
    ev = np.empty((0, 3))
    t, q1, v1, _, _ = _phase(0.0, q, v, c * current, dt, J, -pv / J, pc, pt, seg, 0, ev, 0,
                             EV_STICK)
    return q1, v1


@njit(cache=True, nogil=True)
def eval_segments(seg, nseg, tgrid):
    """Sample (q, v) at the times ``tgrid`` (s, ascending) from recorded segments."""
    m = tgrid.shape[0]
    qs = np.empty(m)
    vs = np.empty(m)
    k = 0
    for i in range(m):
        t = tgrid[i]
        while k < nseg - 1 and t >= seg[k, 1]:
            k += 1
        tau = t - seg[k, 0]
        if tau < 0.0:
            tau = 0.0
        if seg[k, 6] == 0.0:
            qs[i] = seg[k, 2]
            vs[i] = 0.0
        else:
            qs[i], vs[i] = _free(seg[k, 2], seg[k, 3], tau, seg[k, 4], seg[k, 5])
    return qs, vs


def _args(params: Arm1DofParams) -> tuple[float, float, float, float, float]:
    """(J, n·kt, pv, pc, pt): the kernels' physical arguments."""
    return (float(params.J), float(params.n * params.kt), float(params.pv), float(params.pc),
            float(params.pt))


def _profile_arrays(profile: CurrentProfile) -> tuple[np.ndarray, np.ndarray]:
    cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
    times = np.ascontiguousarray(profile.step_times, dtype=float)
    return times, cur


def final_state(params: Arm1DofParams, profile: CurrentProfile, q0: float, qd0: float = 0.0,
                *, to_rest: bool = False) -> tuple[float, float]:
    """(q, q̇) at tf (rad, rad/s), or where the arm comes to rest with ``to_rest``."""
    times, cur = _profile_arrays(profile)
    seg = np.empty((0, _SEG_COLS))
    ev = np.empty((0, 3))
    q, v, _, _ = sim_core(*_args(params), times, cur, profile.tf, float(q0), float(qd0),
                          to_rest, seg, ev)
    return float(q), float(v)


def _one(x: float | Sequence[float] | np.ndarray, name: str) -> float:
    """The joint's value from a number or a 1-element sequence (rad, rad/s or A)."""
    a = np.atleast_1d(np.asarray(x, dtype=float))
    if a.shape != (1,):
        raise ParameterError(f"{name} needs 1 value for model 'arm1dof', got {a.size}")
    return float(a[0])


def simulate_arm1dof(params: Arm1DofParams, profile: CurrentProfile,
                     q0: float | Sequence[float], qd0: float | Sequence[float] | None = None, *,
                     trajectory: bool = False, dt: float = 1e-3,
                     t_end: Optional[float] = None) -> SimResult:
    """Exact simulation from (q0, qd0) (rad, rad/s; numbers or 1-element sequences); returns
    the SimResult at tf.

    With ``trajectory``: samples every ``dt`` s on [0, t_end] (default tf) plus every event and
    switch time; t, q, qd, current arrays (s, rad, rad/s, A, current shape (M, 1)).
    """
    q0 = _one(q0, "q0")
    qd0 = 0.0 if qd0 is None else _one(qd0, "qd0")
    times, cur = _profile_arrays(profile)
    cap = 3 * (cur.shape[0] + 3) + 4
    seg = np.zeros((cap, _SEG_COLS))
    ev = np.zeros((cap, 3))
    args = _args(params)
    q, v, nseg, nev = sim_core(*args, times, cur, profile.tf, float(q0), float(qd0), False,
                               seg, ev)
    events = [(float(ev[i, 0]), EVENT_NAMES[int(ev[i, 1])]) for i in range(min(nev, cap))]
    res = SimResult(q_f=np.array([q]), qd_f=np.array([v]), events=events)
    if trajectory:
        horizon = profile.tf if t_end is None else float(t_end)
        if horizon > profile.tf:   # zero current after tf: re-record up to the horizon
            seg = np.zeros((cap, _SEG_COLS))
            times_x, cur_x = times, cur
            if profile.tf > times[-1]:
                times_x, cur_x = np.append(times, profile.tf), np.append(cur, 0.0)
            _, _, nseg, _ = sim_core(*args, times_x, cur_x, horizon, float(q0), float(qd0),
                                     False, seg, np.empty((0, 3)))
        grid = np.arange(0.0, horizon, dt)
        ev_t = [e[0] for e in events if e[0] <= horizon]
        grid = np.unique(np.concatenate([grid, times, ev_t, [profile.tf, horizon]]))
        grid = grid[(grid >= 0.0) & (grid <= horizon)]
        qs, vs = eval_segments(seg, min(nseg, cap), grid)
        currents = np.array([profile.current_at(t) for t in grid]).reshape(-1, 1)
        res.t, res.q, res.qd, res.current = grid, qs.reshape(-1, 1), vs.reshape(-1, 1), currents
    return res


def rest_position_arm1dof(params: Arm1DofParams, profile: CurrentProfile,
                          q0: float | Sequence[float],
                          qd0: float | Sequence[float] | None = None) -> np.ndarray:
    """Where the arm comes to rest (rad, shape (1,)) with zero current after tf; nan if it never
    stops."""
    q = final_state(params, profile, _one(q0, "q0"), 0.0 if qd0 is None else _one(qd0, "qd0"),
                    to_rest=True)[0]
    return np.array([q])


def advance(params: Arm1DofParams, q: float, qd: float, current: float,
            dt: float) -> tuple[float, float]:
    """(q, q̇) after ``dt`` s of constant ``current`` (A) from (q, q̇) — exact, any dt ≥ 0."""
    if not dt >= 0.0:
        raise ValueError(f"dt must be >= 0 s, got {dt}")
    J, c, pv, pc, pt = _args(params)
    q1, v1 = advance_core(J, c, pv, pc, pt, float(q), float(qd), float(current), float(dt))
    return float(q1), float(v1)


def advance_joints(params: Arm1DofParams, q: float | Sequence[float],
                   qd: float | Sequence[float], currents: float | Sequence[float],
                   dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``advance`` with per-joint arrays of shape (1,) (the model registry's convention)."""
    q1, v1 = advance(params, _one(q, "q"), _one(qd, "qd"), _one(currents, "currents"), dt)
    return np.array([q1]), np.array([v1])


FRICTION = ("pv", "pc", "pt")
#: scale used for a friction parameter whose nominal value is 0 (table 2 magnitudes): relative
#: changes of zero are meaningless, so robustness to it is judged per this absolute amount
ZERO_SCALE = {"pv": 0.05, "pc": 0.19, "pt": 0.22}


def friction_scale(params: Arm1DofParams, uncertain: Sequence[str] = FRICTION) -> np.ndarray:
    """(3,) scales of pv, pc, pt: |p| (or ZERO_SCALE when p = 0) for uncertain ones, else 0.

    Derivatives times these scales are "rad per 100 % change"; the kink radius is in the same
    relative units."""
    out = np.zeros(3)
    for i, k in enumerate(FRICTION):
        if k in uncertain:
            v = abs(float(getattr(params, k)))
            out[i] = v if v > 0.0 else ZERO_SCALE[k]
    return out


@dataclass
class Derivatives1D:
    """Exact derivatives of the final state (rad, rad/s) of a 1-DOF move.

    dq_dp / dqd_dp: {"pv", "pc", "pt"} → ∂q_f/∂p, ∂q̇_f/∂p (rad or rad/s per unit of p).
    dq_dI, dqd_dI: (N,) per A of each step current; d2q_dpdI: (3, N) rows pv, pc, pt.
    t_stop: time (s) the arm came to rest for good (inf while moving).
    tf_radius: relative parameter change after which the arm is no longer at rest at tf (0 when
    it is moving at tf); q(tf) stays C¹ there, q̇(tf) does not, the rest position is smooth.
    kink_radius: first-order relative change of the uncertain parameters that reaches a
    non-smooth point (zero crossing at a switch time, breakaway edge); the derivatives are
    one-sided beyond it. ``smooth`` = kink_radius ≥ the radius asked for.
    """

    q: float
    qd: float
    dq_dp: dict
    dqd_dp: dict
    dq_dI: np.ndarray
    dqd_dI: np.ndarray
    d2q_dpdI: np.ndarray
    t_stop: float
    kink_radius: float
    smooth: bool
    tf_radius: float = math.inf


def derivatives(params: Arm1DofParams, profile: CurrentProfile, q0: float, *,
                uncertain: Sequence[str] = FRICTION, to_rest: bool = False,
                min_radius: float = 1e-3) -> Derivatives1D:
    """Exact (forward-mode) derivatives of q(tf), q̇(tf) — or of the rest position with
    ``to_rest`` — w.r.t. the friction parameters and the step currents."""

    bad = [u for u in uncertain if u not in FRICTION]
    if bad:
        raise ValueError(f"unknown friction parameter(s) {bad}; choose from {FRICTION}")
    times, cur = _profile_arrays(profile)
    n = cur.shape[0]
    W = workspace(n)
    J, c, pv, pc, pt = _args(params)
    pw = friction_scale(params, uncertain)
    kink, tf_radius = hd_sim(J, c, pv, pc, pt, times, cur, profile.tf, float(q0), bool(to_rest),
                             pw, W)
    base = 4 + n
    return Derivatives1D(
        q=float(W[Q_, 0]), qd=float(W[V_, 0]),
        dq_dp={k: float(W[Q_, 1 + i]) for i, k in enumerate(FRICTION)},
        dqd_dp={k: float(W[V_, 1 + i]) for i, k in enumerate(FRICTION)},
        dq_dI=W[Q_, 4:4 + n].copy(), dqd_dI=W[V_, 4:4 + n].copy(),
        d2q_dpdI=W[Q_, base:base + NP * n].reshape(NP, n).copy(),
        t_stop=float(W[TSTOP_, 0]), kink_radius=float(kink), smooth=bool(kink >= min_radius),
        tf_radius=float(tf_radius))


#: methods of ``sensitivities_arm1dof``
SENSITIVITY_METHODS = ("exact", "central", "forward")


def _finite_difference(params: Arm1DofParams, profile: CurrentProfile, q0: float,
                       names: Sequence[str], method: str, rel_step: Optional[float],
                       rest: bool) -> dict[str, np.ndarray]:
    """∂(q_f, q̇_f[, q_rest])/∂p by central or forward differences with a relative step."""

    def outputs(p: Arm1DofParams) -> np.ndarray:
        q, v = final_state(p, profile, q0)
        if rest:
            return np.array([q, v, final_state(p, profile, q0, to_rest=True)[0]])
        return np.array([q, v])

    f0 = outputs(params) if method == "forward" else None
    step = rel_step if rel_step is not None else (1e-3 if method == "forward" else 1e-6)
    if not step > 0.0:
        raise ParameterError(f"rel_step must be > 0, got {step}")
    out = {}
    for name in names:
        pval = float(getattr(params, name))
        h = step * (abs(pval) if pval != 0.0 else 1.0)
        fp = outputs(params.replace(**{name: pval + h}))
        if f0 is not None:
            d = (fp - f0) / h
        else:
            fm = outputs(params.replace(**{name: pval - h}))
            d = (fp - fm) / (2.0 * h)
        out[name] = d
    return out


def sensitivities_arm1dof(params: Arm1DofParams, profile: CurrentProfile,
                          q0: float | Sequence[float], names: Sequence[str] = FRICTION,
                          method: str = "exact", rel_step: Optional[float] = None, *,
                          rest: bool = False) -> dict[str, float]:
    """∂q(tf)/∂p (key "pc"), ∂q̇(tf)/∂p ("qd/pc") and with ``rest`` the derivative of the rest
    position after tf ("qrest/pc"), in rad or rad/s per unit of p, from rest at ``q0`` (rad).

    method "exact": forward mode through the event times (``derivatives``); "central" /
    "forward": finite differences with relative step ``rel_step`` (default 1e-6 / 1e-3).
    """
    qa = np.atleast_1d(np.asarray(q0, dtype=float))
    if qa.shape != (1,) or not np.isfinite(qa[0]):
        raise ParameterError(f"q0 needs 1 finite value for model 'arm1dof', got {qa.tolist()}")
    if method not in SENSITIVITY_METHODS:
        raise ParameterError(f"unknown method {method!r}; use one of "
                             f"{', '.join(SENSITIVITY_METHODS)}")
    if profile.n_joints != 1:
        raise PlanningError(f"profile has {profile.n_joints} current column(s); model "
                            "'arm1dof' needs 1")
    profile.validate()
    q = float(qa[0])
    out: dict[str, float] = {}
    if method == "exact":
        d = derivatives(params, profile, q, uncertain=names)
        for n in names:
            out[n] = d.dq_dp[n]
            out[f"qd/{n}"] = d.dqd_dp[n]
        if rest:
            dr = derivatives(params, profile, q, uncertain=names, to_rest=True)
            for n in names:
                out[f"qrest/{n}"] = dr.dq_dp[n]
        return out
    fd = _finite_difference(params, profile, q, names, method, rel_step, rest)
    for n, dd in fd.items():
        out[n] = float(dd[0])
        out[f"qd/{n}"] = float(dd[1])
        if rest:
            out[f"qrest/{n}"] = float(dd[2])
    return out
