"""Robust rest-to-rest plans for the 2-DOF SCARA arm (paper section 4.2), in seconds, not hours.

Method ("hold link 2, solve joint 1 exactly"): when the task leaves link 2's absolute angle
unchanged (q2f = q20, as in the paper's [-0.5, 0] → [0.5, 0] task), motor 2 can cancel the
reaction of link 1 step by step so that joint 2 never leaves stiction. Then

* q2(t) ≡ q20 for every friction value near nominal, so ∂q2(tf)/∂p = 0 exactly and joint 1
  does not feel pv2, pc2, pt2 (∂q1/∂p2 = 0 exactly);
* joint 1 is EXACTLY the 1-DOF arm with inertia A = Jc1 + m1·lc1² + m2·l1² and joint-1 friction,
  solved with the suite's exact 1-DOF simulator (``ff_planner.model.arm1dof``): multistart
  least-squares on [q1(tf) − q1f, ∂q1(tf)/∂p_i] with the final stop kept strictly inside the
  zero-current coast (rest at tf that survives parameter changes, no kink at the nominal point);
* motor 2's current on each step is the midpoint of the reaction torque's range on that step,
  which maximises the stiction margin; the plan records how far joint-2 friction may drop before
  link 2 would slip (``extra['hold_fraction']``).

Every plan is then verified on the FULL 2-DOF simulation (``ff_planner.model.scara2``): final error,
both joints at rest at tf, and all 12 sensitivities by complex step (exact derivatives). Tasks in
which link 2 must move have no known truly robust plan (see docs/scara2-model.md): the planner
says so (NO_ROBUST_PLAN) and returns its least-worst-case-error plan labelled best_effort.

Units: rad, A, s. No rclpy here.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Optional

import numpy as np
from scipy.optimize import least_squares

from ff_planner.model import arm1dof, scara2
from ff_planner.model.params import Arm1DofParams, Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanRequest, PlanResult

Progress = Optional[Callable[[dict], None]]

STOP_MARGIN = 0.005      # s, final stop at least this far inside the coast (both ends)
HOLD_MIN = 0.25          # aim: joint 2 still holds with its friction 25 % lower
HOLD_FALLBACK = 0.1      # accepted when HOLD_MIN cannot be reached from a start
HOLD_LEVELS = (HOLD_FALLBACK,)   # margins asked for in turn by the continuation
STAGE2_NFEV = 40         # evaluations per continuation attempt (then abandon)
_FD_REL = 1e-5           # relative step of the inner central differences (1-DOF, smooth region)


def _is_pos(key: str) -> bool:
    """'q1/pc2' (position sensitivity), not 'qd1/pc2'."""
    return key.startswith("q") and not key.startswith("qd")


# ----------------------------------------------------------------------------------------------
# joint 1 as an exact 1-DOF problem


def joint1_params(p: Scara2Params) -> Arm1DofParams:
    """The 1-DOF arm that joint 1 is while link 2 is held still: J = A, joint-1 motor and friction."""
    return Arm1DofParams(J=scara2.held_joint1_inertia(p), kt=p.kt1, n=p.n1, i_max=p.i_max1,
                         pv=p.pv1, pc=p.pc1, pt=p.pt1)


def joint2_params(p: Scara2Params) -> Arm1DofParams:
    """The 1-DOF arm that link 2 is while joint 1 is held still: J = C, motor-2 and friction."""
    _, _, C = scara2.inertia_constants(p)
    return Arm1DofParams(J=C, kt=p.kt2, n=p.n2, i_max=p.i_max2, pv=p.pv2, pc=p.pc2, pt=p.pt2)


def _stop_speed(J: float, pv: float, pc: float, tau: float) -> float:
    """Speed (rad/s) at which zero current and friction stop the joint after exactly tau s."""
    a, b = pv / J, pc / J
    if abs(a) < 1e-12:
        return b * tau
    return b * (math.exp(a * tau) - 1.0) / a


class _Joint1Problem:
    """Residuals of the joint-1 problem on a uniform grid of N steps (currents are the unknowns)."""

    def __init__(self, p1: Arm1DofParams, q0: float, qf: float, tf: float, coast: float, N: int,
                 names: tuple[str, ...], p2: Optional[Scara2Params] = None, q2: float = 0.0,
                 hold_min: float = HOLD_MIN, samples: int = 24, held: int = 2,
                 zero_coast: bool = True):
        self.J, self.c = p1.J, p1.n * p1.kt
        self.fr = {"pv": p1.pv, "pc": p1.pc, "pt": p1.pt}
        self.q0, self.qf, self.tf, self.coast, self.N = q0, qf, tf, coast, N
        self.names = names
        self.times = np.linspace(0.0, tf - coast, N + 1)
        self.tN = float(self.times[-1])
        self.v_lo = _stop_speed(p1.J, p1.pv, p1.pc, STOP_MARGIN)
        self.v_hi = _stop_speed(p1.J, p1.pv, p1.pc, coast - STOP_MARGIN)
        self.seg = np.empty((0, 7))
        self.ev = np.empty((0, 3))
        self.i_max = p1.i_max
        self.p2 = p2
        if p2 is not None:   # sample grid for link 2's holding torque, one-sided inside each step
            self.q2, self.hold_min = q2, hold_min
            ends = np.append(self.times, tf)
            grids, idx = [], []
            for k in range(N + 1):
                g = np.linspace(ends[k], ends[k + 1], samples)
                g[0] += 1e-12
                g[-1] -= 1e-12
                grids.append(g)
                idx.append(np.full(samples, k))
            self.grid = np.concatenate(grids)
            self.gidx = np.concatenate(idx)
            self.starts_idx = np.arange(N + 1) * samples
            self.A, self.B, _ = scara2.inertia_constants(p2)
            # the held joint's motor and stiction (link 2 by default; joint 1 when link 2 moves)
            self.held, self.zero_coast = held, zero_coast
            if held == 2:
                self.K2, self.imax_h, self.pch, self.pth = p2.n2 * p2.kt2, p2.i_max2, p2.pc2, p2.pt2
            else:
                self.K2, self.imax_h, self.pch, self.pth = p2.n1 * p2.kt1, p2.i_max1, p2.pc1, p2.pt1
            self.rseg = np.zeros((3 * (N + 3) + 4, 7))
            self.rev = np.zeros((3 * (N + 3) + 4, 3))

    def hold(self, x: np.ndarray):
        """Per phase (N steps + coast): motor-2 torque (Nm) = midpoint of link 1's reaction and
        the hold fraction (unused stiction / stiction level) of link 2."""
        p2 = self.p2
        _, _, nseg, _ = arm1dof.sim_core(self.J, self.c, self.fr["pv"], self.fr["pc"],
                                         self.fr["pt"], self.times, x, self.tf, self.q0, 0.0,
                                         False, self.rseg, self.rev)
        qs, vs = arm1dof.eval_segments(self.rseg, min(nseg, self.rseg.shape[0]), self.grid)
        T1 = self.c * np.append(x, 0.0)[self.gidx]
        L1 = self.fr["pc"] + self.fr["pt"] * np.abs(T1)
        acc = np.where(vs != 0.0, (T1 - self.fr["pv"] * vs - np.sign(vs) * L1) / self.J,
                       np.where(np.abs(T1) > L1, (T1 - np.sign(T1) * L1) / self.J, 0.0))
        if self.held == 2:
            d = qs - self.q2
            R = self.B * np.cos(d) * acc - self.B * np.sin(d) * vs * vs
        else:
            d = self.q2 - qs
            R = self.B * np.cos(d) * acc + self.B * np.sin(d) * vs * vs
        rmin = np.minimum.reduceat(R, self.starts_idx)
        rmax = np.maximum.reduceat(R, self.starts_idx)
        T2 = np.clip(0.5 * (rmin + rmax), -self.K2 * self.imax_h, self.K2 * self.imax_h)
        if self.zero_coast:
            T2[-1] = 0.0
        L2 = self.pch + self.pth * np.abs(T2)
        frac = (L2 - np.maximum(T2 - rmin, rmax - T2)) / L2
        return T2, frac

    def _q(self, x, tend, pv, pc, pt):
        return arm1dof.sim_core(self.J, self.c, pv, pc, pt, self.times, x, tend, self.q0, 0.0,
                                False, self.seg, self.ev)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=float)
        pv, pc, pt = self.fr["pv"], self.fr["pc"], self.fr["pt"]
        qT, vT, _, _ = self._q(x, self.tf, pv, pc, pt)
        _, vN, _, _ = self._q(x, self.tN, pv, pc, pt)
        r = [qT - self.qf]
        for n in self.names:
            h = _FD_REL * abs(self.fr[n])
            fp = dict(self.fr); fp[n] += h
            fm = dict(self.fr); fm[n] -= h
            qp = self._q(x, self.tf, fp["pv"], fp["pc"], fp["pt"])[0]
            qm = self._q(x, self.tf, fm["pv"], fm["pc"], fm["pt"])[0]
            r.append((qp - qm) / (2.0 * h))
        s = abs(vN)
        r.append(10.0 * max(0.0, self.v_lo - s))
        r.append(10.0 * max(0.0, s - self.v_hi))
        if self.p2 is not None:
            _, frac = self.hold(x)
            r.extend(np.maximum(0.0, self.hold_min - frac))
        return np.array(r)

    def solve(self, x0: np.ndarray, max_nfev: int = 60):
        res = least_squares(self.residuals, x0, bounds=(-self.i_max, self.i_max), method="dogbox",
                            diff_step=1e-6, xtol=1e-15, ftol=1e-15, gtol=1e-15,
                            max_nfev=max_nfev)
        return res.x, res.fun, res.nfev


# ----------------------------------------------------------------------------------------------
# motor 2: cancel link 1's reaction step by step


def hold_torques(p: Scara2Params, held: int, profile: CurrentProfile, q_moving0: float,
                 q_held: float, samples_per_step: int = 200, zero_coast: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Torques (Nm) for the motor of the HELD joint (1 or 2) that keep it in stiction while the
    other joint runs ``profile`` (its 1-DOF currents; inertia A for joint 1, C for joint 2) from
    rest at ``q_moving0``: per phase (N steps, then the coast) the midpoint of the reaction's
    range, which maximises the margin. Returns (torques (N+1,), hold fractions (N+1,)): unused
    stiction / stiction level per phase (1 = unloaded, 0 = on the edge, < 0 = slips). With
    ``zero_coast`` the coast torque is 0 (the move's final coast)."""
    A, B, C = scara2.inertia_constants(p)
    if held == 2:
        pm = joint1_params(p)
        Kh, imax_h, pch, pth = p.n2 * p.kt2, p.i_max2, p.pc2, p.pt2
    else:
        pm = joint2_params(p)
        Kh, imax_h, pch, pth = p.n1 * p.kt1, p.i_max1, p.pc1, p.pt1
    Km = pm.n * pm.kt
    times = profile.step_times
    N = profile.n_steps
    seg = np.zeros((3 * (N + 3) + 4, 7))
    ev = np.zeros((3 * (N + 3) + 4, 3))
    cur = np.ascontiguousarray(profile.currents[:, 0], dtype=float)
    _, _, nseg, _ = arm1dof.sim_core(pm.J, Km, pm.pv, pm.pc, pm.pt, times, cur, profile.tf,
                                     float(q_moving0), 0.0, False, seg, ev)
    T = np.zeros(N + 1)
    frac = np.zeros(N + 1)
    for k in range(N + 1):
        t0, t1 = (times[k], times[k + 1]) if k < N else (times[N], profile.tf)
        Tm = Km * cur[k] if k < N else 0.0
        tg = np.linspace(t0, t1, samples_per_step)
        tg[0] += 1e-12          # one-sided limits inside the phase
        tg[-1] -= 1e-12
        qs, vs = arm1dof.eval_segments(seg, min(nseg, seg.shape[0]), tg)
        Lm = pm.pc + pm.pt * abs(Tm)
        acc = np.where(vs != 0.0, (Tm - pm.pv * vs - np.sign(vs) * Lm) / pm.J, 0.0)
        if abs(Tm) > Lm:        # passing through zero velocity under a breakaway torque
            acc = np.where(vs == 0.0, (Tm - math.copysign(Lm, Tm)) / pm.J, acc)
        if held == 2:           # link 2 held: H2 = T2 - (B c a1 - B s v1^2), d = q1 - q2
            d = qs - q_held
            R = B * np.cos(d) * acc - B * np.sin(d) * vs * vs
        else:                   # joint 1 held: H1 = T1 - (B c a2 + B s v2^2), d = q1 - q2
            d = q_held - qs
            R = B * np.cos(d) * acc + B * np.sin(d) * vs * vs
        if k == N and zero_coast:
            Th = 0.0
        else:
            Th = float(np.clip(0.5 * (R.min() + R.max()), -Kh * imax_h, Kh * imax_h))
        L = pch + pth * abs(Th)
        T[k] = Th
        frac[k] = (L - np.max(np.abs(Th - R))) / L
    return T, frac


