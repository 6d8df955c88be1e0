"""robust-box for an arm from a URDF with any number of moving joints.

Plan: N equal current steps per joint on [0, tf − coast], the coast at zero current (or the
holding current ``i_rest``), the move q0 → qf in motor angles θ judged at the REST position (the
arm left to stop after tf). Decision variables: the N·n step currents, |I| ≤ i_max.

1. Goal: from a start, a bounded least-squares solve puts the nominal rest position on qf. One
   moving joint: its 1-DOF robust-derivative plan (``ff_planner.optimize``; exact then). Several:
   first an accelerate/brake pattern per joint sized by its inertia, then (time permitting) the
   joints' own 1-DOF plans corrected for the coupling along their nominal trajectories
   (``_coupled_start``; measured on arm3h it reaches the goal more closely but the search from it
   ended no better).
2. First-order minimax surrogate: a bounded least-squares solve (scipy ``least_squares``, trf) of
   the residuals [W_GOAL·(θ_rest − qf); ∂θ_rest,i/∂p_j·δ_j], δ_j the half-width of p_j's box,
   i.e. the rest-error change each parameter alone causes at its box edge to first order. The
   derivatives are forward sensitivities from Pinocchio's analytical RNEA derivatives along the
   simulated trajectory (``ff_planner.arm.sensitivity``: one simulation and its replay give
   ∂θ_rest/∂p and ∂θ_rest/∂x for all joints); the residuals' Jacobian in the currents is that
   ∂θ_rest/∂x and, for the first-order terms, forward differences in each p_c of it (k + 1
   replays per Jacobian instead of (N·n + 1)·k complex-step simulations). derivatives=
   "complex-step" keeps the earlier scheme for comparison. Zero residuals are the paper's
   zero-derivative plan (needs N·n ≥ n + n·k).
3. Polish the goal on the certificate's substep, certify over the box (``certificate``).

The plan is labelled ``zero-derivative`` when every first-order term is below ``tol`` (rad), else
``least-worst``: the smallest first-order worst case this search found, certified all the same.
Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from scipy.optimize import least_squares

from ff_planner.arm import sim
from ff_planner.arm.model import UrdfArm
from ff_planner.arm.sensitivity import RestSensitivity, rest_sensitivity
from ff_planner.armplan.certificate import CERT_H, BoxSpec, certify_arm
from ff_planner.core.errors import PlanningError
from ff_planner.model import arm1dof
from ff_planner.model.friction import net_torque_array
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult, RobustnessCertificate
from ff_planner.optimize.planner import plan

PLAN_H = 4e-3            # s, RK4 substep while searching (rest positions within ~1e-7 rad of 1 ms)
W_GOAL = 10.0            # weight of the nominal goal error against the first-order terms
DIFF_STEP = 1e-6         # relative forward-difference step in the currents (complex-step mode)
FRICTION_STEP = 1e-6     # relative forward-difference step of the analytical Jacobian in p
SEARCH_SHARE = 0.65      # share of the time budget for the search; the rest for the certificate


class _OutOfTime(Exception):
    pass


@dataclass
class ArmPlan:
    """A plan for an arm from a URDF. label: "zero-derivative" or "least-worst" (see module).
    first_order: (n,) |θ_rest − qf| + Σ_j |∂θ_rest/∂p_j|·δ_j per joint (rad) at the plan;
    sensitivities (n, k) ∂θ_rest,i/∂p_j (rad per unit of p_j) in ``box_names`` order."""

    profile: CurrentProfile
    q0: np.ndarray
    qf: np.ndarray
    label: str
    first_order: np.ndarray
    sensitivities: np.ndarray
    box_names: tuple[str, ...]
    certificate: Optional[RobustnessCertificate]
    rest_nominal: np.ndarray
    solve_time: float
    starts_tried: int
    evaluations: int
    limit_violations: list[str] = field(default_factory=list)

    @property
    def success(self) -> bool:
        return self.certificate is not None and not self.limit_violations and math.isfinite(
            self.certificate.worst_rest_error)

    def to_dict(self) -> dict:
        return {"label": self.label, "q0": self.q0.tolist(), "qf": self.qf.tolist(),
                "tf": float(self.profile.tf), "coast": float(self.profile.coast),
                "step_times": self.profile.step_times.tolist(),
                "currents": self.profile.currents.tolist(),
                "first_order_per_joint": self.first_order.tolist(),
                "rest_nominal": self.rest_nominal.tolist(), "box_names": list(self.box_names),
                "solve_time": self.solve_time, "starts_tried": self.starts_tried,
                "evaluations": self.evaluations, "limit_violations": list(self.limit_violations),
                "certificate": self.certificate.to_dict() if self.certificate else None,
                "units": {"angles": "rad", "currents": "A", "time": "s"}}


class _Problem:
    """Residuals of one move (see the module docstring)."""

    def __init__(self, arm: UrdfArm, q0: np.ndarray, qf: np.ndarray, tf: float, coast: float,
                 n_steps: int, i_rest: Optional[np.ndarray], deadline: float,
                 derivatives: str = "pinocchio"):
        self.arm = arm
        self.derivatives = derivatives
        self._cache: dict = {}
        self.q0 = q0
        self.qf = qf
        self.tf = tf
        self.coast = coast
        self.N = n_steps
        self.i_rest = i_rest
        self.deadline = deadline
        self.spec = BoxSpec.of(arm)
        self.delta = np.array([abs(arm.friction[j, k]) * f
                               for (j, k), f in zip(self.spec.index, self.spec.frac)])
        self.fr0 = sim.friction_array(arm)
        self.evals = 0
        self.best: tuple[float, Optional[np.ndarray]] = (math.inf, None)
        self.goal_best: tuple[float, Optional[np.ndarray]] = (math.inf, None)

    def profile(self, x: np.ndarray) -> CurrentProfile:
        cur = np.asarray(x, float).reshape(self.N, self.arm.n)
        return CurrentProfile.uniform(cur, self.tf, self.coast)

    def _run(self, x: np.ndarray, fr: np.ndarray, h: float) -> tuple:
        self.evals += 1
        prof = self.profile(x)
        return sim.run(self.arm, prof, self.q0, fr=fr, i_rest=self.i_rest, h=h, settle=True)

    def rest(self, x: np.ndarray, h: float = PLAN_H) -> np.ndarray:
        if self.derivatives == "pinocchio":
            rs = self.sensitivity(x, h)
            return np.full(self.arm.n, 1e3) if rs is None else rs.rest
        r = self._run(x, self.fr0, h)
        if r[-1] != sim.OK:
            return np.full(self.arm.n, 1e3)
        return r[1][:self.arm.n].real

    def sensitivity(self, x: np.ndarray, h: float = PLAN_H,
                    scale: Optional[np.ndarray] = None) -> Optional[RestSensitivity]:
        """Rest θ and its forward sensitivities (``ff_planner.arm.sensitivity``) at currents x
        (friction scaled by ``scale``); None if the arm chatters or does not stop. The last few
        results are kept (least_squares asks for the residual and the Jacobian at one x)."""
        key = (np.asarray(x, float).tobytes(), h, None if scale is None else scale.tobytes())
        if key in self._cache:
            return self._cache[key]
        self.evals += 1
        try:
            r: Optional[RestSensitivity] = rest_sensitivity(self.arm, self.profile(x), self.q0, h=h,
                                                            friction_scale=scale, i_rest=self.i_rest)
        except PlanningError:
            r = None
        if len(self._cache) > 2 * self.spec.k + 4:
            self._cache.clear()
        self._cache[key] = r
        return r

    def rest_and_sens(self, x: np.ndarray, h: float = PLAN_H) -> tuple[np.ndarray, np.ndarray]:
        """Nominal rest θ (n,) and ∂θ_rest/∂p (n, k): Pinocchio forward sensitivities (one
        simulation and its replay), or with derivatives="complex-step" k complex simulations."""
        n = self.arm.n
        if self.derivatives == "pinocchio":
            r = self.sensitivity(x, h)
            if r is None:
                return np.full(n, 1e3), np.full((n, self.spec.k), 1e3)
            ix = self.spec.index
            return r.rest, r.d_friction[:, ix[:, 0], ix[:, 1]]
        S = np.zeros((n, self.spec.k))
        rest = None
        for c, (j, k) in enumerate(self.spec.index):
            fr = self.fr0.copy()
            hs = 1e-30 * abs(fr[k, j].real)
            fr[k, j] += 1j * hs
            r2 = self._run(x, fr, h)
            if r2[-1] != sim.OK:
                return np.full(n, 1e3), np.full((n, self.spec.k), 1e3)
            S[:, c] = r2[1][:n].imag / hs
            rest = r2[1][:n].real
        if rest is None:
            rest = self.rest(x, h)
        return rest, S

    def rest_jac(self, x: np.ndarray, h: float = PLAN_H) -> np.ndarray:
        """∂θ_rest/∂x (n, N·n) from the forward sensitivities."""
        r = self.sensitivity(x, h)
        if r is None:
            return np.zeros((self.arm.n, x.size))
        return r.jacobian_currents()

    def goal_jac(self, x: np.ndarray) -> np.ndarray:
        if time.perf_counter() > self.deadline:
            raise _OutOfTime
        return self.rest_jac(x)

    def full_jac(self, x: np.ndarray) -> np.ndarray:
        """Jacobian of ``full_residual``: W·∂θ_rest/∂x and δ_c·∂²θ_rest/∂p_c∂x, the latter by a
        forward difference in p_c (relative FRICTION_STEP) of the analytical ∂θ_rest/∂x."""
        if time.perf_counter() > self.deadline:
            raise _OutOfTime
        n, k = self.arm.n, self.spec.k
        J0 = self.rest_jac(x)
        out = np.zeros((n + n * k, x.size))
        out[:n] = W_GOAL * J0
        for c, (j, kk) in enumerate(self.spec.index):
            if time.perf_counter() > self.deadline:
                raise _OutOfTime
            scale = np.ones((n, 3))
            scale[j, kk] += FRICTION_STEP
            r = self.sensitivity(x, PLAN_H, scale)
            if r is None:
                continue
            dp = FRICTION_STEP * float(self.arm.friction[j, kk])   # signed: p·(1 + ε) − p
            out[n + c::k] = self.delta[c] * (r.jacobian_currents() - J0) / dp
        return out

    def goal_residual(self, x: np.ndarray) -> np.ndarray:
        if time.perf_counter() > self.deadline:
            raise _OutOfTime
        r = self.rest(x) - self.qf
        e = float(np.max(np.abs(r)))
        if e < self.goal_best[0]:
            self.goal_best = (e, np.array(x, float))
        return r

    def full_residual(self, x: np.ndarray) -> np.ndarray:
        if time.perf_counter() > self.deadline:
            raise _OutOfTime
        rest, S = self.rest_and_sens(x)
        r = np.concatenate([W_GOAL * (rest - self.qf), (S * self.delta[None, :]).ravel()])
        worst = float(np.max(np.abs(rest - self.qf) + np.abs(S) @ self.delta))
        if worst < self.best[0]:
            self.best = (worst, np.array(x, float))
        return r


def _bang_bang(arm: UrdfArm, q0: np.ndarray, qf: np.ndarray, N: int, T: float) -> np.ndarray:
    """Per joint: accelerate over the first half of [0, T], brake over the second, sized by the
    joint's own inertia at q0 (M_jj·4·|Δ|/T²) plus / minus its breakaway torque."""
    x = np.zeros((N, arm.n))
    half = max(1, N // 2)
    M = arm.constants.mass_matrix(q0)
    for j in range(arm.n):
        d = float(qf[j] - q0[j])
        s = 1.0 if d >= 0.0 else -1.0
        acc = M[j, j] * 4.0 * abs(d) / (T * T)
        brk = arm.friction[j, 1] / max(1e-9, 1.0 - arm.friction[j, 2])
        x[:half, j] = s * (acc + brk) / arm.torque_per_amp[j]
        x[half:2 * half, j] = -s * max(0.0, acc - brk) / arm.torque_per_amp[j]
    return np.clip(x, -arm.i_max, arm.i_max).ravel()


def _joint_plans(arm: UrdfArm, q0: np.ndarray, qf: np.ndarray, N: int, tf: float, coast: float,
                 seed: int) -> tuple[np.ndarray, list[Optional[Arm1DofParams]]]:
    """Each joint alone: the 1-DOF robust-derivative plan (``ff_planner.optimize``, N equal
    steps, its nonzero friction parameters uncertain) of a 1-DOF arm with the joint's motor and
    friction and the inertia M_jj(q0) it sees with the others still. Returns the currents
    (N, n) (zero for a joint whose 1-DOF plan fails) and the 1-DOF parameters (None there)."""
    x = np.zeros((N, arm.n))
    M = arm.constants.mass_matrix(q0)
    params: list[Optional[Arm1DofParams]] = []
    for j in range(arm.n):
        jc = arm.cells[j]
        assert jc.motor is not None
        p = Arm1DofParams(J=float(M[j, j]), kt=jc.motor.kt, n=jc.motor.gear, i_max=jc.motor.i_max,
                          pv=float(arm.friction[j, 0]), pc=float(arm.friction[j, 1]),
                          pt=float(arm.friction[j, 2]))
        unc = tuple(k for k, v in zip(("pv", "pc", "pt"), arm.friction[j]) if v != 0.0)
        try:
            r = plan(PlanRequest(objective="robust-derivative", model="arm1dof",
                                 q0=(float(q0[j]),), qf=(float(qf[j]),), tf=tf, coast=coast,
                                 steps=N, params=p, uncertain=unc or ("pc",), seed=seed,
                                 time_budget=5.0))
        except PlanningError:
            params.append(None)
            continue
        if r.profile is not None and r.profile.currents.shape == (N, 1):
            x[:, j] = r.profile.currents[:, 0]
            params.append(p)
        else:
            params.append(None)
    return x, params


def _start(arm: UrdfArm, q0: np.ndarray, qf: np.ndarray, N: int, tf: float, coast: float,
           seed: int) -> np.ndarray:
    """The joints' own 1-DOF plans side by side (``_joint_plans``)."""
    x, _ = _joint_plans(arm, q0, qf, N, tf, coast, seed)
    return np.clip(x, -arm.i_max, arm.i_max).ravel()


def _coupled_start(arm: UrdfArm, q0: np.ndarray, qf: np.ndarray, N: int, tf: float,
                   coast: float, seed: int, per_step: int = 24) -> np.ndarray:
    """The joints' own 1-DOF plans, each joint's current corrected for the coupling: along the
    joints' 1-DOF nominal trajectories θ(t) the torque the arm needs is
    T_j − s_j·pt_j·|T_j| = [M(θ)·θ̈ + b(θ, θ̇)]_j + pv_j·θ̇_j + s_j·pc_j (Eq. 9 sliding),
    solved for T_j at ``per_step`` points inside each step and averaged (a stuck joint keeps its
    1-DOF torque plus the coupling)."""
    x1, params = _joint_plans(arm, q0, qf, N, tf, coast, seed)
    n = arm.n
    T = tf - coast
    edges = np.linspace(0.0, T, N + 1)
    frac = (np.arange(per_step) + 0.5) / per_step
    grid = (edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * frac[None, :]).ravel()
    th = np.tile(q0, (grid.size, 1)).astype(float)
    thd = np.zeros_like(th)
    thdd = np.zeros_like(th)
    T1 = np.zeros_like(th)
    for j, p in enumerate(params):
        if p is None:
            continue
        times = np.ascontiguousarray(edges, float)
        cur = np.ascontiguousarray(x1[:, j], float)
        cap = 3 * (N + 3) + 4
        seg = np.zeros((cap, 7))
        _, _, nseg, _ = arm1dof.sim_core(p.J, p.n * p.kt, p.pv, p.pc, p.pt, times, cur, tf,
                                         float(q0[j]), 0.0, False, seg, np.zeros((0, 3)))
        qj, vj = arm1dof.eval_segments(seg, min(nseg, cap), grid)
        th[:, j] = qj
        thd[:, j] = vj
        T1[:, j] = np.repeat(cur, per_step) * p.n * p.kt
        thdd[:, j] = net_torque_array(vj, T1[:, j], p.pv, p.pc, p.pt) / p.J
    out = x1.copy()
    for j in range(n):
        if params[j] is None:
            continue
        pv, pc, pt = arm.friction[j]
        need = np.zeros(grid.size)
        for i in range(grid.size):
            Mi = arm.constants.mass_matrix(th[i])
            bi = arm.constants.bias(th[i], thd[i])
            R = float(Mi[j] @ thdd[i] + bi[j])
            v = thd[i, j]
            if v == 0.0:
                need[i] = T1[i, j] + R - params[j].J * thdd[i, j]   # type: ignore[union-attr]
                continue
            sg = 1.0 if v > 0.0 else -1.0
            R += pv * v + sg * pc
            t_pos = R / (1.0 - sg * pt)
            need[i] = t_pos if t_pos >= 0.0 else R / (1.0 + sg * pt)
        out[:, j] = need.reshape(N, per_step).mean(axis=1) / arm.torque_per_amp[j]
    return np.clip(out, -arm.i_max, arm.i_max).ravel()


def plan_box_robust_arm(arm: UrdfArm, q0: Sequence[float], qf: Sequence[float], tf: float = 1.0,
                        *, coast: float = 0.05, steps: Optional[int] = None, seed: int = 0,
                        time_budget: float = 30.0, tol: float = 1e-6,
                        i_rest: Optional[Sequence[float]] = None, certify: bool = True,
                        derivatives: str = "pinocchio") -> ArmPlan:
    """robust-box plan for the move q0 → qf (motor angles θ, rad) in tf s (see the module).
    ``derivatives``: "pinocchio" (forward sensitivities, the default) or "complex-step" (the
    earlier scheme, forward differences in the currents; kept for comparison)."""
    if derivatives not in ("pinocchio", "complex-step"):
        raise PlanningError(f"derivatives must be 'pinocchio' or 'complex-step', got {derivatives!r}")
    t0 = time.perf_counter()
    n = arm.n
    q0a = np.asarray(q0, float).reshape(-1)
    qfa = np.asarray(qf, float).reshape(-1)
    if q0a.shape != (n,) or qfa.shape != (n,) or not (np.all(np.isfinite(q0a)) and np.all(np.isfinite(qfa))):
        raise PlanningError(f"q0 and qf need {n} finite values each (rad) for arm '{arm.name}'")
    if not (0.0 < coast < tf):
        raise PlanningError(f"coast must be in (0, tf) s, got {coast}")
    if not arm.limits.empty:
        arm.limits.validate(n, q0a.tolist(), qfa.tolist())
    spec = BoxSpec.of(arm)
    if spec.k == 0:
        raise PlanningError(f"arm '{arm.name}': no friction parameter has an uncertainty box")
    N = int(steps) if steps else int(math.ceil((n + n * spec.k) / n)) + 2
    ir = None if i_rest is None else np.asarray(i_rest, float)
    bounds = (-np.tile(arm.i_max, N), np.tile(arm.i_max, N))
    deadline = t0 + float(time_budget) * (SEARCH_SHARE if certify else 1.0)
    prob = _Problem(arm, q0a, qfa, float(tf), float(coast), N, ir, deadline, derivatives)
    analytic = derivatives == "pinocchio"
    jac_goal = prob.goal_jac if analytic else "2-point"
    jac_full = prob.full_jac if analytic else "2-point"
    starts = 0
    while True:
        if n == 1:
            x = _start(arm, q0a, qfa, N, float(tf), float(coast), int(seed) + starts)
        elif starts == 0:
            x = _bang_bang(arm, q0a, qfa, N, float(tf) - float(coast))
        else:
            x = _coupled_start(arm, q0a, qfa, N, float(tf), float(coast), int(seed) + starts)
        starts += 1
        try:
            x = least_squares(prob.goal_residual, x, jac=jac_goal, bounds=bounds, method="trf",
                              xtol=1e-12, ftol=1e-12, gtol=1e-12, diff_step=DIFF_STEP,
                              max_nfev=60 * N * n).x
            least_squares(prob.full_residual, x, jac=jac_full, bounds=bounds, method="trf", xtol=1e-10,
                          ftol=1e-12, gtol=1e-12, diff_step=DIFF_STEP, x_scale=np.tile(arm.i_max, N))
        except _OutOfTime:
            pass
        if prob.best[0] <= tol or time.perf_counter() > deadline:
            break
        if time.perf_counter() - t0 > 0.5 * (deadline - t0):   # not enough time for another start
            break
    if prob.best[1] is None:      # out of time before the robust stage: the goal-only plan
        prob.best = (math.inf, prob.goal_best[1])
    if prob.best[1] is None:
        raise PlanningError(f"arm '{arm.name}': no plan reached the goal within {time_budget:g} s "
                            "(raise time_budget or tf)", "TIME_BUDGET_EXHAUSTED")
    x = prob.best[1]
    # polish the nominal goal on the certificate's substep (small changes of the currents)
    prob.deadline = math.inf
    x = least_squares(lambda v: prob.rest(v, CERT_H) - qfa, x,
                      jac=(lambda v: prob.rest_jac(v, CERT_H)) if analytic else "2-point",
                      bounds=bounds, method="trf",
                      xtol=1e-14, ftol=1e-14, gtol=1e-14, diff_step=DIFF_STEP, max_nfev=20 * N * n).x
    rest, S = prob.rest_and_sens(x, CERT_H)
    fo = np.abs(rest - qfa) + np.abs(S) @ prob.delta
    label = "zero-derivative" if float(fo.max()) <= tol else "least-worst"
    prof = prob.profile(x)
    cert = certify_arm(arm, prof, q0a, qfa, ir) if certify else None
    viol = cert.excursion.violations(arm.limits) if (cert is not None and cert.excursion) else []
    return ArmPlan(profile=prof, q0=q0a, qf=qfa, label=label, first_order=fo, sensitivities=S,
                   box_names=spec.names, certificate=cert, rest_nominal=rest,
                   solve_time=time.perf_counter() - t0, starts_tried=starts,
                   evaluations=prob.evals, limit_violations=viol)


def plan_result(arm: UrdfArm, res: ArmPlan, model: str, solve_time: Optional[float] = None
                ) -> PlanResult:
    """``res`` as the suite's PlanResult (robust-box): a success when certified within the
    limits (error code OK, else NO_ROBUST_PLAN); ``extra`` the joint names, the label and the
    predicted rest (rad)."""
    cert = res.certificate
    ok = res.success
    msg = (f"{res.label} plan for {model}: certified worst rest error "
           f"{cert.worst_rest_error:.3g} rad over the friction box" if cert else "no certificate")
    if res.limit_violations:
        msg += "; limits violated: " + "; ".join(res.limit_violations)
    return PlanResult(
        success=ok, message=msg, profile=res.profile, model=model, params=None, q0=res.q0,
        qf=res.qf, uncertain=list(res.box_names), objective="robust-box",
        q_final=res.rest_nominal, qd_final=np.zeros(arm.n),
        sensitivities={f"q{i + 1}/{nm}": float(res.sensitivities[i, c])
                       for i in range(arm.n) for c, nm in enumerate(res.box_names)},
        robust=res.label == "zero-derivative", error_code="OK" if ok else "NO_ROBUST_PLAN",
        best_effort=res.label != "zero-derivative", starts_tried=res.starts_tried,
        iterations=res.evaluations,
        solve_time=res.solve_time if solve_time is None else solve_time, certificate=cert,
        extra={"joint_names": list(arm.joints), "label": res.label,
               "predicted_rest": [float(x) for x in res.rest_nominal], "source": "urdf",
               "first_order_per_joint": [float(x) for x in res.first_order]})
