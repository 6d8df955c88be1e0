"""Arms from a URDF: robust-box for the 3-DOF horizontal arm (config/arms/arm3h), all three
joints moving; prints JSON (and writes it with --out).

Per task: plan time (the first plan in a fresh process: "cold", numba kernels loaded from their
on-disk cache; the time to load the URDF and fit its dynamics reported apart), the label
(zero-derivative / least-worst), the first-order worst per joint, the certificate (worst rest
error, per joint, per parameter, excursion), and with --check the independent re-simulation
(``ff_planner.arm.reference``: Pinocchio dynamics, DOP853) at --check fresh box points: the
largest joint error and its ratio to the certificate's. Also a baseline: the plan that only puts
the nominal rest on the goal (the start of the robust search), certified the same way. The load
average (1 min) is recorded at start and end.

Derivatives (``derivatives``): the planner's derivatives from Pinocchio's analytical RNEA
derivatives (``ff_planner.arm.sensitivity``, the default) against the earlier complex-step scheme
(``derivatives="complex-step"``: k complex simulations for ∂rest/∂p, forward differences in the
currents), CPU seconds (process time) of: one evaluation of ∂rest/∂p and ∂rest/∂x at the plan,
the Jacobian of the robust residual, the goal stage from the same start (to convergence), and a
whole plan with the same budget (``--compare``, default on), with the plan's first-order and
certified worst for each.

Usage: nice -n 5 .venv/bin/python benchmarks/bench_urdf_arm3h.py [--budget 30] [--check 100]
       [--out benchmarks/results/urdf_arm3h.json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ROBUST_NFEV = 25      # residual evaluations of the fixed-work robust-stage comparison


def _cpu(fn, repeat: int = 1) -> tuple[float, object]:
    c = time.process_time()
    for _ in range(repeat):
        r = fn()
    return (time.process_time() - c) / repeat, r


def _derivatives(arm, res, q0: np.ndarray, qf: np.ndarray, args, cpu_plan: float) -> dict:
    """CPU time of the planner's derivatives, Pinocchio forward sensitivities vs complex step."""
    import math

    from scipy.optimize import least_squares

    from ff_planner.armplan import robust_box as rb
    from ff_planner.armplan.robust_box import plan_box_robust_arm
    N = int(res.profile.n_steps)
    n = arm.n
    x = np.asarray(res.profile.currents, float).ravel()
    probs = {m: rb._Problem(arm, q0, qf, args.tf, float(res.profile.coast), N, None, math.inf, m)
             for m in ("pinocchio", "complex-step")}
    out: dict = {"n_currents": N * n, "k_uncertain": probs["pinocchio"].spec.k,
                 "substep_s": rb.PLAN_H}

    def fresh(m: str):
        p = probs[m]
        p._cache.clear()
        return p

    # one evaluation of rest, ∂rest/∂p and ∂rest/∂x at the plan
    t_an, _ = _cpu(lambda: (fresh("pinocchio").rest_and_sens(x), probs["pinocchio"].rest_jac(x)), 5)

    def cs_eval():
        p = probs["complex-step"]
        rest, S = p.rest_and_sens(x)
        J = np.zeros((n, x.size))
        for c in range(x.size):
            xe = x.copy()
            dx = rb.DIFF_STEP * max(1.0, abs(x[c]))
            xe[c] += dx
            J[:, c] = (p.rest(xe) - rest) / dx
        return J

    t_cs, _ = _cpu(cs_eval, 2)
    out["rest_and_first_derivatives_cpu_s"] = {"pinocchio": t_an, "complex_step_and_differences": t_cs}
    # the robust residual's Jacobian (N·n columns)
    t_jan, _ = _cpu(lambda: fresh("pinocchio").full_jac(x), 2)

    def cs_jac():
        p = probs["complex-step"]
        r0 = p.full_residual(x)
        for c in range(x.size):
            xe = x.copy()
            xe[c] += rb.DIFF_STEP * max(1.0, abs(x[c]))
            p.full_residual(xe)
        return r0

    t_jcs, _ = _cpu(cs_jac, 1)
    out["robust_residual_jacobian_cpu_s"] = {"pinocchio": t_jan, "complex_step_forward_differences": t_jcs}
    # the goal stage from the same start, to convergence
    bounds = (-np.tile(arm.i_max, N), np.tile(arm.i_max, N))
    x0 = rb._bang_bang(arm, q0, qf, N, args.tf - float(res.profile.coast))
    goal = {}
    for m in ("pinocchio", "complex-step"):
        p = fresh(m)
        c = time.process_time()
        r = least_squares(p.goal_residual, x0, jac=p.goal_jac if m == "pinocchio" else "2-point",
                          bounds=bounds, method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12,
                          diff_step=rb.DIFF_STEP, max_nfev=60 * N * n)
        goal[m] = {"cpu_s": time.process_time() - c, "nfev": int(r.nfev), "njev": int(r.njev),
                   "max_goal_error_rad": float(np.max(np.abs(r.fun)))}
    out["goal_stage_from_the_same_start"] = goal
    # the robust stage from the same goal-solved currents, a fixed number of evaluations (CPU
    # time and the first-order worst reached do not depend on the machine's load, unlike a plan
    # with a wall-clock budget)
    xg = least_squares(fresh("pinocchio").goal_residual, x0, jac=probs["pinocchio"].goal_jac,
                       bounds=bounds, method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12).x
    robust = {}
    for m in ("pinocchio", "complex-step"):
        p = fresh(m)
        p.best = (math.inf, None)
        c = time.process_time()
        r = least_squares(p.full_residual, xg, jac=p.full_jac if m == "pinocchio" else "2-point",
                          bounds=bounds, method="trf", xtol=1e-10, ftol=1e-12, gtol=1e-12,
                          diff_step=rb.DIFF_STEP, x_scale=np.tile(arm.i_max, N),
                          max_nfev=ROBUST_NFEV)
        robust[m] = {"cpu_s": time.process_time() - c, "nfev": int(r.nfev), "njev": int(r.njev),
                     "first_order_worst_rad": float(p.best[0])}
    out["robust_stage_fixed_evaluations"] = dict(robust, max_nfev=ROBUST_NFEV)
    plans = {"note": "wall-clock budget: the CPU time each plan got depends on the load",
             "pinocchio": {"cpu_s": cpu_plan, "label": res.label,
                           "first_order_worst_per_joint": res.first_order.tolist(),
                           "certified_worst_per_joint": res.certificate.worst_per_joint
                           if res.certificate else None}}
    if not args.no_compare:
        c = time.process_time()
        t = time.perf_counter()
        r2 = plan_box_robust_arm(arm, q0, qf, args.tf, time_budget=args.budget, seed=args.seed,
                                 derivatives="complex-step")
        plans["complex-step"] = {"cpu_s": time.process_time() - c, "wall_s": time.perf_counter() - t,
                                 "label": r2.label, "first_order_worst_per_joint": r2.first_order.tolist(),
                                 "certified_worst_per_joint": r2.certificate.worst_per_joint
                                 if r2.certificate else None}
    out["whole_plan_same_budget"] = plans
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget", type=float, default=30.0)
    ap.add_argument("--check", type=int, default=100, help="fresh box points re-simulated independently")
    ap.add_argument("--tf", type=float, default=1.5)
    ap.add_argument("--qf", default="0.5,-0.4,0.6")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="")
    ap.add_argument("--no-compare", action="store_true", help="skip the complex-step plan")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    from ff_planner.arm import sim
    from ff_planner.arm.model import load_arm
    from ff_planner.arm import reference
    from ff_planner.arm.reference import reference_rest
    from ff_planner.armplan.certificate import BoxSpec, certify_arm
    from ff_planner.armplan.robust_box import plan_box_robust_arm
    t_import = time.perf_counter() - t
    t = time.perf_counter()
    arm = load_arm(REPO / "config" / "arms" / "arm3h.cell.yaml")
    t_load = time.perf_counter() - t
    q0 = np.zeros(3)
    qf = np.array([float(v) for v in args.qf.split(",")])
    t = time.perf_counter()
    c0 = time.process_time()
    res = plan_box_robust_arm(arm, q0, qf, args.tf, time_budget=args.budget, seed=args.seed)
    t_plan = time.perf_counter() - t
    cpu_plan = time.process_time() - c0
    worst_cert = res.certificate.worst_rest_error if res.certificate else None
    print(f"plan {t_plan:.1f} s, {res.label}, certificate {worst_cert}", file=sys.stderr, flush=True)
    out: dict = {
        "task": {"arm": "config/arms/arm3h.cell.yaml", "q0": q0.tolist(), "qf": qf.tolist(), "tf": args.tf,
                 "coast": float(res.profile.coast), "steps_per_joint": int(res.profile.n_steps),
                 "uncertain": list(res.box_names), "box": "±20 % each", "time_budget_s": args.budget},
        "import_s": t_import, "load_urdf_and_fit_s": t_load, "plan_time_cold_s": t_plan,
        "plan_cpu_s": cpu_plan, "derivatives_used": "pinocchio",
        "plan": res.to_dict(),
    }
    out["derivatives"] = _derivatives(arm, res, q0, qf, args, cpu_plan)
    # baseline: the goal-only plan (first stage of the search), same certificate
    from scipy.optimize import least_squares

    from ff_planner.armplan.robust_box import DIFF_STEP, _start
    N = res.profile.n_steps
    x = _start(arm, q0, qf, N, args.tf, float(res.profile.coast), args.seed)
    bounds = (-np.tile(arm.i_max, N), np.tile(arm.i_max, N))

    def goal(v: np.ndarray) -> np.ndarray:
        from ff_planner.model.profile import CurrentProfile
        p = CurrentProfile.uniform(v.reshape(N, 3), args.tf, float(res.profile.coast))
        return sim.rest_position(arm, p, q0) - qf

    xb = least_squares(goal, x, bounds=bounds, diff_step=DIFF_STEP, xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    from ff_planner.model.profile import CurrentProfile
    pb = CurrentProfile.uniform(xb.reshape(N, 3), args.tf, float(res.profile.coast))
    cb = certify_arm(arm, pb, q0, qf)
    out["baseline_goal_only"] = {"worst_rest_error": cb.worst_rest_error, "worst_per_joint": cb.worst_per_joint}
    if args.check > 0:
        spec = BoxSpec.of(arm)
        rows = np.random.default_rng(99_001).uniform(-1.0, 1.0, (args.check, spec.k))
        worst = np.zeros(3)
        agree = 0.0
        t = time.perf_counter()
        for i, s in enumerate(spec.scales(arm, rows)):
            ref, _ = reference_rest(arm, res.profile, q0, friction_scale=s)
            worst = np.maximum(worst, np.abs(ref - qf))
            if i < 10:
                mine = sim.rest_position(arm, res.profile, q0, friction_scale=s)
                agree = max(agree, float(np.max(np.abs(mine - ref))))
        cert = res.certificate
        assert cert is not None
        out["independent_check"] = {
            "points": args.check, "seed": 99_001,
            "simulator": f"Pinocchio CRBA/RNEA + scipy DOP853 (rtol {reference.RTOL:g})",
            "worst_per_joint": worst.tolist(), "worst": float(worst.max()),
            "ratio_to_certificate_per_joint": (worst / np.array(cert.worst_per_joint)).tolist(),
            "compiled_vs_reference_max_abs_rad_first10": agree, "seconds": time.perf_counter() - t}
    out["load_average_1min"] = {"start": load0, "end": os.getloadavg()[0]}
    text = json.dumps(out, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