def joint2_hold_currents(p: Scara2Params, profile1: CurrentProfile, q0: np.ndarray,
                         samples_per_step: int = 200) -> tuple[np.ndarray, float]:
    """Motor-2 currents (A, one per step) that keep link 2 (absolute angle q0[1]) in stiction
    while joint 1 runs ``profile1`` (joint-1 currents only) to the end of the move (zero current
    in the coast), and the smallest hold fraction over the move."""
    T, frac = hold_torques(p, 2, profile1, float(q0[0]), float(q0[1]), samples_per_step)
    return T[:-1] / (p.n2 * p.kt2), float(frac.min())


# ----------------------------------------------------------------------------------------------
# verification on the full model


def verify_plan(p: Scara2Params, profile: CurrentProfile, q0, qf, names=scara2.FRICTION_NAMES,
                finite=(0.1, 0.4)) -> dict:
    """Full 2-DOF check of a plan: final state, 12 complex-step sensitivities, and the final
    (rest) position error when each friction parameter is off by ±finite fractions."""
    q0 = np.asarray(q0, float)
    qf = np.asarray(qf, float)
    sim = scara2._simulate_raw(p, profile, q0, np.zeros(2), settle=True)
    sens = scara2.sensitivities_scara2(p, profile, q0, names, method="complex")
    worst = {}
    for f in finite:
        w = 0.0
        for n in names:
            for sgn in (1.0, -1.0):
                pp = p.replace(**{n: getattr(p, n) * (1.0 + sgn * f)})
                r = scara2._simulate_raw(pp, profile, q0, np.zeros(2), settle=True)
                w = max(w, float(np.max(np.abs(r.q_rest - qf))))
        worst[f"{int(round(f * 100))}%"] = w
    return {
        "q_final": sim.q_f, "qd_final": sim.qd_f, "q_rest": sim.q_rest,
        "error": float(np.max(np.abs(sim.q_f - qf))),
        "at_rest": bool(sim.stuck_tf[0] and sim.stuck_tf[1]),
        "sensitivities": {k: v for k, v in sens.items() if _is_pos(k)},
        "max_sensitivity": max(abs(v) for k, v in sens.items() if _is_pos(k)),
        "worst_rest_error_one_at_a_time": worst,
    }


