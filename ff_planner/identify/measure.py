"""Simulated measurement of identification runs: the exact arm model plus realistic sensors.

Positions come from an incremental encoder on the motor (``counts_per_rev`` per motor revolution,
quadrature counts included, behind the gear: quantum 2π / (counts_per_rev · n) rad at the joint);
the measured current is the commanded one plus white noise (``current_noise`` A rms) and a
commutation ripple (``ripple`` fraction of |I| at ``ripple_hz``). Used by the tests, the benchmark
and ``ff-identify --simulate``. Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ff_planner.identify.records import RunRecord
from ff_planner.identify.sampling import sample_params
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


def measure_run(params: Arm1DofParams, profile: CurrentProfile, q0: float, sensors: Sensors,
                rng: np.random.Generator, t_end: Optional[float] = None) -> RunRecord:
    """A RunRecord of ``profile`` on the exact arm ``params`` from rest at q0 (rad)."""
    horizon = profile.tf if t_end is None else float(t_end)
    t = np.arange(-sensors.pre, horizon + 1e-12, sensors.sample_period)
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
                 sensors: Sensors, rng: np.random.Generator) -> list[RunRecord]:
    """Records of the runs in order, each starting where the previous one came to rest."""
    out = []
    q = float(q_start)
    for prof in profiles:
        rec = measure_run(params, prof, q, sensors, rng)
        out.append(rec)
        q = float(sample_params(params, prof, q, np.array([prof.tf]))[0][0])
    return out
