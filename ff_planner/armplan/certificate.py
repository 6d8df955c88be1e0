"""The robustness certificate of a plan for an arm from a URDF: its rest-position error over the
friction box, per joint, with the excursion.

The rest position (the motors hold ``i_rest`` after the last step — zero by default, the arm
coasts — until every joint sticks; ``ff_planner.arm.sim``, RK4 substep CERT_H with exact events)
is evaluated at the box's 2^k corners (k = uncertain parameters, all joints together; for
k > MAX_CORNER_DIMS a seeded random CORNER_SAMPLE of them), its centre, its 2k face centres and
CERT_UNIFORM seeded uniform points. worst_rest_error is the largest joint error found,
worst_per_joint each joint's own, per_parameter the largest joint error with each parameter alone
(its two face centres). A point whose simulation chatters or has not stopped 5 s after tf counts
as an infinite error. From each joint's ASCENT_STARTS worst samples a bounded local ascent of
that joint's error (L-BFGS-B, complex-step gradients in the friction parameters, at most
ASCENT_ITERS iterations) looks for a larger error between the samples; the points it ends on are
simulated and counted. Excursion: per joint the lowest / highest motor angle and the peak |speed|
from t = 0 until rest, nominal and over every point simulated. No switch-timing figures yet
(``switch_timing_method`` says so). Units: rad, rad/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from scipy.optimize import minimize

from ff_planner.arm import sim
from ff_planner.arm.cell import FRICTION_KEYS
from ff_planner.arm.model import UrdfArm
from ff_planner.core.errors import PlanningError
from ff_planner.model.limits import Excursion
from ff_planner.model.profile import CurrentProfile, RobustnessCertificate

CERT_H = 4e-3            # s, RK4 substep of the certificate's simulations (events exact;
#                          measured on arm3h: rest positions within ~4e-8 rad of 1 ms)
CERT_UNIFORM = 128       # seeded uniform points
CERT_SEED = 7
MAX_CORNER_DIMS = 12     # up to 4096 corners simulated in full
CORNER_SAMPLE = 1024     # corners drawn beyond that
ASCENT_STARTS = 2        # local ascents per joint, from its worst samples
ASCENT_ITERS = 15        # L-BFGS-B iterations per ascent (each: k complex-step simulations)


@dataclass(frozen=True)
class BoxSpec:
    """The uncertain parameters of an arm: ``index`` (k, 2) rows (joint, parameter 0..2) and
    their ± fractions ``frac`` (k,); names 'pc@elbow'."""

    index: np.ndarray
    frac: np.ndarray
    names: tuple[str, ...]

    @classmethod
    def of(cls, arm: UrdfArm) -> "BoxSpec":
        """Every friction parameter with a nonzero box fraction and a nonzero nominal value."""
        idx, fr, names = [], [], []
        for j, jn in enumerate(arm.joints):
            for k, key in enumerate(FRICTION_KEYS):
                if arm.box[j, k] > 0.0 and arm.friction[j, k] != 0.0:
                    idx.append((j, k))
                    fr.append(arm.box[j, k])
                    names.append(f"{key}@{jn}")
        return cls(np.array(idx, dtype=int).reshape(-1, 2), np.array(fr, float), tuple(names))

    @property
    def k(self) -> int:
        return len(self.names)

    def scales(self, arm: UrdfArm, rows: np.ndarray) -> list[np.ndarray]:
        """Friction scale matrices (n, 3) for unit-box rows (S, k) in [−1, 1]."""
        out = []
        for r in np.atleast_2d(rows):
            s = np.ones((arm.n, 3))
            for (j, kk), f, x in zip(self.index, self.frac, r):
                s[j, kk] = 1.0 + f * x
            out.append(s)
        return out


def _design(spec: BoxSpec) -> tuple[np.ndarray, int]:
    """Unit-box rows: corners (or a sample of them), centre, face centres, uniform points;
    returns (rows, index where the face centres start)."""
    k = spec.k
    rng = np.random.default_rng(CERT_SEED)
    if k <= MAX_CORNER_DIMS:
        corners = ((np.arange(2 ** k)[:, None] >> np.arange(k)[None, :]) & 1) * 2.0 - 1.0
    else:
        corners = rng.choice([-1.0, 1.0], size=(CORNER_SAMPLE, k))
    centre = np.zeros((1, k))
    faces = np.vstack([s * np.eye(k)[i] for i in range(k) for s in (-1.0, 1.0)]).reshape(2 * k, k)
    uniform = rng.uniform(-1.0, 1.0, (CERT_UNIFORM, k))
    rows = np.vstack([corners, centre, faces, uniform])
    return rows, corners.shape[0] + 1


def _rest_grad(arm: UrdfArm, spec: BoxSpec, profile: CurrentProfile, q0: np.ndarray,
               row: np.ndarray, i_rest: Optional[np.ndarray], h: float
               ) -> tuple[Optional[np.ndarray], np.ndarray]:
    """Rest θ (n,) at unit-box point ``row`` and its derivative (n, k) with respect to the row
    (complex step through the simulator, one simulation per parameter); (None, ·) if a
    simulation chatters or does not come to rest."""
    base = sim.friction_array(arm, spec.scales(arm, row)[0])
    G = np.zeros((arm.n, spec.k))
    rest = None
    for c, ((j, k), f) in enumerate(zip(spec.index, spec.frac)):
        fr = base.copy()
        hs = 1e-30
        fr[k, j] += 1j * hs * arm.friction[j, k] * f
        r = sim.run(arm, profile, q0, fr=fr, i_rest=i_rest, h=h, settle=True)
        if r[-1] != sim.OK:
            return None, G
        G[:, c] = r[1][:arm.n].imag / hs
        rest = r[1][:arm.n].real
    return rest, G


def _ascend(arm: UrdfArm, spec: BoxSpec, profile: CurrentProfile, q0: np.ndarray, qf: np.ndarray,
            joint: int, row0: np.ndarray, i_rest: Optional[np.ndarray], h: float
            ) -> tuple[float, np.ndarray, int]:
    """Bounded local ascent (L-BFGS-B) of joint ``joint``'s rest error |θ_rest − qf| over the unit
    box from ``row0``; returns (largest error seen, its row, simulations)."""
    best_e = -1.0
    best_row = row0.copy()
    sims = 0

    def f(row: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal best_e, best_row, sims
        rest, G = _rest_grad(arm, spec, profile, q0, row, i_rest, h)
        sims += spec.k
        if rest is None:
            best_e, best_row = math.inf, row.copy()
            return -1e3, np.zeros(spec.k)
        e = float(rest[joint] - qf[joint])
        if abs(e) > best_e:
            best_e, best_row = abs(e), row.copy()
        sg = 1.0 if e >= 0.0 else -1.0
        return -abs(e), -sg * G[joint]

    minimize(f, row0, jac=True, method="L-BFGS-B", bounds=[(-1.0, 1.0)] * spec.k,
             options={"maxiter": ASCENT_ITERS})
    return best_e, best_row, sims


def certify_arm(arm: UrdfArm, profile: CurrentProfile, q0: np.ndarray, qf: np.ndarray,
                i_rest: Optional[np.ndarray] = None, h: float = CERT_H) -> RobustnessCertificate:
    """The certificate of ``profile`` for the move q0 → qf (motor angles θ, rad)."""
    spec = BoxSpec.of(arm)
    if spec.k == 0:
        raise PlanningError(f"arm '{arm.name}': no friction parameter has an uncertainty box "
                            "(give box: in the cell file)")
    rows, face0 = _design(spec)
    n = arm.n
    qf = np.asarray(qf, float)
    errs = np.full((rows.shape[0], n), math.inf)
    lo = np.full(n, math.inf)
    hi = np.full(n, -math.inf)
    sp = np.zeros(n)
    moving = 0
    nominal = sim.simulate(arm, profile, q0, h=h, i_rest=i_rest)
    for i, s in enumerate(spec.scales(arm, rows)):
        try:
            r = sim.simulate(arm, profile, q0, h=h, friction_scale=s, i_rest=i_rest)
        except PlanningError:
            continue
        if not all(r.stuck_tf):
            moving += 1
        lo = np.minimum(lo, r.q_min)
        hi = np.maximum(hi, r.q_max)
        sp = np.maximum(sp, r.speed)
        if r.q_rest is not None:
            errs[i] = np.abs(r.q_rest - qf)
        else:
            lo[:] = -math.inf
            hi[:] = math.inf
            sp[:] = math.inf
    # local ascents of each joint's error from its worst samples
    extra_rows = []
    for j in range(n):
        for i in np.argsort(-errs[:, j])[:ASCENT_STARTS]:
            if not math.isfinite(errs[i, j]):
                continue
            e, row, _ = _ascend(arm, spec, profile, q0, qf, j, rows[i], i_rest, h)
            extra_rows.append(row)
    if extra_rows:
        more = np.array(extra_rows)
        more_err = np.full((more.shape[0], n), math.inf)
        for i, s_ in enumerate(spec.scales(arm, more)):
            try:
                r = sim.simulate(arm, profile, q0, h=h, friction_scale=s_, i_rest=i_rest)
            except PlanningError:
                continue
            lo = np.minimum(lo, r.q_min)
            hi = np.maximum(hi, r.q_max)
            sp = np.maximum(sp, r.speed)
            if r.q_rest is not None:
                more_err[i] = np.abs(r.q_rest - qf)
        rows = np.vstack([rows, more])
        errs = np.vstack([errs, more_err])
    worst_row = int(np.argmax(errs.max(axis=1)))
    per_param = {}
    for p_i, name in enumerate(spec.names):
        per_param[name] = float(errs[face0 + 2 * p_i: face0 + 2 * p_i + 2].max())
    worst_at = {name: float(1.0 + f * x) for name, f, x in zip(spec.names, spec.frac, rows[worst_row])}
    exc = Excursion(nominal_min=list(nominal.q_min), nominal_max=list(nominal.q_max),
                    nominal_speed=list(nominal.speed), worst_min=list(lo), worst_max=list(hi),
                    worst_speed=list(sp))
    return RobustnessCertificate(
        box={name: float(f) for name, f in zip(spec.names, spec.frac)},
        worst_rest_error=float(errs.max()), worst_at=worst_at, per_parameter=per_param,
        moving_at_tf=moving / rows.shape[0], switch_timing=[], samples=int(rows.shape[0]),
        switch_timing_method="not computed for arms from a URDF",
        worst_per_joint=[float(x) for x in errs.max(axis=0)], excursion=exc)