# ----------------------------------------------------------------------------------------------
# the planner


def _result(request: PlanRequest, p: Scara2Params, **kw) -> PlanResult:
    base = dict(success=False, message="", profile=None, model="scara2", params=p,
                q0=np.asarray(request.q0, float), qf=np.asarray(request.qf, float),
                uncertain=list(request.uncertain), objective=request.objective)
    base.update(kw)
    return PlanResult(**base)


def plan_robust_scara2(request: PlanRequest, progress: Progress = None) -> PlanResult:
    """Robust 2-DOF plan: every |∂q_j(tf)/∂p_i| ≤ tol (true derivatives), |q(tf) − qf| ≤ tol,
    both joints at rest at tf; verified on the full 2-DOF simulation.

    Returns success with the plan, or NO_ROBUST_PLAN / TIME_BUDGET_EXHAUSTED with the best plan
    found labelled ``best_effort``. ``progress`` gets dicts like {"stage": "joint1",
    "starts_done": 12, "best": 3e-4, "elapsed": 0.4}. ``request.starts`` bounds the number of
    continuations (the costly step); joint-1 starts are cheap and run within the time budget.
    """
    t_start = time.perf_counter()
    request.validate()
    p = request.resolved_params()
    if not isinstance(p, Scara2Params):
        raise PlanningError("plan_robust_scara2 needs a scara2 request")
    q0 = np.asarray(request.q0, float)
    qf = np.asarray(request.qf, float)
    tol = float(request.tol)
    N = request.n_steps()
    deadline = t_start + float(request.time_budget)
    names = tuple(request.uncertain)

    if abs(qf[1] - q0[1]) > 0.0:
        return _plan_link2_moving(request, p, progress, t_start)

    names1 = tuple(n[:-1] for n in names if n.endswith("1"))
    p1 = joint1_params(p)
    args = (p1, float(q0[0]), float(qf[0]), float(request.tf), float(request.coast), N, names1)
    prob = _Joint1Problem(*args)                       # stage 1: joint 1 robust, rest in coast
    holds = [_Joint1Problem(*args, p2=p, q2=float(q0[1]), hold_min=h)  # stage 2: + link 2 held
             for h in HOLD_LEVELS]
    rng = np.random.default_rng(request.seed)
    best = None          # (score, profile, verification)
    best_cost = math.inf
    starts = 0
    iters = 0
    candidates = 0
    cprob = _compiled_joint1(p1, q0, qf, request, N, names1)
    found = False
    turn = 0
    # request.starts bounds the expensive part, the continuations from joint-1 robust solutions
    # (each a "start" of the 2-DOF search); cheap joint-1 starts run until the time budget
    while candidates < request.starts and time.perf_counter() < deadline and not found:
        turn += 1
        # alternate two sources of joint-1 robust solutions: robust1d's compiled exact-Jacobian
        # LM (16 fast starts, full current range) and a scipy start (slower, but its solutions
        # reach a held link 2 more often)
        if cprob is not None and (JOINT1_SOURCE == "compiled"
                                  or (JOINT1_SOURCE == "both" and turn % 2 == 0)):
            m = CHUNK
            block = rng.uniform(-p1.i_max, p1.i_max, (m, N))
            try:
                ends = cprob(block)
            except Exception:  # robust1d changed under us: use the scipy path
                cprob = None
                continue
            starts += len(ends)
            iters += sum(e["iterations"] for e in ends)
            best_cost = min([best_cost] + [e["residual2"] for e in ends])
            xs = [e["currents"] for e in ends if e["ok"]]
        else:                      # fallback: scipy least squares on arm1dof (FD Jacobians)
            starts += 1
            x, fun, nfev = prob.solve(rng.uniform(-0.8, 0.8, N) * p1.i_max)
            iters += nfev
            cost = float(np.max(np.abs(fun)))
            best_cost = min(best_cost, cost)
            xs = [x] if cost <= 0.1 * tol else []
        if progress:
            progress({"stage": "joint1", "starts_done": starts, "best": best_cost,
                      "candidates": candidates + len(xs),
                      "elapsed": time.perf_counter() - t_start})
        for x in xs:
            if time.perf_counter() >= deadline or candidates >= request.starts:
                break
            candidates += 1
            # continuation along the solution set (4 spare dimensions at N = 8) until motor 2 can
            # hold link 2 with margin: first asking for HOLD_MIN, else HOLD_FALLBACK
            for hp in holds:
                x2, fun2, nfev2 = hp.solve(x, max_nfev=STAGE2_NFEV)
                iters += nfev2
                if float(np.max(np.abs(fun2))) <= 0.1 * tol:
                    x = x2
                    break
            prof1 = CurrentProfile(prob.times, x.reshape(-1, 1), request.tf, request.coast)
            I2, frac = joint2_hold_currents(p, prof1, q0)
            profile = CurrentProfile(prob.times, np.column_stack([x, I2]), request.tf, request.coast)
            if frac <= 0.0:
                continue
            sim = scara2._simulate_raw(p, profile, q0, np.zeros(2))
            sens = scara2.sensitivities_scara2(p, profile, q0, names, method="complex")
            smax = max(abs(v) for k, v in sens.items() if _is_pos(k))
            err = float(np.max(np.abs(sim.q_f - qf)))
            ok = err <= tol and smax <= tol and sim.stuck_tf[0] and sim.stuck_tf[1]
            score = (0 if ok else 1, -frac if ok else smax + err)
            if best is None or score < best[0]:
                best = (score, profile, sim, sens, frac)
            if progress:
                progress({"stage": "verify", "starts_done": starts, "robust": ok,
                          "hold_fraction": frac, "max_sensitivity": smax, "error": err,
                          "elapsed": time.perf_counter() - t_start})
            if ok:      # frac >= HOLD_FALLBACK > 0 here: first verified robust plan wins
                found = True
                break
    elapsed = time.perf_counter() - t_start
    if best is None:
        code = "TIME_BUDGET_EXHAUSTED" if time.perf_counter() >= deadline else "NO_ROBUST_PLAN"
        return _result(request, p, message=(
            f"no robust plan with N = {N} steps per joint after {starts} joint-1 starts and "
            f"{candidates} continuations (best joint-1 residual {best_cost:.3g}); try a larger "
            f"time budget, more starts, more steps or a longer tf"),
            error_code=code, starts_tried=starts, iterations=iters, solve_time=elapsed)
    (ok_flag, _), profile, sim, sens, frac = best
    robust = ok_flag == 0
    refined = None
    if robust and request.objective == "robust-sampled" and names1:
        refined = _refine(request, p, holds[0], profile, names, names1, deadline, progress,
                          t_start)
        if refined is not None:
            profile, sim, sens, frac = refined
    elapsed = time.perf_counter() - t_start
    msg = (f"robust plan: joint 2 held by stiction (holds down to {100 * (1 - frac):.0f} % "
           f"of nominal joint-2 friction), max |dq/dp| = "
           f"{max(abs(v) for k, v in sens.items() if _is_pos(k)):.2g}")
    if not robust:
        msg = "best plan found is NOT robust to the tolerance: " + msg.split(": ", 1)[1]
    return _result(
        request, p, success=robust, robust=robust, best_effort=not robust,
        error_code="OK" if robust else "NO_ROBUST_PLAN", message=msg, profile=profile,
        q_final=sim.q_f, qd_final=sim.qd_f,
        sensitivities={k: v for k, v in sens.items() if _is_pos(k)},
        starts_tried=starts, iterations=iters, solve_time=elapsed,
        extra={"method": "hold-link2", "hold_fraction": frac, "candidates": candidates,
               "joint1_inertia": p1.J, "sampled_refinement": refined is not None})


