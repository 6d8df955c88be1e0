"""The exact excursion of a 1-DOF move (``arm1dof.track``) against dense numerical integration.

Oracle: an independent fixed-step integrator of Eq. 22 with Eq. 9 (trapezoidal position,
explicit velocity, a velocity that changes sign inside a step is set to zero there and the
stiction test decides the next step), sampled every 10 µs until the arm rests; and the
simulator's own dense trajectory output. Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from ff_planner.model.arm1dof import (
    TR_MAX,
    TR_MIN,
    TR_REST,
    TR_SPEED,
    TR_VTF,
    final_state,
    simulate_arm1dof,
    track,
)
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile

DT = 1e-5


def _dense(params: Arm1DofParams, profile: CurrentProfile, q0: float, scale, dt: float = DT,
           t_max: float = 6.0) -> tuple[float, float, float, float]:
    """(lowest q, highest q, peak |v|, rest q) by fixed-step integration (nan: no rest)."""
    J = params.J
    c = params.n * params.kt
    pv, pc, pt = params.pv * scale[0], params.pc * scale[1], params.pt * scale[2]
    times = list(profile.step_times)
    cur = list(profile.currents[:, 0])
    n = len(cur)
    t, q, v = 0.0, q0, 0.0
    lo = hi = q
    sp = 0.0
    k = 0
    while t < t_max:
        while k < n and t >= times[k + 1] - 1e-12:
            k += 1
        torque = c * cur[k] if k < n else 0.0
        level = pc + pt * abs(torque)
        if v == 0.0:
            if abs(torque) <= level:
                if t >= profile.tf:
                    return lo, hi, sp, q
                t += dt
                continue
            s = 1.0 if torque > 0.0 else -1.0
        else:
            s = 1.0 if v > 0.0 else -1.0
        vn = v + (torque - pv * v - s * level) / J * dt
        if v != 0.0 and vn * v < 0.0:
            frac = v / (v - vn)          # the zero crossing inside the step
            q += 0.5 * v * frac * dt
            vn = 0.0
        else:
            q += 0.5 * (v + vn) * dt
        v = vn
        t += dt
        lo, hi, sp = min(lo, q), max(hi, q), max(sp, abs(v))
    return math.nan, math.nan, math.nan, math.nan


def _plans(count: int, seed: int) -> list[CurrentProfile]:
    """Random 5-step plans (unequal steps, |I| ≤ 3 A, one step near the stiction edge)."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        d = rng.dirichlet(np.full(5, 2.0)) * 0.95
        times = np.concatenate([[0.0], np.cumsum(d)])
        cur = rng.uniform(-3.0, 3.0, 5)
        cur[rng.integers(5)] = rng.uniform(-0.3, 0.3)      # sticks or barely moves
        out.append(CurrentProfile(times, cur.reshape(-1, 1), 1.0, 1.0 - times[-1]))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_track_matches_dense_integration(seed):
    # table 2 has pv < 0: faster than pc/|pv| = 3.8 rad/s the unpowered arm speeds up and never
    # stops, so most random plans run away; the oracle runs on pv > 0 (the same law)
    params = Arm1DofParams().replace(pv=0.05)
    rng = np.random.default_rng(100 + seed)
    compared = 0
    for prof in _plans(2, seed):
        scales = np.vstack([np.ones(3), rng.uniform(0.7, 1.3, (1, 3))])
        exact = track(params, prof, 0.0, scales)
        for s, row in zip(scales, exact):
            lo, hi, sp, rest = _dense(params, prof, 0.0, s)
            if not math.isfinite(rest):      # still sliding after 6 s (or never stops)
                continue
            compared += 1
            # the integrator's O(dt) error grows along a long low-friction slide: measured
            # 4e-3 rad after 6 rad at dt = 10 µs, 3e-4 at 2.5 µs (the exact value between)
            assert row[TR_MIN] == pytest.approx(lo, abs=2e-4, rel=1e-3)
            assert row[TR_MAX] == pytest.approx(hi, abs=2e-4, rel=1e-3)
            assert row[TR_SPEED] == pytest.approx(sp, abs=2e-3, rel=1e-3)
            assert row[TR_REST] == pytest.approx(rest, abs=2e-4, rel=1e-3)
    assert compared >= 2


@pytest.mark.parametrize("pv", [0.05, -0.05])
def test_track_matches_simulator_trajectory_and_rest(pv):
    params = Arm1DofParams().replace(pv=pv)
    compared = 0
    for prof in _plans(4, 7):
        row = track(params, prof, 0.3)[0]
        if not math.isfinite(final_state(params, prof, 0.3, to_rest=True)[0]):
            assert np.all(np.isnan(row[[TR_MIN, TR_MAX, TR_SPEED]]))    # runs away
            continue
        sim = simulate_arm1dof(params, prof, 0.3, trajectory=True, dt=2e-4, t_end=6.0)
        if sim.qd[-1, 0] != 0.0:
            continue        # still sliding at the end of the recorded trajectory
        compared += 1
        # the samples (every 0.2 ms, every switch and every event: the extremes of q sit at
        # zero crossings, those of |v| at switches) lie inside the exact extremes and reach them
        assert sim.q.min() >= row[TR_MIN] - 1e-9 and sim.q.max() <= row[TR_MAX] + 1e-9
        assert np.abs(sim.qd).max() <= row[TR_SPEED] + 1e-9
        assert row[TR_MIN] == pytest.approx(sim.q.min(), abs=1e-8)
        assert row[TR_MAX] == pytest.approx(sim.q.max(), abs=1e-8)
        assert row[TR_SPEED] == pytest.approx(np.abs(sim.qd).max(), abs=1e-8)
        assert row[TR_REST] == pytest.approx(final_state(params, prof, 0.3, to_rest=True)[0],
                                             abs=1e-12)
        assert row[TR_VTF] == pytest.approx(final_state(params, prof, 0.3)[1], abs=1e-12)
    assert compared >= 1


def test_track_of_a_stuck_arm_is_its_start():
    params = Arm1DofParams()
    prof = CurrentProfile.uniform([[0.1], [-0.1]], 1.0)     # below breakaway (0.169 A)
    row = track(params, prof, 0.5)[0]
    assert (row[TR_MIN], row[TR_MAX], row[TR_SPEED], row[TR_REST], row[TR_VTF]) == (
        0.5, 0.5, 0.0, 0.5, 0.0)
