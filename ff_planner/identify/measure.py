"""Simulated measurement of identification runs: the exact arm model plus realistic sensors.

Positions come from an incremental encoder on the motor (``counts_per_rev`` per motor revolution,
quadrature counts included, behind the gear: quantum 2π / (counts_per_rev · n) rad at the joint);
the measured current is the commanded one plus white noise (``current_noise`` A rms) and a
commutation ripple (``ripple`` fraction of |I| at ``ripple_hz``). Used by the tests, the benchmark
and ``ff-identify --simulate``.

``FrictionMismatch`` makes the simulated arm's friction differ from Eq. 9, so that the fit's
adequacy tests are exercised, not just its algebra: a Stribeck rise of the Coulomb level at low
speed (static friction above the sliding level) and a Coulomb level that varies with position
(cogging, a seal or a cable that drags more at some angles). The arm is then advanced in short
steps of the exact Eq. 9 motion with the Coulomb level of the step's start state. Units: rad,
rad/s, A, s, Nm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from numba import njit

from ff_planner.identify.records import RunRecord
from ff_planner.core.errors import ParameterError
from ff_planner.identify.sampling import sample_params
from ff_planner.model.arm1dof import advance_core, final_state
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile


@dataclass(frozen=True)
class Sensors:
    """Encoder and current sensor of the simulated measurement, and the sampling (s)."""

    counts_per_rev: int = 4096
    current_noise: float = 0.02     # A rms
    ripple: float = 0.02            # fraction of |I|
    ripple_hz: float = 180.0        # Hz
    sample_period: float = 1e-3     # s
    pre: float = 0.05               # s of samples at rest before the first step

    def q_resolution(self, params: Arm1DofParams) -> float:
        """rad per encoder count at the joint."""
        return 2.0 * math.pi / (self.counts_per_rev * float(params.n))


@dataclass(frozen=True)
class FrictionMismatch:
    """Friction that is not Eq. 9: the Coulomb level is

        pc·(1 + stribeck·exp(−(q̇/stribeck_speed)²))·(1 + coulomb_ripple·sin(2π·q/coulomb_period))

    (stribeck: extra static friction as a fraction of pc, at |q̇| ≪ stribeck_speed rad/s;
    coulomb_ripple: fraction of pc, period coulomb_period rad). Integrated in ``step`` s steps."""

    stribeck: float = 0.0
    stribeck_speed: float = 0.1      # rad/s
    coulomb_ripple: float = 0.0
    coulomb_period: float = 0.25     # rad
    step: float = 1e-4               # s

    KEYS = ("stribeck", "stribeck_speed", "coulomb_ripple", "coulomb_period")

    @property
    def active(self) -> bool:
        return self.stribeck != 0.0 or self.coulomb_ripple != 0.0

    def validate(self) -> None:
        if not (math.isfinite(self.stribeck) and -1.0 < self.stribeck <= 2.0):
            raise ParameterError(f"stribeck must be in (-1, 2] (a fraction of pc), got {self.stribeck}")
        if not (math.isfinite(self.coulomb_ripple) and 0.0 <= self.coulomb_ripple < 1.0):
            raise ParameterError(f"coulomb_ripple must be in [0, 1) (a fraction of pc), got {self.coulomb_ripple}")
        for key in ("stribeck_speed", "coulomb_period", "step"):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and v > 0.0):
                raise ParameterError(f"{key} must be > 0, got {v}")

    def coulomb(self, pc: float, q: float, v: float) -> float:
        """The Coulomb level (Nm) at position q (rad) and speed v (rad/s)."""
        return (pc * (1.0 + self.stribeck * math.exp(-(v / self.stribeck_speed) ** 2))
                * (1.0 + self.coulomb_ripple * math.sin(2.0 * math.pi * q / self.coulomb_period)))


@njit(cache=True, nogil=True)
def mismatch_steps(J: float, c: float, pv: float, pc: float, pt: float, stribeck: float,
                   stribeck_speed: float, ripple: float, period: float, q: float, v: float,
                   current: float, dt: float, h: float) -> tuple[float, float]:
    """State (rad, rad/s) after ``dt`` s of constant ``current`` (A) from (q, v): sub-steps of
    ``h`` s (the last one shorter), each the exact Eq. 9 motion with the Coulomb level
    (``FrictionMismatch.coulomb``) of its start state. Compiled: a plant that falls behind
    catches up in microseconds per ms, not milliseconds."""
    left = dt
    while left > 0.0:
        hh = min(h, left)               # the last step is exactly what is left: left becomes 0
        level = (pc * (1.0 + stribeck * math.exp(-(v / stribeck_speed) ** 2))
                 * (1.0 + ripple * math.sin(2.0 * math.pi * q / period)))
        q, v = advance_core(J, c, pv, level, pt, q, v, current, hh)
        left -= hh
    return q, v


def advance_mismatch(params: Arm1DofParams, mismatch: FrictionMismatch, q: float, v: float,
                     current: float, dt: float, step: Optional[float] = None) -> tuple[float, float]:
    """``mismatch_steps`` for ``params`` (SI) and ``mismatch`` (sub-step ``step``, default
    ``mismatch.step``)."""
    return mismatch_steps(float(params.J), float(params.torque_per_amp), float(params.pv), float(params.pc),
                          float(params.pt), float(mismatch.stribeck), float(mismatch.stribeck_speed),
                          float(mismatch.coulomb_ripple), float(mismatch.coulomb_period), float(q), float(v),
                          float(current), float(dt), float(mismatch.step if step is None else step))


def simulate_mismatch(params: Arm1DofParams, profile: CurrentProfile, q0: float, t: np.ndarray,
                      mismatch: FrictionMismatch) -> np.ndarray:
    """Positions (rad) at the times ``t`` (s, ascending) of the arm with ``mismatch`` friction,
    from rest at q0: exact Eq. 9 steps of at most ``mismatch.step`` s, each with the Coulomb level
    of its start state, switches and sample times hit exactly."""
    mismatch.validate()
    bounds = [float(x) for x in profile.step_times[1:]]
    q, v, tt = float(q0), 0.0, 0.0
    out = np.full(np.asarray(t).shape, float(q0))
    for k in np.nonzero(np.asarray(t) > 0.0)[0]:
        target = float(t[k])
        while tt < target - 1e-12:
            tn = target
            for b in bounds:
                if b > tt + 1e-12:          # the next switch (one within 1e-12 s counts as passed)
                    tn = min(tn, b)
                    break
            i = profile.current_at(tt + 1e-12)[0]
            q, v = advance_mismatch(params, mismatch, q, v, i, tn - tt)
            tt = tn
        out[k] = q
    return out


def measure_run(params: Arm1DofParams, profile: CurrentProfile, q0: float, sensors: Sensors,
                rng: np.random.Generator, t_end: Optional[float] = None,
                mismatch: Optional[FrictionMismatch] = None) -> RunRecord:
    """A RunRecord of ``profile`` on the arm ``params`` from rest at q0 (rad): the exact Eq. 9
    arm, or with ``mismatch`` friction."""
    horizon = profile.tf if t_end is None else float(t_end)
    t = np.arange(-sensors.pre, horizon + 1e-12, sensors.sample_period)
    if mismatch is not None and mismatch.active:
        q = simulate_mismatch(params, profile, q0, t, mismatch)
    else:
        q, _ = sample_params(params, profile, q0, t)
    return _record(t, q, profile, params, sensors, rng)


def _record(t: np.ndarray, q: np.ndarray, profile: CurrentProfile, params: Arm1DofParams,
            sensors: Sensors, rng: np.random.Generator) -> RunRecord:
    res = sensors.q_resolution(params)
    q_meas = np.floor(q / res + 0.5) * res
    i_cmd = np.array([profile.current_at(x)[0] for x in t])
    i_meas = (i_cmd * (1.0 + sensors.ripple * np.sin(2.0 * math.pi * sensors.ripple_hz * t))
              + sensors.current_noise * rng.standard_normal(t.size))
    return RunRecord(t, q_meas, i_meas, profile, res)


def record_trajectory(t: np.ndarray, q: np.ndarray, profile: CurrentProfile, params: Arm1DofParams,
                      sensors: Sensors, rng: np.random.Generator) -> RunRecord:
    """A RunRecord from a true trajectory (t s, q rad) simulated elsewhere (e.g. another model)."""
    return _record(np.asarray(t, float), np.asarray(q, float), profile, params, sensors, rng)


def measure_runs(params: Arm1DofParams, profiles: Sequence[CurrentProfile], q_start: float,
                 sensors: Sensors, rng: np.random.Generator,
                 mismatch: Optional[FrictionMismatch] = None) -> list[RunRecord]:
    """Records of the runs in order, each starting where the previous one came to rest."""
    out = []
    q = float(q_start)
    for prof in profiles:
        rec = measure_run(params, prof, q, sensors, rng, mismatch=mismatch)
        out.append(rec)
        if mismatch is not None and mismatch.active:
            q = float(simulate_mismatch(params, prof, q, np.array([prof.tf]), mismatch)[0])
        else:
            q = float(sample_params(params, prof, q, np.array([prof.tf]))[0][0])
    return out


def measure_rest(params: Arm1DofParams, profile: CurrentProfile, q0: float, rng: np.random.Generator,
                 sensors: Sensors = Sensors(), noise: float = 0.0) -> float:
    """The rest position (rad) an execution of ``profile`` from rest at q0 shows on the encoder:
    the exact rest position under ``params``, plus ``noise`` rad rms, rounded to the encoder."""
    q = final_state(params, profile, float(q0), to_rest=True)[0] + noise * float(rng.standard_normal())
    res = sensors.q_resolution(params)
    return float(np.floor(q / res + 0.5) * res)