def _refine(request, p, hp, profile, names, names1, deadline, progress, t_start):
    """robust-sampled: spend the spare freedom on smaller finite-change errors; returns
    (profile, sim, sens, frac) of the refined plan if it still verifies, else None."""
    from ff_planner.optimize.robust2d_refine import refine_sampled

    q0 = np.asarray(request.q0, float)
    qf = np.asarray(request.qf, float)
    x = refine_sampled(hp, profile.currents[:, 0].copy(), names1, deadline, request.tol)
    if x is None:
        return None
    prof1 = CurrentProfile(profile.step_times, x.reshape(-1, 1), request.tf, request.coast)
    I2, frac = joint2_hold_currents(p, prof1, q0)
    new = CurrentProfile(profile.step_times, np.column_stack([x, I2]), request.tf, request.coast)
    sim = scara2._simulate_raw(p, new, q0, np.zeros(2))
    sens = scara2.sensitivities_scara2(p, new, q0, names, method="complex")
    smax = max(abs(v) for k, v in sens.items() if _is_pos(k))
    ok = (float(np.max(np.abs(sim.q_f - qf))) <= request.tol and smax <= request.tol
          and all(sim.stuck_tf) and frac > 0.0)
    if progress:
        progress({"stage": "refine-sampled", "robust": ok, "hold_fraction": frac,
                  "elapsed": time.perf_counter() - t_start})
    return (new, sim, sens, frac) if ok else None


