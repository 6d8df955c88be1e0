"""Excitation for friction identification of the 1-DOF arm: constant-current runs inside an envelope.

Sliding, Eq. 9 gives J·q̈ = T − pv·q̇ − s·(pc + pt·|T|) (s = sign q̇, T = n·kt·I). Each run is

    +s·I for t1 (accelerate: J·q̈ = |T|·(1 − pt) − pc − pv·q̇),
    −s·I for t2 (brake through a stop and reverse: J·q̈ = −|T|·(1 + pt) − pc − ..., then the
               aiding case again in the other direction),
    0 A until the arm sticks (coast: J·q̈ = −pc − pv·q̇, then stick),

at several current levels and both directions s = ±1, so that the data separate the terms: coast
phases give pc/J and pv/J, aiding and opposing torque at several levels give (1 ∓ pt)/J (hence pt
and, with J free, J), and each run holds the stick/slip transitions breakaway, reversal and stick.
Runs come in pairs (+, −) at one level: the model is symmetric, so each pair returns the arm to
where it started.

Every run is checked against the user's envelope (positions q_min..q_max, speeds ≤ v_max) at all
corners of a prior box around the guessed friction (``spread``, default ±50 %), and must end at
rest under each corner; the speed is lowered until it fits, and the design is refused
(ParameterError) if the envelope is too small for a useful run. Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from scipy.optimize import brentq

from ff_planner.core.errors import ParameterError
from ff_planner.identify.sampling import sample_params
from ff_planner.model.arm1dof import final_state, simulate_arm1dof
from ff_planner.model.friction import breakaway_torque
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile


@dataclass(frozen=True)
class Envelope:
    """Where the arm may go during identification: q_min..q_max (rad), |q̇| ≤ v_max (rad/s),
    |I| ≤ i_max (A; None = the model's limit)."""

    q_min: float
    q_max: float
    v_max: float
    i_max: Optional[float] = None

    def validate(self, q_start: float) -> None:
        for name in ("q_min", "q_max", "v_max"):
            if not math.isfinite(getattr(self, name)):
                raise ParameterError(f"envelope {name} must be finite")
        if not self.q_min < self.q_max:
            raise ParameterError(f"envelope needs q_min < q_max, got {self.q_min} >= {self.q_max} rad")
        if not self.v_max > 0.0:
            raise ParameterError(f"envelope v_max must be > 0 rad/s, got {self.v_max}")
        if self.i_max is not None and not self.i_max > 0.0:
            raise ParameterError(f"envelope i_max must be > 0 A, got {self.i_max}")
        if not self.q_min <= q_start <= self.q_max:
            raise ParameterError(f"the arm at {q_start:.4g} rad is outside the envelope "
                                 f"[{self.q_min:.4g}, {self.q_max:.4g}] rad")


@dataclass
class ExcitationRun:
    """One run: its profile (starts at rest at q0), level (A), direction (±1), the nominal
    figures (peak speed rad/s, end position rad) under the guessed friction, and ``reach`` (rad):
    the lowest and highest position relative to the start over the prior box's corners, also
    with a switch ``timing_margin`` late (what the envelope check of the design saw)."""

    profile: CurrentProfile
    level: float
    direction: int
    q0: float
    q_end: float
    peak_speed: float
    reach: tuple[float, float] = (0.0, 0.0)


@dataclass
class Excitation:
    """The runs in order (each starts where the previous one ended) and their total time (s)."""

    runs: list[ExcitationRun] = field(default_factory=list)
    spread: float = 0.5
    envelope: Optional[Envelope] = None

    @property
    def duration(self) -> float:
        return float(sum(r.profile.tf for r in self.runs))

    @property
    def profiles(self) -> list[CurrentProfile]:
        return [r.profile for r in self.runs]


def prior_corners(guess: Arm1DofParams, spread: float) -> list[Arm1DofParams]:
    """The 8 corners of the box guess·(1 ± spread) in pv, pc, pt (pt kept below 0.95)."""
    out = []
    for signs in itertools.product((-1.0, 1.0), repeat=3):
        vals = {k: float(getattr(guess, k)) * (1.0 + s * spread) for k, s in zip(("pv", "pc", "pt"), signs)}
        vals["pt"] = min(max(vals["pt"], 0.0), 0.95)
        vals["pc"] = max(vals["pc"], 0.0)
        out.append(guess.replace(**vals))
    return out


def _speed_after(p: Arm1DofParams, level: float, t1: float) -> float:
    prof = CurrentProfile(np.array([0.0, t1]), np.array([[level]]), t1, 0.0)
    return final_state(p, prof, 0.0)[1]


def _run_profile(p: Arm1DofParams, level: float, v_target: float, reverse: float) -> Optional[tuple[float, float]]:
    """(t1, t2) so that the nominal arm reaches v_target (rad/s) after t1 s of +level A and
    −reverse·v_target after t2 more s of −level A; None if level cannot reach v_target."""
    T = level * p.torque_per_amp
    if T <= breakaway_torque(p.pc, p.pt):
        return None
    hi = 1e-3
    while _speed_after(p, level, hi) < v_target:
        hi *= 2.0
        if hi > 60.0:
            return None
    t1 = brentq(lambda t: _speed_after(p, level, t) - v_target, 0.0, hi, xtol=1e-6)

    def v_end(t2: float) -> float:
        prof = CurrentProfile(np.array([0.0, t1, t1 + t2]), np.array([[level], [-level]]), t1 + t2, 0.0)
        return final_state(p, prof, 0.0)[1] + reverse * v_target

    hi2 = 1e-3
    while v_end(hi2) > 0.0:
        hi2 *= 2.0
        if hi2 > 60.0:
            return None
    return t1, float(brentq(v_end, 0.0, hi2, xtol=1e-6))


def _late(prof: CurrentProfile, margin: float) -> list[CurrentProfile]:
    """The profile and its copies with the brake switch, or the final zero, ``margin`` s late."""
    out = [prof]
    if margin > 0.0:
        st = prof.step_times
        for i in (1, 2):
            late = st.copy()
            late[i:] += margin
            out.append(CurrentProfile(late, prof.currents, prof.tf + margin, prof.coast))
    return out


def _check_corners(corners: Sequence[Arm1DofParams], prof: CurrentProfile, q0: float,
                   env: Envelope, margin: float = 0.0) -> tuple[bool, float, tuple[float, float]]:
    """(fits, time to rest s, reach rad relative to q0): every corner stays in the envelope and
    sticks for good before tf, also with a switch ``margin`` s late."""
    t_rest = 0.0
    lo = hi = 0.0
    for c, p in itertools.product(corners, _late(prof, margin)):
        res = simulate_arm1dof(c, p, q0, trajectory=True, dt=2e-3, t_end=p.tf)
        assert res.q is not None and res.qd is not None
        q, v = res.q[:, 0], res.qd[:, 0]
        if not (np.all(np.isfinite(q)) and q.min() >= env.q_min and q.max() <= env.q_max
                and np.abs(v).max() <= env.v_max and abs(float(res.qd_f[0])) == 0.0):
            return False, math.inf, (lo, hi)
        sticks = [t for t, kind in res.events if kind == "stick"]
        t_rest = max(t_rest, sticks[-1] if sticks else 0.0)
        lo, hi = min(lo, float(q.min()) - q0), max(hi, float(q.max()) - q0)
    return True, t_rest, (lo, hi)


def design_excitation(guess: Arm1DofParams, envelope: Envelope, q_start: float = 0.0, *,
                      levels: Optional[Sequence[float]] = None, n_levels: int = 4,
                      speed_fraction: float = 0.8, reverse: float = 0.4, spread: float = 0.5,
                      max_coast: float = 2.5, min_step: float = 0.02,
                      timing_margin: float = 0.0) -> Excitation:
    """Runs at ``n_levels`` currents (or the given ``levels``, A) in both directions, each inside
    ``envelope`` for every corner of the prior box guess·(1 ± spread).

    Levels default to a geometric series from 2.5× the breakaway current of the highest-friction
    corner to the current limit. Each run aims at speed_fraction·v_max and is slowed down (to
    1/4 of that at most) until all corners fit; ParameterError when a level cannot fit, when its
    drive phases would be shorter than ``min_step`` s (too few samples to see them) or the arm
    would not stop within ``max_coast`` s of zero current. ``timing_margin`` (s): the envelope
    must also hold when the brake switch or the final zero comes that late (a loaded host).
    """
    envelope.validate(q_start)
    if not 0.0 <= timing_margin < 1.0:
        raise ParameterError(f"timing_margin must be in [0, 1) s, got {timing_margin}")
    if not 0.0 <= spread < 1.0:
        raise ParameterError(f"spread must be in [0, 1), got {spread}")
    i_lim = float(guess.i_max if envelope.i_max is None else min(envelope.i_max, guess.i_max))
    corners = prior_corners(guess, spread)
    i_break = max(breakaway_torque(c.pc, c.pt) for c in corners) / guess.torque_per_amp
    if levels is None:
        lo = 2.5 * i_break
        if lo > i_lim:
            raise ParameterError(f"current limit {i_lim:.3g} A is below 2.5x the breakaway current "
                                 f"({i_break:.3g} A) of the prior box: the arm would barely move")
        levels = list(np.geomspace(lo, i_lim, max(1, int(n_levels)))) if n_levels > 1 else [i_lim]
    levels = [float(x) for x in levels]
    for x in levels:
        if not i_break < x <= i_lim + 1e-12:
            raise ParameterError(f"level {x:.3g} A must exceed the prior box's breakaway current "
                                 f"{i_break:.3g} A and stay within {i_lim:.3g} A")
    out = Excitation(spread=spread, envelope=envelope)
    q = float(q_start)
    first = 1 if (envelope.q_max - q) >= (q - envelope.q_min) else -1
    for level in levels:
        for direction in (first, -first):
            run = _fit_run(guess, corners, envelope, level, direction, q, speed_fraction, reverse,
                           max_coast, min_step, timing_margin)
            out.runs.append(run)
            q = run.q_end
    return out


def _fit_run(guess: Arm1DofParams, corners: Sequence[Arm1DofParams], env: Envelope, level: float,
             direction: int, q0: float, speed_fraction: float, reverse: float,
             max_coast: float, min_step: float, margin: float) -> ExcitationRun:
    v_target = speed_fraction * env.v_max
    why = "does not stay"
    for _ in range(6):
        tt = _run_profile(guess, level, v_target, reverse)
        if tt is not None:
            t1, t2 = tt
            if min(t1, t2) < min_step:
                why = f"needs drive phases shorter than {min_step:.3g} s to stay"
                break
            cur = direction * np.array([[level], [-level]])
            prof = CurrentProfile(np.array([0.0, t1, t1 + t2]), cur, t1 + t2 + max_coast, max_coast)
            ok, t_rest, reach = _check_corners(corners, prof, q0, env, margin)
            if ok:
                coast = max(0.05, t_rest - (t1 + t2)) + 0.1
                prof = CurrentProfile(prof.step_times, cur, t1 + t2 + coast, coast)
                tq = np.linspace(0.0, prof.tf, 400)
                qn, vn = sample_params(guess, prof, q0, tq)
                return ExcitationRun(prof, level, direction, q0, float(qn[-1]), float(np.abs(vn).max()), reach)
        v_target *= 0.75
    room = min(env.q_max - q0, q0 - env.q_min) if direction < 0 else env.q_max - q0
    raise ParameterError(
        f"envelope too small for the excitation: a run at {level:.3g} A from {q0:.4g} rad {why} "
        f"within [{env.q_min:.4g}, {env.q_max:.4g}] rad, |v| <= {env.v_max:.3g} rad/s and stop within "
        f"{max_coast:.3g} s for all friction in the ±{100 * (spread_of(corners, guess)):.0f} % prior box "
        f"(room ahead {room:.3g} rad); widen the envelope, lower the levels or narrow the prior")


def spread_of(corners: Sequence[Arm1DofParams], guess: Arm1DofParams) -> float:
    """The relative half-width of the prior box in pc (the corners' spread)."""
    if guess.pc == 0.0:
        return 0.0
    return max(abs(c.pc / guess.pc - 1.0) for c in corners)
