"""A held-link-2 SCARA plan re-solved on the drive's SYNC grid (drive-exact plans).

``plan_robust_scara2`` places N equal steps on [0, tf − coast]; a drive applies setpoints only at
its SYNC instants, so the drive-exact profile has its switch times moved to the nearest SYNC (up
to half a period). With joint-1 currents of several amperes that shift moves the landing by the
impulse it adds or removes (0.1 rad on the paper task [-0.5, 0] → [0.5, 0] rad in 1 s at a
10 ms SYNC). ``resolve_on_times`` solves joint 1's problem again (``Joint1Problem``'s residuals:
q1(tf) = q1f, ∂q1(tf)/∂p_i = 0, stop inside the coast, link 2 held) on the snapped switch
times, starting from the plan's own currents, recomputes motor 2's holding currents and verifies
the result on the full 2-DOF model. Units: rad, A, s.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile
from ff_planner.optimize.hold_joint import Joint1Problem, joint1_params, joint2_hold_currents
from ff_planner.optimize.limits1d import Limits1D

RESOLVE_NFEV = 80        # evaluations of the re-solve (from a nearby solution: a few Newton steps)
RESOLVE_HOLD = 0.1       # hold fraction asked for (robust2d.HOLD_FALLBACK)


class _TimedJoint1Problem(Joint1Problem):
    """``Joint1Problem`` on given switch times (s, N + 1 values from 0 to tf − coast) instead
    of N equal steps: the times and the hold-sample grid that depends on them are replaced
    (the base class builds both from ``linspace``)."""

    def __init__(self, times: np.ndarray, *args: Any, samples: int = 24, **kw: Any) -> None:
        super().__init__(*args, **dict(kw, samples=samples))
        self.times = np.ascontiguousarray(times, dtype=float)
        self.tN = float(self.times[-1])
        if self.p2 is not None:
            ends = np.append(self.times, self.tf)
            grids, idx = [], []
            for k in range(self.N + 1):
                g = np.linspace(ends[k], ends[k + 1], samples)
                g[0] += 1e-12
                g[-1] -= 1e-12
                grids.append(g)
                idx.append(np.full(samples, k))
            self.grid = np.concatenate(grids)
            self.gidx = np.concatenate(idx)


def resolve_on_times(p: Scara2Params, profile: CurrentProfile, times: np.ndarray,
                     q0: np.ndarray, qf: np.ndarray, uncertain: list[str], tol: float,
                     limits: Optional[Limits1D] = None) -> Optional[tuple[CurrentProfile, dict]]:
    """Joint 1's currents of the held-link-2 ``profile`` solved again on switch times ``times``
    (s), motor 2's holding currents recomputed; returns (profile, figures) when the result
    verifies on the full 2-DOF model (|q(tf) − qf| ≤ tol, every position |∂q/∂p| ≤ tol, both
    joints stuck at tf, link 2 held), else None. Only for tasks that keep link 2 (q2f = q20).
    ``limits``: joint 1's position range and speed limit (``limits2d.joint1_limits``), held by
    the re-solve as ``Joint1Problem``'s limit rows."""
    q0 = np.asarray(q0, float)
    qf = np.asarray(qf, float)
    if abs(float(qf[1]) - float(q0[1])) > 0.0 or profile.currents.shape[1] != 2:
        return None
    names1 = tuple(n[:-1] for n in uncertain if n.endswith("1"))
    n = profile.n_steps
    hp = _TimedJoint1Problem(np.asarray(times, float), joint1_params(p), float(q0[0]),
                             float(qf[0]), float(profile.tf), float(profile.coast), n, names1,
                             p2=p, q2=float(q0[1]), hold_min=RESOLVE_HOLD, limits=limits)
    x0 = np.clip(np.asarray(profile.currents[:, 0], float), -hp.i_max, hp.i_max)
    x, fun, nfev = hp.solve(x0, max_nfev=RESOLVE_NFEV)
    if not np.all(np.isfinite(fun)) or float(np.max(np.abs(fun))) > 0.1 * tol:
        return None
    prof1 = CurrentProfile(hp.times, x.reshape(-1, 1), profile.tf, profile.coast)
    i2, frac = joint2_hold_currents(p, prof1, q0)
    if frac <= 0.0:
        return None
    new = CurrentProfile(hp.times.copy(), np.column_stack([x, i2]), profile.tf, profile.coast)
    sim = scara2._simulate_raw(p, new, q0, np.zeros(2))
    sens = scara2.sensitivities_scara2(p, new, q0, tuple(uncertain), method="complex")
    pos = {k: float(v) for k, v in sens.items() if k.startswith("q") and not k.startswith("qd")}
    smax = max((abs(v) for v in pos.values()), default=0.0)
    err = float(np.max(np.abs(sim.q_f - qf)))
    if not (err <= tol and smax <= tol and sim.stuck_tf[0] and sim.stuck_tf[1]):
        return None
    return new, {"evaluations": int(nfev), "hold_fraction": float(frac),
                 "max_abs_derivative": smax, "q_tf_error_rad": err, "sensitivities": pos,
                 "q_final": np.asarray(sim.q_f, float), "qd_final": np.asarray(sim.qd_f, float)}