CHUNK = 16   # joint-1 starts per compiled call (budget checked between calls)
JOINT1_SOURCE = "compiled"   # "compiled" (robust1d's LM), "scipy", or "both" (alternating)


def _compiled_joint1(p1: Arm1DofParams, q0, qf, request: PlanRequest, N: int, names1):
    """robust1d's compiled solver for joint 1 (``robust1d.solve_block``): a callable taking an
    (M, N) block of starts and returning the end points; None if unavailable."""
    try:
        from functools import partial

        from ff_planner.optimize.robust1d import solve_block

        return partial(solve_block, p1, float(q0[0]), float(qf[0]), float(request.tf),
                       tuple(names1), coast=float(request.coast), tol=float(request.tol))
    except Exception:  # pragma: no cover - robust1d missing or incompatible
        return None


def _plan_link2_moving(request: PlanRequest, p: Scara2Params, progress: Progress,
                       t_start: float) -> PlanResult:
    """Link 2 must move. First one joint at a time, each an exact robust 1-DOF problem with the
    other joint held by stiction (``_robust2d_sequential``, up to half the budget); failing that,
    the least-worst-case plan over one-at-a-time ±10 % friction changes, labelled best_effort."""
    from ff_planner.optimize.robust2d_least_worst import plan_least_worst
    from ff_planner.optimize.robust2d_sequential import plan_sequential

    half = t_start + 0.5 * float(request.time_budget)
    res = plan_sequential(request, p, progress, t_start, half)
    if res is not None:
        return res
    return plan_least_worst(request, p, progress, t_start)


def warm_up() -> float:
    """Compile/load every kernel the 2-DOF planner uses (scara2, arm1dof, robust1d's solver)
    by planning a short task; returns the seconds it took. For install time or node start."""
    t = time.perf_counter()
    scara2.warm_up()
    req = PlanRequest(model="scara2", q0=(-0.5, 0.0), qf=(0.5, 0.0), tf=1.0,
                      uncertain=scara2.FRICTION_NAMES, starts=32, seed=0, time_budget=600)
    plan_robust_scara2(req)
    return time.perf_counter() - t
